"""Fit a recorded log: read it, refer the motor angle to the load side, run an estimator.

The thin layer between the CLI and the estimators: it returns plain results with units in
their names and never prints. The recursive fit runs the one loop of
:mod:`online_backlash.pipeline`; the columns of its outputs are declared in
:mod:`online_backlash.output_columns`.
"""

from __future__ import annotations

import inspect
import itertools
import math
import os
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import InvalidParameterError, NotExcitedError
from .estimators import BacklashRLS, VorosBacklash
from .estimators.uncertainty import SCATTER_EVERY_S, EstimateAt, RecursivePlayScatter
from .gap_policy import GapTally
from .load_aware import DwellTracker, PlayChooser, TorqueBacklash, TorqueBacklashRLS
from .load_aware.choice import (
    NO_TORQUE,
    PathEstimate,
    check_play_method,
    choose_play_method,
    kinematic_path,
    torque_dwell_test,
    torque_path,
)
from .load_aware.datasheet import DatasheetFigures
from .load_aware.engagement import torque_orientation
from .load_aware.observability import engagement_torques
from .load_aware.report import batch_keys, has_torque, recursive_keys
from .output_columns import (
    ARCMIN_PER_DEG,
    REPORT_KEYS,
    TRACE_COLUMNS,
    EstimateRow,
    describe_counts,
    select,
    source_counts,
)
from .pipeline import OrderedWorker, Pipeline, PipelineStep, check_every
from .stream import SampleChunk

#: Plausible range of the fitted slopes' magnitude: after referring, load and motor move alike (eq. 1, m ~ +-1).
PLAUSIBLE_SLOPE = (0.5, 2.0)
#: Largest plausible play, degrees on the load side (worn gearboxes have tenths of a degree, not degrees).
PLAUSIBLE_PLAY_DEG = 5.0
#: The kinematic path's settings: encoder zeros are arbitrary (origin at the first sample), and the flank
#: lines are fitted where the flanks are fully engaged
#: (:class:`~online_backlash.estimators.full_engagement.FullEngagement`, issue 27: a partial crossing of the gap
#: belongs to neither line); the recursive estimator takes the latter (its origin is the first sample already).
KINEMATIC = {"origin": "first", "full_engagement": True}
#: Blocks the bookkeeping of :func:`fit_recursive` (play scatter, dwells) may lag behind the estimator in
#: its worker thread, with ``ahead`` > 0 (:class:`~online_backlash.pipeline.OrderedWorker`; 0: inline).
BOOKKEEPING_AHEAD = 2

__all__ = [
    "ARCMIN_PER_DEG",
    "TRACE_COLUMNS",
    "BacklashReport",
    "fit_batch",
    "fit_recursive",
    "plausibility",
    "report_text",
]


def slope_note(m_left: float, m_right: float, ratio: float) -> str | None:
    """One sentence when a flank's slope of eq. (1) is far from +-1 after referring (``|m|`` outside
    :data:`PLAUSIBLE_SLOPE`), else None: the two angles are then in different units (counts under a
    degrees header, wrong counts per revolution) or the ratio is off by ``m`` (``ratio / m`` would give
    slope 1). A gear pair's load follows its referred motor one to one, so such a fit's play, in load
    degrees, is no play of the gearbox."""
    slopes = [m for m in (m_left, m_right) if np.isfinite(m)]
    low, high = PLAUSIBLE_SLOPE
    if not slopes or all(low <= abs(m) <= high for m in slopes):
        return None
    m = float(np.mean(slopes))
    return (
        f"fitted slope {m:.4g}, not near +-1 after referring: the motor and load angles are likely in different "
        f"units (encoder counts under a degrees header: give --units counts --motor-cpr N --load-cpr N; or wrong "
        f"counts per revolution), or the ratio is off (--ratio {ratio / m:.4g} would give slope 1)"
    )


def plausibility(
    m_left: float, m_right: float, backlash_deg: float, ratio: float, with_torque: bool = False
) -> str | None:
    """One sentence naming the likely cause when a fit of eq. (1) looks like wrong units or ratio, else None.

    After referring (``u = motor / ratio``) the flanks of eq. (1) have slopes near +-1
    (:func:`slope_note`). A play ``backlash_deg`` above
    :data:`PLAUSIBLE_PLAY_DEG` degrees points at counts read as degrees; a negative play is not
    physical (``with_torque``: wind-up and play not told apart). Shared by ``estimate`` (the
    report's fit) and ``diagnose`` (its base fit).
    """
    off_slope = slope_note(m_left, m_right, ratio)
    if off_slope is not None:
        return off_slope
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
    backlash_upper_bound_deg: float | None = None
    reason: str | None = None
    play_method: str | None = None
    play_method_reason: str | None = None
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
        """:func:`plausibility` of this fit (a torque column: ``torque_reversals`` is set); None where the
        report's ``reason`` says it already (a play withheld for its slopes, :meth:`withhold_off_slope`)."""
        note = plausibility(self.m_left, self.m_right, self.backlash_deg, ratio, self.torque_reversals is not None)
        return None if note is not None and self.reason is not None and note in self.reason else note

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
        return self.reason or (
            "the fit gave no finite play: check the units (--units, --motor-cpr/--load-cpr) and --ratio"
        )

    def withhold_off_slope(self, ratio: float) -> BacklashReport:
        """Withhold the play of a fit whose slopes say the angles are in different units or the ratio is
        off (:func:`slope_note`): null, ``play_observable`` false and the note as its ``reason``
        (issue 27 item 2: nothing non-physical is reported as a play). Returns self."""
        note = slope_note(self.m_left, self.m_right, ratio)
        if note is not None and math.isfinite(self.backlash_deg):
            self.add_load_keys({"backlash_deg": None, "play_observable": False, "reason": f"not reported: {note}"})
        return self

    def add_load_keys(self, keys: Mapping[str, Any]) -> BacklashReport:
        """Take the load-aware keys (:mod:`online_backlash.load_aware.report`): the declared ones as
        fields, the rest in ``extra`` (the play as its verdict reports it: NaN, JSON null, where it is
        not reported, :func:`online_backlash.physical.play_verdict`). Returns self."""
        for name, value in keys.items():
            if name == "backlash_deg":
                self.backlash_deg = math.nan if value is None else float(value)
            elif name in self.__dataclass_fields__ and name != "extra":
                setattr(self, name, value)
            else:
                self.extra[name] = value
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
        """Carry the source's counters (:data:`~online_backlash.output_columns.COUNTER_KEYS`; ``samples`` stays
        the samples fitted) in ``extra``, hence in :meth:`as_dict` and :func:`report_text`; returns self."""
        self.extra.update({k: v for k, v in source_counts(counts).items() if k != "samples"})
        return self


def _own_params(cls: type, params: Mapping[str, Any]) -> dict[str, Any]:
    """The settings of ``params`` that ``cls`` takes."""
    names = inspect.signature(cls).parameters
    return {k: v for k, v in params.items() if k in names}


def _check_torque_asked(play_method: str, torque_present: bool) -> None:
    if play_method == "torque" and not torque_present:
        raise InvalidParameterError("--play-method torque needs a torque column: map it with --columns torque=NAME")


def fit_batch(
    chunk: SampleChunk,
    ratio: float,
    *,
    rated_torque_Nm: float | None = None,
    play_method: str = "auto",
    no_torque_why: str = NO_TORQUE,
    **params: Any,
) -> tuple[BacklashReport, VorosBacklash | TorqueBacklash]:
    """Fit a whole log in memory, the path chosen by the data (issue 27, :mod:`online_backlash.load_aware.choice`).

    With a torque column (unless ``play_method="kinematic"``),
    :class:`~online_backlash.load_aware.TorqueBacklash` (flank lines with wind-up, the flanks told apart
    about the torques at which they engage as the dwells show them; the data-sheet figures, lost motion
    at 3 % of ``rated_torque_Nm`` N m if given); and (unless ``play_method="torque"``)
    :class:`VorosBacklash` (eq. 8-14, then the output-error refinement; its lines where the flanks are fully
    engaged, :data:`KINEMATIC`) with the kinematic observability
    (:class:`~online_backlash.load_aware.DwellTracker`). ``auto`` picks the path the data support
    (:func:`~online_backlash.load_aware.choice.choose_play_method`); the report carries its estimator's
    lines, and its play as :func:`online_backlash.physical.play_verdict` lets it be reported. Returns the
    report and the chosen path's estimator. ``no_torque_why``: why there is no torque path (the report says).
    """
    check_play_method(play_method)
    u, y = chunk.referred(ratio)
    gaps = GapTally.of_chunk(chunk).values()
    q = chunk.torque_Nm if has_torque(chunk.torque_Nm) else None
    _check_torque_asked(play_method, q is not None)
    tracker = DwellTracker()
    tracker.update(u, y, chunk.after_gap, q)
    torque_est = None
    if q is not None and play_method != "kinematic":
        torque_params = _own_params(TorqueBacklash, params)
        torque_est = TorqueBacklash(**torque_params).fit(u, y, q, engagement_torques(tracker.dwells_))
    kin_est, kinematic = None, None
    if torque_est is None or play_method == "auto":
        try:  # encoder zeros are arbitrary: origin "first"
            kin_est = VorosBacklash(**{**KINEMATIC, **_own_params(VorosBacklash, params)}).fit(u, y)
            kinematic = kinematic_path(kin_est.backlash_, kin_est.backlash_std_, tracker)
        except NotExcitedError as exc:
            if torque_est is None:
                raise
            failed = f"not observable: the kinematic fit failed ({exc})"
            kinematic = PathEstimate("kinematic", math.nan, math.nan, False, failed)
    torque = None if torque_est is None else torque_path(torque_est, tracker)
    test = None if torque is None or not torque.observable else torque_dwell_test(torque_est, tracker)
    decision = choose_play_method(play_method, torque, kinematic, test, no_torque_why)
    taken = decision.method == "torque"
    chosen: VorosBacklash | TorqueBacklash = torque_est if taken else kin_est  # type: ignore[assignment]
    report = BacklashReport.from_estimator("batch", len(chunk), chosen, n_iter=chosen.n_iter_, **gaps)
    keys = decision.keys()
    if torque_est is not None:
        keys = {**batch_keys(torque_est, u, y, q, rated_torque_Nm, taken), **keys}  # type: ignore[arg-type]
    return report.add_load_keys(keys).withhold_off_slope(ratio), chosen


def _first_and_rest(chunks: Iterable[SampleChunk]) -> tuple[SampleChunk | None, Iterable[SampleChunk]]:
    """The first chunk (None for an empty stream) and an iterable of all of them, the first included."""
    it = iter(chunks)
    first = next(it, None)
    return first, (it if first is None else itertools.chain([first], it))


def recursive_estimator(
    first: SampleChunk | None, ratio: float, play_method: str = "auto", no_torque_why: str = NO_TORQUE, **params: Any
) -> PlayChooser:
    """A new recursive estimator of the play for a stream that begins with ``first``: a
    :class:`~online_backlash.load_aware.PlayChooser` around :class:`TorqueBacklashRLS` where it has a torque
    column and the torque path is wanted (its sign from
    :func:`~online_backlash.load_aware.engagement.torque_orientation`, the settings it shares with ``params``;
    with ``play_method="auto"`` a :class:`BacklashRLS` learns beside it),
    else around :class:`BacklashRLS` with ``params``; the :class:`BacklashRLS` fits its lines where the flanks
    are fully engaged unless ``params`` say otherwise (:data:`KINEMATIC`)."""
    check_play_method(play_method)
    present = first is not None and has_torque(first.torque_Nm)
    _check_torque_asked(play_method, present)
    kinematic = {"full_engagement": KINEMATIC["full_engagement"], **params}
    if present and play_method != "kinematic":
        assert first is not None
        sign = torque_orientation(*first.referred(ratio), first.torque_Nm)
        shared = _own_params(TorqueBacklashRLS, params)
        main: BacklashRLS | TorqueBacklashRLS = TorqueBacklashRLS(**{"torque_sign": sign, **shared})
    else:
        main = BacklashRLS(**kinematic)
    return PlayChooser.beside(main, play_method, no_torque_why, **kinematic)


def _update_scatter(
    step: PipelineStep, scatter: RecursivePlayScatter | None, estimates: Sequence[EstimateAt], end: EstimateAt
) -> None:
    """The bookkeeping of one learned block: the kinematic play's scatter (with the estimate at each of its
    ticks, ``estimates``, and as it was right after the block, ``end``) takes the block; reads nothing but its
    arguments."""
    if scatter is not None:
        scatter.update_ticks(step.u_deg, step.chunk.load_deg, step.chunk.after_gap, step.ticks, estimates, end)


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
    play_method: str = "auto",
    no_torque_why: str = NO_TORQUE,
    **params: Any,
) -> tuple[BacklashReport, PlayChooser]:
    """Stream a log through :class:`BacklashRLS` chunk by chunk (memory stays flat); through
    :class:`~online_backlash.load_aware.TorqueBacklashRLS` when its first chunk has a torque column,
    with a :class:`BacklashRLS` beside it where the data decide the path (``play_method="auto"``,
    :class:`~online_backlash.load_aware.PlayChooser`; issue 27).

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
        Called with an :class:`~online_backlash.output_columns.EstimateRow` every ``every_s`` seconds of
        data once the estimator has started (stamped with the time of the last sample learned),
        and with a final row at the end of the log (:meth:`EstimateRow.trace` gives the
        columns of ``estimate --trace``).
    estimator : BacklashRLS or PlayChooser, optional
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
    play_method : {"auto", "torque", "kinematic"}
        The path of the play: chosen by the data, or the one given (:mod:`online_backlash.load_aware.choice`).
    no_torque_why : str
        Why there is no torque path, where there is none (the report says).
    **params
        Settings of a new :class:`BacklashRLS` (those it shares with ``TorqueBacklashRLS`` for torque),
        e.g. ``gap_policy`` (:class:`~online_backlash.gap_policy.GapPolicy`: which gaps it is carried across).

    Returns
    -------
    report : BacklashReport
        ``method="recursive"``; ``extra`` has ``backlash_std_deg``, ``n_reversals``, the gap
        figures (:data:`~online_backlash.output_columns.GAP_KEYS`) and, where the start failed, ``warm_start``
        (how the estimator started and why); the path taken and why, the load-aware keys
        (observability, bounds, figures).
    est : PlayChooser
        The estimators (``est.estimator``, ``est.companion``) and the evidence (``est.tracker``).
    """
    first, chunks = _first_and_rest(chunks)
    if estimator is None:
        est = recursive_estimator(first, ratio, play_method, no_torque_why, **params)
    elif isinstance(estimator, PlayChooser):
        est = estimator
    else:
        est = PlayChooser(estimator, play_method, no_torque_why=no_torque_why)
    check_every(every_s)
    # rows cost time: every every_s for a trace, else none, only the ticks of the scatter every SCATTER_EVERY_S
    pipeline = Pipeline(est, ratio, every_s if trace is not None else SCATTER_EVERY_S, rows=trace is not None)
    kinematic = est.kinematic
    # backlash_std_deg of the kinematic play: its scatter over the reversal cycles too (the torque path states its own)
    scatter = None if kinematic is None else RecursivePlayScatter(kinematic)
    # with a reader thread (a recorded file), the bookkeeping overlaps the next block's estimation too
    with OrderedWorker(BOOKKEEPING_AHEAD if ahead > 0 else 0) as books:
        for step in pipeline.run(chunks, os.fspath(source), ahead):
            end = scatter.snapshot(step.due) if scatter is not None else EstimateAt(False, math.nan, math.nan, math.nan)
            at_ticks = step.estimates if step.estimates is not None else [end] * step.due
            books.call(_update_scatter, step, scatter, at_ticks, end)
            if step.row is not None and trace is not None:
                trace(step.row)
    last = pipeline.finish()
    if scatter is not None:
        scatter.finish()
    if last is not None and trace is not None:
        trace(last)
    decision = est.decide(None if scatter is None or kinematic is None or not kinematic.started else scatter.std_deg)
    chosen = est.chosen(decision)
    if chosen is None or not chosen.started:  # that path never started: its play is null, the lines the other's
        chosen = est.estimator
    report = BacklashReport.from_estimator(
        "recursive",
        est.n_samples_seen_,
        chosen,
        n_reversals=chosen.n_reversals_,
        **pipeline.gap_tally.values(),
    )
    main = est.estimator
    if main.warm_start_.get("method") == "cold" and not main.takes_torque:
        report.extra["warm_start"] = dict(main.warm_start_)
    keys = decision.keys()
    if est.torque is not None:
        keys = {**recursive_keys(est.torque, rated_torque_Nm, decision.method == "torque"), **keys}
    return report.add_load_keys(keys).withhold_off_slope(ratio), est


def report_text(report: BacklashReport, source: str | os.PathLike[str] | None = None) -> str:
    """The report as the text ``estimate`` prints without ``--json``: one line a figure, with units (``source``:
    the log named on the first line)."""
    lines = []
    if source is not None:
        lines.append(f"log:            {os.fspath(source)}")
    play = (
        f"{report.backlash_deg:.4f} deg  ({report.backlash_arcmin:.2f} arcmin, load side)"
        if np.isfinite(report.backlash_deg)
        else "not reported (see play:)"
    )
    lines += [
        f"method:         {report.method}",
        f"samples:        {report.samples}",
        f"backlash:       {play}",
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


def describe(report: BacklashReport, source: str | os.PathLike[str] | None = None) -> str:
    """The old name of :func:`report_text` (before issue 29), with a DeprecationWarning."""
    warnings.warn(
        "online_backlash.log_fit.describe is renamed report_text: call that (describe will be removed in a later "
        "release)",
        DeprecationWarning,
        stacklevel=2,
    )
    return report_text(report, source)


def _load_lines(report: BacklashReport) -> list[str]:
    """The report's load-aware lines: the path of the play and why (one line), why the play is not
    reported or is a measured zero (one line, with the bounds the data support), the data-sheet figures."""
    values = report.as_dict()
    lines = []
    if values.get("play_method") is not None:
        lines.append(f"path:           {values['play_method']} ({values.get('play_method_reason')})")
    if values.get("unused_torque_columns"):
        unused = ", ".join(values["unused_torque_columns"])
        lines.append(f"torque:         column(s) {unused} present but not used (map one with --columns torque=NAME)")
    reason = report.reason or report.no_play_reason()  # a measured zero has a play and its reason
    if reason is not None:
        lower, upper = report.backlash_lower_bound_deg, values.get("backlash_upper_bound_deg")
        bounds = [f"at least {lower:.4f} deg"] if lower else []
        bounds += [f"at most {upper:.4f} deg"] if upper is not None else []
        shown = f"; {', '.join(bounds)}" if bounds and not reason.startswith("zero") else ""
        lines.append(f"play:           {reason}{shown}")
    if report.torque_reversals is not None:
        deadband = report.extra.get("torque_deadband_Nm", math.nan)
        lines.append(f"torque:         {report.torque_reversals} reversals through a dead band of {deadband:.4g} N m")
    if report.stiffness_nm_per_arcmin is not None:
        lines.append(
            f"stiffness:      {report.stiffness_nm_per_arcmin:.4g} N m/arcmin (left "
            f"{_fmt(report.stiffness_left_nm_per_arcmin)}, "
            f"right {_fmt(report.stiffness_right_nm_per_arcmin)})"
        )
    fitted = values.get("stiffness_segments_fitted") or []
    if fitted:
        stiffness = {name: values[f"stiffness_{name.lower()}_nm_per_arcmin"] for name in fitted}
        segs = ", ".join(f"{name} {k:.4g}" for name, k in stiffness.items() if k is not None)
        t1, t2 = values["stiffness_torques_Nm"]
        lines.append(f"segments:       {segs} N m/arcmin (T1 {t1:g}, T2 {t2:g} N m; fitted: {', '.join(fitted)})")
    if values.get("figures_reason"):
        lines.append(f"figures:        {values['figures_reason']}")
    if report.lost_motion_arcmin is not None:
        at = report.extra.get("lost_motion_torque_Nm", math.nan)
        basis = "; ".join(b for b in (report.extra.get("lost_motion_basis"), report.extra.get("datasheet_fit")) if b)
        lines.append(f"lost motion:    {report.lost_motion_arcmin:.3f} arcmin at +-{at:.4g} N m ({basis})")
    if report.hysteresis_loss_arcmin is not None:
        lines.append(f"hysteresis loss: {report.hysteresis_loss_arcmin:.3f} arcmin")
    return lines


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.4g}"
