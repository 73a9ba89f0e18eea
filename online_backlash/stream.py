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
from typing import Iterable, Iterator, Protocol, runtime_checkable

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


@runtime_checkable
class Source(Protocol):
    """What every adapter provides: iterate Samples, count, close."""

    counters: StreamCounters

    def __iter__(self) -> Iterator[Sample]: ...

    def close(self) -> None: ...

    def __enter__(self) -> "Source": ...

    def __exit__(self, *exc: object) -> None: ...


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

    ``segment_start[i]`` is True where sample ``i`` follows a gap (or starts the stream).
    Times in seconds, angles in degrees, torque in N m (NaN where absent).
    """

    time_s: np.ndarray
    motor_deg: np.ndarray
    load_deg: np.ndarray
    torque_Nm: np.ndarray
    after_gap: np.ndarray

    def __len__(self) -> int:
        return len(self.time_s)


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
