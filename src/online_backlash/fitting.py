"""Fit a recorded log: read it, refer the motor angle to the load side, run an estimator.

The thin layer between the CLI and the estimators: it returns plain results with units in
their names and never prints. The recursive fit runs the one loop of
:mod:`online_backlash.pipeline`; the columns of its outputs are declared in
:mod:`online_backlash.rows`.
"""

from __future__ import annotations

import inspect
import itertools
import math
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .bridging import GapTally
from .estimators import BacklashRLS, VorosBacklash
from .estimators.uncertainty import SCATTER_EVERY_S, EstimateAt, RecursivePlayScatter
from .load_aware import DwellTracker, TorqueBacklash, TorqueBacklashRLS
from .load_aware.datasheet import DatasheetFigures
from .load_aware.engagement import torque_orientation
from .load_aware.report import batch_keys, has_torque, kinematic_keys, recursive_keys, why_not_observable
from .pipeline import OrderedWorker, Pipeline, PipelineStep, check_every
from .rows import ARCMIN_PER_DEG, REPORT_KEYS, TRACE_COLUMNS, EstimateRow, describe_counts, select, source_counts
from .stream import SampleChunk

#: Plausible range of the fitted slopes' magnitude: after referring, load and motor move alike (eq. 1, m ~ +-1).
PLAUSIBLE_SLOPE = (0.5, 2.0)
#: Largest plausible play, degrees on the load side (worn gearboxes have tenths of a degree, not degrees).
PLAUSIBLE_PLAY_DEG = 5.0
#: Blocks the bookkeeping of :func:`fit_recursive` (play scatter, dwells) may lag behind the estimator in
#: its worker thread, with ``ahead`` > 0 (:class:`~online_backlash.pipeline.OrderedWorker`; 0: inline).
BOOKKEEPING_AHEAD = 2

__all__ = [
    "ARCMIN_PER_DEG", "TRACE_COLUMNS", "BacklashReport", "describe", "fit_batch", "fit_recursive", "plausibility",
]


def plausibility(
    m_left: float, m_right: float, backlash_deg: float, ratio: float, with_torque: bool = False
) -> str | None:
    """One sentence naming the likely cause when a fit of eq. (1) looks like wrong units or ratio, else None.

    After referring (``u = motor / ratio``) the flanks of eq. (1) have slopes near +-1; a slope
    ``m`` far from that (``|m|`` outside :data:`PLAUSIBLE_SLOPE`) means the two angles are in
    different units (counts under a degrees header, wrong counts per revolution) or the ratio
    is off by ``m`` (``ratio / m`` would give slope 1). A play ``backlash_deg`` above
    :data:`PLAUSIBLE_PLAY_DEG` degrees points at counts read as degrees; a negative play is not
    physical (``with_torque``: wind-up and play not told apart). Shared by ``estimate`` (the
    report's fit) and ``diagnose`` (its base fit).
    """
    slopes = [m for m in (m_left, m_right) if np.isfinite(m)]
    low, high = PLAUSIBLE_SLOPE
    if slopes and not all(low <= abs(m) <= high for m in slopes):
        m = float(np.mean(slopes))
        return (
            f"fitted slope {m:.4g}, not near +-1 after referring: the motor and load angles are likely in different "
            f"units (encoder counts under a degrees header: give --units counts --motor-cpr N --load-cpr N; or wrong "
            f"counts per revolution), or the ratio is off (--ratio {ratio / m:.4g} would give slope 1)"
        )
    if np.isfinite(backlash_deg) and backlash_deg < 0:
        why = (
            "with torque, the flank offsets at zero torque are an extrapolation the data do not support here (the "
            "torque barely varies on each flank, so wind-up and play are confounded): read lost_motion_arcmin, or "
            "leave out the torque column for the kinematic play"
            if with_torque
            else "the flanks cross: check the sign of --ratio and the units"
        )
        return f"a negative play ({backlash_deg:.4g} deg) is not physical: {why}"
    if np.isfinite(backlash_deg) and abs(backlash_deg) > PLAUSIBLE_PLAY_DEG:
        return (
            f"a play of {backlash_deg:.4g} deg is more than gearboxes have: check the units (counts read as degrees: "
            "--units counts --motor-cpr N --load-cpr N) and the ratio"
        )
    return None


@dataclass
class BacklashReport:
    """The result of fitting one log; angles in degrees (load side), as in ``estimate --json``."""

    method: str
    samples: int
    backlash_deg: float
    c_left_deg: float
    c_right_deg: float
    m_left: float
    m_right: float
    residual_rms_deg: float
    play_observable: bool = True
    torque_reversals: int | None = None
    backlash_lower_bound_deg: float | None = None
    stiffness_nm_per_arcmin: float | None = None
    stiffness_left_nm_per_arcmin: float | None = None
    stiffness_right_nm_per_arcmin: float | None = None
    lost_motion_arcmin: float | None = None
    hysteresis_loss_arcmin: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_estimator(cls, method: str, samples: int, est: Any, **extra: Any) -> BacklashReport:
        """The report of a fitted estimator (batch or recursive: the same fitted attributes, degrees)."""
        return cls(
            method=method,
            samples=samples,
            backlash_deg=est.backlash_,
            c_left_deg=est.c_left_,
            c_right_deg=est.c_right_,
            m_left=est.m_left_,
            m_right=est.m_right_,
            residual_rms_deg=est.residual_rms_,
            extra=extra,
        )

    def plausibility(self, ratio: float) -> str | None:
        """:func:`plausibility` of this fit (a torque column: ``torque_reversals`` is set)."""
        return plausibility(self.m_left, self.m_right, self.backlash_deg, ratio, self.torque_reversals is not None)

    def take_datasheet(self, drawn: BacklashReport) -> BacklashReport:
        """Take the data-sheet figures (stiffness, lost motion, hysteresis loss: :class:`DatasheetFigures`' keys)
        of the batch fit ``drawn`` whose curve was plotted, so that the text and the plot show one figure,
        computed once; marked ``datasheet_fit``. A fit without torque has none to take. Returns self."""
        if drawn.torque_reversals is None:
            return self
        keys = drawn.as_dict()
        self.add_load_keys({name: keys.get(name) for name in DatasheetFigures.__dataclass_fields__})
        self.extra["datasheet_fit"] = "batch fit of the whole log, as plotted"
        return self

    def no_play_reason(self) -> str | None:
        """Why the report has no finite play, in one line (None when it has one): the data's reason
        where the play is not observable, else a fit that gave no number (check units and ratio)."""
        if math.isfinite(self.backlash_deg):
            return None
        return why_not_observable(self.as_dict()) or (
            "the fit gave no finite play: check the units (--units, --motor-cpr/--load-cpr) and --ratio"
        )

    def add_load_keys(self, keys: Mapping[str, Any]) -> BacklashReport:
        """Take the load-aware keys (:mod:`online_backlash.load_aware.report`): the declared ones as
        fields, the rest in ``extra``; a play that is not observable becomes NaN (JSON null). Returns self."""
        for name, value in keys.items():
            if name in self.__dataclass_fields__ and name != "extra":
                setattr(self, name, value)
            else:
                self.extra[name] = value
        if not self.play_observable:
            self.backlash_deg = math.nan
            self.extra["backlash_std_deg"] = None
        return self

    @property
    def backlash_arcmin(self) -> float:
        """The play in arc minutes."""
        return self.backlash_deg * ARCMIN_PER_DEG

    def as_dict(self) -> dict[str, Any]:
        """The JSON contract of ``online-backlash estimate --json`` (more keys may follow)."""
        out = select(REPORT_KEYS, {**vars(self), "backlash_arcmin": self.backlash_arcmin})
        out.update(self.extra)
        return out

    def add_counters(self, counts: Mapping[str, int]) -> BacklashReport:
        """Carry the source's counters (:data:`~online_backlash.rows.COUNTER_KEYS`; ``samples`` stays
        the samples fitted) in ``extra``, hence in :meth:`as_dict` and :func:`describe`; returns self."""
        self.extra.update({k: v for k, v in source_counts(counts).items() if k != "samples"})
        return self


def fit_batch(
    chunk: SampleChunk, ratio: float, *, rated_torque_Nm: float | None = None, **params: Any
) -> tuple[BacklashReport, VorosBacklash | TorqueBacklash]:
    """Fit a whole log in memory: with a torque column, :class:`~online_backlash.load_aware.TorqueBacklash`
    (flank lines with wind-up; the data-sheet figures, lost motion at 3 % of ``rated_torque_Nm``
    N m if given); without, :class:`VorosBacklash` (eq. 8-14, then the output-error refinement)
    and the kinematic observability (:class:`~online_backlash.load_aware.DwellTracker`)."""
    u, y = chunk.referred(ratio)
    gaps = GapTally.of_chunk(chunk).values()
    if has_torque(chunk.torque_Nm):
        torque_est = TorqueBacklash(**params).fit(u, y, chunk.torque_Nm)
        report = BacklashReport.from_estimator("batch", len(chunk), torque_est, n_iter=torque_est.n_iter_, **gaps)
        return report.add_load_keys(batch_keys(torque_est, u, y, chunk.torque_Nm, rated_torque_Nm)), torque_est
    est = VorosBacklash(**{"origin": "first", **params}).fit(u, y)  # encoder zeros are arbitrary
    tracker = DwellTracker()
    tracker.update(u, y, chunk.after_gap)
    extra = {"backlash_std_deg": est.backlash_std_, "n_iter": est.n_iter_, **gaps}
    report = BacklashReport.from_estimator("batch", len(chunk), est, **extra)
    return report.add_load_keys(kinematic_keys(tracker)), est


def _first_and_rest(chunks: Iterable[SampleChunk]) -> tuple[SampleChunk | None, Iterable[SampleChunk]]:
    """The first chunk (None for an empty stream) and an iterable of all of them, the first included."""
    it = iter(chunks)
    first = next(it, None)
    return first, (it if first is None else itertools.chain([first], it))


def _torque_params(params: Mapping[str, Any]) -> dict[str, Any]:
    """The settings that :class:`TorqueBacklashRLS` shares with :class:`BacklashRLS`."""
    names = inspect.signature(TorqueBacklashRLS).parameters
    return {k: v for k, v in params.items() if k in names}


def recursive_estimator(first: SampleChunk | None, ratio: float, **params: Any) -> BacklashRLS | TorqueBacklashRLS:
    """A new recursive estimator for a stream that begins with ``first``: :class:`TorqueBacklashRLS`
    where it has a torque column (its sign from :func:`~online_backlash.load_aware.engagement.torque_orientation`,
    the settings it shares with ``params``), else :class:`BacklashRLS` with ``params``."""
    if first is not None and has_torque(first.torque_Nm):
        return TorqueBacklashRLS(**{"torque_sign": torque_orientation(*first.referred(ratio), first.torque_Nm), **_torque_params(params)})
    return BacklashRLS(**params)


def _keep_books(
    step: PipelineStep, scatter: RecursivePlayScatter, estimates: Sequence[EstimateAt], end: EstimateAt, dwells: DwellTracker | None
) -> None:
    """The bookkeeping of one learned block: the play's scatter (with the estimate at each of its
    ticks, ``estimates``, and as it was right after the block, ``end``) and, for a kinematic
    estimator, the dwells; reads nothing but its arguments."""
    scatter.update_ticks(step.u_deg, step.chunk.load_deg, step.chunk.after_gap, step.ticks, estimates, end)
    if dwells is not None:
        dwells.update(step.u_deg, step.chunk.load_deg, step.chunk.after_gap)


def fit_recursive(
    chunks: Iterable[SampleChunk],
    ratio: float,
    *,
    every_s: float = 1.0,
    trace: Callable[[EstimateRow], None] | None = None,
    estimator: BacklashRLS | None = None,
    source: str | os.PathLike[str] = "<stream>",
    ahead: int = 0,
    rated_torque_Nm: float | None = None,
    **params: Any,
) -> tuple[BacklashReport, BacklashRLS | TorqueBacklashRLS]:
    """Stream a log through :class:`BacklashRLS` chunk by chunk (memory stays flat); through
    :class:`~online_backlash.load_aware.TorqueBacklashRLS` when its first chunk has a torque column.

    Parameters
    ----------
    chunks : iterable of SampleChunk
        Consecutive blocks, e.g. ``CsvLog(path).iter_chunks()``; ``after_gap``, time and
        torque are passed on.
    ratio : float
        Gear ratio motor:load (``u = motor_deg / ratio``).
    every_s : float
        With ``trace``, one row per ``every_s`` seconds of data (:class:`~online_backlash.pipeline.DataClock`).
    trace : callable, optional
        Called with an :class:`~online_backlash.rows.EstimateRow` every ``every_s`` seconds of
        data once the estimator has started (stamped with the time of the last sample learned),
        and with a final row at the end of the log (:meth:`EstimateRow.trace` gives the
        columns of ``estimate --trace``).
    estimator : BacklashRLS, optional
        Continue this estimator (e.g. resumed from a saved state) instead of a new one.
    source : str or PathLike
        Names the log in errors.
    ahead : int
        Chunks read ahead in a reader thread (:func:`~online_backlash.pipeline.read_ahead`; 0: none).
        For recorded files: the reading overlaps the estimation, and the per-block bookkeeping (the
        play's scatter, the dwells) runs in a worker thread of its own (:data:`BOOKKEEPING_AHEAD`
        blocks behind at most, the results identical). Live sources keep 0 (one thread).
    rated_torque_Nm : float, optional
        With torque: lost motion at 3 % of it (N m); else at the torque dead band.
    **params
        Settings of a new :class:`BacklashRLS` (those it shares with ``TorqueBacklashRLS`` for torque),
        e.g. ``gap_policy`` (:class:`~online_backlash.bridging.GapPolicy`: which gaps it is carried across).

    Returns
    -------
    report : BacklashReport
        ``method="recursive"``; ``extra`` has ``backlash_std_deg``, ``n_reversals``, the gap
        figures (:data:`~online_backlash.rows.GAP_KEYS`) and, where the start failed, ``warm_start``
        (how the estimator started and why); the load-aware keys (observability, figures).
    est : BacklashRLS or TorqueBacklashRLS
    """
    first, chunks = _first_and_rest(chunks)
    est = estimator if estimator is not None else recursive_estimator(first, ratio, **params)
    check_every(every_s)
    tracker = DwellTracker()
    # rows cost time: every every_s for a trace, else none, only the ticks of the scatter every SCATTER_EVERY_S
    pipeline = Pipeline(est, ratio, every_s if trace is not None else SCATTER_EVERY_S, rows=trace is not None)
    scatter = RecursivePlayScatter(est)  # backlash_std_deg: the play's scatter over the reversal cycles too
    dwells = None if isinstance(est, TorqueBacklashRLS) else tracker
    # with a reader thread (a recorded file), the bookkeeping overlaps the next block's estimation too
    with OrderedWorker(BOOKKEEPING_AHEAD if ahead > 0 else 0) as books:
        for step in pipeline.run(chunks, os.fspath(source), ahead):
            end = scatter.snapshot(step.due)
            books.call(_keep_books, step, scatter, step.estimates if step.estimates is not None else [end] * step.due, end, dwells)
            if step.row is not None and trace is not None:
                trace(step.row)
    last = pipeline.finish()
    scatter.finish()
    if last is not None and trace is not None:
        trace(last)
    report = BacklashReport.from_estimator(
        "recursive", est.n_samples_seen_, est, backlash_std_deg=scatter.std_deg, n_reversals=est.n_reversals_,
        **pipeline.gap_tally.values(),
    )
    if est.warm_start_.get("method") == "cold":
        report.extra["warm_start"] = dict(est.warm_start_)
    keys = recursive_keys(est, rated_torque_Nm) if isinstance(est, TorqueBacklashRLS) else kinematic_keys(tracker)
    return report.add_load_keys(keys), est


def describe(report: BacklashReport, source: str | os.PathLike[str] | None = None) -> str:
    """A short human-readable report with units."""
    lines = []
    if source is not None:
        lines.append(f"log:            {os.fspath(source)}")
    lines += [
        f"method:         {report.method}",
        f"samples:        {report.samples}",
        f"backlash:       {report.backlash_deg:.4f} deg  ({report.backlash_arcmin:.2f} arcmin, load side)"
        if math.isfinite(report.backlash_deg)
        else "backlash:       none",
        f"  left flank:   {report.c_left_deg:.4f} deg from the start position, slope {report.m_left:.5f}",
        f"  right flank:  {report.c_right_deg:.4f} deg from the start position, slope {report.m_right:.5f}",
        f"residual RMS:   {report.residual_rms_deg:.5f} deg",
    ]
    std = report.extra.get("backlash_std_deg")
    if std is not None and np.isfinite(std):
        lines.insert(3 if source is None else 4, f"  std error:    {std:.5f} deg")
    counts = describe_counts(report.as_dict())
    if counts:
        lines.append(f"source:         {counts}")
    lines += _load_lines(report)
    warm = report.extra.get("warm_start")
    if warm is not None:
        lines.append(f"warm start:     failed, cold start ({warm.get('reason', 'no reason given')})")
    return "\n".join(lines)


def _load_lines(report: BacklashReport) -> list[str]:
    """The report's load-aware lines: why the play is not observable (one line), the data-sheet figures."""
    lines = []
    reason = report.no_play_reason()
    if reason is not None:
        bound = report.backlash_lower_bound_deg
        lines.append(f"play:           {reason}" + (f"; at least {bound:.4f} deg" if bound else ""))
    if report.torque_reversals is not None:
        deadband = report.extra.get("torque_deadband_Nm", math.nan)
        lines.append(f"torque:         {report.torque_reversals} reversals through a dead band of {deadband:.4g} N m")
    if report.stiffness_nm_per_arcmin is not None:
        lines.append(
            f"stiffness:      {report.stiffness_nm_per_arcmin:.4g} N m/arcmin (left {_fmt(report.stiffness_left_nm_per_arcmin)}, "
            f"right {_fmt(report.stiffness_right_nm_per_arcmin)})"
        )
    if report.lost_motion_arcmin is not None:
        at = report.extra.get("lost_motion_torque_Nm", math.nan)
        basis = "; ".join(b for b in (report.extra.get("lost_motion_basis"), report.extra.get("datasheet_fit")) if b)
        lines.append(f"lost motion:    {report.lost_motion_arcmin:.3f} arcmin at +-{at:.4g} N m ({basis})")
    if report.hysteresis_loss_arcmin is not None:
        lines.append(f"hysteresis loss: {report.hysteresis_loss_arcmin:.3f} arcmin")
    return lines


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.4g}"
