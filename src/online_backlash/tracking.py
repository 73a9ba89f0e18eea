"""Track a gearbox: run its logs through the pipeline and checkpoint it, with its estimates, in the store.

One gearbox has one :class:`~online_backlash.pipeline.Pipeline` (its estimator,
:class:`~online_backlash.estimators.BacklashRLS`, the recursive form of Vörös 2013, and its data
clock) and one :class:`~online_backlash.history.usage.UsageCounter` for its whole life: every
log continues from the state the previous one left, so the estimate follows the wear. Each log is a *run* of the store, keyed by its
samples (:func:`sample_key`: the SHA-256 of the first :data:`IDENTITY_SAMPLES` times and angles, decoded), not by its
bytes: ``day01.csv.gz`` and its unzipped copy are one log, and a copy with a bad row fixed
after the first samples is the log already tracked.

A gearbox's logs are tracked in time order: a new log that starts before a stored run of the
gearbox ends (an overlapping copy, a log placed by a wrong clock, an older log given after a
newer one) is refused with :class:`~online_backlash.errors.HistoryError` naming that run, so no
operating hour is counted twice and no use per day is negative. :func:`in_time_order` sorts the
logs of one call by their first sample's calendar time.

Every ``every_s`` seconds of data an estimate is appended, and in the same transaction the
tracker state (estimator, with its effects by name; usage counters; data clock) becomes the gearbox's checkpoint and the
run's resume point (``samples_done``) moves on. A process killed at any instant therefore
leaves a consistent store; run again on the same log, it skips the samples the checkpoint
already holds and continues, so the history ends the same as an uninterrupted run: no
duplicate, no missing row, nothing learnt twice. Of a log already complete only its first
samples are read (its key). A store written before logs were keyed by their samples holds the
files' SHA-256 (:func:`file_sha256`) as keys: a log whose sample key the gearbox does not know is
looked up by that too, so its runs are still found complete or resumed.

Calendar time of a sample: ``start_unix_s + (time_s - first time_s)`` when a start is given;
the time column itself when it holds UNIX times (at least :data:`UNIX_TIME_MIN`); otherwise
the log file's modification time is taken as its start. The first run of a log fixes it
(``runs.started_unix_s``); a resumed run keeps it. :attr:`TrackResult.clock` names the clock used.

This module sits above :mod:`online_backlash.history` (which only stores rows) and below the
CLI: it is where readers, estimators and the store meet.
"""

from __future__ import annotations

import copy
import datetime as dt
import hashlib
import math
import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from importlib import resources
from itertools import chain
from typing import Any, NamedTuple

import numpy as np

from .effect_terms import effect_to_dict
from .errors import HistoryError, InvalidParameterError, LogFormatError, NotExcitedError
from .estimators import BacklashRLS
from .fitting import recursive_estimator
from .history.condition import LoadCondition
from .history.series import WearSeries
from .history.store import Gearbox, HistoryStore, Run
from .history.usage import UsageCounter
from .load_aware import PlayChooser, TorqueBacklashRLS
from .load_aware.choice import NO_TORQUE, check_play_method
from .pipeline import DataClock, Pipeline, check_every, tail
from .replay import open_log
from .rows import STORE_COLUMNS, EstimateRow, select, source_counts
from .stream import UNIX_TIME_MIN, SampleChunk, SampleSource, live_clock_offset, refer_to_load

#: Version of the checkpoint's layout (inside the store's ``gearboxes.checkpoint``).
CHECKPOINT_FORMAT = 1

#: ``progress(samples_fed, backlash_deg or None)``, called after every block.
ProgressCallback = Callable[[int, "float | None"], None]
#: ``on_row(row, time_unix_s)``, called after each estimate is committed.
RowCallback = Callable[[EstimateRow, float], None]


def file_sha256(path: str | os.PathLike[str], block_bytes: int = 1 << 20) -> str:
    """SHA-256 of a file's bytes: the key of a log in stores written before :func:`sample_key`."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(block_bytes):
            digest.update(block)
    return digest.hexdigest()


#: Samples at the start of a log whose times and angles identify it (:func:`sample_key`).
IDENTITY_SAMPLES = 4096

#: The clocks a log's samples can be placed by (:attr:`TrackResult.clock`).
CLOCK_START, CLOCK_UNIX, CLOCK_MTIME, CLOCK_LIVE = "--start", "UNIX time column", "file modification time", "live: first sample is now"


class LogClock(NamedTuple):
    """How a log's ``time_s`` becomes calendar time: ``offset_s`` seconds to add, and the clock's name."""

    offset_s: float
    name: str


def log_clock(path: str | os.PathLike[str], first_time_s: float, start_unix_s: float | None = None) -> LogClock:
    """The clock of a log whose first sample is at ``first_time_s`` (see the module docstring)."""
    if start_unix_s is not None:
        return LogClock(start_unix_s - first_time_s, CLOCK_START)
    if first_time_s >= UNIX_TIME_MIN:
        return LogClock(0.0, CLOCK_UNIX)
    return LogClock(os.stat(path).st_mtime - first_time_s, CLOCK_MTIME)


def log_clock_offset(path: str | os.PathLike[str], first_time_s: float, start_unix_s: float | None = None) -> float:
    """Seconds to add to the log's ``time_s`` to get UNIX time (see the module docstring)."""
    return log_clock(path, first_time_s, start_unix_s).offset_s


def sample_key(chunks: Iterable[SampleChunk], n: int = IDENTITY_SAMPLES) -> tuple[str | None, Iterator[SampleChunk]]:
    """A log's identity: SHA-256 (hex) of its first ``n`` samples' ``time_s``, ``motor_deg`` and
    ``load_deg`` (little-endian float64), and the chunks again, none lost (None for no samples).

    The samples as decoded, not the file's bytes: the same recording compressed, renamed or in
    another container gives the same key.
    """
    it = iter(chunks)
    head: list[SampleChunk] = []
    count = 0
    for chunk in it:
        head.append(chunk)
        count += len(chunk)
        if count >= n:
            break
    if count == 0:
        return None, chain(head, it)
    digest = hashlib.sha256()
    for name in ("time_s", "motor_deg", "load_deg"):
        values = np.concatenate([np.asarray(getattr(c, name), dtype=np.float64) for c in head])[:n]
        digest.update(values.astype("<f8").tobytes())
    return digest.hexdigest(), chain(head, it)


def first_time_unix_s(path: str | os.PathLike[str], log_options: dict[str, Any] | None = None, start_unix_s: float | None = None) -> float:
    """Calendar time of a log's first sample, UNIX seconds (reads only its first block)."""
    with open_log(path, **(log_options or {})) as reader:
        first = next(iter(reader.iter_chunks()), None)
    if first is None or len(first) == 0:
        raise LogFormatError(path, None, "no data rows")
    first_time_s = float(first.time_s[0])
    return first_time_s + log_clock(path, first_time_s, start_unix_s).offset_s


def in_time_order(
    paths: Iterable[str | os.PathLike[str]], log_options: Callable[[str], dict[str, Any]], start_unix_s: float | None = None
) -> list[str]:
    """The logs sorted by their first sample's calendar time (stable: equal times keep their order).

    ``log_options(path)`` gives each log's reader options.
    """
    named = [os.fspath(p) for p in paths]
    starts = {p: first_time_unix_s(p, log_options(p), start_unix_s) for p in named}
    return sorted(named, key=lambda p: starts[p])


def log_files(path: str | os.PathLike[str]) -> list[str]:
    """A log, or the files of a log directory (a ``listen --raw-log`` folder) in name (= time) order.

    A capture still being written (``...-active.<suffix>``) and hidden files are left out.
    """
    path = os.fspath(path)
    if not os.path.isdir(path):
        return [path]
    names = sorted(e.name for e in os.scandir(path) if e.is_file() and not e.name.startswith(".") and "-active." not in e.name)
    if not names:
        raise LogFormatError(path, None, "no finished log files in this directory")
    return [os.path.join(path, name) for name in names]


@dataclass
class TrackResult:
    """What one ``track`` call did.

    Attributes
    ----------
    already_imported : bool
        The log's hash was stored as a complete run: nothing was read or written.
    resumed_from : int
        Samples of the log skipped because an earlier, interrupted run had committed them.
    samples_fed : int
        Samples fed to the estimator by this call.
    estimates_added : int
        Rows appended to the store by this call.
    last_estimate : dict or None
        The last row appended (column name -> value).
    counters : dict
        The log reader's counters (frames, samples, corrupt, skipped, gaps).
    clock : str
        The clock that placed the samples in calendar time (:data:`CLOCK_START`,
        :data:`CLOCK_UNIX`, :data:`CLOCK_MTIME`, :data:`CLOCK_LIVE`).
    note : str or None
        Why no estimate was added, when none was (the log still counts as read: its samples
        stay in the gearbox's state, and the next log continues from them).
    """

    gearbox_id: str
    run_id: int
    source: str
    already_imported: bool = False
    resumed_from: int = 0
    samples_fed: int = 0
    estimates_added: int = 0
    last_estimate: dict | None = None
    counters: dict = field(default_factory=dict)
    clock: str = ""
    note: str | None = None


class GearboxTracker:
    """Track one gearbox: feed its estimator, append estimates, checkpoint in the store.

    Parameters
    ----------
    store : HistoryStore
        Where the gearbox, its runs and its estimates live.
    gearbox_id : str
        The gearbox; registered on its first run with ``ratio``.
    ratio : float
        Gear ratio motor:load (negative for a reversing stage); must match the stored one.
    every_s : float
        Seconds of data between estimates.
    limit_arcmin : float, optional
        Nominal backlash limit, stored with the gearbox (replaces a stored one).
    estimator_params : dict, optional
        Parameters of a new gearbox's :class:`BacklashRLS`; a known gearbox keeps its own, and
        parameters given that differ from them raise HistoryError.
    usage_params : dict, optional
        Parameters of a new gearbox's :class:`UsageCounter`.
    play_method : {"auto", "torque", "kinematic"}, optional
        The path of a new gearbox's play (:mod:`online_backlash.load_aware.choice`; None: ``auto``); a
        known gearbox keeps its own, and one given that differs raises HistoryError.
    no_torque_why : str
        Why a log has no torque path, where it has none (stored with each estimate's path).
    """

    def __init__(
        self,
        store: HistoryStore,
        gearbox_id: str,
        ratio: float,
        every_s: float = 60.0,
        limit_arcmin: float | None = None,
        estimator_params: dict | None = None,
        usage_params: dict | None = None,
        play_method: str | None = None,
        no_torque_why: str = NO_TORQUE,
    ) -> None:
        self.store = store
        self.gearbox_id = gearbox_id
        self.ratio = ratio
        self.every_s = every_s
        self.limit_arcmin = limit_arcmin
        self.estimator_params = estimator_params
        self.usage_params = usage_params
        self.play_method = None if play_method is None else check_play_method(play_method)
        self.no_torque_why = no_torque_why

    # -- public ----------------------------------------------------------------------------
    def track_log(
        self,
        path: str | os.PathLike[str],
        log_options: dict[str, Any] | None = None,
        start_unix_s: float | None = None,
        progress: ProgressCallback | None = None,
    ) -> TrackResult:
        """Feed one recorded log (resuming an interrupted run of it; nothing if already complete).

        Parameters
        ----------
        path : str or os.PathLike
            The log; its reader is chosen by suffix (:func:`online_backlash.replay.open_log`).
        log_options : dict, optional
            Reader options (``columns``, ``units``, ``motor_cpr``, ``load_cpr``, ``skip_bad``).
        start_unix_s : float, optional
            Calendar time of the first sample, UNIX seconds (see the module docstring).
        progress : callable, optional
            ``progress(samples_fed, backlash_deg or None)`` after every block.
        """
        path = os.fspath(path)
        os.stat(path)  # FileNotFoundError naming the path, before any reader is chosen
        with open_log(path, **(log_options or {})) as reader:
            key, chunks = sample_key(reader.iter_chunks())
            key = self._stored_key(key, path)
            return self.track_chunks(
                chunks,
                path,
                key=key,
                clock_offset=lambda first_time_s: log_clock(path, first_time_s, start_unix_s),
                counters=lambda: reader.counters.as_dict(),
                progress=progress,
            )

    def track_source(
        self, source: SampleSource, label: str, progress: ProgressCallback | None = None, on_row: RowCallback | None = None
    ) -> TrackResult:
        """Feed a live source (``online_backlash.drivers``' CanSource, SerialSource) until it ends.

        A live stream cannot be read again, so it has no key: each call is a new run that
        continues the gearbox's state. A process killed meanwhile loses the samples after the
        last checkpoint (the raw capture the source wrote still holds them); the store stays
        consistent and the next call continues from the checkpoint. Times that are not UNIX
        times (a device clock) are placed by taking the first sample as now.

        Parameters
        ----------
        source : SampleSource
            A live source: ``iter_chunks()`` yields what has arrived, ``counters`` counts it.
        label : str
            Description stored with the run, e.g. ``can socketcan can0``.
        on_row : callable, optional
            ``on_row(row, time_unix_s)`` after each estimate is committed (e.g. to publish it).
        """
        return self.track_chunks(source.iter_chunks(), label, counters=lambda: source.counters.as_dict(), progress=progress, on_row=on_row)

    def track_chunks(
        self,
        chunks: Iterable[SampleChunk],
        source: str,
        key: str | None = None,
        clock_offset: Callable[[float], float | LogClock] | None = None,
        counters: Callable[[], dict] | None = None,
        progress: ProgressCallback | None = None,
        on_row: RowCallback | None = None,
    ) -> TrackResult:
        """Feed a stream of sample chunks as one run (the engine under :meth:`track_log`).

        Parameters
        ----------
        chunks : iterable of SampleChunk
            The samples (seconds, degrees; motor angle on the motor shaft).
        source : str
            Description stored with the run (a path, a bus and channel).
        key : str, optional
            Identity of the data (a log's :func:`sample_key`): a complete run with this key is not fed
            again, an interrupted one is resumed. Without a key every call is a new run. A keyed
            run new to the gearbox must start after every stored run ends (else HistoryError).
        clock_offset : callable, optional
            ``clock_offset(first_time_s)``: seconds to add to ``time_s`` for UNIX time (or a
            :class:`LogClock`, which also names the clock); default 0 for UNIX times (at least
            :data:`UNIX_TIME_MIN`), else "the first sample is now".
        counters : callable, optional
            Returns the source's counters at the end (default: only ``samples``).
        progress : callable, optional
            ``progress(samples_fed, backlash_deg or None)`` after every block.
        on_row : callable, optional
            ``on_row(row, time_unix_s)`` with each :class:`~online_backlash.rows.EstimateRow` once committed.
        """
        self._validate()
        chunks = iter(chunks)
        first = next(chunks, None)
        if first is None:
            raise LogFormatError(source, None, "no data rows")
        first_time_s = float(first.time_s[0])
        placed = clock_offset(first_time_s) if clock_offset is not None else LogClock(live_clock_offset(first_time_s), CLOCK_LIVE)
        offset, clock_name = placed if isinstance(placed, LogClock) else (placed, "")
        known = self.store.find_gearbox(self.gearbox_id)
        self._check_estimator_params(known)
        if key is not None and known is not None and known.ratio == self.ratio:  # a contradicting ratio: begin_run says so
            check_time_order(self.store.runs(self.gearbox_id), key, source, first_time_s + offset, clock_name)
        gearbox, run = self.store.begin_run(self.gearbox_id, self.ratio, source, key, first_time_s + offset, self.limit_arcmin)
        result = TrackResult(self.gearbox_id, run.id, source, resumed_from=run.samples_done, clock=clock_name)
        if run.complete:
            result.already_imported = True
            result.counters = {k: getattr(run, k) for k in _COUNTERS}
            return result
        # a resumed run keeps its first clock (begin_run stored it; it is None only in a foreign store)
        clock = (run.started_unix_s if run.started_unix_s is not None else first_time_s + offset) - first_time_s
        gearbox, run, state, ended = self._feed(gearbox, run, first, chain([first], chunks), clock, result, progress, on_row)
        done = result.resumed_from + result.samples_fed
        counts = counters() if counters is not None else {k: done if k == "samples" else 0 for k in _COUNTERS}
        result.counters = {**source_counts(counts), **state.pipeline.gap_tally.values()}
        self.store.commit(gearbox, run, done, state.checkpoint(run.id), counters=result.counters, ended_unix_s=ended)
        if result.estimates_added == 0:
            result.note = why_no_estimate(state.pipeline.estimator, self.every_s)
        return result

    # -- internals -------------------------------------------------------------------------
    def _stored_key(self, key: str | None, path: str) -> str | None:
        """``key``, or the file's SHA-256 where an older store keyed this log's run by it."""
        if key is None or self.store.find_gearbox(self.gearbox_id) is None:
            return key
        keys = {r.log_sha256 for r in self.store.runs(self.gearbox_id)}
        if key in keys or not os.path.isfile(path):
            return key
        legacy = file_sha256(path)
        return legacy if legacy in keys else key

    def _check_estimator_params(self, gearbox: Gearbox | None) -> None:
        """A known gearbox keeps its estimator and the path of its play: refuse parameters that differ from its own."""
        if gearbox is None or gearbox.checkpoint is None:
            return
        saved_method = (gearbox.checkpoint.get("play") or {}).get("play_method", "auto")
        if self.play_method is not None and self.play_method != saved_method:
            raise HistoryError(
                f"gearbox {gearbox.id!r} is tracked with play_method={saved_method!r}; "
                f"play_method={self.play_method!r} would change its estimator (use another gearbox id to start afresh)"
            )
        if not self.estimator_params:
            return
        saved = gearbox.checkpoint["estimator"]["params"]
        for name, value in self.estimator_params.items():
            given = [effect_to_dict(e) for e in value or []] if name == "effects" else value
            if saved.get(name) != given:
                raise HistoryError(
                    f"gearbox {gearbox.id!r} is tracked with {name}={saved.get(name)!r}; {name}={given!r} would change "
                    "its estimator (use another gearbox id to start afresh)"
                )

    def _validate(self) -> None:
        check_every(self.every_s)
        try:
            refer_to_load(0.0, self.ratio)
        except InvalidParameterError as exc:
            raise HistoryError(str(exc)) from exc

    def _feed(
        self,
        gearbox: Gearbox,
        run: Run,
        first: SampleChunk,
        chunks: Iterable[SampleChunk],
        clock: float,
        result: TrackResult,
        progress: ProgressCallback | None,
        on_row: RowCallback | None = None,
    ) -> tuple[Gearbox, Run, TrackerState, float | None]:
        """Skip what the run already committed, learn the rest, commit at every estimate.

        Returns the latest gearbox and run records, the state after the last sample and the
        calendar time of the last sample (None if every sample was skipped).
        """
        state = TrackerState.load(
            gearbox.checkpoint, self.ratio, self.every_s, self.estimator_params, self.usage_params, first,
            self.play_method or "auto", self.no_torque_why,
        )  # fmt: skip
        if run.samples_done == 0 or (gearbox.checkpoint or {}).get("run_id") != run.id:
            state.mark_gap()  # the log does not continue the samples the state saw last
        skip = run.samples_done
        done = run.samples_done  # samples of this log in the state
        ended = None
        for chunk in chunks:
            ended = clock + float(chunk.time_s[-1])
            if skip >= len(chunk):
                skip -= len(chunk)
                continue
            if skip:
                chunk, skip = tail(chunk, skip), 0
            for step in state.pipeline.feed(chunk):
                state.usage.update(step.chunk.time_s, step.u_deg, step.chunk.after_gap)
                state.condition.update(step.chunk.torque_Nm)
                done += len(step.chunk)
                result.samples_fed += len(step.chunk)
                if step.row is not None:
                    row = state.store_row(step.row, done, clock + step.row.time_s)
                    gearbox, run = self.store.commit(gearbox, run, done, state.checkpoint(run.id), [row])
                    result.estimates_added += 1
                    result.last_estimate = row
                    if on_row is not None:
                        on_row(step.row, row["time_unix_s"])
                if progress is not None:
                    progress(result.samples_fed, current_backlash_deg(state.pipeline.estimator))
        return gearbox, run, state, ended


_COUNTERS = ("frames", "samples", "corrupt", "skipped", "gaps")


def why_no_estimate(estimator: Any, every_s: float) -> str:
    """Why a run added no estimate: the estimator has not started (the reason its warm start would
    fail now, tried on a copy) or less than ``every_s`` seconds of data came since the last row."""
    if estimator.started:
        return f"less than --every {every_s:g} s of data since the gearbox's last estimate; the next log continues the count"
    probe = copy.deepcopy(estimator)
    try:
        probe.force_start()
    except NotExcitedError as exc:
        return f"the estimator has not started: {exc}; its samples are kept and the gearbox's next log continues them"
    return "the estimator's warm start waits for more samples; the gearbox's next log continues it"


def _utc(time_unix_s: float) -> str:
    return dt.datetime.fromtimestamp(time_unix_s, dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def check_time_order(runs: Iterable[Run], key: str, source: str, start_unix_s: float, clock: str = "") -> None:
    """Refuse a log new to the gearbox (no stored run has its ``key``) that starts before one of
    its stored ``runs`` ends: it overlaps a tracked log, or it is older than one.

    An interrupted run, whose end is not stored, counts as ending at its start. Raises
    HistoryError naming the run and the clock that placed the new log.
    """
    runs = list(runs)
    if any(r.log_sha256 == key for r in runs):
        return  # the same log: already imported, or resumed
    later: list[tuple[Run, float]] = []
    for r in runs:
        end = r.ended_unix_s if r.ended_unix_s is not None else r.started_unix_s
        if end is not None and start_unix_s < end:
            later.append((r, end))
    if not later:
        return
    run, end = max(later, key=lambda item: item[1])
    by = f" by the {clock}" if clock else ""
    began = run.started_unix_s if run.started_unix_s is not None else end
    if start_unix_s >= began:
        raise HistoryError(
            f"{source}: starts {_utc(start_unix_s)}{by}, inside run {run.id} ({run.source}, {_utc(began)} to {_utc(end)}) "
            "already tracked for this gearbox; an overlapping log is refused, nothing was added (a corrected copy of a "
            "tracked log cannot be added again: track it into a new gearbox id; if the clock is wrong, give --start)"
        )
    raise HistoryError(
        f"{source}: starts {_utc(start_unix_s)}{by}, before run {run.id} ({run.source}, {_utc(began)} to {_utc(end)}) "
        "already tracked for this gearbox; logs are tracked in time order, nothing was added (give the logs in one "
        "call to have them sorted, or track into a new gearbox id; if the clock is wrong, give --start)"
    )


def current_backlash_deg(estimator: Any) -> float | None:
    """The estimator's current play, degrees, or None before it has one (for progress displays)."""
    if not estimator.started:
        return None
    value = float(estimator.backlash_)
    return value if math.isfinite(value) else None


class TrackerState:
    """Everything a gearbox's tracking carries from one sample to the next, JSON round-trippable.

    Attributes
    ----------
    pipeline : Pipeline
        The gearbox's estimator (a :class:`~online_backlash.load_aware.PlayChooser` around
        :class:`BacklashRLS` or :class:`TorqueBacklashRLS`: the path of the play chosen by the data) and data clock
        (:class:`~online_backlash.pipeline.DataClock`: seconds of data seen, steps across gaps
        and between logs excluded, and when the next estimate is due).
    usage : UsageCounter
        Operating time, load revolutions and reversals since new.
    condition : LoadCondition
        The torque since the last estimate (stored with the next one).
    """

    def __init__(self, pipeline: Pipeline, usage: UsageCounter, condition: LoadCondition | None = None) -> None:
        self.pipeline = pipeline
        self.usage = usage
        self.condition = condition if condition is not None else LoadCondition()

    @classmethod
    def load(
        cls,
        checkpoint: dict | None,
        ratio: float,
        every_s: float,
        estimator_params: dict | None = None,
        usage_params: dict | None = None,
        first: SampleChunk | None = None,
        play_method: str = "auto",
        no_torque_why: str = NO_TORQUE,
    ) -> TrackerState:
        """The state saved in a gearbox's checkpoint, or a new one (with these parameters) if None.

        A new gearbox whose first chunk ``first`` has a torque column gets the torque-aware
        estimator (:func:`~online_backlash.fitting.recursive_estimator`, with ``play_method``); a saved
        one keeps its class and its path (a checkpoint written before issue 27 gets a new
        :class:`~online_backlash.load_aware.PlayChooser` with ``play_method``).

        A saved estimator's effects are rebuilt by :meth:`BacklashRLS.from_state` from their
        names and parameters (:data:`online_backlash.effect_terms.EFFECTS`), stream history
        included, so a resumed run continues them exactly.
        """
        if checkpoint is None:
            fresh = recursive_estimator(first, ratio, play_method, no_torque_why, **(estimator_params or {}))
            return cls(Pipeline(fresh, ratio, every_s), UsageCounter(**(usage_params or {})))
        if checkpoint.get("format") != CHECKPOINT_FORMAT:
            raise HistoryError(f"checkpoint format {checkpoint.get('format')!r} is not {CHECKPOINT_FORMAT}; upgrade online-backlash")
        saved = checkpoint["estimator"]
        kind = TorqueBacklashRLS if saved.get("estimator") == TorqueBacklashRLS.__name__ else BacklashRLS
        main = kind.from_state(saved)
        estimator = PlayChooser.from_state(main, checkpoint.get("play"), play_method)
        clock = DataClock.from_state(every_s, checkpoint)
        usage = UsageCounter.from_state(checkpoint["usage"])
        return cls(Pipeline(estimator, ratio, every_s, clock), usage, LoadCondition.from_state(checkpoint.get("condition")))

    def checkpoint(self, run_id: int | None = None) -> dict:
        """The state as a JSON-serialisable dict, noting the run whose sample it saw last."""
        return {
            "format": CHECKPOINT_FORMAT,
            "run_id": run_id,
            "estimator": self.pipeline.estimator.estimator.state_dict(),
            "play": self.pipeline.estimator.state_dict(),
            "usage": self.usage.state_dict(),
            "condition": self.condition.state_dict(),
            **self.pipeline.clock.state_dict(),
        }

    def mark_gap(self) -> None:
        """The next sample does not continue the last one."""
        self.pipeline.mark_gap()
        self.usage.mark_gap()

    def store_row(self, row: EstimateRow, sample_index: int, time_unix_s: float) -> dict[str, Any]:
        """An estimate as a row of the store's ``estimates`` table (:data:`~online_backlash.rows.STORE_COLUMNS`)."""
        usage = {
            "operating_hours": self.usage.operating_hours,
            "load_revolutions": self.usage.load_revolutions,
            "reversals": self.usage.reversals,
        }
        values = {**row.values(), **usage, **self.condition.take(), "sample_index": sample_index, "time_unix_s": time_unix_s}
        est = self.pipeline.estimator
        reversed_since_last = est.takes_torque and self.condition.reversed_since_last(est.estimator.n_reversals_)
        if row.play_method == "torque" and values["play_observable"] and not reversed_since_last:
            # the torque path sees the play only where the torque reversed since the last estimate
            values["play_observable"] = False
            values["reason"] = "not observable since the last estimate: the torque did not reverse (the play last seen)"
        return select(STORE_COLUMNS, values)


def track_series(
    series: WearSeries, store: HistoryStore, progress: ProgressCallback | None = None, shift_s: float = 0.0
) -> list[TrackResult]:
    """Track every log of a wear series into ``store`` under its gearbox id (a log already there adds nothing).

    ``shift_s`` moves the series' clock (each log starts at its manifest ``start`` plus ``shift_s``).
    """
    m = series.manifest
    tracker = GearboxTracker(
        store, m["gearbox"], m["ratio"], every_s=m["every_s"], limit_arcmin=m["limit_arcmin"], estimator_params=m["estimator_params"]
    )
    results = []
    for item in series.files:
        with resources.as_file(item) as path:
            start = series.start_unix_s(item) + shift_s if shift_s else None
            results.append(tracker.track_log(path, m["log_options"], start_unix_s=start, progress=progress))
    return results
