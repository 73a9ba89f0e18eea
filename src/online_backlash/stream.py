"""The stream contract: every source of samples, live or recorded, is a :class:`SampleSource`.

A source yields blocks of samples as :class:`SampleChunk` arrays (:meth:`SampleSource.iter_chunks`,
the fast path into ``learn_many``) or one :class:`Sample` at a time (iterating it), counts what it
saw in :class:`StreamCounters` (``counters``), releases its file, bus or port in ``close()`` and is
a context manager. Estimators never see a source: :meth:`SampleChunk.referred` gives their input
``u = motor_deg / ratio`` and output ``y = load_deg`` (the one place the ratio is applied).

Units at this edge: time in seconds, angles in degrees (multi-turn, unwrapped),
torque in newton metres.
"""

from __future__ import annotations

import math
import os
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from .errors import InvalidParameterError, LogFormatError

#: A sample time of at least this many seconds is a UNIX time (2001-09-09 on); smaller ones are a device clock.
UNIX_TIME_MIN = 1.0e9


def live_clock_offset(first_time_s: float) -> float:
    """Seconds to add to a live source's times to get UNIX time: 0 for UNIX times (at least
    :data:`UNIX_TIME_MIN`), else the device clock is placed so that its first sample is now."""
    return 0.0 if first_time_s >= UNIX_TIME_MIN else time.time() - first_time_s


#: A time step longer than this many nominal sample periods is a gap (every source uses this rule).
GAP_PERIODS = 3.0
#: Event-driven frames: the largest time between the motor's and the load's frame of one sample, seconds
#: (the pairing rule of every frame source, live and replayed).
MAX_SKEW_S = 1e-3


@dataclass(frozen=True, slots=True)
class Sample:
    """One timestamped pair of encoder readings.

    Attributes
    ----------
    time_s : float
        Time of the reading, seconds (source clock; monotonic within one source).
    motor_deg : float
        Motor shaft angle, degrees, multi-turn (unwrapped), *not* divided by the ratio.
    load_deg : float
        Load (output) shaft angle, degrees, multi-turn (unwrapped).
    torque_Nm : float or None
        Measured torque, N m, where the source has it (carried along for diagnostics).
    seq : int or None
        Sequence number, where the source has one (frame counter, CSV line, ...).
    after_gap : bool
        True when samples are missing just before this one (the source saw a gap);
        an estimator must not read the jump from the previous sample as motion.
    """

    time_s: float
    motor_deg: float
    load_deg: float
    torque_Nm: float | None = None
    seq: int | None = None
    after_gap: bool = False

    def is_finite(self) -> bool:
        """True when time and both angles (and the torque, if present) are finite numbers."""
        torque = () if self.torque_Nm is None else (self.torque_Nm,)
        return all(math.isfinite(v) for v in (self.time_s, self.motor_deg, self.load_deg, *torque))


@dataclass(frozen=True, slots=True)
class Gap:
    """A reported gap in a stream: ``duration_s`` seconds (``missing`` samples, if known) before ``time_s``."""

    time_s: float
    duration_s: float
    missing: int | None = None


@dataclass
class StreamCounters:
    """What a source saw. Every frame read is accounted for.

    Attributes
    ----------
    frames : int
        Raw units read: CAN frames, serial frames or lines, CSV data rows.
    samples : int
        Samples yielded to the consumer.
    corrupt : int
        Frames rejected as damaged (bad checksum/CRC, wrong length, unparsable, non-finite).
    skipped : int
        Frames that are not ours (other traffic on a shared bus, ignored IDs).
    gaps : int
        Gaps reported (missing sequence numbers or a time step longer than three nominal periods).
    gap_log : deque of Gap
        The most recent gaps (at most ``max_gap_log``), with time and length.
    """

    frames: int = 0
    samples: int = 0
    corrupt: int = 0
    skipped: int = 0
    gaps: int = 0
    gap_log: deque = field(default_factory=lambda: deque(maxlen=1000))

    def report_gap(self, gap: Gap) -> None:
        """Count a gap and keep it in ``gap_log``."""
        self.gaps += 1
        self.gap_log.append(gap)

    def as_dict(self) -> dict[str, int]:
        """The integer counters as a plain dict (for JSON output)."""
        return {
            "frames": self.frames,
            "samples": self.samples,
            "corrupt": self.corrupt,
            "skipped": self.skipped,
            "gaps": self.gaps,
        }


_SourceT = TypeVar("_SourceT", bound="SampleSource")


class SampleSource(ABC):
    """The one contract every source implements: live CAN and serial, and every recorded log.

    A source yields its samples as :class:`SampleChunk` blocks (:meth:`iter_chunks`, the fast
    path into ``learn_many``) or one :class:`Sample` at a time (``__iter__``, written once here
    on top of the blocks), counts what it saw in ``counters`` and releases its file, bus or port
    in :meth:`close`; it is a context manager that closes on exit. A subclass writes only
    :meth:`iter_chunks` and :meth:`close`, and sets ``counters`` in its ``__init__``.

    Units: time in seconds, angles in degrees on their own shafts (the motor angle is *not*
    divided by the ratio: :meth:`SampleChunk.referred` does that, in one place), torque in N m.

    A recording that carries a clock of its own (an MDF4 header's start time, a TDMS waveform's
    ``wf_start_time``, a Parquet timestamp column) says, once its first block has been read, which
    calendar time its ``time_s = 0`` is: :attr:`time_origin_unix_s` (UNIX seconds, UTC) and
    :attr:`time_origin_name` (what it was read from); None and "" where it has none.
    """

    counters: StreamCounters
    #: UNIX time (UTC, seconds) of ``time_s = 0`` by the recording's own clock; None: it has none.
    time_origin_unix_s: float | None = None
    #: What :attr:`time_origin_unix_s` was read from, e.g. ``"MDF4 header start time"``.
    time_origin_name: str = ""

    @abstractmethod
    def iter_chunks(self, max_samples: int | None = None) -> Iterator[SampleChunk]:
        """The samples in blocks of at most ``max_samples`` (None: the source's natural block,
        e.g. whatever one receive delivered live, or one parsed block of a file)."""

    @abstractmethod
    def close(self) -> None:
        """Release the file, bus or port (idempotent)."""

    def __iter__(self) -> Iterator[Sample]:
        """The samples one at a time (the slow path, for per-sample consumers and tests)."""
        for chunk in self.iter_chunks():
            yield from chunk.samples()

    def __enter__(self: _SourceT) -> _SourceT:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: Range of a gear ratio's magnitude, motor:load: a speed-up of 1:10,000 to a reduction of 100,000:1 (a worm and a
#: planetary stage); beyond it the referred motor angle carries no resolvable motion or swamps the fit (--ratio 1e308).
RATIO_LIMITS = (1e-4, 1e5)


def check_ratio(ratio: float) -> float:
    """``ratio`` as a float if it is a gear ratio motor:load: finite, non-zero, ``|ratio|`` within
    :data:`RATIO_LIMITS`; else InvalidParameterError saying what was expected."""
    low, high = RATIO_LIMITS
    if not isinstance(ratio, (int, float)) or not math.isfinite(ratio) or ratio == 0:
        raise InvalidParameterError(f"ratio must be a finite non-zero number, got {ratio!r}")
    if not low <= abs(ratio) <= high:
        limits = f"{low:g} <= |ratio| <= {high:g}"
        raise InvalidParameterError(f"ratio must be a gear ratio with {limits} (motor:load), got {ratio!r}")
    return float(ratio)


def refer_to_load(motor_deg: np.ndarray | float, ratio: float) -> np.ndarray | float:
    """Motor angle referred to the load side, degrees: ``u = motor_deg / ratio``.

    ``ratio`` is the gear ratio motor:load (e.g. 30 for a 30:1 reducer); it is negative
    for a stage that reverses the direction of rotation (:func:`check_ratio`).
    """
    return motor_deg / check_ratio(ratio)


@dataclass
class SampleChunk:
    """A block of consecutive samples as arrays (the fast path of ``learn_many``).

    ``after_gap[i]`` is True where sample ``i`` follows a gap. Times in seconds, angles in
    degrees on their own shafts, torque in N m (NaN where absent); ``seq`` holds the source's
    sequence numbers (frame counter, CSV line; -1 where unknown) where it has them, else None.
    """

    time_s: np.ndarray
    motor_deg: np.ndarray
    load_deg: np.ndarray
    torque_Nm: np.ndarray
    after_gap: np.ndarray

    seq: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.time_s)

    def slice(self, start: int, stop: int) -> SampleChunk:
        """Samples ``start`` to ``stop`` (views of the arrays)."""
        part = slice(start, stop)
        seq = None if self.seq is None else self.seq[part]
        return SampleChunk(
            self.time_s[part],
            self.motor_deg[part],
            self.load_deg[part],
            self.torque_Nm[part],
            self.after_gap[part],
            seq,
        )

    def referred(self, ratio: float) -> tuple[np.ndarray, np.ndarray]:
        """The estimator's input and output, degrees on the load side: ``(u, y) = (motor_deg / ratio, load_deg)``.

        The one place where the motor angle is referred to the load side (:func:`refer_to_load`); the
        pipeline's compiled pass that refers and checks a chunk at once gives the same numbers, bit for bit
        (``pipeline._refer_checked``, tested against this method).
        """
        return np.asarray(refer_to_load(self.motor_deg, ratio)), self.load_deg

    def samples(self) -> Iterator[Sample]:
        """The block as :class:`Sample` objects (torque None where NaN, seq None where absent or negative)."""
        seq = self.seq.tolist() if self.seq is not None else [None] * len(self)
        for t, m, y, q, n, g in zip(
            self.time_s.tolist(),
            self.motor_deg.tolist(),
            self.load_deg.tolist(),
            self.torque_Nm.tolist(),
            seq,
            self.after_gap.tolist(),
        ):
            yield Sample(t, m, y, None if math.isnan(q) else q, None if n is None or n < 0 else n, g)


def chunked(samples: Iterable[Sample], size: int = 65536) -> Iterator[SampleChunk]:
    """Group an iterable of Samples into :class:`SampleChunk` blocks of at most ``size`` samples.

    Memory stays bounded by ``size`` whatever the length of the stream. The sequence numbers ride
    along (``seq``, -1 where a sample has none) when any sample of the block has one.
    """
    _check_size(size)
    buf: list[Sample] = []
    for s in samples:
        buf.append(s)
        if len(buf) == size:
            yield samples_to_chunk(buf)
            buf = []
    if buf:
        yield samples_to_chunk(buf)


def samples_to_chunk(samples: Sequence[Sample]) -> SampleChunk:
    """One :class:`SampleChunk` of a list of Samples (the per-frame paths; torque NaN and seq -1 where absent)."""
    n = len(samples)
    seq = [s.seq for s in samples]
    return SampleChunk(
        time_s=np.fromiter((s.time_s for s in samples), float, n),
        motor_deg=np.fromiter((s.motor_deg for s in samples), float, n),
        load_deg=np.fromiter((s.load_deg for s in samples), float, n),
        torque_Nm=np.fromiter((np.nan if s.torque_Nm is None else s.torque_Nm for s in samples), float, n),
        after_gap=np.fromiter((s.after_gap for s in samples), bool, n),
        seq=np.fromiter((-1 if q is None else q for q in seq), np.int64, n)
        if any(q is not None for q in seq)
        else None,
    )


#: One checked sample as the per-frame codecs produce it: time (s), motor and load angles (deg),
#: sequence number (None: none), after_gap.
Row = tuple[float, float, float, "int | None", bool]


def rows_to_chunk(rows: Sequence[Row]) -> SampleChunk:
    """One :class:`SampleChunk` of per-frame rows (torque NaN; ``seq`` -1 where a row has none,
    None when no row has one): how the per-frame codecs hand on a block without Sample objects."""
    n = len(rows)
    time_s, motor, load, seq, after_gap = zip(*rows) if n else ((), (), (), (), ())
    has_seq = any(q is not None for q in seq)
    return SampleChunk(
        np.array(time_s, dtype=float),
        np.array(motor, dtype=float),
        np.array(load, dtype=float),
        np.full(n, np.nan),
        np.array(after_gap, dtype=bool),
        seq=np.array([-1 if q is None else q for q in seq], dtype=np.int64) if has_seq else None,
    )


def concat_chunks(chunks: Sequence[SampleChunk]) -> SampleChunk:
    """The blocks joined into one (``seq`` kept only when every block has it)."""
    seqs = [c.seq for c in chunks if c.seq is not None]

    def joined(name: str) -> np.ndarray:
        return np.concatenate([getattr(c, name) for c in chunks])

    seq = np.concatenate(seqs) if len(seqs) == len(chunks) else None
    return SampleChunk(
        joined("time_s"), joined("motor_deg"), joined("load_deg"), joined("torque_Nm"), joined("after_gap"), seq
    )


def read_all(source: SampleSource, name: str | os.PathLike[str], empty: str = "no samples") -> SampleChunk:
    """Every sample of ``source`` in one :class:`SampleChunk` (for batch fits of logs that fit in
    memory); the source is closed. :class:`~online_backlash.errors.LogFormatError` naming ``name``
    (reason ``empty``) when it has none."""
    with source:
        chunks = list(source.iter_chunks())
    if not chunks:
        raise LogFormatError(name, None, empty)
    return concat_chunks(chunks)


def rechunk(chunks: Iterable[SampleChunk], max_samples: int | None) -> Iterator[SampleChunk]:
    """Blocks of exactly ``max_samples`` (the last one shorter) from blocks of any length, in order.

    ``None`` passes the blocks through as they come (empty ones dropped). Memory stays bounded
    by ``max_samples`` plus one incoming block.
    """
    if max_samples is None:
        yield from (c for c in chunks if len(c))
        return
    _check_size(max_samples)
    held: list[SampleChunk] = []
    n_held = 0
    for chunk in chunks:
        if not len(chunk):
            continue
        held.append(chunk)
        n_held += len(chunk)
        if n_held < max_samples:
            continue
        joined = concat_chunks(held) if len(held) > 1 else held[0]
        start = 0
        while n_held - start >= max_samples:
            yield joined.slice(start, start + max_samples)
            start += max_samples
        held = [joined.slice(start, n_held)] if start < n_held else []
        n_held -= start
    if n_held:
        yield concat_chunks(held) if len(held) > 1 else held[0]


def _check_size(size: int) -> None:
    if size < 1:
        raise InvalidParameterError(f"chunk size must be >= 1, got {size}")
