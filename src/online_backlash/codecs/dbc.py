"""CAN frames to checked raw angle values with cantools, from a DBC file.

The motor and load angles are two signals of a DBC (``Message.Signal``, or a bare signal name
that is unique in the database). They may sit in one message (one frame per sample) or in two
(paired by :mod:`~online_backlash.codecs.pairing`). Each message of ours may carry:

- a rolling counter (signal ``counter_signal``, default ``Counter``) for pairing and gap detection;
- a checksum (signal ``checksum_signal``, default ``Checksum``): one byte-aligned 8-bit signal holding
  CRC-8/SAE-J1850 (:class:`crccheck.crc.Crc8SaeJ1850`) of the other data bytes in order.

A signal's unit string decides what it is (:mod:`~online_backlash.codecs.units`): an angle
(``deg``, ``rad``, ``rev``, ``arcmin``, ... any case) is scaled to degrees with the DBC's scale and
offset and is multi-turn as given (unless ``wrap_deg`` says it wraps); an encoder count (``counts``,
``cnt``, ``inc``, ``""``, ``-`` with scale 1) wraps at its counts per revolution (the DBC's raw range,
or ``2**length``, unless given; single-turn absolute encoders) and is unwrapped downstream. Any other
unit stops with an error naming the signal; ``units`` overrides the DBC's unit.

Frames whose ID is not one of our messages (or that are error or remote frames) are *not ours*;
frames of ours with a wrong length, a bad checksum or a count out of range are *corrupt*.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeAlias, cast

import can
import cantools
import numpy as np
from cantools.database.can import Database, Message, Signal
from crccheck.crc import Crc8SaeJ1850

from online_backlash.errors import FrameError, InvalidParameterError

from .units import ANGLE_UNITS, COUNT_UNITS, unit_key

#: The example DBC shipped with the package (``RigAngles``; ``MotorAngle`` + ``LoadAngle``).
RIG_DBC = Path(__file__).with_name("rig.dbc")

MOTOR, LOAD, BOTH = 1, 2, 3


def load_dbc(dbc: str | os.PathLike[str] | Database) -> Database:
    """A cantools database from a path (or the database itself); errors name the file."""
    if isinstance(dbc, Database):
        return dbc
    try:
        return cast(Database, cantools.database.load_file(os.fspath(dbc), database_format="dbc"))
    except OSError:
        raise
    except Exception as exc:  # cantools raises parser-specific types; all mean "not a usable DBC"
        raise InvalidParameterError(f"{os.fspath(dbc)}: not a usable DBC file: {exc}") from exc


@dataclass(frozen=True)
class EncoderSignal:
    """One angle signal of a DBC: where it is, and how its raw value becomes degrees.

    The decoders read raw integer values (cantools ``scaling=False``); a sample's angle is
    ``unwrapped_raw * deg_per_raw + offset_deg`` degrees.

    Attributes
    ----------
    message : cantools Message
    signal : str
        Signal name within the message.
    unit : str
        The unit that decided the kind (the DBC's, or the ``units`` override).
    is_count : bool
        True for an encoder count (unit ``counts``, ``cnt``, ``inc``, ``""``, ``-`` with scale 1):
        raw counts, wrapping at ``counts_per_rev``, checked to lie in ``[low, low + counts_per_rev)``.
        False for an angle (``deg``, ``rad``, ``rev``, ...): the DBC's scale and offset converted
        to degrees, multi-turn as given unless a wrap was asked for.
    modulus : int or None
        Where the raw value wraps (counts per revolution of a count, ``wrap_deg / deg_per_raw``
        of a wrapping angle); None: multi-turn, not unwrapped.
    deg_per_raw : float
        Degrees per raw value (``360 / counts_per_rev``, or the DBC scale times the unit's degrees).
    offset_deg : float
        Degrees added after scaling (the DBC offset of an angle; 0 for a count).
    low : int
        Smallest valid raw count of a count signal (0 unsigned, ``-counts_per_rev // 2`` signed).
    """

    message: Message
    signal: str
    modulus: int | None
    deg_per_raw: float
    offset_deg: float = 0.0
    unit: str = "counts"
    is_count: bool = True
    low: int = 0

    @property
    def counts_per_rev(self) -> int | None:
        """Raw values per wrap (None for a multi-turn angle)."""
        return self.modulus

    @property
    def deg_per_count(self) -> float:
        """Degrees per raw value (:attr:`deg_per_raw`)."""
        return self.deg_per_raw

    def raw_range(self) -> tuple[int, int] | None:
        """``(low, high)``: the valid raw values ``low <= v < high`` of a count; None (no check) for an angle."""
        if not self.is_count or self.modulus is None:
            return None
        return self.low, self.low + self.modulus

    def degrees(self, unwrapped: float) -> float:
        """Degrees of an unwrapped raw value."""
        return unwrapped * self.deg_per_raw + self.offset_deg


def _find_signal(db: Database, spec: str) -> tuple[Message, Signal]:
    if not isinstance(spec, str) or not spec:
        raise InvalidParameterError(f"signal must be a name like 'Message.Signal', got {spec!r}")
    msg_name, dot, sig_name = spec.rpartition(".")
    matches = [(m, s) for m in db.messages for s in m.signals if s.name == sig_name and (not dot or m.name == msg_name)]
    if not matches:
        known = [f"{m.name}.{s.name}" for m in db.messages for s in m.signals]
        raise InvalidParameterError(f"signal {spec!r} is not in the DBC; signals: {known}")
    if len(matches) > 1:
        raise InvalidParameterError(
            f"signal {spec!r} is ambiguous; use one of {[f'{m.name}.{s.name}' for m, s in matches]}"
        )
    return matches[0]


def resolve_signal(
    db: Database, spec: str, counts_per_rev: int | None = None, units: str | None = None, wrap_deg: float | None = None
) -> EncoderSignal:
    """Find signal ``spec`` (``Message.Signal`` or a unique bare name) in ``db`` and decide its kind by its unit.

    Parameters
    ----------
    counts_per_rev : int, optional
        Of a count signal; default from the DBC (raw range ``max - min + 1``, else ``2**length``).
    units : str, optional
        Replaces the DBC's unit string (e.g. ``counts`` for a signal whose unit says nothing).
    wrap_deg : float, optional
        An angle signal wraps every ``wrap_deg`` degrees (e.g. 360 for a single-turn angle) and is
        unwrapped; default: multi-turn as given. Ignored for counts.
    """
    message, signal = _find_signal(db, spec)
    name = f"{message.name}.{signal.name}"
    unit = (signal.unit or "") if units is None else units
    key = unit_key(unit)
    scale, offset = float(signal.scale), float(signal.offset)
    counts_override = units is not None and key in COUNT_UNITS
    if key in COUNT_UNITS and (counts_override or scale == 1.0):
        return _count_signal(message, signal, name, unit, counts_per_rev)
    if key not in ANGLE_UNITS:
        what = f"unit {unit!r} with scale {signal.scale}" if key in COUNT_UNITS else f"unit {unit!r}"
        raise InvalidParameterError(
            f"signal {name} has {what}: not an angle ({', '.join(sorted(ANGLE_UNITS))}) nor an encoder count "
            "(counts, cnt, inc, '' or '-' with scale 1); say what it is with --units"
        )
    deg_per_raw = scale * ANGLE_UNITS[key]
    modulus = None
    if wrap_deg is not None:
        if not (isinstance(wrap_deg, (int, float)) and math.isfinite(wrap_deg) and wrap_deg > 0):
            raise InvalidParameterError(f"wrap_deg of {name} must be a positive number of degrees, got {wrap_deg!r}")
        ratio = wrap_deg / abs(deg_per_raw)
        modulus = round(ratio)
        if modulus < 2 or abs(ratio - modulus) > 1e-6 * ratio:
            raise InvalidParameterError(
                f"signal {name}: a wrap of {wrap_deg} deg is not a whole number of raw steps of {abs(deg_per_raw)} deg"
            )
    return EncoderSignal(message, signal.name, modulus, deg_per_raw, offset * ANGLE_UNITS[key], unit, is_count=False)


def _count_signal(message: Message, signal: Signal, name: str, unit: str, counts_per_rev: int | None) -> EncoderSignal:
    low = 0
    lowest, highest = signal.minimum, signal.maximum
    if counts_per_rev is None:
        if lowest is not None and highest is not None and lowest < 0 < highest:
            low = round((lowest - signal.offset) / signal.scale)
            counts_per_rev = round((highest - lowest) / signal.scale) + 1
        elif highest:  # a range [0|0] says nothing
            counts_per_rev = round((highest - signal.offset) / signal.scale) + 1
        else:
            counts_per_rev = 2**signal.length
            low = -(2 ** (signal.length - 1)) if signal.is_signed else 0
    elif signal.is_signed and isinstance(counts_per_rev, int):
        low = -(counts_per_rev // 2)
    if not isinstance(counts_per_rev, int) or counts_per_rev < 2:
        raise InvalidParameterError(f"counts per revolution of {name} must be an integer >= 2, got {counts_per_rev!r}")
    return EncoderSignal(
        message, signal.name, counts_per_rev, 360.0 / counts_per_rev, 0.0, unit, is_count=True, low=low
    )


@dataclass(frozen=True)
class MessageLayout:
    """What to check in one of our messages.

    Attributes
    ----------
    role : int
        MOTOR, LOAD or BOTH: the angle(s) the message carries.
    length : int
        Data bytes the message must have.
    counter : str or None
        Name of its rolling counter signal (None: none).
    counter_modulus : int or None
        Wrap of that counter (``2**bits``).
    checksum_byte : int or None
        Index of the byte that holds the CRC-8 of the others (None: no checksum).
    """

    role: int
    length: int
    counter: str | None
    counter_modulus: int | None
    checksum_byte: int | None


@dataclass(slots=True)
class DecodedFrame:
    """One frame of ours, checked: raw signal values (unscaled, not unwrapped; 0 for an angle the frame does not
    carry)."""

    time_s: float
    role: int
    counter: int | None
    motor_count: int
    load_count: int


def _checksum_byte(message: Message, name: str) -> int | None:
    try:
        sig = message.get_signal_by_name(name)
    except KeyError:
        return None
    aligned = sig.length == 8 and sig.start % 8 == (0 if sig.byte_order == "little_endian" else 7)
    if not aligned:
        raise InvalidParameterError(f"checksum {message.name}.{name} must be one whole byte (8 bits, byte-aligned)")
    return sig.start // 8


def _counter_modulus(message: Message, name: str | None) -> int | None:
    if name is None:
        return None
    try:
        sig = message.get_signal_by_name(name)
    except KeyError:
        return None
    return 2**sig.length


class DbcDecoder:
    """Check and decode the frames that carry the motor and load angles.

    Parameters
    ----------
    dbc : path or cantools Database
        The DBC (e.g. :data:`RIG_DBC`).
    motor_signal, load_signal : str
        ``Message.Signal`` of the motor and load encoder counts.
    motor_cpr, load_cpr : int, optional
        Counts per revolution of a count signal; default from the DBC (raw range, else ``2**length``).
    counter_signal, checksum_signal : str or None
        Names of the rolling counter and checksum signals within our messages (None: not used).
    units : str, optional
        Replaces the unit strings of both angle signals (see :func:`resolve_signal`).
    wrap_deg : float or mapping, optional
        Angle signals (not counts) wrap every ``wrap_deg`` degrees; default: multi-turn as given.
        Per signal: ``{"motor": 360.0, "load": None}`` (:func:`wrap_per_signal`, :func:`parse_wrap_deg`).

    A signal of a multiplexed message is read from the frames whose multiplexer selects it; the
    other frames of that message are not ours (skipped).

    Attributes
    ----------
    motor, load : EncoderSignal
    paired : bool
        True when the two angles come in two messages that must be paired.
    counter_modulus : int or None
        Wrap of the rolling counter (the same in both messages), or None without counters.
    layouts : dict of int to MessageLayout
        Per frame id of our messages: what is checked.
    messages : dict of int to cantools Message
        Per frame id: our messages in the DBC.
    """

    def __init__(
        self,
        dbc: str | os.PathLike[str] | Database,
        motor_signal: str,
        load_signal: str,
        motor_cpr: int | None = None,
        load_cpr: int | None = None,
        counter_signal: str | None = "Counter",
        checksum_signal: str | None = "Checksum",
        units: str | None = None,
        wrap_deg: WrapDeg = None,
    ) -> None:
        self.db = load_dbc(dbc)
        motor_wrap, load_wrap = wrap_per_signal(wrap_deg)
        self.motor = resolve_signal(self.db, motor_signal, motor_cpr, units, motor_wrap)
        self.load = resolve_signal(self.db, load_signal, load_cpr, units, load_wrap)
        self.paired = self.motor.message.frame_id != self.load.message.frame_id
        if not self.paired and self.motor.message.is_multiplexed():
            motor_ids, load_ids = (
                self.motor.message.get_signal_by_name(e.signal).multiplexer_ids for e in (self.motor, self.load)
            )
            if motor_ids is not None and load_ids is not None and not set(motor_ids) & set(load_ids):
                raise InvalidParameterError(
                    f"{motor_signal} and {load_signal} are never in the same frame of multiplexed message "
                    f"{self.motor.message.name}"
                )
        roles = (
            [(self.motor.message, MOTOR), (self.load.message, LOAD)] if self.paired else [(self.motor.message, BOTH)]
        )
        self.layouts: dict[int, MessageLayout] = {}
        for message, role in roles:
            modulus = _counter_modulus(message, counter_signal)
            checksum = _checksum_byte(message, checksum_signal) if checksum_signal else None
            self.layouts[message.frame_id] = MessageLayout(
                role, message.length, counter_signal if modulus else None, modulus, checksum
            )
        moduli = {lay.counter_modulus for lay in self.layouts.values()}
        self.counter_modulus = moduli.pop() if len(moduli) == 1 else None
        self.messages: dict[int, Message] = {m.frame_id: m for m, _ in roles}
        # hot path of decode(): one lookup per frame
        self._by_id = {
            fid: (m.is_extended_frame, self.layouts[fid], m.decode_simple) for fid, m in self.messages.items()
        }
        self._motor_name, self._motor_range = self.motor.signal, self.motor.raw_range()
        self._load_name, self._load_range = self.load.signal, self.load.raw_range()

    def decode(self, msg: can.Message) -> DecodedFrame | None:
        """The checked content of ``msg``, None if it is not ours; raises FrameError if it is corrupt."""
        entry = self._by_id.get(msg.arbitration_id)
        if entry is None or msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id != entry[0]:
            return None
        _, layout, decode = entry
        data = msg.data
        if len(data) != layout.length:
            raise FrameError(f"frame 0x{msg.arbitration_id:X}: {len(data)} data bytes, expected {layout.length}")
        i = layout.checksum_byte
        if i is not None and Crc8SaeJ1850.calc(data[:i] + data[i + 1 :]) != data[i]:
            raise FrameError(f"frame 0x{msg.arbitration_id:X}: bad checksum")
        values = decode(bytes(data), False, False)  # integer signals, unscaled: ints
        motor = load = 0
        if layout.role & MOTOR:
            if self._motor_name not in values:  # a multiplexed frame that does not carry it
                return None
            motor = cast(int, values[self._motor_name])
            _check_range(msg, "motor", motor, self._motor_range)
        if layout.role & LOAD:
            if self._load_name not in values:
                return None
            load = cast(int, values[self._load_name])
            _check_range(msg, "load", load, self._load_range)
        return DecodedFrame(
            msg.timestamp, layout.role, cast(int, values[layout.counter]) if layout.counter else None, motor, load
        )


def _check_range(msg: can.Message, which: str, value: int, valid: tuple[int, int] | None) -> None:
    if valid is not None and not valid[0] <= value < valid[1]:
        raise FrameError(f"frame 0x{msg.arbitration_id:X}: {which} count {value} out of range")


class FrameEncoder:
    """The inverse of :class:`DbcDecoder`, for simulators, tests and benchmarks.

    ``frames(time_s, motor_count, load_count, counter)`` gives the one or two CAN messages of one
    sample, with the counter and the checksum filled in.
    """

    def __init__(self, decoder: DbcDecoder) -> None:
        self.decoder = decoder

    def frames(self, time_s: float, motor_count: int, load_count: int, counter: int = 0) -> list[can.Message]:
        dec = self.decoder
        out = []
        for frame_id, layout in dec.layouts.items():
            message = dec.messages[frame_id]
            values = {s.name: 0 for s in message.signals}
            if layout.role & MOTOR:
                values[dec.motor.signal] = _wrapped(motor_count, dec.motor)
            if layout.role & LOAD:
                values[dec.load.signal] = _wrapped(load_count, dec.load)
            if layout.counter and layout.counter_modulus:
                values[layout.counter] = counter % layout.counter_modulus
            data = bytearray(message.encode(values, scaling=False, strict=False))
            if layout.checksum_byte is not None:
                i = layout.checksum_byte
                data[i] = Crc8SaeJ1850.calc(bytes(data[:i] + data[i + 1 :]))
            out.append(
                can.Message(
                    timestamp=time_s,
                    arbitration_id=frame_id,
                    is_extended_id=message.is_extended_frame,
                    is_fd=message.is_fd,
                    data=data,
                )
            )
        return out


#: ``wrap_deg`` of both angle signals (degrees; None: multi-turn), or per signal (``{"motor": 360.0, "load": None}``).
WrapDeg: TypeAlias = float | Mapping[str, float | None] | None
#: The signals a per-signal option names.
WRAP_ROLES = ("motor", "load")


def wrap_per_signal(wrap_deg: WrapDeg) -> tuple[float | None, float | None]:
    """``(motor, load)`` wraps in degrees (None: multi-turn) of a ``wrap_deg`` for both or per signal.

    >>> wrap_per_signal(360.0), wrap_per_signal({"load": 360.0})
    ((360.0, 360.0), (None, 360.0))
    """
    if wrap_deg is None or not isinstance(wrap_deg, Mapping):
        return wrap_deg, wrap_deg
    unknown = sorted(set(wrap_deg) - set(WRAP_ROLES))
    if unknown:
        raise InvalidParameterError(
            f"wrap_deg names {', '.join(map(repr, unknown))}; the signals are {' and '.join(WRAP_ROLES)}"
        )
    return wrap_deg.get("motor"), wrap_deg.get("load")


def parse_wrap_deg(text: str) -> WrapDeg:
    """``--wrap-deg``: ``360`` (both angle signals), or per signal ``motor=360,load=none`` (degrees; ``none``:
    multi-turn; a signal not named is multi-turn). InvalidParameterError on anything else.

    >>> parse_wrap_deg("360"), parse_wrap_deg("motor=360,load=none")
    (360.0, {'motor': 360.0, 'load': None})
    """

    def degrees(value: str, what: str) -> float | None:
        if value.strip().lower() == "none":
            return None
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not (math.isfinite(number) and number > 0):
            raise InvalidParameterError(
                f"--wrap-deg {text!r}: {what} must be a positive number of degrees or 'none', got {value!r}"
            )
        return number

    if "=" not in text:
        return degrees(text, "the wrap")
    out: dict[str, float | None] = {}
    for part in text.split(","):
        role, eq, value = part.partition("=")
        role = role.strip().lower()
        if not eq or role not in WRAP_ROLES or role in out:
            raise InvalidParameterError(
                f"--wrap-deg {text!r}: expected DEG or motor=DEG,load=DEG (DEG a number or 'none')"
            )
        out[role] = degrees(value, role)
    return out


def _wrapped(raw: int, signal: EncoderSignal) -> int:
    """A raw value brought into the signal's wrap (``[low, low + modulus)``), unchanged for a multi-turn angle."""
    if signal.modulus is None:
        return raw
    return (raw - signal.low) % signal.modulus + signal.low


def counts_of(angle_deg: Sequence[float] | np.ndarray | float, signal: EncoderSignal) -> np.ndarray:
    """Raw values (rounded, not wrapped) of angles in degrees, for feeding :class:`FrameEncoder` from a simulation."""
    return np.rint((np.asarray(angle_deg) - signal.offset_deg) / signal.deg_per_raw).astype(np.int64)
