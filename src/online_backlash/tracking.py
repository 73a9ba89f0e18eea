"""Track a gearbox: run its logs through the pipeline and checkpoint it, with its estimates, in the store.

One gearbox has one :class:`~online_backlash.pipeline.Pipeline` (its estimator,
:class:`~online_backlash.estimators.BacklashRLS`, the recursive form of Vörös 2013, and its data
clock) and one :class:`~online_backlash.history.usage.UsageCounter` for its whole life: every
log continues from the state the previous one left, so the estimate follows the wear. Each log is a *run* of the store, keyed by the SHA-256 of the file.

Every ``every_s`` seconds of data an estimate is appended, and in the same transaction the
tracker state (estimator, with its effects by name; usage counters; data clock) becomes the gearbox's checkpoint and the
run's resume point (``samples_done``) moves on. A process killed at any instant therefore
leaves a consistent store; run again on the same log, it skips the samples the checkpoint
already holds and continues, so the history ends the same as an uninterrupted run: no
duplicate, no missing row, nothing learnt twice. A log already complete is not read again.

Calendar time of a sample: ``start_unix_s + (time_s - first time_s)`` when a start is given;
the time column itself when it holds UNIX times (at least :data:`UNIX_TIME_MIN`); otherwise
the log file's modification time is taken as its start. The first run of a log fixes it
(``runs.started_unix_s``); a resumed run keeps it.

This module sits above :mod:`online_backlash.history` (which only stores rows) and below the
CLI: it is where readers, estimators and the store meet.
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from importlib import resources
from itertools import chain
from typing import Any

from .effect_terms import effect_to_dict
from .errors import HistoryError, InvalidParameterError, LogFormatError
from .estimators import BacklashRLS
from .history.series import WearSeries
from .history.store import Gearbox, HistoryStore, Run
from .history.usage import UsageCounter
from .pipeline import DataClock, Pipeline, check_every, tail
from .replay import open_log
from .rows import STORE_COLUMNS, EstimateRow, select, source_counts
from .stream import UNIX_TIME_MIN, SampleChunk, SampleSource, live_clock_offset, refer_to_load

#: Times at or above this (2001-09-09) are read as UNIX seconds.

#: Version of the checkpoint's layout (inside the store's ``gearboxes.checkpoint``).
CHECKPOINT_FORMAT = 1

#: ``progress(samples_fed, backlash_deg or None)``, called after every block.
ProgressCallback = Callable[[int, "float | None"], None]
#: ``on_row(row, time_unix_s)``, called after each estimate is committed.
RowCallback = Callable[[EstimateRow, float], None]


def file_sha256(path: str | os.PathLike[str], block_bytes: int = 1 << 20) -> str:
    """SHA-256 of a file's bytes (a compressed log is hashed as stored)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(block_bytes):
            digest.update(block)
    return digest.hexdigest()


def log_clock_offset(path: str | os.PathLike[str], first_time_s: float, start_unix_s: float | None = None) -> float:
    """Seconds to add to the log's ``time_s`` to get UNIX time (see the module docstring)."""
    if start_unix_s is not None:
        return start_unix_s - first_time_s
    if first_time_s >= UNIX_TIME_MIN:
        return 0.0
    return os.stat(path).st_mtime - first_time_s


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
    ) -> None:
        self.store = store
        self.gearbox_id = gearbox_id
        self.ratio = ratio
        self.every_s = every_s
        self.limit_arcmin = limit_arcmin
        self.estimator_params = estimator_params
        self.usage_params = usage_params

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
        digest = file_sha256(path)
        with open_log(path, **(log_options or {})) as reader:
            return self.track_chunks(
                reader.iter_chunks(),
                path,
                key=digest,
                clock_offset=lambda first_time_s: log_clock_offset(path, first_time_s, start_unix_s),
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
        clock_offset: Callable[[float], float] | None = None,
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
            Identity of the data (a log's SHA-256): a complete run with this key is not fed
            again, an interrupted one is resumed. Without a key every call is a new run.
        clock_offset : callable, optional
            ``clock_offset(first_time_s)``: seconds to add to ``time_s`` for UNIX time; default
            0 for UNIX times (at least :data:`UNIX_TIME_MIN`), else "the first sample is now".
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
        offset = clock_offset(first_time_s) if clock_offset is not None else live_clock_offset(first_time_s)
        self._check_estimator_params(self.store.find_gearbox(self.gearbox_id))
        gearbox, run = self.store.begin_run(self.gearbox_id, self.ratio, source, key, first_time_s + offset, self.limit_arcmin)
        result = TrackResult(self.gearbox_id, run.id, source, resumed_from=run.samples_done)
        if run.complete:
            result.already_imported = True
            result.counters = {k: getattr(run, k) for k in _COUNTERS}
            return result
        # a resumed run keeps its first clock (begin_run stored it; it is None only in a foreign store)
        clock = (run.started_unix_s if run.started_unix_s is not None else first_time_s + offset) - first_time_s
        gearbox, run, state, ended = self._feed(gearbox, run, chain([first], chunks), clock, result, progress, on_row)
        done = result.resumed_from + result.samples_fed
        counts = counters() if counters is not None else {k: done if k == "samples" else 0 for k in _COUNTERS}
        result.counters = {**source_counts(counts), **state.pipeline.gap_tally.values()}
        self.store.commit(gearbox, run, done, state.checkpoint(run.id), counters=result.counters, ended_unix_s=ended)
        return result

    # -- internals -------------------------------------------------------------------------
    def _check_estimator_params(self, gearbox: Gearbox | None) -> None:
        """A known gearbox keeps its estimator: refuse parameters that differ from its own."""
        if gearbox is None or gearbox.checkpoint is None or not self.estimator_params:
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
        state = TrackerState.load(gearbox.checkpoint, self.ratio, self.every_s, self.estimator_params, self.usage_params)
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
        The gearbox's estimator (:class:`BacklashRLS`) and data clock
        (:class:`~online_backlash.pipeline.DataClock`: seconds of data seen, steps across gaps
        and between logs excluded, and when the next estimate is due).
    usage : UsageCounter
        Operating time, load revolutions and reversals since new.
    """

    def __init__(self, pipeline: Pipeline, usage: UsageCounter) -> None:
        self.pipeline = pipeline
        self.usage = usage

    @classmethod
    def load(
        cls,
        checkpoint: dict | None,
        ratio: float,
        every_s: float,
        estimator_params: dict | None = None,
        usage_params: dict | None = None,
    ) -> TrackerState:
        """The state saved in a gearbox's checkpoint, or a new one (with these parameters) if None.

        A saved estimator's effects are rebuilt by :meth:`BacklashRLS.from_state` from their
        names and parameters (:data:`online_backlash.effect_terms.EFFECTS`), stream history
        included, so a resumed run continues them exactly.
        """
        if checkpoint is None:
            return cls(Pipeline(BacklashRLS(**(estimator_params or {})), ratio, every_s), UsageCounter(**(usage_params or {})))
        if checkpoint.get("format") != CHECKPOINT_FORMAT:
            raise HistoryError(f"checkpoint format {checkpoint.get('format')!r} is not {CHECKPOINT_FORMAT}; upgrade online-backlash")
        estimator = BacklashRLS.from_state(checkpoint["estimator"])
        clock = DataClock.from_state(every_s, checkpoint)
        return cls(Pipeline(estimator, ratio, every_s, clock), UsageCounter.from_state(checkpoint["usage"]))

    def checkpoint(self, run_id: int | None = None) -> dict:
        """The state as a JSON-serialisable dict, noting the run whose sample it saw last."""
        return {
            "format": CHECKPOINT_FORMAT,
            "run_id": run_id,
            "estimator": self.pipeline.estimator.state_dict(),
            "usage": self.usage.state_dict(),
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
        return select(STORE_COLUMNS, {**row.values(), **usage, "sample_index": sample_index, "time_unix_s": time_unix_s})


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
