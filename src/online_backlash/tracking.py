"""Track a gearbox: run its logs through the pipeline and checkpoint it, with its estimates, in the store.

One gearbox has one :class:`~online_backlash.pipeline.Pipeline` (its estimator,
:class:`~online_backlash.estimators.BacklashRLS`, the recursive form of Vörös 2013, and its data
clock) and one :class:`~online_backlash.history.usage.UsageCounter` for its whole life: every
log continues from the state the previous one left, so the estimate follows the wear. Each log is a *run* of the store,
keyed by its samples (:func:`sample_key`: the SHA-256 of the first :data:`IDENTITY_SAMPLES` times and angles, decoded),
not by its bytes: ``day01.csv.gz`` and its unzipped copy are one log, and a copy with a bad row fixed after the first
samples is the log already tracked.

A gearbox's logs are tracked in time order: a new log that starts before a stored run of the
gearbox ends (an overlapping copy, a log placed by a wrong clock, an older log given after a
newer one) is refused with :class:`~online_backlash.errors.HistoryError` naming that run, so no
operating hour is counted twice and no use per day is negative. :func:`in_time_order` sorts the
logs of one call by their first sample's calendar time.

Every ``every_s`` seconds of data an estimate is made; the estimates are appended in transactions
(:class:`_Transactions`: each at once where they come seconds apart, as live; those a replayed log makes within
:data:`COMMIT_EVERY_S` of each other together, up to :data:`COMMIT_ROWS`), and in the same transaction the
tracker state after the last of them (estimator, with its effects by name; usage counters; data clock) becomes the
gearbox's checkpoint and the run's resume point (``samples_done``) moves on. A process killed at any instant
therefore leaves a consistent store; run again on the same log, it skips the samples the checkpoint
already holds and continues, so the history ends the same as an uninterrupted run: no
duplicate, no missing row, nothing learnt twice. A run stopped by an error commits the estimates it made
before the error first. Of a log already complete only its first
samples are read (its key). A store written before logs were keyed by their samples holds the
files' SHA-256 (:func:`file_sha256`) as keys: a log whose sample key the gearbox does not know is
looked up by that too, so its runs are still found complete or resumed.

Calendar time of a sample: the log's clock (:mod:`online_backlash.clocks`: a start given for it or
read from its file name, the time column when it holds UNIX times, the recording's own clock, else
its file's modification time). The first run of a log fixes it (``runs.started_unix_s``); a resumed
run keeps it. :attr:`TrackResult.clock` names the clock used. Logs placed by their modification times
that overlap are refused, naming both and the option that places them
(:func:`in_time_order`, :func:`check_time_order`).

The machine's own use: with an hour meter (:class:`~online_backlash.hour_meter.MachineUsage`: its
reading at a log's first sample, or a column recorded with the angles) every estimate stores the
machine hours at its sample (``machine_hours``), and the checkpoint the last reading; a meter that
reads less than the gearbox's last reading is refused.

This module sits above :mod:`online_backlash.history` (which only stores rows) and below the
CLI: it is where readers, estimators and the store meet.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime as dt
import hashlib
import json
import math
import os
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from importlib import resources
from itertools import chain, pairwise
from typing import Any, NamedTuple

import numpy as np

from .clocks import (
    CLOCK_LIVE,
    CLOCK_MTIME,
    CLOCK_START,
    CLOCK_UNIX,
    ClockOptions,
    LogClock,
    log_clock,
    suggest_name_pattern,
    time_unit_scale,
)
from .effect_terms import effect_to_dict
from .errors import BacklashWarning, HistoryError, InvalidParameterError, LogFormatError, NotExcitedError
from .estimators import BacklashRLS
from .history.condition import LoadCondition
from .history.series import WearSeries
from .history.store import Gearbox, HistoryStore, Run
from .history.usage import UsageCounter
from .hour_meter import METER_TOLERANCE_H, HourMeter, MachineUsage
from .load_aware import PlayChooser, TorqueBacklashRLS
from .load_aware.choice import NO_TORQUE, check_play_method
from .log_fit import recursive_estimator
from .output_columns import STORE_COLUMNS, EstimateRow, select, source_counts
from .pipeline import DataClock, Pipeline, check_every, tail
from .replay import open_log
from .stream import SampleChunk, SampleSource, live_clock_offset, refer_to_load

__all__ = [
    "CLOCK_LIVE",
    "CLOCK_MTIME",
    "CLOCK_START",
    "CLOCK_UNIX",
    "GearboxTracker",
    "LogClock",
    "TrackResult",
    "log_clock",
]

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


def scaled_times(chunks: Iterable[SampleChunk], scale: float) -> Iterator[SampleChunk]:
    """The chunks with their times multiplied by ``scale`` (seconds per unit of the time column)."""
    if scale == 1.0:
        yield from chunks
        return
    for chunk in chunks:
        yield dataclasses.replace(chunk, time_s=np.asarray(chunk.time_s, dtype=float) * scale)


class FirstBlock(NamedTuple):
    """Where a log starts: calendar time of its first sample (UNIX s), the clock that placed it, and
    the time its first block spans (seconds: the least the log lasts)."""

    start_unix_s: float
    clock: str
    span_s: float


def first_block(
    path: str | os.PathLike[str], log_options: dict[str, Any] | None = None, clock: ClockOptions | None = None
) -> FirstBlock:
    """Where a log starts (:class:`FirstBlock`; reads only its first block)."""
    clock = clock or ClockOptions()
    with open_log(path, **(log_options or {})) as reader:
        first = next(iter(reader.iter_chunks()), None)
        origin = (reader.time_origin_unix_s, reader.time_origin_name)
    if first is None or len(first) == 0:
        raise LogFormatError(path, None, "no data rows")
    with warnings.catch_warnings():  # said once, when the log is tracked
        warnings.simplefilter("ignore", BacklashWarning)
        scale = time_unit_scale(first.time_s, clock.time_unit, os.fspath(path))
    first_time_s = float(first.time_s[0]) * scale
    placed = log_clock(path, first_time_s, clock.start_unix_s, origin, clock.start_pattern)
    return FirstBlock(first_time_s + placed.offset_s, placed.name, float(first.time_s[-1] - first.time_s[0]) * scale)


def first_time_unix_s(
    path: str | os.PathLike[str], log_options: dict[str, Any] | None = None, clock: ClockOptions | None = None
) -> float:
    """Calendar time of a log's first sample, UNIX seconds (reads only its first block)."""
    return first_block(path, log_options, clock).start_unix_s


def in_time_order(
    paths: Iterable[str | os.PathLike[str]],
    log_options: Callable[[str], dict[str, Any]],
    clock_of: Callable[[str], ClockOptions] | None = None,
) -> list[str]:
    """The logs sorted by their first sample's calendar time (stable: equal times keep their order).

    ``log_options(path)`` gives each log's reader options, ``clock_of(path)`` what the user said of
    its clock. Logs placed by their files' modification times that overlap (one starts before the
    first block of the one before it ends: copies made without preserving times) are refused with
    HistoryError naming both and the option that places them, before anything is tracked.
    """
    named = [os.fspath(p) for p in paths]
    firsts = {p: first_block(p, log_options(p), clock_of(p) if clock_of is not None else None) for p in named}
    ordered = sorted(named, key=lambda p: firsts[p].start_unix_s)
    for before, after in pairwise(ordered):
        a, b = firsts[before], firsts[after]
        if a.clock == b.clock == CLOCK_MTIME and b.start_unix_s < a.start_unix_s + a.span_s:
            inside = f"{before} (placed by its {CLOCK_MTIME} too)"
            raise HistoryError(mtime_overlap(after, b.start_unix_s, before, inside))
    return ordered


def mtime_overlap(source: str, start_unix_s: float, other: str, inside: str) -> str:
    """Why a log ``source`` placed by its modification time at ``start_unix_s``, inside the log ``other``
    (described as ``inside``), is refused, with the option that places them."""
    pattern = suggest_name_pattern(source, other)
    if pattern is not None:
        option = f"their names hold their start times: give --start-from-name '{pattern}'"
    else:
        option = (
            "give each log's start: --start-from-name PATTERN if their names hold it (e.g. '%Y-%m-%d_%H%M%S'), "
            'a per-log start in a fleet manifest (logs = [{ path = "...", start = "2026-11-02T08:00:00" }]), '
            "or --start TIME for one log"
        )
    return (
        f"{source}: starts {_utc(start_unix_s)} by the {CLOCK_MTIME}, inside {inside}: logs whose time starts at 0 are "
        "placed by their files' modification times, which copies made without preserving times (cp, a download, an "
        f"e-mail) set to nearly the same moment; nothing was added; {option}"
    )


def log_files(path: str | os.PathLike[str]) -> list[str]:
    """A log, or the files of a log directory (a ``listen --raw-log`` folder) in name (= time) order.

    A capture still being written (``...-active.<suffix>``) and hidden files are left out.
    """
    path = os.fspath(path)
    if not os.path.isdir(path):
        return [path]
    names = sorted(
        e.name for e in os.scandir(path) if e.is_file() and not e.name.startswith(".") and "-active." not in e.name
    )
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
    machine_hours : float or None
        The machine's hour meter at the log's last sample, hours (None: the log told none).
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
    machine_hours: float | None = None


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
        clock: ClockOptions | None = None,
        usage: MachineUsage | None = None,
    ) -> TrackResult:
        """Feed one recorded log (resuming an interrupted run of it; nothing if already complete).

        Parameters
        ----------
        path : str or os.PathLike
            The log; its reader is chosen by suffix (:func:`online_backlash.replay.open_log`).
        log_options : dict, optional
            Reader options (``columns``, ``units``, ``motor_cpr``, ``load_cpr``, ``skip_bad``).
        start_unix_s : float, optional
            Calendar time of the first sample, UNIX seconds (see the module docstring); the same as
            ``clock=ClockOptions(start_unix_s=...)``.
        progress : callable, optional
            ``progress(samples_fed, backlash_deg or None)`` after every block.
        clock : ClockOptions, optional
            What the user says of the log's clock (:mod:`online_backlash.clocks`).
        usage : MachineUsage, optional
            How the log tells the machine's hours (:mod:`online_backlash.hour_meter`).
        """
        path = os.fspath(path)
        os.stat(path)  # FileNotFoundError naming the path, before any reader is chosen
        clock = clock or ClockOptions()
        if start_unix_s is not None:
            clock = dataclasses.replace(clock, start_unix_s=start_unix_s)
        options = log_options or {}
        with open_log(path, **options) as reader:
            key, chunks = sample_key(reader.iter_chunks())
            key = self._stored_key(key, path)
            head = next(chunks, None)
            scale = 1.0 if head is None else time_unit_scale(head.time_s, clock.time_unit, path)
            origin = (reader.time_origin_unix_s, reader.time_origin_name)
            meter = None
            if usage is not None and usage.given:
                meter = lambda first_time_s: usage.meter(path, first_time_s, options, scale)  # noqa: E731
            return self.track_chunks(
                scaled_times(chain([] if head is None else [head], chunks), scale),
                path,
                key=key,
                clock_offset=lambda first_s: log_clock(path, first_s, clock.start_unix_s, origin, clock.start_pattern),
                counters=lambda: reader.counters.as_dict(),
                progress=progress,
                hour_meter=meter,
            )

    def track_source(
        self,
        source: SampleSource,
        label: str,
        progress: ProgressCallback | None = None,
        on_row: RowCallback | None = None,
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
        return self.track_chunks(
            source.iter_chunks(), label, counters=lambda: source.counters.as_dict(), progress=progress, on_row=on_row
        )

    def track_chunks(
        self,
        chunks: Iterable[SampleChunk],
        source: str,
        key: str | None = None,
        clock_offset: Callable[[float], float | LogClock] | None = None,
        counters: Callable[[], dict] | None = None,
        progress: ProgressCallback | None = None,
        on_row: RowCallback | None = None,
        hour_meter: Callable[[float], HourMeter] | None = None,
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
            ``on_row(row, time_unix_s)`` with each :class:`~online_backlash.output_columns.EstimateRow` once committed.
        hour_meter : callable, optional
            ``hour_meter(first_time_s)``: the machine's hour meter along the data
            (:class:`~online_backlash.hour_meter.HourMeter`), asked for only when there are samples to
            feed. A new run whose meter reads less than the gearbox's last reading is refused (HistoryError).
        """
        self._validate()
        chunks = iter(chunks)
        first = next(chunks, None)
        if first is None:
            raise LogFormatError(source, None, "no data rows")
        first_time_s = float(first.time_s[0])
        placed = (
            clock_offset(first_time_s)
            if clock_offset is not None
            else LogClock(live_clock_offset(first_time_s), CLOCK_LIVE)
        )
        offset, clock_name = placed if isinstance(placed, LogClock) else (placed, "")
        known = self.store.find_gearbox(self.gearbox_id)
        self._check_estimator_params(known)
        runs = self.store.runs(self.gearbox_id) if known is not None else []
        stored = next((r for r in runs if key is not None and r.log_sha256 == key), None)
        if (
            key is not None and known is not None and known.ratio == self.ratio
        ):  # a contradicting ratio: begin_run says so
            check_time_order(runs, key, source, first_time_s + offset, clock_name)
        meter = hour_meter(first_time_s) if hour_meter is not None and (stored is None or not stored.complete) else None
        if meter is not None and stored is None and known is not None:
            check_machine_hours(known.checkpoint, meter.hours_at(first_time_s), first_time_s + offset, source)
        gearbox, run = self.store.begin_run(
            self.gearbox_id, self.ratio, source, key, first_time_s + offset, self.limit_arcmin
        )
        result = TrackResult(self.gearbox_id, run.id, source, resumed_from=run.samples_done, clock=clock_name)
        if run.complete:
            result.already_imported = True
            result.counters = {k: getattr(run, k) for k in _COUNTERS}
            return result
        # a resumed run keeps its first clock (begin_run stored it; it is None only in a foreign store)
        clock = (run.started_unix_s if run.started_unix_s is not None else first_time_s + offset) - first_time_s
        everything = chain([first], chunks)
        fed = self._feed(gearbox, run, first, everything, clock, result, progress, on_row, meter)
        gearbox, run, state, ended, waiting = fed
        if meter is not None and ended is not None:
            result.machine_hours = state.note_machine_hours(meter.hours_at(ended - clock), ended)
        done = result.resumed_from + result.samples_fed
        counts = counters() if counters is not None else {k: done if k == "samples" else 0 for k in _COUNTERS}
        result.counters = {**source_counts(counts), **state.pipeline.gap_tally.values()}
        waiting.commit(gearbox, run, done, state.checkpoint(run.id), counters=result.counters, ended_unix_s=ended)
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
        meter: HourMeter | None = None,
    ) -> tuple[Gearbox, Run, TrackerState, float | None, _Transactions]:
        """Skip what the run already committed, learn the rest, commit the estimates (:class:`_Transactions`).

        Returns the latest gearbox and run records, the state after the last sample, the calendar
        time of the last sample (None if every sample was skipped) and the estimates still waiting for
        the run's last transaction. An error (but the store's own) commits the estimates made before it.
        """
        state = TrackerState.load(
            gearbox.checkpoint, self.ratio, self.every_s, self.estimator_params, self.usage_params, first,
            self.play_method or "auto", self.no_torque_why,
        )  # fmt: skip
        state.meter = meter
        if run.samples_done == 0 or (gearbox.checkpoint or {}).get("run_id") != run.id:
            state.mark_gap()  # the log does not continue the samples the state saw last
        skip = run.samples_done
        done = run.samples_done  # samples of this log in the state
        ended = None
        waiting = _Transactions(self.store, on_row)
        try:
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
                        gearbox, run = waiting.add(gearbox, run, row, step.row, done, state)
                        result.estimates_added += 1
                        result.last_estimate = row
                    if progress is not None:
                        progress(result.samples_fed, current_backlash_deg(state.pipeline.estimator))
        except BaseException as exc:
            if not isinstance(exc, HistoryError):  # the store refused a commit: it would refuse this one too
                waiting.commit_saved(gearbox, run)
            raise
        return gearbox, run, state, ended, waiting


#: Estimates of a run that wait for one transaction at most: a replayed log makes one every few milliseconds,
#: and a transaction each (the checkpoint's JSON, two updates, an insert) cost more than estimating them
COMMIT_ROWS = 64
#: Wall seconds after the last commit at which the next estimate is committed at once (with those waiting)
COMMIT_EVERY_S = 0.5


class _Transactions:
    """The estimates of a run waiting for their transaction, and the checkpoint after the last of them.

    :meth:`add` commits an estimate at once, with those waiting, when :data:`COMMIT_EVERY_S` seconds of wall
    time have passed since the last commit (a live stream: its estimates come ``every_s`` seconds apart) or
    :data:`COMMIT_ROWS` are waiting; else it keeps the estimate and the checkpoint (JSON) after it, which
    :meth:`commit_saved` commits when the run stops on an error. Each transaction holds its estimates and the
    state after the last of them: a run killed between two resumes from the first and ends with the same rows.
    ``on_row(row, time_unix_s)`` is called for each estimate once it is committed.
    """

    def __init__(self, store: HistoryStore, on_row: RowCallback | None) -> None:
        self.store = store
        self.on_row = on_row
        self.rows: list[tuple[dict[str, Any], EstimateRow]] = []
        self.saved: tuple[int, str] | None = None  # samples done and the checkpoint (JSON) after the last row
        self.committed_at = time.monotonic()

    def add(
        self, gearbox: Gearbox, run: Run, row: dict[str, Any], estimate: EstimateRow, done: int, state: TrackerState
    ) -> tuple[Gearbox, Run]:
        """Take the store row of ``estimate``, made after ``done`` samples of the run in ``state``."""
        self.rows.append((row, estimate))
        if len(self.rows) >= COMMIT_ROWS or time.monotonic() - self.committed_at >= COMMIT_EVERY_S:
            return self.commit(gearbox, run, done, state.checkpoint(run.id))
        self.saved = (done, json.dumps(state.checkpoint(run.id)))
        return gearbox, run

    def commit(self, gearbox: Gearbox, run: Run, done: int, checkpoint: dict, **end: Any) -> tuple[Gearbox, Run]:
        """Commit the waiting estimates with ``checkpoint``, the state after ``done`` samples of the run (``end``:
        the run's ``counters`` and ``ended_unix_s`` when it is complete); returns the updated records."""
        rows, self.rows, self.saved = self.rows, [], None
        gearbox, run = self.store.commit(gearbox, run, done, checkpoint, [row for row, _ in rows], **end)
        self.committed_at = time.monotonic()
        if self.on_row is not None:
            for row, estimate in rows:
                self.on_row(estimate, row["time_unix_s"])
        return gearbox, run

    def commit_saved(self, gearbox: Gearbox, run: Run) -> None:
        """Commit the waiting estimates with the checkpoint saved after the last of them (a run that stops)."""
        if self.saved is not None:
            done, checkpoint = self.saved
            self.commit(gearbox, run, done, json.loads(checkpoint))


_COUNTERS = ("frames", "samples", "corrupt", "skipped", "gaps")


def why_no_estimate(estimator: Any, every_s: float) -> str:
    """Why a run added no estimate: the estimator has not started (the reason its warm start would
    fail now, tried on a copy) or less than ``every_s`` seconds of data came since the last row."""
    if estimator.started:
        return (
            f"less than --every {every_s:g} s of data since the gearbox's last estimate; the next log continues "
            "the count"
        )
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
    HistoryError naming the run and the clock that placed the new log; one placed by its file's
    modification time inside a run names the option that places both (:func:`mtime_overlap`).
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
    if start_unix_s >= began and clock == CLOCK_MTIME:
        inside = f"run {run.id} ({run.source}, {_utc(began)} to {_utc(end)})"
        raise HistoryError(mtime_overlap(source, start_unix_s, run.source, inside))
    if start_unix_s >= began:
        raise HistoryError(
            f"{source}: starts {_utc(start_unix_s)}{by}, inside run {run.id} ({run.source}, {_utc(began)} to "
            f"{_utc(end)}) "
            "already tracked for this gearbox; an overlapping log is refused, nothing was added (a corrected copy of a "
            "tracked log cannot be added again: track it into a new gearbox id; if the clock is wrong, give --start)"
        )
    raise HistoryError(
        f"{source}: starts {_utc(start_unix_s)}{by}, before run {run.id} ({run.source}, {_utc(began)} to {_utc(end)}) "
        "already tracked for this gearbox; logs are tracked in time order, nothing was added (give the logs in one "
        "call to have them sorted, or track into a new gearbox id; if the clock is wrong, give --start)"
    )


def check_machine_hours(checkpoint: dict | None, hours: float, start_unix_s: float, source: str) -> None:
    """Refuse a new log whose hour meter reads ``hours`` at its first sample (calendar time ``start_unix_s``)
    below the gearbox's last reading (in its ``checkpoint``): a meter does not go back. One that ran
    faster than calendar time since is warned of (BacklashWarning): a wrong unit or clock."""
    last = (checkpoint or {}).get("machine")
    if not last:
        return
    if hours < last["hours"] - METER_TOLERANCE_H:
        raise HistoryError(
            f"{source}: the hour meter reads {hours:g} h at its first sample, less than the {last['hours']:g} h of the "
            f"gearbox's last tracked sample ({_utc(last['time_unix_s'])}); an hour meter does not go back, nothing was "
            "added (a replaced meter or controller: track into a new gearbox id)"
        )
    elapsed_h = (start_unix_s - last["time_unix_s"]) / 3600.0
    if hours - last["hours"] > 1.01 * elapsed_h + 0.01:
        warnings.warn(
            f"{source}: the hour meter advanced {hours - last['hours']:.4g} h in {elapsed_h:.4g} h of calendar time "
            "since the gearbox's last tracked sample, faster than time itself: check --hours-unit and the log's clock",
            BacklashWarning,
            stacklevel=2,
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
    machine : dict or None
        The machine's last hour-meter reading: ``{"hours": h, "time_unix_s": t}`` (None: none yet).
    meter : HourMeter or None
        The hour meter along the log being fed (not saved: each log tells its own).
    """

    def __init__(
        self,
        pipeline: Pipeline,
        usage: UsageCounter,
        condition: LoadCondition | None = None,
        machine: dict | None = None,
    ) -> None:
        self.pipeline = pipeline
        self.usage = usage
        self.condition = condition if condition is not None else LoadCondition()
        self.machine = machine
        self.meter: HourMeter | None = None

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
        estimator (:func:`~online_backlash.log_fit.recursive_estimator`, with ``play_method``); a saved
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
            raise HistoryError(
                f"checkpoint format {checkpoint.get('format')!r} is not {CHECKPOINT_FORMAT}; upgrade online-backlash"
            )
        saved = checkpoint["estimator"]
        kind = TorqueBacklashRLS if saved.get("estimator") == TorqueBacklashRLS.__name__ else BacklashRLS
        main = kind.from_state(saved)
        estimator = PlayChooser.from_state(main, checkpoint.get("play"), play_method)
        clock = DataClock.from_state(every_s, checkpoint)
        usage = UsageCounter.from_state(checkpoint["usage"])
        condition = LoadCondition.from_state(checkpoint.get("condition"))
        return cls(Pipeline(estimator, ratio, every_s, clock), usage, condition, checkpoint.get("machine"))

    def checkpoint(self, run_id: int | None = None) -> dict:
        """The state as a JSON-serialisable dict, noting the run whose sample it saw last."""
        return {
            "format": CHECKPOINT_FORMAT,
            "run_id": run_id,
            "estimator": self.pipeline.estimator.estimator.state_dict(),
            "play": self.pipeline.estimator.state_dict(),
            "usage": self.usage.state_dict(),
            "condition": self.condition.state_dict(),
            "machine": self.machine,
            **self.pipeline.clock.state_dict(),
        }

    def note_machine_hours(self, hours: float, time_unix_s: float) -> float:
        """Remember the hour meter's reading ``hours`` at calendar time ``time_unix_s`` (for the next checkpoint)."""
        self.machine = {"hours": hours, "time_unix_s": time_unix_s}
        return hours

    def mark_gap(self) -> None:
        """The next sample does not continue the last one."""
        self.pipeline.mark_gap()
        self.usage.mark_gap()

    def store_row(self, row: EstimateRow, sample_index: int, time_unix_s: float) -> dict[str, Any]:
        """An estimate as a row of the store's ``estimates`` table
        (:data:`~online_backlash.output_columns.STORE_COLUMNS`)."""
        usage = {
            "operating_hours": self.usage.operating_hours,
            "load_revolutions": self.usage.load_revolutions,
            "reversals": self.usage.reversals,
        }
        machine = None if self.meter is None else self.note_machine_hours(self.meter.hours_at(row.time_s), time_unix_s)
        values = {
            **row.values(),
            **usage,
            **self.condition.take(),
            "sample_index": sample_index,
            "time_unix_s": time_unix_s,
            "machine_hours": machine,
        }
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
    """Track every log of a wear series into ``store`` under its gearbox id (a log already there adds nothing),
    with its hour meter (the manifest's ``hours_column``).

    ``shift_s`` moves the series' clock (each log starts at its manifest ``start`` plus ``shift_s``).
    """
    m = series.manifest
    tracker = GearboxTracker(
        store,
        m["gearbox"],
        m["ratio"],
        every_s=m["every_s"],
        limit_arcmin=m["limit_arcmin"],
        estimator_params=m["estimator_params"],
    )
    usage = MachineUsage(hours_column=m.get("hours_column"))
    results = []
    for item in series.files:
        with resources.as_file(item) as path:
            start = series.start_unix_s(item) + shift_s if shift_s else None
            result = tracker.track_log(path, m["log_options"], start_unix_s=start, progress=progress, usage=usage)
            results.append(result)
    return results
