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
   when a later term comes in (:func:`._refits.walk_settings`), as the delay's lag is refitted.
4. Repeat until nothing is significant or the residual is within ``floor_ratio`` of the noise
   floor. Then every term is held out once more, given all the others in the final model.

A long record (at least three times ``screen_cycles`` reversal cycles, and three times
:data:`._folds.SCREEN_MIN_SAMPLES` samples) is screened: steps 2 and 3 score and refit the candidates
on about ``screen_cycles`` of its cycles spread evenly over it (more where its cycles are short;
:meth:`._folds.Folds.screen`; the scores on every :data:`._folds.SCREEN_STRIDE`-th sample of them, the
refits on every sample); the effect they choose is then detected again on every sample
(its configuration and evidence as without the screen, :meth:`._search_round.SearchRound.settled`; refused if the whole
record does not bear it out), the terms are fitted jointly on every sample (the step's figures
and the next round's residual), and the settings of the terms (the compliance's torque average, the
new term's and those of the terms already in) are walked there, as without the screen. The screen
decides which effect comes next, the whole record how it is configured, set, fitted and evidenced.

Angles in degrees on the load side, time in seconds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from ..estimators import VorosBacklash
from ..estimators.validation import check_int, check_real
from ..stream import SampleChunk
from ._causal import sample_period_s
from ._final_model import finish_terms
from ._folds import SCREEN_CYCLES, cycle_folds
from ._initial_state import estimate_initial_state
from ._loop_record import LoopRecord
from ._record_cache import RecordCache
from ._scoring import BIC_THRESHOLD, MIN_GAIN
from ._search_round import SearchRound, SelectionRules
from ._term_columns import TermColumns
from .diagnosis import AddedTerm, Diagnosis
from .joint import JointFit
from .residuals import noise_floor, simulation_residual

__all__ = ["ONE_BLAS_THREAD", "AddedTerm", "Diagnosis", "diagnose", "diagnose_arrays"]


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
    record = _loop_record(chunk, ratio, screen_cycles)
    rules = SelectionRules(bic_threshold, min_gain, label_ratio)
    current = JointFit(record.base.params_, np.empty(0), record.residual_before_deg, 1.0, float("nan"), False)
    steps: list[AddedTerm] = []
    refused: set[type] = set()
    while len(steps) < max_terms and current.rms_deg > floor_ratio * record.noise.floor_deg:
        search = SearchRound.detect(record, current, steps, refused, rules)
        if not search.found_any:
            break
        added = search.next_term(len(steps) + 1)
        if added is None:  # refused (and added to ``refused``): try the others
            continue
        terms, current, step = added
        for earlier, effect in zip(steps, terms):
            earlier.retuned = earlier.retuned or effect is not earlier.effect
            earlier.effect = effect
        steps.append(step)
        record.built.keep_only([s.effect for s in steps])  # the candidates' columns are not needed again
    finish_terms(steps, current, record)
    return _diagnosis(record, current, steps)


def _diagnosis(r: LoopRecord, current: JointFit, steps: list[AddedTerm]) -> Diagnosis:
    """The loop's answer on the record ``r``: its final fit ``current`` and the terms added, ``steps``."""
    after = r.start.coasting(r.residual_before_deg, current.residual_deg)  # until a flank first catches the load
    screened = len(r.screen.segments) if r.screen.screened else None
    return Diagnosis(
        r.base,
        current,
        steps,
        r.noise,
        r.residual_before_deg,
        after,
        r.u_deg,
        r.load_deg,
        r.time_s,
        r.ratio,
        r.torque_Nm,
        r.start,
        screened,
        r.folds.n_cycles,
    )


def _loop_record(chunk: SampleChunk, ratio: float, screen_cycles: int) -> LoopRecord:
    """The record referred to the load side (``ratio``), fitted by the base model (the "before"), its start
    estimated and its folds and screen (``screen_cycles``) formed."""
    u, y = (np.asarray(v, dtype=float) for v in chunk.referred(ratio))
    t = np.asarray(chunk.time_s, dtype=float)
    q = np.asarray(chunk.torque_Nm, dtype=float)
    base = VorosBacklash(refine=True, origin="first").fit(u, y)  # encoder zeros are arbitrary
    uc, yc = u - base.u_ref_, y - base.y_ref_
    # the load's state in the dead band at the start: the model's initial condition, not an effect
    start = estimate_initial_state(base.params_, uc, yc, t)
    before = simulation_residual(base.params_, uc, yc, start.path_deg)
    yc = yc - start.correction_deg(base.params_, uc)  # every fit runs the model from rest: the start taken out
    noise = noise_floor(y)
    period = round(sample_period_s(t), 12)  # 0.001, not 0.000999999...
    folds = cycle_folds(u)
    screen = folds.screen(screen_cycles) if screen_cycles else folds  # a long record's candidates are tried on these
    cache, columns = RecordCache(), TermColumns(u, t, q)  # the record's columns, and the terms', built once
    return LoopRecord(
        u, y, t, q, float(ratio), base, uc, yc, start, before, noise, period, folds, screen, cache, columns
    )


def diagnose_arrays(
    time_s: np.ndarray,
    motor_deg: np.ndarray,
    load_deg: np.ndarray,
    ratio: float,
    torque_Nm: np.ndarray | None = None,
    **options: Any,
) -> Diagnosis:
    """:func:`diagnose` on plain arrays (torque optional)."""
    n = len(time_s)
    torque = np.full(n, np.nan) if torque_Nm is None else np.asarray(torque_Nm, dtype=float)
    time, motor, load = (np.asarray(v, float) for v in (time_s, motor_deg, load_deg))
    chunk = SampleChunk(time, motor, load, torque, np.zeros(n, bool))
    return diagnose(chunk, ratio, **options)
