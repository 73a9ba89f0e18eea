"""The checks and decoding of :meth:`DbcDecoder.decode <online_backlash.codecs.dbc.DbcDecoder.decode>`
on a block of CAN frames held in numpy arrays (the fast replay path).

The DBC is still read by cantools: every signal is cut from the data bytes with cantools' own
metadata (``Signal.start``, ``length``, ``byte_order``, ``is_signed``; the start bit of a
big-endian signal converted with :func:`cantools.database.utils.start_bit`), as raw counts like
``decode_simple(data, decode_choices=False, scaling=False)``. The CRC-8/SAE-J1850 checksum is
computed with a 256-entry table generated once from crccheck's :class:`~crccheck.crc.Crc8SaeJ1850`
(:func:`crc8_table`), byte by byte over the whole block at once.

Each frame gets a status: :data:`OK` (ours and valid), :data:`CORRUPT` (ours, but wrong length,
bad checksum or a count out of range) or :data:`SKIPPED` (not ours: other ID, error or remote
frame, other ID format), exactly as the per-frame decoder decides.

Supported: our messages at most 8 bytes, integer signals, no multiplexing (:attr:`BlockDecoder.supported`);
otherwise the caller uses the per-frame path.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import can
import numpy as np
from cantools.database.can import Message, Signal
from cantools.database.utils import start_bit
from crccheck.crc import Crc8SaeJ1850

from .dbc import LOAD, MOTOR, DbcDecoder

OK, CORRUPT, SKIPPED = 0, 1, 2
#: Longest message (bytes) of the block path: signals are cut from one 64-bit word.
MAX_BYTES = 8


def crc8_table(crc: type[Crc8SaeJ1850] = Crc8SaeJ1850) -> np.ndarray:
    """The 256-entry table of a non-reflected 8-bit CRC, generated from crccheck's ``calc``.

    ``table[x]`` is the register after feeding byte ``x`` to a zero register, i.e. crccheck's
    result for ``[x]`` from initial value 0 with its output XOR taken off again. Then for data
    ``d``: ``reg = init; reg = table[reg ^ b] for b in d; crc = reg ^ xorout`` (see :func:`crc8`).
    """
    xorout = crc.calc(b"", initvalue=0)
    return np.array([crc.calc(bytes([x]), initvalue=0) ^ xorout for x in range(256)], dtype=np.uint8)


_TABLE = crc8_table()
_XOROUT = Crc8SaeJ1850.calc(b"", initvalue=0)
_INIT = Crc8SaeJ1850.calc(b"") ^ _XOROUT


def crc8(rows: np.ndarray) -> np.ndarray:
    """CRC-8/SAE-J1850 of each row of a ``(n, k)`` uint8 array (equal to ``Crc8SaeJ1850.calc(row)``)."""
    reg = np.full(rows.shape[0], _INIT, dtype=np.uint8)
    for j in range(rows.shape[1]):
        reg = _TABLE[reg ^ rows[:, j]]
    return reg ^ np.uint8(_XOROUT)


def signal_values(words_le: np.ndarray, words_be: np.ndarray, signal: Signal) -> np.ndarray:
    """Raw values (int64) of a cantools integer ``signal`` in the data of each frame.

    ``words_le`` / ``words_be`` are the data bytes (zero-padded to 8) read as one little- / big-endian
    unsigned 64-bit word per frame.
    """
    mask = np.uint64((1 << signal.length) - 1)
    if signal.byte_order == "little_endian":
        raw = (words_le >> np.uint64(signal.start)) & mask
    else:
        raw = (words_be >> np.uint64(64 - start_bit(signal) - signal.length)) & mask
    values = raw.astype(np.int64)
    if signal.is_signed:
        values = np.where(values >= 1 << (signal.length - 1), values - (1 << signal.length), values)
    return values


def words(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``(n, L <= 8)`` data bytes as little- and big-endian 64-bit words (zero-padded)."""
    padded = np.zeros((rows.shape[0], MAX_BYTES), dtype=np.uint8)
    padded[:, : rows.shape[1]] = rows
    return padded.view("<u8")[:, 0], padded.view(">u8")[:, 0].astype(np.uint64)


def frame_arrays(frames: Sequence[can.Message]) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """Timestamps (seconds), and the arguments of :meth:`BlockDecoder.decode`, of a block of frames."""
    n = len(frames)
    ids = np.fromiter([m.arbitration_id for m in frames], np.int64, n)
    extended = np.fromiter([m.is_extended_id for m in frames], np.bool_, n)
    special = np.fromiter([m.is_error_frame or m.is_remote_frame for m in frames], np.bool_, n)
    time_s = np.fromiter([m.timestamp for m in frames], np.float64, n)
    data = [m.data for m in frames]
    lengths = np.fromiter(map(len, data), np.int64, n)
    offsets = np.cumsum(lengths) - lengths
    return time_s, (ids, extended, special, lengths, offsets, np.frombuffer(b"".join(data), np.uint8))


@dataclass
class DecodedBlock:
    """Per frame of a block: ``status`` (OK/CORRUPT/SKIPPED), ``role`` (MOTOR/LOAD/BOTH, 0 if not OK),
    ``counter`` (-1 without one), ``motor`` and ``load`` (raw signal values, 0 where absent)."""

    status: np.ndarray
    role: np.ndarray
    counter: np.ndarray
    motor: np.ndarray
    load: np.ndarray


class BlockDecoder:
    """Decode blocks of frames for a :class:`~online_backlash.codecs.dbc.DbcDecoder` (same checks, same values).

    Attributes
    ----------
    supported : bool
        False when one of our messages is longer than 8 bytes, multiplexed, or carries one of our
        signals as a float: use the per-frame decoder then.
    """

    def __init__(self, decoder: DbcDecoder) -> None:
        self.decoder = decoder
        self._entries = []
        for frame_id, layout in decoder.layouts.items():
            message: Message = decoder.messages[frame_id]
            wanted = {}
            if layout.role & MOTOR:
                wanted["motor"] = (message.get_signal_by_name(decoder.motor.signal), decoder.motor.raw_range())
            if layout.role & LOAD:
                wanted["load"] = (message.get_signal_by_name(decoder.load.signal), decoder.load.raw_range())
            counter = message.get_signal_by_name(layout.counter) if layout.counter else None
            self._entries.append((frame_id, message.is_extended_frame, layout, wanted, counter))
        signals = [s for *_, wanted, c in self._entries for s in [v[0] for v in wanted.values()] + ([c] if c else [])]
        messages = decoder.messages.values()
        self.supported = all(m.length <= MAX_BYTES and not m.is_multiplexed() for m in messages) and not any(
            s.is_float for s in signals
        )

    def decode(
        self,
        ids: np.ndarray,
        extended: np.ndarray,
        special: np.ndarray,
        lengths: np.ndarray,
        offsets: np.ndarray,
        data: np.ndarray,
    ) -> DecodedBlock:
        """Check and decode ``n`` frames: arbitration ids, extended-id flags, error-or-remote flags,
        data lengths, offsets of each frame's data in ``data`` (all data bytes concatenated, uint8)."""
        n = ids.shape[0]
        status = np.full(n, SKIPPED, dtype=np.int8)
        role = np.zeros(n, dtype=np.int8)
        counter = np.full(n, -1, dtype=np.int64)
        motor = np.zeros(n, dtype=np.int64)
        load = np.zeros(n, dtype=np.int64)
        for frame_id, is_extended, layout, wanted, counter_signal in self._entries:
            ours = (ids == frame_id) & (extended == is_extended) & ~special
            status[ours] = CORRUPT
            index = np.flatnonzero(ours & (lengths == layout.length))
            rows = data[offsets[index, None] + np.arange(layout.length)]
            good = np.ones(index.shape[0], dtype=bool)
            i = layout.checksum_byte
            if i is not None:
                good &= crc8(np.delete(rows, i, axis=1)) == rows[:, i]
            le, be = words(rows)
            for name, (signal, valid) in wanted.items():
                values = signal_values(le, be, signal)
                if valid is not None:  # DbcDecoder's range check of a count
                    good &= (values >= valid[0]) & (values < valid[1])
                (motor if name == "motor" else load)[index] = values
            if counter_signal is not None:
                counter[index] = signal_values(le, be, counter_signal)
            index = index[good]
            status[index] = OK
            role[index] = layout.role
        return DecodedBlock(status, role, counter, motor, load)
