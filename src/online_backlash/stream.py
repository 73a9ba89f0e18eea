"""The one sample type that flows from every source into every estimator.

A *source* (live CAN or serial adapter, or a recorded log replayed) is an iterable of
:class:`Sample` that is also a context manager, has ``close()`` and exposes
:class:`StreamCounters` as ``counters``. Estimators never see a source: the caller refers
the motor angle to the load side (``u = motor_deg / ratio``) and feeds ``u`` and
``y = load_deg`` to ``learn_one``/``learn_many``.

Units at this edge: time in seconds, angles in degrees (multi-turn, unwrapped),
torque in newton metres.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from abc import ABC, abstractmethod
from typing import Iterable, Iterator, TypeVar

import numpy as np

from .errors import InvalidParameterError

#: A time step longer than this many nominal sample periods is a gap (every source uses this rule).
GAP_PERIODS = 3.0


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
        values = (self.time_s, self.motor_deg, self.load_deg)
        if self.torque_Nm is not None:
            values += (self.torque_Nm,)
        return all(math.isfinite(v) for v in values)


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
    """

    counters: StreamCounters

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


def refer_to_load(motor_deg: np.ndarray | float, ratio: float) -> np.ndarray | float:
    """Motor angle referred to the load side, degrees: ``u = motor_deg / ratio``.

    ``ratio`` is the gear ratio motor:load (e.g. 30 for a 30:1 reducer); it is negative
    for a stage that reverses the direction of rotation.
    """
    if not isinstance(ratio, (int, float)) or not math.isfinite(ratio) or ratio == 0:
        raise InvalidParameterError(f"ratio must be a finite non-zero number, got {ratio!r}")
    return motor_deg / ratio


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

    def referred(self, ratio: float) -> tuple[np.ndarray, np.ndarray]:
        """The estimator's input and output, degrees on the load side: ``(u, y) = (motor_deg / ratio, load_deg)``.

        The one place where the motor angle is referred to the load side (:func:`refer_to_load`).
        """
        return np.asarray(refer_to_load(self.motor_deg, ratio)), self.load_deg

    def samples(self) -> Iterator[Sample]:
        """The block as :class:`Sample` objects (torque None where NaN, seq None where absent or negative)."""
        seq = self.seq.tolist() if self.seq is not None else [None] * len(self)
        for t, m, y, q, n, g in zip(
            self.time_s.tolist(), self.motor_deg.tolist(), self.load_deg.tolist(), self.torque_Nm.tolist(), seq, self.after_gap.tolist()
        ):
            yield Sample(t, m, y, None if math.isnan(q) else q, None if n is None or n < 0 else n, g)


def chunked(samples: Iterable[Sample], size: int = 65536) -> Iterator[SampleChunk]:
    """Group an iterable of Samples into :class:`SampleChunk` blocks of at most ``size`` samples.

    Memory stays bounded by ``size`` whatever the length of the stream.
    """
    if size < 1:
        raise InvalidParameterError(f"chunk size must be >= 1, got {size}")
    buf: list[Sample] = []
    for s in samples:
        buf.append(s)
        if len(buf) == size:
            yield _to_chunk(buf)
            buf = []
    if buf:
        yield _to_chunk(buf)


def _to_chunk(buf: list[Sample]) -> SampleChunk:
    return SampleChunk(
        time_s=np.fromiter((s.time_s for s in buf), float, len(buf)),
        motor_deg=np.fromiter((s.motor_deg for s in buf), float, len(buf)),
        load_deg=np.fromiter((s.load_deg for s in buf), float, len(buf)),
        torque_Nm=np.fromiter((np.nan if s.torque_Nm is None else s.torque_Nm for s in buf), float, len(buf)),
        after_gap=np.fromiter((s.after_gap for s in buf), bool, len(buf)),
    )
