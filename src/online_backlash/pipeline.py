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
4. a :class:`PipelineStep` reports the block (samples, referred input), whether a row is due
   after it (``due``) and, where one is due and the pipeline makes rows (``rows=True``), the
   :class:`~online_backlash.output_columns.EstimateRow` (a row costs the estimator's standard error: a
   caller that only needs the instants, as ``estimate`` without ``--trace``, asks for none; then
   the estimator learns each chunk in one call and records its estimate at the ticks inside it,
   ``learn_many(..., snapshot_at=)``, so the ticks do not cut its compiled loop).

Each chunk is referred and checked once for non-finite angles (one compiled pass,
:func:`_refer_checked`, the same division as :meth:`SampleChunk.referred`) before any of it reaches
the estimator, which then skips its own per-block check (``learn_many(..., assume_finite=True)``).
The clock's cutting is compiled too; the loop itself only hands arrays from one compiled pass
to the next, so the GIL is free most of the time for a reader thread (:func:`read_ahead`).

The clock counts whole nanoseconds in an integer, so where the rows fall does not depend on
how the stream was cut into chunks (a resumed run, a live stream, a replay of its raw log).
The pipeline's state (estimator and clock) is a JSON-serialisable dict: the wear history
checkpoints it with each row. The library never prints; the caller decides what a row becomes.
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Generic, NamedTuple, Protocol, TypeVar

import numba
import numpy as np

from .errors import InvalidParameterError, LogFormatError
from .gap_policy import GapTally
from .output_columns import EstimateRow
from .stream import SampleChunk, refer_to_load


@numba.njit(cache=True, nogil=True)
def _cut(time_s, after_gap, prev, data_ns, has_due, due_ns, every_ns):  # pragma: no cover - compiled
    """:meth:`DataClock.blocks` in one pass: each block's end, whether a row is due after it, and the
    clock (data ns, next due ns) there. A step counts ``rint(step * 1e9)`` ns unless it follows a
    gap, starts a segment (``prev`` NaN) or goes back."""
    n = time_s.size
    ends = np.empty(n, dtype=np.int64)
    dues = np.zeros(n, dtype=np.bool_)
    datas = np.empty(n, dtype=np.int64)
    nexts = np.empty(n, dtype=np.int64)
    k = 0
    for i in range(n):
        step = time_s[i] - prev
        if after_gap[i] or not step > 0.0:  # NaN (start of a segment) and a clock that went back count nothing
            step = 0.0
        data_ns += np.int64(np.rint(step * 1e9))
        prev = time_s[i]
        if (has_due and data_ns >= due_ns) or i == n - 1:
            dues[k] = has_due and data_ns >= due_ns
            while has_due and every_ns > 0 and due_ns <= data_ns:
                due_ns += every_ns
            ends[k], datas[k], nexts[k] = i + 1, data_ns, due_ns
            k += 1
    return ends[:k], dues[:k], datas[:k], nexts[:k]


@numba.njit(cache=True, nogil=True)
def _refer_checked(motor_deg, load_deg, ratio):  # pragma: no cover - compiled
    """``u = motor_deg / ratio`` (:func:`~online_backlash.stream.refer_to_load`, the same IEEE division, so the
    same numbers) and the index of the first sample where ``u`` or ``load_deg`` is not finite (-1 if none),
    in one pass over the chunk instead of a division pass and a checking pass."""
    n = motor_deg.size
    u = np.empty(n)
    bad = -1
    for i in range(n):
        u[i] = motor_deg[i] / ratio
        if bad < 0 and not (math.isfinite(u[i]) and math.isfinite(load_deg[i])):
            bad = i
    return u, bad


class Snapshot(Protocol):
    """The estimate at one instant, as ``learn_many(..., snapshot_at=)`` records it
    (:class:`~online_backlash.estimators.EstimateAt`): the pipeline reads whether the estimator had started."""

    @property
    def started(self) -> bool: ...


class LearningEstimator(Protocol):
    """What the pipeline calls of its estimator: every recursive estimator on
    :class:`~online_backlash.estimators.RecursiveEstimator` (``BacklashRLS``, ``CascadeRLS``,
    ``TorqueBacklashRLS``) and :class:`~online_backlash.load_aware.PlayChooser` have it.

    ``learn_many`` learns a block (``u``, ``y`` deg, ``after_gap``; ``time_s`` s and ``torque_Nm`` N m passed
    through); with ``assume_finite=True`` it skips its own finiteness check (the pipeline checked the chunk
    once); with ``snapshot_at`` (ascending sample counts of the block) it returns its estimate after each,
    else None. A row reads the estimator's fitted figures (:meth:`EstimateRow.from_estimator
    <online_backlash.output_columns.EstimateRow.from_estimator>`).
    """

    @property
    def started(self) -> bool: ...

    @property
    def gaps_(self) -> GapTally: ...

    def learn_many(
        self,
        u: np.ndarray,
        y: np.ndarray,
        after_gap: np.ndarray | None = None,
        *,
        time_s: np.ndarray | None = None,
        torque_Nm: np.ndarray | None = None,
        assume_finite: bool = False,
        snapshot_at: np.ndarray | None = None,
    ) -> Sequence[Snapshot] | None: ...

    def mark_gap(self) -> None: ...

    def force_start(self) -> None: ...


#: The estimator type a :class:`Pipeline` runs (so ``pipeline.estimator`` keeps its own type)
E = TypeVar("E", bound=LearningEstimator)


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

    def __init__(
        self, every_s: float | None, data_ns: int = 0, next_due_ns: int | None = None, prev_time_s: float | None = None
    ) -> None:
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
        ends, dues, data_ns, next_ns, has_due = self._cut(time_s, after_gap)
        start = 0
        for end, due, data, next_due in zip(ends.tolist(), dues.tolist(), data_ns.tolist(), next_ns.tolist()):
            self.data_ns = data
            self.prev_time_s = float(time_s[end - 1])
            self.next_due_ns = next_due if has_due else self.next_due_ns
            yield start, end, due
            start = end

    def ticks(self, time_s: np.ndarray, after_gap: np.ndarray) -> tuple[int, ...]:
        """The ticks in a chunk, as counts of its samples (a tick falls right after sample ``ticks[k] - 1``),
        ascending: the ends of the due blocks of :meth:`blocks`, and the clock at the chunk's end, as after
        iterating them all (one compiled pass, no Python per block)."""
        ends, dues, data_ns, next_ns, has_due = self._cut(time_s, after_gap)
        if not ends.size:
            return ()
        self.data_ns = int(data_ns[-1])
        self.prev_time_s = float(time_s[ends[-1] - 1])
        self.next_due_ns = int(next_ns[-1]) if has_due else self.next_due_ns
        return tuple(ends[dues].tolist())

    def _cut(
        self, time_s: np.ndarray, after_gap: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
        """:func:`_cut` from the clock's state: each block's end, due, data ns and next due ns; and whether
        the clock has a due instant (without ``every_s``, one restored from a state never moves on)."""
        if self.next_due_ns is None and self.every_ns is not None:
            self.next_due_ns = self.data_ns + self.every_ns
        prev = math.nan if self.prev_time_s is None else self.prev_time_s
        has_due = self.next_due_ns is not None
        ends, dues, data_ns, next_ns = _cut(
            np.ascontiguousarray(time_s, dtype=float), np.ascontiguousarray(after_gap, dtype=np.bool_),
            prev, self.data_ns, has_due, self.next_due_ns or 0, self.every_ns or 0,
        )  # fmt: skip
        return ends, dues, data_ns, next_ns, has_due

    def state_dict(self) -> dict[str, Any]:
        """The clock as JSON-serialisable values (``every_s`` is the caller's setting, not state)."""
        return {"data_ns": self.data_ns, "next_estimate_ns": self.next_due_ns, "prev_time_s": self.prev_time_s}

    @classmethod
    def from_state(cls, every_s: float | None, d: dict[str, Any]) -> DataClock:
        """A clock from :meth:`state_dict` that continues with ``every_s`` seconds between rows."""
        return cls(every_s, d["data_ns"], d["next_estimate_ns"], d["prev_time_s"])


class _Referred(NamedTuple):
    """A chunk ready for the estimator: ``u`` (motor / ratio) and ``y``, deg, checked finite, and for a
    pipeline that learns whole chunks (:meth:`Pipeline._feed_whole`) the data-clock ticks in it."""

    chunk: SampleChunk
    u_deg: np.ndarray
    y_deg: np.ndarray
    ticks: tuple[int, ...] | None = None


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
        The estimate, where one is due after this block, the estimator has one and the pipeline
        makes rows (``rows``).
    due : bool
        The block ends at a data-clock tick (a row belongs right after it), rows made or not.
    ticks : tuple of int
        The data-clock ticks in the block, as counts of its samples (a tick falls right after
        sample ``ticks[k] - 1``), ascending: ``(len(chunk),)`` or ``()`` for a block cut at the
        ticks; a pipeline without rows over an estimator that records snapshots hands whole chunks
        with every tick in them.
    estimates : list or None
        Where the block was not cut at its ticks: the estimator's estimate at each tick, as its
        ``learn_many(..., snapshot_at=ticks)`` gave it (``started``, the play and slopes); else None.
    """

    chunk: SampleChunk
    u_deg: np.ndarray
    samples: int
    row: EstimateRow | None
    due: bool = False
    ticks: tuple[int, ...] = ()
    estimates: Sequence[Snapshot] | None = None


def _block(chunk: SampleChunk, start: int, end: int) -> SampleChunk:
    if start == 0 and end == len(chunk):
        return chunk
    seq = None if chunk.seq is None else chunk.seq[start:end]
    part = slice(start, end)
    return SampleChunk(
        chunk.time_s[part],
        chunk.motor_deg[part],
        chunk.load_deg[part],
        chunk.torque_Nm[part],
        chunk.after_gap[part],
        seq,
    )


def tail(chunk: SampleChunk, start: int) -> SampleChunk:
    """The samples of ``chunk`` from index ``start`` on."""
    return _block(chunk, start, len(chunk))


#: Blocks a reader thread may hold ready ahead of the estimator (:func:`read_ahead`).
READ_AHEAD = 1


class _Raised:
    """An exception of the reader thread, handed to the consumer to raise."""

    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


_END = object()


_Item = TypeVar("_Item")


def read_ahead(chunks: Iterable[_Item], depth: int = READ_AHEAD) -> Iterator[_Item]:
    """The items of ``chunks`` (chunks, or chunks made ready for the estimator: :meth:`Pipeline.run`),
    read in a thread of their own at most ``depth`` items ahead.

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


class OrderedWorker:
    """Calls run one at a time, in the order given, in a worker thread at most ``depth`` calls behind.

    For per-block bookkeeping that reads only what it is handed (the block's arrays, a snapshot of
    the estimator taken when the call was made), so that it overlaps the next block's estimation on
    a second core. An exception of a call is raised on the caller's thread, at the next
    :meth:`call` or at :meth:`join`; the calls after it are skipped. ``depth=0`` runs each call at
    once on the caller's thread (no thread at all). As a context manager: leaving the block
    normally joins the worker (raising its exception); leaving it by an exception stops the worker
    (the calls still queued are dropped) and waits for it.

    Attributes
    ----------
    stopped : threading.Event
        Set when the caller failed (the calls still queued are dropped); a call may wait for it.
    """

    def __init__(self, depth: int, name: str = "online-backlash-bookkeeping") -> None:
        self._calls: queue.Queue[Any] = queue.Queue(maxsize=max(depth, 1))
        self._error: BaseException | None = None
        self.stopped = threading.Event()
        self._thread = threading.Thread(target=self._work, name=name, daemon=True) if depth > 0 else None
        if self._thread is not None:
            self._thread.start()

    def _work(self) -> None:
        while (item := self._calls.get()) is not _END:
            if self._error is None and not self.stopped.is_set():
                fn, args, kwargs = item
                try:
                    fn(*args, **kwargs)
                except BaseException as exc:  # handed over: raised on the caller's thread
                    self._error = exc

    def call(self, fn: Callable[..., object], *args: Any, **kwargs: Any) -> None:
        """Run ``fn(*args, **kwargs)`` after the calls given before (waits while ``depth`` are queued)."""
        if self._thread is None:
            fn(*args, **kwargs)
            return
        self._raise()
        self._calls.put((fn, args, kwargs))

    def _raise(self) -> None:
        if self._error is not None:
            raise self._error

    def _end(self) -> None:
        """Let the worker run what is queued (unless stopped), then end it and wait for it."""
        if self._thread is not None and self._thread.is_alive():
            self._calls.put(_END)
            self._thread.join()

    def join(self) -> None:
        """Wait until every call given has run; raise the exception of a call that failed."""
        self._end()
        self._raise()

    def __enter__(self) -> OrderedWorker:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: Any) -> None:
        if exc_type is None:
            self.join()
        else:  # the caller failed: drop the queued calls, keep the caller's exception
            self.stopped.set()
            self._end()


class Pipeline(Generic[E]):
    """Feed chunks of samples to a recursive estimator and emit a row every ``every_s`` seconds of data.

    Parameters
    ----------
    estimator : LearningEstimator
        A recursive estimator (:class:`LearningEstimator`: ``learn_many(u, y, after_gap, time_s=, torque_Nm=,
        assume_finite=, snapshot_at=)``, ``started``, ``force_start()``, ``mark_gap()``, ``gaps_``, and the
        fitted attributes :class:`EstimateRow` reads); the pipeline checks each chunk once.
    ratio : float
        Gear ratio motor:load (negative for a reversing stage): ``u = motor_deg / ratio``.
    every_s : float or None
        Seconds of data between rows (None: no rows but the one :meth:`finish` gives).
    clock : DataClock, optional
        Continue this clock (e.g. from a checkpoint) instead of a new one.
    rows : bool
        Make the :class:`EstimateRow` of each tick (``PipelineStep.row``). False: the steps only say
        where a tick falls (``PipelineStep.due``), for a caller that needs the instants but not
        the rows, which cost time (the estimator's standard error); :meth:`finish` still gives
        the last row. The estimator then learns each chunk in one call, its estimate recorded at every
        tick inside it (``snapshot_at``; ``PipelineStep.ticks`` and ``estimates``): a tick does not cut
        the compiled loop.

    The estimator decides which gaps are bridged (its ``gap_policy``,
    :class:`~online_backlash.gap_policy.GapPolicy`) and tallies them (``gaps_``, read here as
    :attr:`gap_tally`); the pipeline passes every ``after_gap`` on.

    Examples
    --------
    >>> from online_backlash import BacklashRLS
    >>> from online_backlash.simulation.rig import simulate_rig
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
        estimator: E,
        ratio: float,
        every_s: float | None = 1.0,
        clock: DataClock | None = None,
        rows: bool = True,
    ) -> None:
        refer_to_load(0.0, ratio)  # validates the ratio now, not at the first chunk
        self.estimator = estimator
        self.ratio = ratio
        self.rows = rows
        # without rows, a tick needs only the estimate there: recorded inside one call per chunk
        self._whole_chunks = not rows
        self.clock = clock if clock is not None else DataClock(every_s)
        self.samples = 0
        self.samples_since_row = 0
        self.last_time_s: float | None = None

    @property
    def gap_tally(self) -> GapTally:
        """The gaps seen (:class:`~online_backlash.gap_policy.GapTally`): the estimator's ``gaps_``."""
        tally: GapTally = self.estimator.gaps_
        return tally

    def mark_gap(self) -> None:
        """The next sample does not continue the last one (a new log, a resumed run): never bridged."""
        self.estimator.mark_gap()
        self.clock.mark_gap()

    def feed(self, chunk: SampleChunk) -> Iterator[PipelineStep]:
        """Learn one chunk, block by block; yield a :class:`PipelineStep` after each block.

        Every ``after_gap`` reaches the estimator, which bridges the short ones (its
        ``gap_policy``); the data clock counts no time across any gap.
        """
        yield from self._learn(self._refer(chunk))

    def _refer(self, chunk: SampleChunk) -> _Referred | None:
        """A chunk's estimator input and output (``u = motor / ratio``, ``y``), checked finite once
        for the whole chunk, so the estimator skips its own check (the division and the check in
        one compiled pass, :func:`_refer_checked`); None for an empty chunk. For a pipeline that learns
        whole chunks, the data clock's ticks in the chunk too (:meth:`DataClock.ticks`). Depends on nothing
        the estimator changes: :meth:`run` calls it in the reader thread (the clock then runs up to the
        chunks read ahead beyond the estimator until the run ends)."""
        if not len(chunk):
            return None
        # once per chunk, not per block: a non-finite value never reaches the estimator
        y = np.ascontiguousarray(chunk.load_deg, dtype=float)
        if chunk.motor_deg.dtype == np.float64:
            u, bad = _refer_checked(np.ascontiguousarray(chunk.motor_deg), y, float(self.ratio))
        else:  # numpy divides other dtypes in their own precision: referred as such, then checked (/ 1.0 is exact)
            u, bad = _refer_checked(np.ascontiguousarray(chunk.referred(self.ratio)[0], dtype=float), y, 1.0)
        if bad >= 0:
            name = "u (motor angle / ratio)" if not math.isfinite(u[bad]) else "y (load angle)"
            raise InvalidParameterError(
                f"{name} has non-finite values, first at index {bad} of the chunk (time {chunk.time_s[bad]} s)"
            )
        return _Referred(chunk, u, y, self.clock.ticks(chunk.time_s, chunk.after_gap) if self._whole_chunks else None)

    def _learn(self, referred: _Referred | None) -> Iterator[PipelineStep]:
        """The estimator learns a referred chunk, block by block (or whole, see :meth:`_feed_whole`)."""
        if referred is None:
            return
        chunk, u, y, ticks = referred
        if ticks is not None:
            yield self._feed_whole(chunk, u, y, ticks)
            return
        for start, end, due in self.clock.blocks(chunk.time_s, chunk.after_gap):
            block = _block(chunk, start, end)
            self.estimator.learn_many(
                u[start:end],
                y[start:end],
                block.after_gap,
                time_s=block.time_s,
                torque_Nm=block.torque_Nm,
                assume_finite=True,
            )
            self.samples += end - start
            self.samples_since_row += end - start
            self.last_time_s = float(block.time_s[-1])
            row = EstimateRow.from_estimator(self.estimator, self.last_time_s) if due and self.rows else None
            if row is not None or (due and not self.rows and self.estimator.started):
                self.samples_since_row = 0
            yield PipelineStep(block, u[start:end], self.samples, row, due, (end - start,) if due else ())

    def _feed_whole(self, chunk: SampleChunk, u: np.ndarray, y: np.ndarray, ticks: tuple[int, ...]) -> PipelineStep:
        """:meth:`feed` of a pipeline without rows over an estimator that records snapshots: the whole
        chunk in one ``learn_many`` call, the estimate recorded at each of its ``ticks`` (``snapshot_at``);
        the same estimates, ticks and counts as cutting the chunk at the ticks."""
        estimates = self.estimator.learn_many(
            u,
            y,
            chunk.after_gap,
            time_s=chunk.time_s,
            torque_Nm=chunk.torque_Nm,
            snapshot_at=np.array(ticks, dtype=np.int64),
            assume_finite=True,
        )
        assert estimates is not None  # (snapshot_at given)
        n = len(chunk)
        self.samples += n
        started = [
            tick for tick, at in zip(ticks, estimates) if at.started
        ]  # a tick of a started estimator makes its row
        self.samples_since_row = n - started[-1] if started else self.samples_since_row + n
        self.last_time_s = float(chunk.time_s[-1])
        return PipelineStep(chunk, u, self.samples, None, bool(ticks) and ticks[-1] == n, ticks, estimates)

    def run(self, chunks: Iterable[SampleChunk], source: str = "<stream>", ahead: int = 0) -> Iterator[PipelineStep]:
        """:meth:`feed` every chunk; LogFormatError naming ``source`` if there was no sample at all.

        ``ahead`` > 0 reads the chunks in a thread of their own, that many ahead (:func:`read_ahead`):
        for recorded files, whose reading then overlaps the estimation; that thread also refers each
        chunk to the load side and checks it finite (:meth:`_refer`), so the estimator's thread only learns.
        """
        seen = self.samples
        # with a reader thread, the chunks are referred and checked there too (beside the decoding)
        for referred in read_ahead(map(self._refer, chunks), ahead):
            yield from self._learn(referred)
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
