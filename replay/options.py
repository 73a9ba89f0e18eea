"""The typed options a recorded-log reader takes, each a small frozen dataclass shared where its meaning is shared.

A :class:`~online_backlash.replay.formats.LogFormat` names the option types its reader takes; the CLI builds
those (and only those) from its arguments, and :meth:`ReaderOption.kwargs` gives each one's keyword arguments
of the reader. An option left at None is the reader's default (sniffed, learnt or read from the file).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any


class ReaderOption:
    """One group of reader options: :meth:`kwargs` are its keyword arguments of a reader."""

    def kwargs(self) -> dict[str, Any]:
        """The reader's keyword arguments this option sets."""
        raise NotImplementedError


@dataclass(frozen=True)
class Columns(ReaderOption):
    """Role (``time``, ``motor``, ``load``, ``torque``) -> the file's column or channel name (None: by role)."""

    columns: dict[str, str] | None = None

    def kwargs(self) -> dict[str, Any]:
        return {"columns": self.columns}


@dataclass(frozen=True)
class Units(ReaderOption):
    """The motor and load angles' unit (``deg``, ``rad``, ``rev``, ``arcmin``, ``counts``; None: the file's own)."""

    units: str | None = None

    def kwargs(self) -> dict[str, Any]:
        return {"units": self.units}


@dataclass(frozen=True)
class Counts(ReaderOption):
    """Encoder counts per revolution of the motor (on its own shaft) and of the load (with ``counts`` units)."""

    motor_cpr: float | None = None
    load_cpr: float | None = None

    def kwargs(self) -> dict[str, Any]:
        return {"motor_cpr": self.motor_cpr, "load_cpr": self.load_cpr}


@dataclass(frozen=True)
class WholeCounts(Counts):
    """Counts per revolution as whole counts, as a CAN decoder takes them (a fraction is cut off)."""

    def kwargs(self) -> dict[str, Any]:
        return {k: None if v is None else int(v) for k, v in super().kwargs().items()}


@dataclass(frozen=True)
class BadRows(ReaderOption):
    """Malformed rows, frames or records counted and skipped (True) or the end of the read (False)."""

    skip_bad: bool = False

    def kwargs(self) -> dict[str, Any]:
        return {"skip_bad": self.skip_bad}


@dataclass(frozen=True)
class Pace(ReaderOption):
    """A CAN log or serial capture replayed at its recorded pace (True) or as fast as it is read."""

    realtime: bool = False

    def kwargs(self) -> dict[str, Any]:
        return {"realtime": self.realtime}


@dataclass(frozen=True)
class Timing(ReaderOption):
    """The nominal sample period, s, for gap detection (None: learnt from the first steps)."""

    period_s: float | None = None

    def kwargs(self) -> dict[str, Any]:
        return {} if self.period_s is None else {"period_s": self.period_s}


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


@dataclass(frozen=True)
class SerialFraming(ReaderOption):
    """How a serial capture's bytes are framed: ``ascii`` lines or ``binary`` COBS frames (required to read one)."""

    serial_format: str | None = None

    def kwargs(self) -> dict[str, Any]:
        return {"serial_format": self.serial_format}


@dataclass(frozen=True)
class Canopen:
    """A CANopen drive's angles: the motor node's EDS/DCF and node-ID, and where the load angle is
    (:meth:`~online_backlash.codecs.canopen.CanopenLayout.from_files`)."""

    eds: str | os.PathLike[str]
    node: int
    load_node: int | None = None
    load_eds: str | os.PathLike[str] | None = None
    load_subindex: int | None = None


@dataclass(frozen=True)
class CanDecoding(ReaderOption):
    """How CAN frames become angles: a DBC's signals (:class:`~online_backlash.codecs.dbc.DbcDecoder`) or, given
    ``canopen``, a CANopen drive's object dictionary; ``max_skew_s`` pairs the motor and load frames
    (:class:`~online_backlash.codecs.pairing.FramePipeline`; None: its default)."""

    dbc: Any = None
    motor_signal: str | None = None
    load_signal: str | None = None
    counter_signal: str | None = None
    checksum_signal: str | None = None
    units: str | None = None
    wrap_deg: Any = None
    max_skew_s: float | None = None
    canopen: Canopen | None = None

    def kwargs(self) -> dict[str, Any]:
        skew = {} if self.max_skew_s is None else {"max_skew_s": self.max_skew_s}
        if self.canopen is not None:
            c = self.canopen
            where = {"load_node": c.load_node, "load_eds": c.load_eds, "load_subindex": c.load_subindex}
            return {"eds": c.eds, "node": c.node, **where} | skew
        return skew | {
            "dbc": self.dbc, "motor_signal": self.motor_signal, "load_signal": self.load_signal,
            "counter_signal": self.counter_signal, "checksum_signal": self.checksum_signal, "units": self.units,
            "wrap_deg": self.wrap_deg,
        }  # fmt: skip
