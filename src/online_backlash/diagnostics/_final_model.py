"""The terms' figures in the final model, once :func:`.loop.diagnose` has added them all.

Each :class:`.diagnosis.AddedTerm` gets its parameters from the final joint fit, its held-out gain given
all the other terms in the final model, the evidence of the setting it ends at (a term a later one
retuned), and residuals with the record's start as estimated. Angles in degrees on the load side.
"""

from __future__ import annotations

from dataclasses import replace
from functools import reduce
from itertools import pairwise

import numpy as np

from ._fit_view import FitView, detection_data, held_columns_per_term, own_support
from ._initial_state import InitialState
from ._loop_record import LoopRecord
from .diagnosis import AddedTerm
from .joint import JointFit


def finish_terms(steps: list[AddedTerm], final: JointFit, record: LoopRecord) -> None:
    """Every term's evidence of its final setting, its parameters and held-out gain in the final model
    ``final``, and its residuals with the record's start as estimated."""
    for step in steps:
        if step.retuned:
            rescore_retuned(step)
        step.scored_data = None  # a record's worth of cross-products: not kept with the result
    set_parameters(steps, final)
    hold_out_each(steps, final, record)
    apply_estimated_start(steps, record.start, record.residual_before_deg)


def rescore_retuned(step: AddedTerm) -> None:
    """A retuned term's detection scored again with its final setting, on what it was first scored
    on (the fit just before it came in and the terms it had then: :attr:`.diagnosis.AddedTerm.scored_data`):
    the evidence then describes the setting the parameters report, not the one it came in with."""
    assert step.scored_data is not None  # kept for every term with a setting to move
    step.detection = replace(step.effect.detection(step.scored_data), rivals=step.detection.rivals)


def set_parameters(steps: list[AddedTerm], final: JointFit) -> None:
    """Each step's parameters from the final joint coefficients."""
    start = 0
    for s in steps:
        n = s.effect.n_terms
        s.parameters = s.effect.describe(final.coef[start : start + n])
        start += n


def hold_out_each(steps: list[AddedTerm], final: JointFit, record: LoopRecord) -> None:
    """Each term's held-out gain given all the others in the final model (blocked over cycles).

    The term's part is put back into the final residual, and its columns are scored with the
    backlash directions and the other terms as nuisance: every term from one set of cross-products
    of the backlash directions, all the terms and the final residual
    (:meth:`._scoring.DetectionData.scores_left_out`), the final model's view and the terms' held
    columns formed once; a term zero on most samples (:func:`._fit_view.own_support`, the dead band's
    motion) is read on the rows where it is not, after the others.
    """
    if not steps:
        return
    r = record
    view = FitView.of(r.uc, final.params)
    terms = [s.effect for s in steps]
    columns = held_columns_per_term(terms, r.built, view)
    supports = [own_support(e, r.built) for e in terms]
    dense = [part for part, support in zip(columns, supports) if support is None]
    data = detection_data(
        r.u_deg,
        r.time_s,
        r.torque_Nm,
        r.uc,
        final,
        terms,
        r.ratio,
        r.period_s,
        r.folds,
        r.built,
        view=view,
        done_columns=dense,
    )
    assert data.nuisance is not None
    sparse = [(part, support) for part, support in zip(columns, supports) if support is not None]
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


def apply_estimated_start(steps: list[AddedTerm], start: InitialState, before: np.ndarray) -> None:
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
