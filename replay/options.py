"""The typed options a recorded-log reader takes, each a small frozen dataclass shared where its meaning is shared.

A :class:`~online_backlash.replay.formats.LogFormat` names the option types its reader takes; the CLI builds
those (and only those) from its arguments, and :meth:`ReaderOption.kwargs` gives each one's keyword arguments
of the reader. An option left at None is the reader's default (sniffed, learnt or read from the file).
The options the frame rules take too (CAN decoding, counts per revolution, timing, serial framing) are declared in
:mod:`online_backlash.codecs.options`, which the live sources share, and named here with the rest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from online_backlash.codecs.options import (
    CanDecoding,
    Canopen,
    Counts,
    FrameRules,
    ReaderOption,
    SerialFraming,
    Timing,
    WholeCounts,
)

__all__ = [
    "BadRows", "CanDecoding", "Canopen", "Columns", "Counts", "CsvDialect", "FrameRules", "Pace", "ReaderOption",
    "SerialFraming", "Timing", "Units", "WholeCounts",
]  # fmt: skip


@dataclass(frozen=True)
class Columns(ReaderOption):
    """Role (``time``, ``motor``, ``load``, ``torque``) -> the file's column or channel name (None: by role)."""

    columns: dict[str, str] | None = None


@dataclass(frozen=True)
class Units(ReaderOption):
    """The motor and load angles' unit (``deg``, ``rad``, ``rev``, ``arcmin``, ``counts``; None: the file's own)."""

    units: str | None = None


@dataclass(frozen=True)
class BadRows(ReaderOption):
    """Malformed rows, frames or records counted and skipped (True) or the end of the read (False)."""

    skip_bad: bool = False


@dataclass(frozen=True)
class Pace(ReaderOption):
    """A CAN log or serial capture replayed at its recorded pace (True) or as fast as it is read."""

    realtime: bool = False


@dataclass(frozen=True)
class CsvDialect(ReaderOption):
    """What the user says of a CSV's text: field separator, decimal mark, comment character, encoding (None: sniffed,
    :func:`~online_backlash.replay.csv.sniff_dialect`)."""

    delimiter: str | None = None
    decimal: str | None = None
    comment: str | None = None
    encoding: str | None = None

    def kwargs(self) -> dict[str, Any]:
        given = {
            "delimiter": self.delimiter,
            "decimal": self.decimal,
            "comment": self.comment,
            "encoding": self.encoding,
        }
        return {k: v for k, v in given.items() if v is not None}
