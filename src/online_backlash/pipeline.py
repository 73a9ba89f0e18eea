"""The one loop from samples to estimates: chunks -> recursive estimator -> a row every N s of data.

``estimate --trace``, the ``listen`` status line, ``track`` (logs and live) and the wear history
all run :class:`Pipeline`:

1. each :class:`~online_backlash.stream.SampleChunk` is referred to the load side once
   (:meth:`SampleChunk.referred`: ``u = motor_deg / ratio``, ``y = load_deg``);
2. :class:`DataClock` cuts it where an estimate is due: after every ``every_s`` seconds of
   *data*, the sum of the steps between consecutive samples of one segment (steps across a
   gap, across a clock that went back, or from one log to the next count nothing);
3. each block goes to ``estimator.learn_many(u, y, after_gap, time_s=..., torque_Nm=...)``
   (Vörös 2013, eq. 19-25 in :class:`~online_backlash.estimators.BacklashRLS`), with the
   source's time and torque passed through for the estimator's effects;
4. a :class:`PipelineStep` reports the block (samples, referred input) and, where one is due,
   the :class:`~online_backlash.rows.EstimateRow`.

The clock counts whole nanoseconds in an integer, so where the rows fall does not depend on
how the stream was cut into chunks (a resumed run, a live stream, a replay of its raw log).
The pipeline's state (estimator and clock) is a JSON-serialisable dict: the wear history
checkpoints it with each row. The library never prints; the caller decides what a row becomes.
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import InvalidParameterError, LogFormatError
from .rows import GAP_KEYS, EstimateRow
from .stream import SampleChunk, refer_to_load


def check_every(every_s: object) -> float:
    """``every_s`` as a float, or InvalidParameterError unless it is a finite number > 0 (seconds)."""
    if isinstance(every_s, bool) or not isinstance(every_s, (int, float)) or not math.isfinite(every_s) or every_s <= 0:
        raise InvalidParameterError(f"every_s must be a finite number of seconds > 0, got {every_s!r}")
    return float(every_s)


class DataClock:
    """Seconds of data seen, and where the next row is due.

    Parameters
    ----------
    every_s : float or None
        Seconds of data between rows; None: no rows (the clock only counts).
    data_ns : int
        Nanoseconds of data seen so far. Each step is rounded to a whole nanosecond and summed
        as an integer, so the sum does not depend on how the stream was cut into blocks.
    next_due_ns : int, optional
        ``data_ns`` at which the next row is due (default: ``every_s`` after the first sample).
    prev_time_s : float, optional
        Time of the last sample seen in the current segment (None at the start of one).
    """

    def __init__(self, every_s: float | None, data_ns: int = 0, next_due_ns: int | None = None, prev_time_s: float | None = None) -> None:
        self.every_ns = None if every_s is None else max(1, round(check_every(every_s) * 1e9))
        self.data_ns = int(data_ns)
        self.next_due_ns = next_due_ns
        self.prev_time_s = prev_time_s

    def mark_gap(self) -> None:
        """The next sample does not continue the last one: the step to it is no data time."""
        self.prev_time_s = None

    def blocks(self, time_s: np.ndarray, after_gap: np.ndarray) -> Iterator[tuple[int, int, bool]]:
        """Cut a chunk's times into blocks: yield ``(start, end, due)`` for each, in order.

        A block ends at the sample where the data time reaches the next due instant (``due``
        True: a row belongs right after it) or at the end of the chunk. The clock stands at the
        end of a block when it is yielded: the caller learns the block before asking for the next.
        """
        if self.next_due_ns is None and self.every_ns is not None:
            self.next_due_ns = self.data_ns + self.every_ns
        previous = np.concatenate(([np.nan if self.prev_time_s is None else self.prev_time_s], time_s[:-1]))
        step = time_s - previous
        step[after_gap | ~(step > 0.0)] = 0.0  # NaN (start of a segment) and a clock that went back count nothing
        data_ns = self.data_ns + np.cumsum(np.rint(step * 1e9).astype(np.int64))
        n, start = time_s.size, 0
        while start < n:
            due_ns = self.next_due_ns
            reach = n if due_ns is None else start + int(np.searchsorted(data_ns[start:], due_ns, side="left"))
            due = reach < n
            end = reach + 1 if due else n
            self.data_ns = int(data_ns[end - 1])
            self.prev_time_s = float(time_s[end - 1])
            while due_ns is not None and self.every_ns is not None and due_ns <= self.data_ns:
                due_ns += self.every_ns
            self.next_due_ns = due_ns
            yield start, end, due
            start = end

    def state_dict(self) -> dict[str, Any]:
        """The clock as JSON-serialisable values (``every_s`` is the caller's setting, not state)."""
        return {"data_ns": self.data_ns, "next_estimate_ns": self.next_due_ns, "prev_time_s": self.prev_time_s}

    @classmethod
    def from_state(cls, every_s: float | None, d: dict[str, Any]) -> DataClock:
        """A clock from :meth:`state_dict` that continues with ``every_s`` seconds between rows."""
        return cls(every_s, d["data_ns"], d["next_estimate_ns"], d["prev_time_s"])


@dataclass(frozen=True)
class PipelineStep:
    """One block just learned.

    Attributes
    ----------
    chunk : SampleChunk
        The block's samples as the source gave them (time s, angles deg, torque N m).
    u_deg : numpy.ndarray
        The block's motor angle referred to the load side, degrees.
    samples : int
        Samples learned through this pipeline so far, this block included.
    row : EstimateRow or None
        The estimate, where one is due after this block and the estimator has one.
    """

    chunk: SampleChunk
    u_deg: np.ndarray
    samples: int
    row: EstimateRow | None


def _block(chunk: SampleChunk, start: int, end: int) -> SampleChunk:
    if start == 0 and end == len(chunk):
        return chunk
    seq = None if chunk.seq is None else chunk.seq[start:end]
    part = slice(start, end)
    return SampleChunk(chunk.time_s[part], chunk.motor_deg[part], chunk.load_deg[part], chunk.torque_Nm[part], chunk.after_gap[part], seq)


def tail(chunk: SampleChunk, start: int) -> SampleChunk:
    """The samples of ``chunk`` from index ``start`` on."""
    return _block(chunk, start, len(chunk))


#: Default longest gap bridged, seconds: 100 nominal periods of a 1 kHz log (a lost frame, a USB
#: adapter's stall); a longer gap restarts the estimator's reading of the motion.
BRIDGE_S = 0.1
#: Default largest step of either angle across a bridged gap, degrees on the load side: more than
#: a shaft travels in BRIDGE_S at rig speeds (tens of deg/s), so a larger step is a jump in the data
#: (an encoder re-zeroed, another log) and restarts.
JUMP_DEG = 5.0


@dataclass(frozen=True)
class GapPolicy:
    """Which gaps the estimator is carried across (*bridged*) and which restart its reading of the motion.

    A gap (``after_gap`` of a sample) is *short* when the time step across it is at most
    ``bridge_s`` seconds (and positive), and a *jump* when the referred motor angle ``u`` or the
    load angle ``y`` changes by more than ``jump_deg`` degrees across it. A short gap without a
    jump is bridged: the estimator keeps its state (warm-up buffer, flank, covariance) and learns
    the sample after the gap from the one before it, as one longer step. A long gap, a jump, or a
    gap before the first sample after :meth:`Pipeline.mark_gap` is passed on as ``after_gap``.
    ``bridge_s=0`` bridges nothing (every gap restarts, the behaviour before bridging).
    """

    bridge_s: float = BRIDGE_S
    jump_deg: float = JUMP_DEG

    def __post_init__(self) -> None:
        for name in ("bridge_s", "jump_deg"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise InvalidParameterError(f"{name} must be a finite number >= 0, got {value!r}")

    def bridged(self, dt_s: np.ndarray, du_deg: np.ndarray, dy_deg: np.ndarray) -> np.ndarray:
        """True where a gap with time step ``dt_s`` (s) and angle steps ``du_deg``, ``dy_deg`` (deg) is bridged
        (NaN steps, i.e. no sample before the gap, are never bridged)."""
        with np.errstate(invalid="ignore"):
            return (dt_s > 0.0) & (dt_s <= self.bridge_s) & (np.abs(du_deg) <= self.jump_deg) & (np.abs(dy_deg) <= self.jump_deg)


@dataclass
class GapTally:
    """The gaps a stream had: count, longest and total time step across them (seconds), and how many were bridged."""

    gaps: int = 0
    longest_s: float = 0.0
    total_s: float = 0.0
    bridged: int = 0

    def add(self, dt_s: np.ndarray, bridged: np.ndarray) -> None:
        """Count gaps with time steps ``dt_s`` (s; NaN where the step is unknown) and their bridged flags."""
        known = dt_s[np.isfinite(dt_s)]
        self.gaps += int(dt_s.size)
        self.bridged += int(np.count_nonzero(bridged))
        if known.size:
            self.longest_s = max(self.longest_s, float(known.max()))
            self.total_s += float(known.sum())

    def values(self) -> dict[str, float | int]:
        """The gap figures of a result (:data:`~online_backlash.rows.GAP_KEYS`)."""
        return dict(zip(GAP_KEYS, (self.longest_s, self.total_s, self.bridged)))

    @classmethod
    def of_chunk(cls, chunk: SampleChunk) -> GapTally:
        """The gaps of one whole log in memory (no gap bridged: a batch fit reads no motion across them)."""
        tally = cls()
        index = np.flatnonzero(chunk.after_gap[1:]) + 1
        tally.add(chunk.time_s[index] - chunk.time_s[index - 1], np.zeros(index.size, dtype=bool))
        if chunk.after_gap.size and chunk.after_gap[0]:
            tally.add(np.array([np.nan]), np.zeros(1, dtype=bool))
        return tally


#: Blocks a reader thread may hold ready ahead of the estimator (:func:`read_ahead`).
READ_AHEAD = 1


class _Raised:
    """An exception of the reader thread, handed to the consumer to raise."""

    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


_END = object()


def read_ahead(chunks: Iterable[SampleChunk], depth: int = READ_AHEAD) -> Iterator[SampleChunk]:
    """The chunks of ``chunks``, read in a thread of their own at most ``depth`` chunks ahead.

    The compiled estimator releases the GIL while it learns a block (``nogil``), and the file
    readers' libraries (pyarrow, asammdf, numpy) do most of their work without it, so on two
    cores the next block is decoded while the current one is learned. The chunks, their order
    and what the source counts are those of iterating ``chunks`` directly; an exception of the
    reader is raised here, at the chunk where it occurred. Closing this generator early (the
    consumer stopped) stops the reader and closes ``chunks`` in the reader's thread.
    ``depth=0`` reads on the caller's thread (no thread at all).
    """
    if depth <= 0:
        yield from chunks
        return
    ready: queue.Queue[Any] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def hand(item: Any) -> bool:
        """Put ``item`` in the queue unless the consumer has stopped; False if it has."""
        while not stop.is_set():
            try:
                ready.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def reader() -> None:
        source = iter(chunks)
        try:
            for chunk in source:
                if not hand(chunk):
                    break
            else:
                hand(_END)
        except BaseException as exc:  # handed over: raised on the consumer's thread
            hand(_Raised(exc))
        finally:
            close = getattr(source, "close", None)
            if close is not None:
                close()

    thread = threading.Thread(target=reader, name="online-backlash-read-ahead", daemon=True)
    thread.start()
    try:
        while True:
            item = ready.get()
            if item is _END:
                break
            if isinstance(item, _Raised):
                raise item.exc
            yield item
    finally:
        stop.set()
        thread.join()


class Pipeline:
    """Feed chunks of samples to a recursive estimator and emit a row every ``every_s`` seconds of data.

    Parameters
    ----------
    estimator : BacklashRLS-like
        A recursive estimator (``learn_many(u, y, after_gap, time_s=, torque_Nm=)``, ``started``,
        ``force_start()``, ``mark_gap()`` and the fitted attributes :class:`EstimateRow` reads).
    ratio : float
        Gear ratio motor:load (negative for a reversing stage): ``u = motor_deg / ratio``.
    every_s : float or None
        Seconds of data between rows (None: no rows but the one :meth:`finish` gives).
    clock : DataClock, optional
        Continue this clock (e.g. from a checkpoint) instead of a new one.
    gap_policy : GapPolicy, optional
        Which gaps are bridged (default: :class:`GapPolicy` with ``BRIDGE_S``, ``JUMP_DEG``).
        The gaps seen are tallied in ``gap_tally`` (:class:`GapTally`).

    Examples
    --------
    >>> from online_backlash import BacklashRLS
    >>> from online_backlash.rig import simulate_rig
    >>> rec = simulate_rig(duration_s=20.0, ratio=30.0, play_deg=0.5, seed=1)
    >>> pipe = Pipeline(BacklashRLS(), 30.0, every_s=5.0)
    >>> rows = [s.row for s in pipe.run([rec.to_chunk()]) if s.row is not None]
    >>> [round(r.time_s) for r in rows]  # after the 10 s warm start, every 5 s of data
    [10, 15]
    >>> round(pipe.finish().backlash_deg, 1)
    0.5
    """

    def __init__(
        self,
        estimator: Any,
        ratio: float,
        every_s: float | None = 1.0,
        clock: DataClock | None = None,
        gap_policy: GapPolicy | None = None,
    ) -> None:
        refer_to_load(0.0, ratio)  # validates the ratio now, not at the first chunk
        self.estimator = estimator
        self.ratio = ratio
        self.clock = clock if clock is not None else DataClock(every_s)
        self.gap_policy = gap_policy if gap_policy is not None else GapPolicy()
        self.gap_tally = GapTally()
        self.samples = 0
        self.samples_since_row = 0
        self.last_time_s: float | None = None
        self._last_uy: tuple[float, float] | None = None  # referred angles of the last sample of the segment (deg)

    def mark_gap(self) -> None:
        """The next sample does not continue the last one (a new log, a resumed run): never bridged."""
        self.estimator.mark_gap()
        self.clock.mark_gap()
        self._last_uy = None

    def _restarts(self, chunk: SampleChunk, u: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The chunk's ``after_gap`` without the gaps :attr:`gap_policy` bridges; tallies every gap."""
        index = np.flatnonzero(chunk.after_gap)
        if not index.size:
            return chunk.after_gap
        last = (np.nan, np.nan, np.nan) if self._last_uy is None or self.last_time_s is None else (self.last_time_s, *self._last_uy)
        dt, du, dy = (x[index] - np.concatenate(([x0], x[:-1]))[index] for x, x0 in zip((chunk.time_s, u, y), last))
        bridged = self.gap_policy.bridged(dt, du, dy)
        self.gap_tally.add(dt, bridged)
        restarts = chunk.after_gap.copy()
        restarts[index[bridged]] = False
        return restarts

    def feed(self, chunk: SampleChunk) -> Iterator[PipelineStep]:
        """Learn one chunk, block by block; yield a :class:`PipelineStep` after each block.

        Gaps that :attr:`gap_policy` bridges reach the estimator as ordinary steps; the data
        clock counts no time across any gap.
        """
        if not len(chunk):
            return
        u, y = chunk.referred(self.ratio)
        restarts = self._restarts(chunk, u, y)
        self._last_uy = (float(u[-1]), float(y[-1]))
        for start, end, due in self.clock.blocks(chunk.time_s, chunk.after_gap):
            block = _block(chunk, start, end)
            self.estimator.learn_many(u[start:end], y[start:end], restarts[start:end], time_s=block.time_s, torque_Nm=block.torque_Nm)
            self.samples += end - start
            self.samples_since_row += end - start
            self.last_time_s = float(block.time_s[-1])
            row = EstimateRow.from_estimator(self.estimator, self.last_time_s) if due else None
            if row is not None:
                self.samples_since_row = 0
            yield PipelineStep(block, u[start:end], self.samples, row)

    def run(self, chunks: Iterable[SampleChunk], source: str = "<stream>", ahead: int = 0) -> Iterator[PipelineStep]:
        """:meth:`feed` every chunk; LogFormatError naming ``source`` if there was no sample at all.

        ``ahead`` > 0 reads the chunks in a thread of their own, that many ahead (:func:`read_ahead`):
        for recorded files, whose reading then overlaps the estimation.
        """
        seen = self.samples
        for chunk in read_ahead(chunks, ahead):
            yield from self.feed(chunk)
        if self.samples == seen:
            raise LogFormatError(source, None, "no data rows")

    def finish(self) -> EstimateRow | None:
        """End of the stream: start the estimator on what it buffered (a stream shorter than its
        warm start), and return the last row if samples were learned since the last one."""
        self.estimator.force_start()
        if not self.samples_since_row or self.last_time_s is None:
            return None
        self.samples_since_row = 0
        return EstimateRow.from_estimator(self.estimator, self.last_time_s)
