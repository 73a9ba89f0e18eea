"""The two serial frame formats, as byte-stream parsers that resynchronise after garbage.

``ascii``
    One sample per line: ``time,motor,load\\n`` (seconds, degrees, degrees; multi-turn angles;
    ``\\r\\n`` accepted). Gaps are found from time steps.
``binary``
    One sample per frame, little-endian, 20 bytes before framing::

        seq u16 | time_us u64 | motor_counts i32 | load_counts i32 | crc u16

    ``crc`` is CRC-16/CCITT-FALSE (:class:`crccheck.crc.Crc16CcittFalse`) of the first 18 bytes;
    ``time_us`` is the device clock in microseconds; counts are multi-turn encoder counts (their
    32-bit rollover is unwrapped) converted with ``motor_cpr``/``load_cpr`` counts per revolution.
    The frame is COBS-encoded (:mod:`cobs`) and ends with a zero byte, so any zero byte marks a
    frame boundary: after garbage the parser resynchronises at the next zero. Gaps are found
    from ``seq`` jumps and time steps.

A parser is fed whatever bytes arrive and returns the complete samples, as one
:class:`~online_backlash.stream.SampleChunk` (:meth:`FrameParser.feed_chunk`, what the sources
use) or as :class:`~online_backlash.stream.Sample` objects (:meth:`FrameParser.feed`); a partial
frame waits for the next call. Every delimited record is a frame:
``frames == samples + corrupt`` once :meth:`FrameParser.finish` has accounted for the tail.
"""

from __future__ import annotations

import struct

from cobs import cobs
from crccheck.crc import Crc16CcittFalse

from online_backlash.errors import FrameError, InvalidParameterError
from online_backlash.stream import Row, Sample, SampleChunk, StreamCounters, rows_to_chunk

from .options import SERIAL_FORMATS
from .sample_checks import SampleAssembler
from .unwrap import Unwrapper

#: What a record parses to: time (s), motor and load angles (deg), sequence number (None: none).
Reading = tuple[float, float, float, "int | None"]

_BINARY = struct.Struct("<HQii")
_CRC = struct.Struct("<H")
BINARY_FRAME_BYTES = _BINARY.size + _CRC.size


def encode_ascii(time_s: float, motor_deg: float, load_deg: float) -> bytes:
    """One ``ascii`` line (microsecond time, nanodegree angles)."""
    return f"{time_s:.6f},{motor_deg:.9f},{load_deg:.9f}\n".encode("ascii")


def encode_binary(seq: int, time_us: int, motor_counts: int, load_counts: int) -> bytes:
    """One ``binary`` frame, COBS-encoded, with its zero delimiter (counts wrap to int32)."""
    wrap = lambda c: (c + 2**31) % 2**32 - 2**31  # noqa: E731
    body = _BINARY.pack(seq % 2**16, time_us, wrap(motor_counts), wrap(load_counts))
    return cobs.encode(body + _CRC.pack(Crc16CcittFalse.calc(body))) + b"\0"


class FrameParser:
    """Split a byte stream into records at ``delimiter`` and parse each one (base class).

    Parameters
    ----------
    period_s : float, optional
        Nominal sample period for gap detection (learnt if None).
    strict : bool
        Raise FrameError on a corrupt frame instead of counting it.

    Attributes
    ----------
    counters : StreamCounters
    """

    delimiter = b"\n"
    max_frame_bytes = 256
    counter_modulus: int | None = None

    def __init__(self, period_s: float | None = None, strict: bool = False) -> None:
        self.strict = strict
        self.counters = StreamCounters()
        self._row = SampleAssembler(self.counters, self.counter_modulus, period_s, strict).row
        self._buf = bytearray()
        self._discarding = False

    @property
    def pending_bytes(self) -> int:
        """Bytes of an incomplete frame waiting for more data."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Sample]:
        """Parse ``data`` (appended to what is pending); return the samples completed."""
        return list(self.feed_chunk(data).samples())

    def feed_chunk(self, data: bytes) -> SampleChunk:
        """Parse ``data`` (appended to what is pending); return the samples completed as one block
        (seconds, degrees; ``seq`` where the format has one)."""
        buf = self._buf
        buf += data
        rows: list[Row] = []
        row = self._row
        pos = 0
        delim = self.delimiter
        while True:
            end = buf.find(delim, pos)
            if end < 0:
                break
            record = bytes(buf[pos:end])
            pos = end + 1
            if self._discarding:  # the rest of an over-long record, already counted
                self._discarding = False
                continue
            reading = self._record(record)
            if reading is not None and (checked := row(*reading)) is not None:
                rows.append(checked)
        del buf[:pos]
        if len(buf) > self.max_frame_bytes:  # garbage with no delimiter: one corrupt frame
            if not self._discarding:
                self.counters.frames += 1
                self._count_corrupt(f"no frame delimiter in {len(buf)} bytes")
                self._discarding = True
            buf.clear()
        return rows_to_chunk(rows)

    def finish(self) -> bytes:
        """End of stream: return the bytes of the incomplete last frame (empty if none) and forget them."""
        tail = bytes(self._buf)
        self._buf.clear()
        self._discarding = False
        return tail

    def _record(self, record: bytes) -> Reading | None:
        """The reading of one delimited record, or None (empty, or corrupt and counted)."""
        record = self._strip(record)
        if not record:
            return None
        self.counters.frames += 1
        try:
            return self._parse(record)
        except FrameError as exc:
            self._count_corrupt(str(exc))
            return None

    def _count_corrupt(self, reason: str) -> None:
        if self.strict:
            raise FrameError(reason)
        self.counters.corrupt += 1

    def _strip(self, record: bytes) -> bytes:
        return record

    def _parse(self, record: bytes) -> Reading:
        """The reading of a non-empty record; raises FrameError if it is damaged."""
        raise NotImplementedError


class AsciiParser(FrameParser):
    r"""``time,motor,load`` lines (seconds, degrees, degrees).

    Examples
    --------
    >>> p = AsciiParser()
    >>> p.feed(b"0.001,10.5,0.25\nnoise\n0.002,10.6")
    [Sample(time_s=0.001, motor_deg=10.5, load_deg=0.25, torque_Nm=None, seq=None, after_gap=False)]
    >>> p.feed(b",0.26\n")
    [Sample(time_s=0.002, motor_deg=10.6, load_deg=0.26, torque_Nm=None, seq=None, after_gap=False)]
    >>> p.counters.as_dict()
    {'frames': 3, 'samples': 2, 'corrupt': 1, 'skipped': 0, 'gaps': 0}
    """

    def _strip(self, record: bytes) -> bytes:
        return record.strip()

    def _parse(self, record: bytes) -> Reading:
        fields = record.split(b",")
        if len(fields) != 3:
            raise FrameError(f"expected 3 comma-separated fields, got {len(fields)}")
        try:
            time_s, motor_deg, load_deg = (float(f) for f in fields)
        except ValueError:
            raise FrameError(f"not a number in {record[:40]!r}") from None
        return time_s, motor_deg, load_deg, None


class BinaryParser(FrameParser):
    """COBS-framed binary frames with CRC-16 (see the module docstring).

    Parameters
    ----------
    motor_cpr, load_cpr : float
        Encoder counts per revolution of the motor and load shafts (required).
    """

    delimiter = b"\0"
    max_frame_bytes = 2 * BINARY_FRAME_BYTES
    counter_modulus = 2**16

    def __init__(
        self,
        motor_cpr: float | None = None,
        load_cpr: float | None = None,
        period_s: float | None = None,
        strict: bool = False,
    ) -> None:
        self._motor_scale = 360.0 / require_cpr("motor_cpr", motor_cpr)
        self._load_scale = 360.0 / require_cpr("load_cpr", load_cpr)
        super().__init__(period_s, strict)
        self._motor_turns = Unwrapper(2**32)
        self._load_turns = Unwrapper(2**32)

    def _parse(self, record: bytes) -> Reading:
        try:
            body = cobs.decode(record)
        except cobs.DecodeError as exc:
            raise FrameError(f"bad COBS framing ({exc})") from None
        if len(body) != BINARY_FRAME_BYTES:
            raise FrameError(f"frame of {len(body)} bytes, expected {BINARY_FRAME_BYTES}")
        payload = body[: _BINARY.size]
        if Crc16CcittFalse.calc(payload) != _CRC.unpack_from(body, _BINARY.size)[0]:
            raise FrameError("bad CRC")
        seq, time_us, motor, load = _BINARY.unpack(payload)
        return (
            time_us * 1e-6,
            self._motor_turns(motor) * self._motor_scale,
            self._load_turns(load) * self._load_scale,
            seq,
        )


def require_cpr(name: str, cpr: float | None) -> float:
    """``cpr`` (counts per revolution of the binary format's ``name`` encoder) if positive, else
    InvalidParameterError."""
    if cpr is None or not cpr > 0:
        raise InvalidParameterError(f"the binary serial format needs {name} (counts per revolution > 0), got {cpr!r}")
    return cpr


def make_parser(
    serial_format: str,
    motor_cpr: float | None = None,
    load_cpr: float | None = None,
    period_s: float | None = None,
    strict: bool = False,
) -> FrameParser:
    """The parser of ``serial_format`` (``ascii`` or ``binary``)."""
    if serial_format == "ascii":
        return AsciiParser(period_s, strict)
    if serial_format == "binary":
        return BinaryParser(motor_cpr, load_cpr, period_s, strict)
    raise InvalidParameterError(f"serial format must be one of {SERIAL_FORMATS}, got {serial_format!r}")
