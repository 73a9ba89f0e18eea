"""CAN frames to encoder counts with cantools, from a DBC file.

The motor and load angles are two signals of a DBC (``Message.Signal``, or a bare signal name
that is unique in the database). They may sit in one message (one frame per sample) or in two
(paired by :mod:`~online_backlash.codecs.pairing`). Each message of ours may carry:

- a rolling counter (signal ``counter_signal``, default ``Counter``) for pairing and gap detection;
- a checksum (signal ``checksum_signal``, default ``Checksum``): one byte-aligned 8-bit signal holding
  CRC-8/SAE-J1850 (:class:`crccheck.crc.Crc8SaeJ1850`) of the other data bytes in order.

Counts per revolution of each encoder come from the DBC (the signal's raw maximum + 1, or
``2**length`` when it has no maximum) unless given; the counts wrap at that value (single-turn
absolute encoders) and are unwrapped downstream.

Frames whose ID is not one of our messages (or that are error or remote frames) are *not ours*;
frames of ours with a wrong length, a bad checksum or a count out of range are *corrupt*.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import can
import cantools
import numpy as np
from cantools.database.can import Database, Message
from crccheck.crc import Crc8SaeJ1850

from online_backlash.errors import FrameError, InvalidParameterError

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
    """One encoder angle in a DBC: where it is and how to scale it.

    Attributes
    ----------
    message : cantools Message
    signal : str
        Signal name within the message.
    counts_per_rev : int
        Counts per revolution; counts wrap at this value.
    deg_per_count : float
        ``360 / counts_per_rev``.
    """

    message: Message
    signal: str
    counts_per_rev: int

    @property
    def deg_per_count(self) -> float:
        return 360.0 / self.counts_per_rev


def resolve_signal(db: Database, spec: str, counts_per_rev: int | None = None) -> EncoderSignal:
    """Find signal ``spec`` (``Message.Signal`` or a unique bare name) in ``db``."""
    if not isinstance(spec, str) or not spec:
        raise InvalidParameterError(f"signal must be a name like 'Message.Signal', got {spec!r}")
    msg_name, dot, sig_name = spec.rpartition(".")
    matches = [
        (m, s)
        for m in db.messages
        for s in m.signals
        if s.name == sig_name and (not dot or m.name == msg_name)
    ]
    if not matches:
        known = [f"{m.name}.{s.name}" for m in db.messages for s in m.signals]
        raise InvalidParameterError(f"signal {spec!r} is not in the DBC; signals: {known}")
    if len(matches) > 1:
        raise InvalidParameterError(f"signal {spec!r} is ambiguous; use one of {[f'{m.name}.{s.name}' for m, s in matches]}")
    message, signal = matches[0]
    if counts_per_rev is None:
        if signal.maximum is not None:
            counts_per_rev = round((signal.maximum - signal.offset) / signal.scale) + 1
        else:
            counts_per_rev = 2**signal.length
    if not isinstance(counts_per_rev, int) or counts_per_rev < 2:
        raise InvalidParameterError(f"counts per revolution of {spec!r} must be an integer >= 2, got {counts_per_rev!r}")
    return EncoderSignal(message, signal.name, counts_per_rev)


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
    """One frame of ours, checked: counts are raw (single-turn) encoder counts (0 for an angle the frame does not carry)."""

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
        Counts per revolution; default from the DBC (signal maximum + 1, else ``2**length``).
    counter_signal, checksum_signal : str or None
        Names of the rolling counter and checksum signals within our messages (None: not used).

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
    ) -> None:
        self.db = load_dbc(dbc)
        self.motor = resolve_signal(self.db, motor_signal, motor_cpr)
        self.load = resolve_signal(self.db, load_signal, load_cpr)
        self.paired = self.motor.message.frame_id != self.load.message.frame_id
        roles = [(self.motor.message, MOTOR), (self.load.message, LOAD)] if self.paired else [(self.motor.message, BOTH)]
        self.layouts: dict[int, MessageLayout] = {}
        for message, role in roles:
            modulus = _counter_modulus(message, counter_signal)
            checksum = _checksum_byte(message, checksum_signal) if checksum_signal else None
            self.layouts[message.frame_id] = MessageLayout(role, message.length, counter_signal if modulus else None, modulus, checksum)
        moduli = {lay.counter_modulus for lay in self.layouts.values()}
        self.counter_modulus = moduli.pop() if len(moduli) == 1 else None
        self.messages: dict[int, Message] = {m.frame_id: m for m, _ in roles}
        # hot path of decode(): one lookup per frame
        self._by_id = {fid: (m.is_extended_frame, self.layouts[fid], m.decode_simple) for fid, m in self.messages.items()}
        self._motor_name, self._motor_cpr = self.motor.signal, self.motor.counts_per_rev
        self._load_name, self._load_cpr = self.load.signal, self.load.counts_per_rev

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
            motor = cast(int, values[self._motor_name])
            if motor >= self._motor_cpr or motor < 0:
                raise FrameError(f"frame 0x{msg.arbitration_id:X}: motor count {motor} out of range")
        if layout.role & LOAD:
            load = cast(int, values[self._load_name])
            if load >= self._load_cpr or load < 0:
                raise FrameError(f"frame 0x{msg.arbitration_id:X}: load count {load} out of range")
        return DecodedFrame(msg.timestamp, layout.role, cast(int, values[layout.counter]) if layout.counter else None, motor, load)


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
                values[dec.motor.signal] = motor_count % dec.motor.counts_per_rev
            if layout.role & LOAD:
                values[dec.load.signal] = load_count % dec.load.counts_per_rev
            if layout.counter and layout.counter_modulus:
                values[layout.counter] = counter % layout.counter_modulus
            data = bytearray(message.encode(values, scaling=False, strict=False))
            if layout.checksum_byte is not None:
                i = layout.checksum_byte
                data[i] = Crc8SaeJ1850.calc(bytes(data[:i] + data[i + 1 :]))
            out.append(can.Message(timestamp=time_s, arbitration_id=frame_id, is_extended_id=message.is_extended_frame, data=data))
        return out


def counts_of(angle_deg: Sequence[float] | np.ndarray | float, signal: EncoderSignal) -> np.ndarray:
    """Encoder counts (rounded, not wrapped) of angles in degrees, for feeding :class:`FrameEncoder` from a simulation."""
    return np.rint(np.asarray(angle_deg) / signal.deg_per_count).astype(np.int64)
