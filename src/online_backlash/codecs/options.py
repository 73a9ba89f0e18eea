"""The options of the frame rules, each a small frozen dataclass declared once (issue 29): how CAN frames become
angles (:class:`CanDecoding`), encoder counts per revolution (:class:`Counts`), the frames' timing and strictness
(:class:`FrameRules`).

The recorded-log readers (:mod:`online_backlash.replay`: ``CanLog``, ``CanopenLog``, ``SerialCapture``) and the live
sources (:mod:`online_backlash.drivers`: ``CanSource``, ``CanopenSource``, ``SerialSource``) take these objects, so
an option is declared here and nowhere else. :func:`gather_options` makes them of the flat keyword arguments that
:func:`~online_backlash.replay.registry.open_log` takes for every format (each option by its field's name).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from online_backlash.errors import InvalidParameterError
from online_backlash.stream import MAX_SKEW_S

if TYPE_CHECKING:
    from .canopen import CanopenLayout
    from .dbc import DbcDecoder

#: How a serial capture's or port's bytes are framed (:mod:`~online_backlash.codecs.serialframes`).
SERIAL_FORMATS = ("ascii", "binary")


class ReaderOption:
    """One group of reader options: :meth:`kwargs` are its keyword arguments of a reader
    (:meth:`~online_backlash.replay.formats.LogFormat.reader_kwargs`)."""

    def kwargs(self) -> dict[str, Any]:
        """The reader's keyword arguments this option sets: by default each of its fields by its own name (an
        option whose reader takes them otherwise says how)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}  # type: ignore[arg-type]

    @classmethod
    def take_from(cls, flat: dict[str, Any]) -> Any:
        """The option made of the keyword arguments in ``flat`` named by its fields (taken out of ``flat``);
        a field not given keeps its default."""
        return cls(**{f.name: flat.pop(f.name) for f in fields(cls) if f.name in flat})  # type: ignore[arg-type]


@dataclass(frozen=True)
class Counts(ReaderOption):
    """Encoder counts per revolution of the motor (on its own shaft) and of the load (with ``counts`` units; None:
    from the file, the DBC or the drive's dictionary)."""

    motor_cpr: float | None = None
    load_cpr: float | None = None


@dataclass(frozen=True)
class WholeCounts(Counts):
    """Counts per revolution as whole counts, as a CAN decoder takes them (a fraction is cut off)."""

    def kwargs(self) -> dict[str, Any]:
        return {k: None if v is None else int(v) for k, v in super().kwargs().items()}


@dataclass(frozen=True)
class Timing(ReaderOption):
    """The nominal sample period, s, for gap detection (None: learnt from the first steps)."""

    period_s: float | None = None

    def kwargs(self) -> dict[str, Any]:
        return {} if self.period_s is None else {"period_s": self.period_s}


@dataclass(frozen=True)
class FrameRules(Timing):
    """The frame rules' timing (:class:`Timing`'s ``period_s``; with a frame counter, sample times are the first
    time plus counter periods) and ``strict``: a corrupt frame raises
    :class:`~online_backlash.errors.FrameError` instead of being counted and skipped."""

    strict: bool = False

    def kwargs(self) -> dict[str, Any]:
        return super().kwargs() | {"strict": self.strict}


#: Counts per revolution from the source (the file, the DBC, the drive's dictionary).
DEFAULT_COUNTS = Counts()
#: The period learnt, corrupt frames counted and skipped.
DEFAULT_FRAMES = FrameRules()


@dataclass(frozen=True)
class SerialFraming(ReaderOption):
    """How a serial capture's bytes are framed: ``ascii`` lines or ``binary`` COBS frames (required to read one)."""

    serial_format: str | None = None


@dataclass(frozen=True)
class Canopen(ReaderOption):
    """A CANopen drive's angles: the motor node's EDS/DCF and node-ID, and where the load angle is
    (:meth:`~online_backlash.codecs.canopen.CanopenLayout.from_files`)."""

    eds: str | os.PathLike[str]
    node: int
    load_node: int | None = None
    load_eds: str | os.PathLike[str] | None = None
    load_subindex: int | None = None


@dataclass(frozen=True)
class CanDecoding(ReaderOption):
    """How CAN frames become angles: a DBC's signals (:class:`~online_backlash.codecs.dbc.DbcDecoder`: ``dbc``,
    ``motor_signal``, ``load_signal``, the rolling counter and checksum signals, None for none, ``units``
    replacing the DBC's, ``wrap_deg``) or, given ``canopen``, a CANopen drive's object dictionary; ``max_skew_s``
    pairs the motor and load frames by time, seconds (:class:`~online_backlash.codecs.pairing.FramePipeline`)."""

    dbc: Any = None
    motor_signal: str | None = None
    load_signal: str | None = None
    counter_signal: str | None = "Counter"
    checksum_signal: str | None = "Checksum"
    units: str | None = None
    wrap_deg: Any = None
    max_skew_s: float = MAX_SKEW_S
    canopen: Canopen | None = None

    def kwargs(self) -> dict[str, Any]:
        if self.canopen is not None:
            return self.canopen.kwargs() | {"max_skew_s": self.max_skew_s}
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "canopen"}

    def dbc_decoder(self, counts: Counts) -> DbcDecoder:
        """The DBC's decoder of these signals, with ``counts`` per revolution (its :meth:`~Counts.kwargs`)."""
        from .dbc import DbcDecoder  # cantools loads only when frames are decoded

        if self.dbc is None or self.motor_signal is None or self.load_signal is None:
            raise InvalidParameterError(
                "CAN frames are decoded by a DBC's motor_signal and load_signal: give all three"
            )
        return DbcDecoder(
            self.dbc, self.motor_signal, self.load_signal, counter_signal=self.counter_signal,
            checksum_signal=self.checksum_signal, units=self.units, wrap_deg=self.wrap_deg, **counts.kwargs(),
        )  # fmt: skip

    def canopen_layout(self, counts: Counts) -> CanopenLayout:
        """The CANopen drive's encoder objects and PDOs
        (:meth:`~online_backlash.codecs.canopen.CanopenLayout.from_files`),
        with ``counts`` per revolution."""
        from .canopen import CanopenLayout  # canopen loads only for CANopen drives

        if self.canopen is None:
            raise InvalidParameterError("a CANopen drive is read with its eds and node (--eds, --node)")
        where = self.canopen.kwargs()
        return CanopenLayout.from_files(where.pop("eds"), where.pop("node"), **where, **counts.kwargs())

    @classmethod
    def take_from(cls, flat: dict[str, Any]) -> CanDecoding:
        """:meth:`ReaderOption.take_from`; a drive's ``eds`` (with ``node`` and where the load is) makes ``canopen``."""
        where = Canopen.take_from(flat) if flat.get("eds") is not None else None
        return super().take_from(flat) if where is None else cls(canopen=where, **_taken(flat, "max_skew_s"))


def _taken(flat: dict[str, Any], *names: str) -> dict[str, Any]:
    return {name: flat.pop(name) for name in names if name in flat}


def gather_options(flat: dict[str, Any], **option_types: type[ReaderOption]) -> dict[str, Any]:
    """Flat keyword arguments as options: ``gather_options({"dbc": f, "strict": True, "skip_bad": True},
    decoding=CanDecoding, frames=FrameRules)`` is ``{"decoding": CanDecoding(f), "frames": FrameRules(strict=True),
    "skip_bad": True}``: each option of the fields given (its defaults for the rest), the arguments of no option
    passed on as they are."""
    rest = dict(flat)
    gathered = {keyword: option_type.take_from(rest) for keyword, option_type in option_types.items()}
    return gathered | rest
