"""The selection loop: fit, look at the residual, add the effect it shows, refit, repeat.

1. Fit the base model, the four backlash parameters of eq. (1) refitted on the simulation
   (free-run) residual (:class:`~online_backlash.estimators.VorosBacklash` with
   ``refine=True``). Its residual is the "before": the paper's equation-error estimate alone
   leaves a larger one and would flatter every effect.
2. Score every effect of the library and every generic term on the residual (an information
   criterion with an effective sample size, plus a minimum share explained in sample and on
   reversal cycles held out of the fit, see :mod:`._scoring` and :mod:`._folds`).
3. Refit the backlash and all terms jointly by output error (:func:`.joint.fit_guarded`), once
   with the best significant named effect and once with the best generic term; keep the named
   effect unless the generic term leaves clearly less (then the structure is *unexplained*: it
   is reported with where it sits and closed with that generic term). If the new terms blur
   the play (variance inflation above :data:`.joint.MAX_PLAY_INFLATION` or standard error
   above :data:`.joint.MAX_PLAY_STD_SHARE` of the play), the play is held and the report says
   so. A term whose joint refit does not remove at least ``min_gain`` of the mean square
   residual is refused (the linear score can promise more than the refit delivers when the
   play is held), and so is one whose joint refit gives a term a figure no drive can have (the
   dead band's creep back through the flank the load left, or beyond the other one:
   :meth:`.dead_band.DeadBandMotion.is_physical`, within the noise floor).
   The two named effects that explain most are both refitted and the better refit is the
   candidate; if the other refits about as well and neither adds ``min_gain`` once the other is
   in, the two are reported together as *not separable* (and neither is claimed). A term with a
   setting of its own (the compliance's torque average) has it fitted in the refit, and retuned
   when a later term comes in (:func:`_tuned`), as the delay's lag is refitted.
4. Repeat until nothing is significant or the residual is within ``floor_ratio`` of the noise
   floor. Then every term is held out once more, given all the others in the final model.

A long record (at least three times ``screen_cycles`` reversal cycles, and three times
:data:`._folds.SCREEN_MIN_SAMPLES` samples) is screened: steps 2 and 3 score and refit the candidates
on about ``screen_cycles`` of its cycles spread evenly over it (more where its cycles are short;
:meth:`._folds.Folds.screen`; the scores on every :data:`._folds.SCREEN_STRIDE`-th sample of them, the
refits on every sample); the effect they choose is then detected again on every sample
(its configuration and evidence as without the screen, :func:`_confirmed`; refused if the whole
record does not bear it out), the terms are fitted jointly on every sample (the step's figures
and the next round's residual), and the settings of the terms (the compliance's torque average, the
new term's and those of the terms already in) are walked there, as without the screen. The screen
decides which effect comes next, the whole record how it is configured, set, fitted and evidenced.

Angles in degrees on the load side, time in seconds.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from functools import reduce
from itertools import pairwise
from typing import Any, Protocol

import numpy as np
from threadpoolctl import threadpool_limits

from ..estimators import VorosBacklash
from ..estimators._validation import check_int, check_real
from ..model import simulate_backlash
from ..stream import SampleChunk
from ._causal import sample_period_s, savgol_derivative
from ._folds import SCREEN_CYCLES, Folds, cycle_folds
from ._initial_state import InitialState, estimate_initial_state
from ._normal_equations import Projector, left_sum_of_squares
from ._record_cache import RecordCache
from ._scoring import BIC_THRESHOLD, MIN_GAIN, Detection, DetectionData
from ._term_columns import TermColumns
from .effects import LIBRARY
from .generic import GENERIC
from .joint import MAX_PLAY_INFLATION, MAX_PLAY_STD_SHARE, ColumnParts, JointFit, Support, _switched, fit_guarded, hold_columns, play_sensitivity
from .residuals import NoiseFloor, Profile, noise_floor, one_step_residual, profile, simulation_residual

#: the runner-up named effect is refitted too when its linear gain is at least this share of the best one's
RUNNER_UP_SHARE = 0.8


@dataclass
class Step:
    """One term added by the loop.

    ``kind`` is ``"effect"`` (a named effect of the library) or ``"unexplained"`` (a generic term
    closing structure no named effect explains), ``number`` its place in the order added (from 1).
    ``parameters`` come from the final joint fit;
    ``rms_before_deg`` and ``rms_after_deg`` are the residual RMS just before and after adding it.
    """

    kind: str
    effect: Any
    detection: Detection
    rms_before_deg: float
    rms_after_deg: float
    play_before_deg: float
    play_after_deg: float
    play_inflation: float
    play_std_deg: float
    play_held: bool
    number: int = 0
    parameters: dict[str, Any] = field(default_factory=dict)
    #: the simulation residual after this term was added, deg
    residual_after_deg: np.ndarray = field(default_factory=lambda: np.empty(0), repr=False)
    #: how the held-out cycles were chosen (``folds``, ``cycles``, ``split``)
    heldout_split: dict[str, Any] = field(default_factory=dict)
    #: held-out gain of this term given all the others, in the final model (NaN if not measured)
    heldout_gain_final: float = float("nan")
    #: named effects that explain the same part of the residual (kind ``"not_separable"``)
    rivals: tuple[str, ...] = ()
    #: the fit just before this term came in and the terms it had then: what ``detection`` was
    #: scored on (see :func:`_rescored`)
    scored_on: tuple[JointFit, tuple[Any, ...]] | None = field(default=None, repr=False)
    #: the detection data of ``scored_on`` over every sample, kept while the loop runs for a term whose
    #: setting a later round may move (``neighbours``): :func:`_rescored` scores the final setting on it
    scored_data: DetectionData | None = field(default=None, repr=False)
    #: True when a later term moved this term's setting (:func:`_tuned`): ``effect`` and the
    #: evidence are of the final setting
    retuned: bool = False

    def as_dict(self) -> dict[str, Any]:
        """The JSON object of this term (``name``, ``parameters``, ``rms_before_deg``, ``rms_after_deg``, ``evidence``)."""
        s = self.detection.score
        evidence: dict[str, Any] = {
            "summary": self.detection.evidence,
            "statistic": "delta_bic_eff",
            "delta_bic_eff": s.delta_bic,
            "threshold": BIC_THRESHOLD,
            "share_of_residual_explained": s.gain,
            "heldout_gain": s.heldout_gain,
            "heldout_gain_in_final_model": self.heldout_gain_final,
            "heldout_split": self.heldout_split,
            "effective_samples": s.n_eff,
            "own_variance_share": s.own_share,
            "play_variance_inflation": self.play_inflation,
            "play_std_deg": self.play_std_deg,
            "play_separable": not self.play_held,
            "retuned_by_later_terms": self.retuned,
        }
        if self.play_held:
            evidence["note"] = (
                "the data cannot separate this term from the play (play variance inflation "
                f"{self.play_inflation:.1f}, limit {MAX_PLAY_INFLATION:.0f}; play standard error "
                f"{self.play_std_deg:.2g} deg, limit {MAX_PLAY_STD_SHARE:.1%} of the play), "
                "so the play was held at its value without the term"
            )
        out = {
            "step": self.number,
            "name": "not_separable" if self.kind == "not_separable" else self.effect.name,
            "parameters": self.parameters,
            "rms_before_deg": self.rms_before_deg,
            "rms_after_deg": self.rms_after_deg,
            "backlash_before_deg": self.play_before_deg,
            "backlash_after_deg": self.play_after_deg,
            "evidence": evidence,
        }
        if self.kind == "unexplained":
            out["where"] = self.effect.location()
        if self.kind == "not_separable":
            names = [self.effect.name, *self.rivals]
            out["candidates"] = names
            out["closed_with"] = self.effect.name
            out["where"] = (
                f"{' and '.join(names)} explain the same part of the residual (each adds less than "
                f"{MIN_GAIN:.0%} once the other is in): not separable on this record; closed with {self.effect.name}"
            )
        return out


@dataclass
class Diagnosis:
    """What the loop found in one record. Angles in degrees (load side).

    Attributes
    ----------
    base : VorosBacklash
        The base fit (the "before").
    final : JointFit
        The backlash and all added terms fitted jointly (the "after"), centred frame.
    steps : list of Step
        The terms in the order added.
    noise : NoiseFloor
    residual_before_deg, residual_after_deg : arrays
        Simulation residuals of the base and final models.
    u_deg, load_deg, time_s : arrays
        The referred motor angle, the load angle and the time of the record.
    ratio : float
        Gear ratio motor:load.
    initial_state : InitialState
        The load's state in the dead band at the record's start (a nuisance of the base fit, taken
        out of the residual before and after alike; not an effect).
    """

    base: VorosBacklash
    final: JointFit
    steps: list[Step]
    noise: NoiseFloor
    residual_before_deg: np.ndarray
    residual_after_deg: np.ndarray
    u_deg: np.ndarray
    load_deg: np.ndarray
    time_s: np.ndarray
    ratio: float
    torque_Nm: np.ndarray | None = None
    initial_state: InitialState = field(default_factory=InitialState)
    #: reversal cycles the candidates were scored and refitted on (a screen of a long record,
    #: :meth:`._folds.Folds.screen`); None: every cycle
    screened_cycles: int | None = None
    #: reversal cycles in the record (:func:`._folds.cycle_folds`)
    cycles: int = 0

    @property
    def effects(self) -> list[Any]:
        """Fresh copies of the named effects found (for ``BacklashRLS(effects=...)``)."""
        return [s.effect.clone() for s in self.steps if s.kind == "effect"]

    @property
    def all_terms(self) -> list[Any]:
        """Fresh copies of every term added, named and generic."""
        return [s.effect.clone() for s in self.steps]

    @property
    def rms_before_deg(self) -> float:
        return float(np.sqrt(np.mean(self.residual_before_deg**2)))

    @property
    def rms_after_deg(self) -> float:
        return float(np.sqrt(np.mean(self.residual_after_deg**2)))

    @property
    def one_step_residual_deg(self) -> np.ndarray:
        """The equation error of eq. (14) with the base fit's parameters, deg."""
        return one_step_residual(self.base.params_, self.u_deg - self.base.u_ref_, self.load_deg - self.base.y_ref_)

    def profiles(self, bins: int = 40) -> dict[str, tuple[Profile, Profile]]:
        """The simulation residual before and after, binned against time, load angle, motor angle and velocity."""
        period = sample_period_s(self.time_s)
        variables = {
            "time": (self.time_s, "s"),
            "load angle": (self.load_deg, "deg"),
            "motor angle": (self.u_deg * self.ratio, "deg"),
            "velocity": (np.gradient(self.u_deg, period), "deg/s"),
        }
        return {
            name: (profile(self.residual_before_deg, v, name, unit, bins), profile(self.residual_after_deg, v, name, unit, bins))
            for name, (v, unit) in variables.items()
        }

    def step_residuals(self) -> list[tuple[Step, np.ndarray, np.ndarray]]:
        """Every step with the simulation residual just before and just after it, deg."""
        out, before = [], self.residual_before_deg
        for s in self.steps:
            out.append((s, before, s.residual_after_deg))
            before = s.residual_after_deg
        return out

    def axis(self, step: Step) -> tuple[str, str, np.ndarray]:
        """The variable a term acts along, ``(name, unit, values)``: load angle (transmission error,
        per-flank harmonics), velocity (delay, velocity function), torque or acceleration
        (compliance), time (drift), time since the switching functions changed (dead band motion)."""
        name = step.effect.name
        period = sample_period_s(self.time_s)
        if name == "compliance":
            if getattr(step.effect, "proxy", "") == "torque" and self.torque_Nm is not None:
                return "torque", "N m", np.nan_to_num(self.torque_Nm, nan=0.0)
            return "acceleration", "deg/s^2", savgol_derivative(self.u_deg, self.time_s, step.effect.window_samples, 2)
        if name == "drift":
            return "time", "s", self.time_s
        if name == "dead_band_motion":
            return "time since the flank left (< 0) or engaged (> 0)", "s", step.effect.switch_clock(self.u_deg, self.time_s)
        if name in ("delay", "velocity_function"):
            return "velocity", "deg/s", np.gradient(self.u_deg, period)
        return "load angle", "deg", self.load_deg

    def as_dict(self) -> dict[str, Any]:
        """The JSON contract of ``online-backlash diagnose --json``."""
        return {
            "rms_before_deg": self.rms_before_deg,
            "rms_after_deg": self.rms_after_deg,
            "noise_floor_deg": self.noise.floor_deg,
            "backlash_before_deg": self.base.backlash_,
            "backlash_after_deg": self.final.params.play,
            "effects": [s.as_dict() for s in self.steps if s.kind == "effect"],
            "unexplained": [s.as_dict() for s in self.steps if s.kind != "effect"],
            "samples": int(self.u_deg.size),
            "load_step_deg": self.noise.step_deg,
            "load_noise_deg": self.noise.noise_deg,
            "initial_state": self.initial_state.as_dict(),
            "screened_cycles": self.screened_cycles,
        }


def _column_parts(terms: Sequence[Any], built: TermColumns, x: np.ndarray) -> ColumnParts:
    """The terms' columns, as parts (:class:`.joint.ColumnParts`, :func:`_parts`), with their support when
    they are zero on most samples (:class:`.joint.Support`, the dead band's motion), for the joint fits."""
    return ColumnParts(_parts(terms, built, x), tuple(None if hasattr(e, "output_columns") else built.support(e) for e in terms))


def _parts(terms: Sequence[Any], built: TermColumns, x: np.ndarray) -> tuple[np.ndarray, ...]:
    """The terms' columns, an ``(n, n_terms)`` array per term: an effect defined on the model's output
    (``output_columns``, the delay) is built on ``x``, the current backlash output; the others come
    from ``built`` (once per record)."""
    n = built.u_deg.size
    return tuple(np.reshape(e.output_columns(x) if hasattr(e, "output_columns") else built.get(e), (n, e.n_terms)) for e in terms)


def _columns(terms: Sequence[Any], built: TermColumns, x: np.ndarray) -> np.ndarray:
    """The terms' columns (:func:`_parts` side by side; a term's own read-only columns when it is the only one)."""
    return ColumnParts(_parts(terms, built, x)).block()


def _held(terms: Sequence[Any]) -> np.ndarray:
    """Which columns are held through the dead band (input-side effects not built on the model's output)."""
    if not terms:
        return np.zeros(0, bool)
    return np.concatenate([np.full(e.n_terms, bool(e.input_side) and not hasattr(e, "output_columns")) for e in terms])


def _own_support(effect: Any, built: TermColumns) -> Support | None:
    """The :class:`.joint.Support` of a term whose columns are read as they are built (neither held
    through the dead band nor built on the model's output; what :func:`_held_parts` hands out for it is
    its own columns), when they are zero on most samples."""
    plain = not (hasattr(effect, "output_columns") or _held([effect]).any())
    return built.support(effect) if plain else None


def _held_parts(terms: Sequence[Any], built: TermColumns, view: _ModelView) -> list[np.ndarray]:
    """Each term's columns as the model of ``view`` sees them (:func:`_parts`, the input-side ones held
    through its dead band, :func:`.joint.hold_columns`): one array per term, a term's own read-only
    columns where that does not apply (no block of all of them is formed)."""
    return [hold_columns(part, _held([term]), view.index) for part, term in zip(_parts(terms, built, view.x), terms)]


def _significant(found: list[Detection | None], bic_threshold: float, min_gain: float) -> list[Detection]:
    """The significant detections, the one that explains most first."""
    ok = [d for d in found if d is not None and d.score.significant(bic_threshold, min_gain)]
    return sorted(ok, key=lambda d: -d.score.gain)


def _prepared(data: DetectionData, effect: Any, built: TermColumns) -> np.ndarray:
    """An effect's columns as the scoring sees them: the input-side ones held through the dead band."""
    assert data.model_output_deg is not None
    x = _columns([effect], built, data.model_output_deg)
    return data.hold(x) if _held([effect]).any() else x


def _rivals(
    data: DetectionData, chosen: Detection, others: list[Detection], min_gain: float, built: TermColumns | None = None
) -> tuple[str, ...]:
    """Named effects that explain the same part of the residual as the chosen one: neither
    removes ``min_gain`` of the residual's mean square once the other is in. ``built``: the loop's
    term columns of this record (else built here)."""
    built = TermColumns(data.u_deg, data.time_s, data.torque_Nm) if built is None else built
    xa = _prepared(data, chosen.effect, built)
    names = []
    for d in others:
        if d is chosen:
            continue
        xb = _prepared(data, d.effect, built)
        if data.with_nuisance(xb).score(False, xa).gain < min_gain and data.with_nuisance(xa).score(False, xb).gain < min_gain:
            names.append(str(getattr(d.effect, "name", "")))
    return tuple(names)


#: The loop's least squares run on one BLAS thread. Its truncated eigen-solves of the normal
#: equations (:mod:`._normal_equations`) drop directions below a relative cut-off; a term with
#: nearly collinear columns (the dead band's coast and entry transient) can have an eigenvalue near
#: it, and the sums a multi-threaded BLAS forms in another order can move it across: on run20 of
#: the shared recordings the dead band's coefficients, and whether a third term is significant,
#: changed with the number of BLAS threads. On one thread the result is the same on a machine
#: whatever its core count (and the 600,000 x 30 products here gain little from a second thread).
ONE_BLAS_THREAD = threadpool_limits.wrap(limits=1, user_api="blas")


@ONE_BLAS_THREAD
def diagnose(
    chunk: SampleChunk,
    ratio: float,
    *,
    max_terms: int = 6,
    bic_threshold: float = BIC_THRESHOLD,
    min_gain: float = MIN_GAIN,
    label_ratio: float = 1.1,
    floor_ratio: float = 1.25,
    screen_cycles: int = SCREEN_CYCLES,
) -> Diagnosis:
    """Run the loop on a record in memory.

    Parameters
    ----------
    chunk : SampleChunk
        Time (s), motor angle (deg, motor shaft), load angle (deg), torque (N m, NaN if none).
    ratio : float
        Gear ratio motor:load (negative for a reversing stage).
    max_terms : int
        Most terms (named and generic) added.
    bic_threshold, min_gain : float
        Significance: criterion below ``bic_threshold`` and at least ``min_gain`` of the
        residual's mean square explained.
    label_ratio : float
        A named effect is chosen only if, after the joint refit, the mean square residual it
        leaves is at most this many times what the best generic term leaves; otherwise the
        structure is reported as unexplained (and closed with the generic term).
    floor_ratio : float
        Stop when the residual RMS is within this factor of the noise floor (1.25: with the
        record's start estimated, :mod:`._initial_state`, the clean two-mass logs sit at
        0.96-1.07 times the floor; ``docs/closing-the-loop.md``, point 7).
    screen_cycles : int
        A record of at least three times this many reversal cycles (and three times
        :data:`._folds.SCREEN_MIN_SAMPLES` samples) is *screened*: the candidates are scored (on every
        :data:`._folds.SCREEN_STRIDE`-th sample), and the candidates' joint refits fitted, on about this
        many of its cycles (more where they hold fewer than that many samples), spread evenly over it
        (:meth:`._folds.Folds.screen`); the effect chosen is then detected again, the terms fitted and
        their settings walked on every sample, and the final model's held-out gains use every
        cycle. 0: every cycle, always.

    Raises
    ------
    NotExcitedError
        When the record does not engage both flanks.
    """
    check_int("max_terms", max_terms, 0)
    check_real("min_gain", min_gain, 0.0, low_open=False)
    check_real("label_ratio", label_ratio, 1.0, low_open=False)
    check_real("floor_ratio", floor_ratio, 1.0, low_open=False)
    check_int("screen_cycles", screen_cycles, 0)
    u, y = (np.asarray(v, dtype=float) for v in chunk.referred(ratio))
    t = np.asarray(chunk.time_s, dtype=float)
    q = np.asarray(chunk.torque_Nm, dtype=float)
    base = VorosBacklash(refine=True, origin="first").fit(u, y)  # encoder zeros are arbitrary
    uc, yc = u - base.u_ref_, y - base.y_ref_
    # the load's state in the dead band at the start: the model's initial condition, not an effect
    start = estimate_initial_state(base.params_, uc, yc, t)
    before = simulation_residual(base.params_, uc, yc, start.path_deg)
    yc = yc - start.correction_deg(base.params_, uc)  # every fit below runs the model from rest: the start taken out
    noise = noise_floor(y)
    period = round(sample_period_s(t), 12)  # 0.001, not 0.000999999...
    folds = cycle_folds(u)
    screen = folds.screen(screen_cycles) if screen_cycles else folds  # a long record's candidates: scored and refitted on these cycles
    rows = screen.cycle_rows if screen.screened else None  # the candidates' refits: every sample of the screen's cycles
    cache = RecordCache()  # columns that depend on the record only, shared by every round
    built = TermColumns(u, t, q)  # the columns of the terms taken, built once
    current = JointFit(base.params_, np.empty(0), before, 1.0, float("nan"), False)
    steps: list[Step] = []
    refused: set[type] = set()
    while len(steps) < max_terms and current.rms_deg > floor_ratio * noise.floor_deg:
        taken = {type(s.effect) for s in steps} | refused
        view = _ModelView.of(uc, current.params)  # the round's model: its detectors' and its confirmation's
        done = [s.effect for s in steps]
        data = _detection_data(u, t, q, uc, current, done, float(ratio), period, screen, built, cache, view,
                               noise=noise)
        named_all = [_kept_columns(d, built) for d in _significant([c.detect(data) for c in LIBRARY if c not in taken], bic_threshold, min_gain)]
        generic_all = _significant([c.detect(data) for c in GENERIC if c not in taken], bic_threshold, min_gain)
        generic = generic_all[0] if generic_all else None
        if not named_all and generic is None:
            break

        x_now = data.model_output_deg  # the current backlash output, simulated once for this round
        assert x_now is not None

        def refit_with(
            terms: list[Any], current: JointFit = current, x_now: np.ndarray = x_now, rows: np.ndarray | None = rows,
            view: _ModelView = view, start: JointFit | None = None,
        ) -> JointFit:
            """The joint refit of ``terms`` over ``rows``, from the round's fit, or from ``start`` (a fit of
            nearly these terms: the search then needs fewer steps, and ends at the same least squares to its
            tolerance: within 2e-9 of every figure on the bench logs)."""
            columns = _column_parts(terms, built, x_now)
            if start is None:
                fit = fit_guarded(uc, yc, columns, current.params, _held(terms), rows, view.switched)
            else:
                fit = fit_guarded(uc, yc, columns, start.params, _held(terms), rows)
            if any(hasattr(e, "output_columns") for e in terms):  # built on the model's output: once more on the refitted one
                x = simulate_backlash(uc, fit.params, 0.0)
                fit = fit_guarded(uc, yc, _column_parts(terms, built, x), fit.params, _held(terms), rows)
            return fit

        def tuned(terms: list[Any], fit: JointFit, which: Iterable[int], rows: np.ndarray | None = rows) -> tuple[list[Any], JointFit]:
            """The settings of the terms at ``which`` walked on the joint refit linearised at ``fit``
            (:func:`_linearised_refit`), then confirmed by one joint refit: kept only if it is better.
            ``fit`` is over ``rows`` (the screen's, or None: every sample), and so are the walk and the refit."""
            for i in which:
                if not hasattr(terms[i], "neighbours"):
                    continue
                walk = _linearised_refit(terms, i, fit, uc, folds if rows is None else screen, built)
                walked, _ = _tuned(terms, walk(terms), walk, [i])
                if walked[i] is not terms[i]:
                    trial = refit_with(walked, rows=rows, start=fit)
                    if trial.rms_deg < fit.rms_deg:
                        terms, fit = walked, trial
            return terms, fit

        def refit(found: Detection, done: list = done, data: DetectionData = data) -> tuple[Detection, JointFit]:
            terms = [*done, found.effect]
            terms, fit = tuned(terms, refit_with(terms), [len(done)])  # the candidate's own setting
            return (found if terms[-1] is found.effect else replace(terms[-1].detection(data), rivals=found.rivals)), fit

        # the two named effects that explain most are both refitted: the better joint fit is named
        named: Detection | None = None
        fit_named: JointFit | None = None
        refits: list[tuple[Detection, JointFit]] = []

        def physical(found: Detection, fit: JointFit, done: list = done) -> bool:
            """False (and the candidate refused) where its refit gives a term a figure no drive can have."""
            if _physical([*done, found.effect], fit.coef, u, t, noise.floor_deg):
                return True
            refused.add(type(found.effect))
            return False

        for candidate in named_all[:2]:
            if fit_named is not None and candidate.score.gain < RUNNER_UP_SHARE * named_all[0].score.gain:
                break
            tried = refit(candidate)
            if not physical(*tried):
                continue
            refits.append(tried)
            if fit_named is None or refits[-1][1].rms_deg < fit_named.rms_deg:
                named, fit_named = refits[-1]
        # a named effect must do about as well as a flexible generic term in the joint refit
        fit_generic: JointFit | None = None
        if generic is not None:
            generic, fit_generic = refit(generic)
            if not physical(generic, fit_generic):
                generic = fit_generic = None
        kind: str
        chosen: Detection
        fit: JointFit
        if named is not None and fit_named is not None and (fit_generic is None or fit_named.rms_deg**2 <= label_ratio * fit_generic.rms_deg**2):
            kind, chosen, fit = "effect", named, fit_named
        elif generic is not None and fit_generic is not None:
            kind, chosen, fit = "unexplained", generic, fit_generic
        else:  # every refit refused as unphysical: try the others
            continue
        if fit.rms_deg**2 > (1.0 - min_gain) * current.rms_deg**2:
            refused.add(type(chosen.effect))  # the refit does not realise the gain: try the others
            continue
        # rivals: refitted about as well as the chosen one, and explaining the same part of the residual
        close = [d for d, f in refits if d is not chosen and f.rms_deg**2 <= label_ratio * fit.rms_deg**2]
        rivals = (*chosen.rivals, *_rivals(data, chosen, close, min_gain, built)) if kind == "effect" else ()
        if rows is None:
            # the settings of the terms already in, retuned with the new one in (the compliance's torque average)
            terms, fit = tuned([*done, chosen.effect], fit, range(len(done)))
        else:  # chosen on the screen: configured, evidenced and fitted on every sample, as without the screen
            whole = _detection_data(u, t, q, uc, current, done, float(ratio), period, folds, built, cache, view,
                                    noise=noise)
            confirmed = _confirmed(chosen, whole, built, bic_threshold, min_gain)
            if confirmed is None:
                refused.add(type(chosen.effect))  # the whole record does not bear it out: try the others
                continue
            # every setting walked on every sample: the new term's own first (as :func:`refit` does), then
            # those of the terms already in
            terms = [*done, confirmed.effect]
            terms, fit = tuned(terms, refit_with(terms, rows=None, start=fit), [len(done), *range(len(done))], rows=None)
            chosen = confirmed if terms[-1] is confirmed.effect else replace(terms[-1].detection(whole), rivals=confirmed.rivals)
        for step, effect in zip(steps, terms):
            step.retuned = step.retuned or effect is not step.effect
            step.effect = effect
        steps.append(
            Step(
                "not_separable" if rivals else kind, chosen.effect, chosen, current.rms_deg, fit.rms_deg, current.params.play,
                fit.params.play, fit.play_inflation, fit.play_std_deg, fit.play_held, len(steps) + 1,
                residual_after_deg=fit.residual_deg, heldout_split=folds.as_dict(), rivals=rivals, scored_on=(current, tuple(done)),
                scored_data=(data if rows is None else whole) if hasattr(chosen.effect, "neighbours") else None,
            )
        )
        current = fit
        built.keep_only([s.effect for s in steps])  # the candidates' columns are not needed again
    for step in steps:
        if step.retuned:
            _rescored(step)
        step.scored_data = None  # a record's worth of cross-products: not kept with the result
    _describe(steps, current)
    _hold_out_final(steps, current, u, t, q, uc, float(ratio), period, folds, built)
    _start_as_estimated(steps, start, before)
    after = start.coasting(before, current.residual_deg)  # until a flank first catches the load, the start's own path
    screened = len(screen.segments) if screen.screened else None
    return Diagnosis(base, current, steps, noise, before, after, u, y, t, float(ratio), q, start, screened, folds.n_cycles)


def _physical(terms: Sequence[Any], coef: np.ndarray, u: np.ndarray, t: np.ndarray, tolerance_deg: float) -> bool:
    """True unless the joint coefficients ``coef`` (the terms' side by side) give a term with ``is_physical``
    (the dead band's creep) a figure no drive can have, beyond ``tolerance_deg`` (the noise floor); ``u`` and
    ``t``: the record's referred motor angle (deg) and time (s)."""
    ends = np.cumsum([0, *(e.n_terms for e in terms)])
    checked = [(e, a, b) for e, a, b in zip(terms, ends[:-1], ends[1:]) if hasattr(e, "is_physical")]
    return all(e.is_physical(coef[a:b], u, t, tolerance_deg) for e, a, b in checked)


def _confirmed(chosen: Detection, data: DetectionData, built: TermColumns, bic_threshold: float, min_gain: float) -> Detection | None:
    """A term chosen on a screen of the record, detected again on ``data``, every sample of it (the
    round's residual, the terms it had): its configuration (the harmonic orders, the dead band's
    parts, ...) and its evidence as without the screen. A term with a setting walked in the refit
    (``neighbours``, the compliance's torque average) is scored with its setting from the screen
    (the caller walks it again on every sample). None when the whole record does not find it significant."""
    effect: Any = chosen.effect
    again = effect.detection(data) if hasattr(effect, "neighbours") else type(effect).detect(data)
    if again is None or not again.score.significant(bic_threshold, min_gain):
        return None
    return replace(_kept_columns(again, built), rivals=chosen.rivals)


def _kept_columns(found: Detection, built: TermColumns) -> Detection:
    """``found`` without its columns, which go to ``built`` for the fits (a detector that formed its
    effect's columns on every sample hands them on: :attr:`._scoring.Detection.columns`)."""
    if found.columns is None:
        return found
    built.put(found.effect, found.columns, found.nonzero_rows)
    return replace(found, columns=None, nonzero_rows=None)


def _rescored(step: Step) -> None:
    """A retuned term's detection scored again with its final setting, on what it was first scored
    on (the fit just before it came in and the terms it had then: :attr:`Step.scored_data`): the
    evidence then describes the setting the parameters report, not the one it came in with."""
    assert step.scored_data is not None  # kept for every term with a setting to move
    step.detection = replace(step.effect.detection(step.scored_data), rivals=step.detection.rivals)


def _start_as_estimated(steps: list[Step], start: InitialState, before: np.ndarray) -> None:
    """Each step's residual after it (and its RMS before and after, deg) with the record's start as
    estimated until a flank first catches the load (:meth:`.InitialState.coasting`), as the final
    residual is: the figures of the steps and of the whole agree. Unchanged when no start was estimated."""
    if not start.estimated:
        return
    rms_before = float(np.sqrt(np.mean(before**2)))
    for s in steps:
        s.residual_after_deg = start.coasting(before, s.residual_after_deg)
        s.rms_before_deg, s.rms_after_deg = rms_before, float(np.sqrt(np.mean(s.residual_after_deg**2)))
        rms_before = s.rms_after_deg


@dataclass(frozen=True)
class _ModelView:
    """What the detectors need of one backlash fit (eq. 1-6), centred frame, degrees: the play's
    sensitivity ``g`` and the other directions (:func:`.joint.play_sensitivity`), the model's output
    ``x``, and ``switched``: the output by the switching functions and the last engaged sample of every
    sample (:func:`.joint._switched`, what a joint fit started from these parameters plans with)."""

    g: np.ndarray
    others: np.ndarray
    switched: tuple[np.ndarray, np.ndarray]
    x: np.ndarray

    @classmethod
    def of(cls, uc: np.ndarray, params: Any) -> _ModelView:
        g, others, x = play_sensitivity(uc, params)
        return cls(g, others, _switched(uc, params), x)

    @property
    def index(self) -> np.ndarray:
        """For every sample, the last sample with a flank engaged (:func:`.joint.engaged_index`)."""
        return self.switched[1]


class _Fitted(Protocol):
    """A fit's residual RMS (deg): a :class:`.joint.JointFit`, or :class:`_Linearised`."""

    @property
    def rms_deg(self) -> float: ...


@dataclass(frozen=True)
class _Linearised:
    """The RMS (deg) of a joint refit linearised at fixed backlash parameters (:func:`_linearised_refit`)."""

    rms_deg: float


def _tuned(terms: list[Any], fit: _Fitted, refit_with: Callable[[list[Any]], _Fitted], which: Iterable[int]) -> tuple[list[Any], _Fitted]:
    """The settings of the terms at ``which`` fitted in the joint refit, as the delay's lag is.

    ``fit`` is the (joint or linearised) fit of ``terms`` as they are. A term with
    ``neighbours()`` (the compliance's torque average, :class:`.effects.Compliance`) is refitted
    by ``refit_with`` with each neighbouring setting, the other terms as they are, and moves to the
    one that leaves the smallest residual while that is smaller than where it stands. Returns the
    terms (a term that did not move is the same object) and their fit. A term with ``neighbours()``
    also has ``detection(data)``: its evidence is scored again with the setting it ends at
    (:func:`_rescored`).
    """
    for i in which:
        tried = {repr(terms[i])}
        while hasattr(terms[i], "neighbours"):
            options = [e for e in terms[i].neighbours() if repr(e) not in tried]
            tried.update(repr(e) for e in options)
            trials = [(refit_with([*terms[:i], e, *terms[i + 1 :]]), e) for e in options]
            best = min(trials, key=lambda pair: pair[0].rms_deg, default=None)
            if best is None or best[0].rms_deg >= fit.rms_deg:
                break
            fit, terms = best[0], [*terms[:i], best[1], *terms[i + 1 :]]
    return terms, fit


def _linearised_refit(terms: list[Any], i: int, fit: JointFit, uc: np.ndarray, folds: Folds, built: TermColumns) -> Callable[[list[Any]], _Linearised]:
    """The joint refit of ``terms`` with the ``i``-th term swapped, linearised at ``fit``: the backlash
    parameters fixed at ``fit.params`` with their sensitivities as free directions (one Gauss-Newton
    step of the quasi-linear fit, eq. 8), the other terms as they are fitted. The ``i``-th term's part
    is put back into the residual, and each setting's columns are fitted beyond the rest: a cheap way
    to walk a setting, which the caller confirms with one joint refit. Only the sum of squares left is
    needed, so it is the least squares through the projection off the backlash directions and the
    other terms (:class:`._normal_equations.Projector`, formed once; a term zero on most samples read on
    its support, :class:`.joint.Support`), over every sample, or a screen's scored rows
    (:attr:`._folds.Folds.row_index`). Returns ``terms -> _Linearised`` (RMS over those samples, deg)."""
    view = _ModelView.of(uc, fit.params)
    parts = _held_parts(terms, built, view)
    start = sum(e.n_terms for e in terms[:i])
    restored = fit.residual_deg + parts[i] @ fit.coef[start : start + terms[i].n_terms]
    others = [(e, part) for j, (e, part) in enumerate(zip(terms, parts)) if j != i]
    rows = folds.row_index if folds.screened else None
    nuisance: list[np.ndarray] = [view.others, view.g[:, None]]
    supports: list[Support | None] = [None, None]
    for e, part in others:
        nuisance.append(part)
        supports.append(_own_support(e, built) if rows is None else None)
    if rows is not None:
        projector = Projector(ColumnParts(tuple(nuisance)).at(rows))
        restored = restored[rows]
    else:
        projector = Projector(ColumnParts(tuple(nuisance), tuple(supports)))
    n = restored.size
    restored_cross, restored_square = projector.columns.t_dot(restored), float(restored @ restored)  # the same for every setting

    def refit(swapped: list[Any]) -> _Linearised:
        x = _held_parts([swapped[i]], built, view)[0]
        x = x if rows is None else x[rows]
        x_restored = x.T @ restored
        gram = np.block([[x.T @ x, x_restored[:, None]], [x_restored[None, :], np.array([[restored_square]])]])  # of [x, restored]
        rss = left_sum_of_squares(projector.left_of(gram, np.column_stack((projector.columns.t_dot(x), restored_cross))))
        return _Linearised(float(np.sqrt(rss / n)))

    return refit


def _detection_data(
    u: np.ndarray, t: np.ndarray, q: np.ndarray, uc: np.ndarray, current: JointFit, done: list[Any], ratio: float, period: float, folds: Folds,
    built: TermColumns, cache: RecordCache | None = None, view: _ModelView | None = None, done_columns: Sequence[np.ndarray] | None = None,
    noise: NoiseFloor | None = None,
) -> DetectionData:
    """What the detectors see given the current fit.

    The nuisance columns are the backlash's own directions (a constant, ``dx/dmL``,
    ``dx/dmR``, ``dx/d(play)``) and the terms already added (they may move too). ``view`` is
    :class:`_ModelView` of ``current.params`` and ``done_columns`` the held columns of ``done`` (in parts, side by side),
    when already at hand (the same numbers; formed here otherwise). ``noise``: the record's noise floor, for
    the detectors' physical bounds (none: 0).
    """
    view = _ModelView.of(uc, current.params) if view is None else view
    parts = [view.others, view.g]
    if done:
        parts.extend(_held_parts(done, built, view) if done_columns is None else done_columns)
    return DetectionData.stacked(
        parts, current.residual_deg, u_deg=u, time_s=t, torque_Nm=q, ratio=ratio, sample_period_s=period, engaged_index=view.index,
        n_backlash=view.others.shape[1] + 1, folds=folds, model_output_deg=view.x, backlash_params=current.params, cache=cache,
        noise_floor_deg=0.0 if noise is None else noise.floor_deg,
    )


def _hold_out_final(
    steps: list[Step], final: JointFit, u: np.ndarray, t: np.ndarray, q: np.ndarray, uc: np.ndarray, ratio: float, period: float, folds: Folds,
    built: TermColumns,
) -> None:
    """Each term's held-out gain given all the others in the final model (blocked over cycles).

    The term's part is put back into the final residual, and its columns are scored with the
    backlash directions and the other terms as nuisance: every term from one set of cross-products
    of the backlash directions, all the terms and the final residual
    (:meth:`._scoring.DetectionData.scores_left_out`), the final model's view and the terms' held
    columns formed once; a term zero on most samples (:func:`_own_support`, the dead band's motion)
    is read on the rows where it is not, after the others.
    """
    if not steps:
        return
    view = _ModelView.of(uc, final.params)
    terms = [s.effect for s in steps]
    parts = _held_parts(terms, built, view)
    supports = [_own_support(e, built) for e in terms]
    dense = [part for part, support in zip(parts, supports) if support is None]
    data = _detection_data(u, t, q, uc, final, terms, ratio, period, folds, built, view=view, done_columns=dense)
    assert data.nuisance is not None
    sparse = [(part, support) for part, support in zip(parts, supports) if support is not None]
    rows = extra = None
    if sparse:
        rows = reduce(np.union1d, [support.rows for _, support in sparse])
        extra = np.column_stack([np.take(part, rows, axis=0) for part, _ in sparse])
    at = {"dense": data.n_backlash, "sparse": data.nuisance.shape[1]}  # where each kind's next columns go
    groups = []
    for e, support in zip(terms, supports):
        kind = "dense" if support is None else "sparse"
        groups.append(np.arange(at[kind], at[kind] + e.n_terms))
        at[kind] += e.n_terms
    ends = np.cumsum([0, *(e.n_terms for e in terms)])
    scores = data.scores_left_out(groups, [final.coef[a:b] for a, b in pairwise(ends)], extra, rows)
    for s, score in zip(steps, scores):
        s.heldout_gain_final = score.heldout_gain


def _describe(steps: list[Step], final: JointFit) -> None:
    """Each step's parameters from the final joint coefficients."""
    start = 0
    for s in steps:
        n = s.effect.n_terms
        s.parameters = s.effect.describe(final.coef[start : start + n])
        start += n


def diagnose_arrays(
    time_s: np.ndarray, motor_deg: np.ndarray, load_deg: np.ndarray, ratio: float, torque_Nm: np.ndarray | None = None, **options: Any
) -> Diagnosis:
    """:func:`diagnose` on plain arrays (torque optional)."""
    n = len(time_s)
    torque = np.full(n, np.nan) if torque_Nm is None else np.asarray(torque_Nm, dtype=float)
    chunk = SampleChunk(np.asarray(time_s, float), np.asarray(motor_deg, float), np.asarray(load_deg, float), torque, np.zeros(n, bool))
    return diagnose(chunk, ratio, **options)
