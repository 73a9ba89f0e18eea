"""The joint refits of one round of :func:`.loop.diagnose`, and the walk of the terms' settings in them.

A candidate is refitted jointly with the backlash and the terms already in by output error
(:func:`.joint.fit_guarded`). A term with a setting of its own (``neighbours()``: the compliance's torque
average) has it fitted there, as the delay's lag is: walked on the refit linearised at the current fit
(:func:`linearised_refit`, cheap), then confirmed by one joint refit (:meth:`RoundRefits.walked`).
Angles in degrees on the load side.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from ..model import simulate_backlash
from ._fit_view import FitView, held_columns_per_term, held_mask, joint_columns, own_support
from ._folds import Folds
from ._loop_record import LoopRecord
from ._normal_equations import Projector, left_sum_of_squares
from ._scoring import Detection, DetectionData
from ._term_columns import TermColumns
from .joint import ColumnParts, JointFit, Support, fit_guarded


class FitWithRms(Protocol):
    """A fit's residual RMS (deg): a :class:`.joint.JointFit`, or :class:`LinearisedFit`."""

    @property
    def rms_deg(self) -> float: ...


@dataclass(frozen=True)
class LinearisedFit:
    """The RMS (deg) of a joint refit linearised at fixed backlash parameters (:func:`linearised_refit`)."""

    rms_deg: float


def walk_settings(
    terms: list[Any], fit: FitWithRms, refit_with: Callable[[list[Any]], FitWithRms], which: Iterable[int]
) -> tuple[list[Any], FitWithRms]:
    """The settings of the terms at ``which`` fitted in the joint refit, as the delay's lag is.

    ``fit`` is the (joint or linearised) fit of ``terms`` as they are. A term with
    ``neighbours()`` (the compliance's torque average, :class:`.effects.Compliance`) is refitted
    by ``refit_with`` with each neighbouring setting, the other terms as they are, and moves to the
    one that leaves the smallest residual while that is smaller than where it stands. Returns the
    terms (a term that did not move is the same object) and their fit. A term with ``neighbours()``
    also has ``detection(data)``: its evidence is scored again with the setting it ends at
    (:func:`._final_model.rescore_retuned`).
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


def linearised_refit(
    terms: list[Any], i: int, fit: JointFit, uc: np.ndarray, folds: Folds, built: TermColumns
) -> Callable[[list[Any]], LinearisedFit]:
    """The joint refit of ``terms`` with the ``i``-th term swapped, linearised at ``fit``: the backlash
    parameters fixed at ``fit.params`` with their sensitivities as free directions (one Gauss-Newton
    step of the quasi-linear fit, eq. 8), the other terms as they are fitted. The ``i``-th term's part
    is put back into the residual, and each setting's columns are fitted beyond the rest: a cheap way
    to walk a setting, which the caller confirms with one joint refit. Only the sum of squares left is
    needed, so it is the least squares through the projection off the backlash directions and the
    other terms (:class:`._normal_equations.Projector`, formed once; a term zero on most samples read on
    its support, :class:`.joint.Support`), over every sample, or a screen's scored rows
    (:attr:`._folds.Folds.row_index`). Returns ``terms -> LinearisedFit`` (RMS over those samples, deg)."""
    view = FitView.of(uc, fit.params)
    columns = held_columns_per_term(terms, built, view)
    start = sum(e.n_terms for e in terms[:i])
    restored = fit.residual_deg + columns[i] @ fit.coef[start : start + terms[i].n_terms]
    others = [(e, part) for j, (e, part) in enumerate(zip(terms, columns)) if j != i]
    rows = folds.row_index if folds.screened else None
    nuisance: list[np.ndarray] = [view.other_directions, view.play_direction[:, None]]
    supports: list[Support | None] = [None, None]
    for e, part in others:
        nuisance.append(part)
        supports.append(own_support(e, built) if rows is None else None)
    if rows is not None:
        projector = Projector(ColumnParts(tuple(nuisance)).at(rows))
        restored = restored[rows]
    else:
        projector = Projector(ColumnParts(tuple(nuisance), tuple(supports)))
    n = restored.size
    # the same for every setting
    restored_cross, restored_square = projector.columns.t_dot(restored), float(restored @ restored)

    def refit(swapped: list[Any]) -> LinearisedFit:
        x = held_columns_per_term([swapped[i]], built, view)[0]
        x = x if rows is None else x[rows]
        x_restored = x.T @ restored
        # the Gram matrix of [x, restored]
        gram = np.block([[x.T @ x, x_restored[:, None]], [x_restored[None, :], np.array([[restored_square]])]])
        cross = np.column_stack((projector.columns.t_dot(x), restored_cross))
        rss = left_sum_of_squares(projector.left_of(gram, cross))
        return LinearisedFit(float(np.sqrt(rss / n)))

    return refit


@dataclass(frozen=True)
class RoundRefits:
    """The joint refits of one round: from the round's fit ``current``, whose directions are ``view``, with
    the terms ``done`` already in; over the screen's cycles (``record.screen_rows``) unless ``every_sample``."""

    record: LoopRecord
    current: JointFit
    view: FitView
    #: the terms already in, in the order added
    done: list[Any]
    #: what the round's detectors scored (on the screen's cycles)
    data: DetectionData

    def refit(self, terms: list[Any], *, every_sample: bool = False, start: JointFit | None = None) -> JointFit:
        """The joint refit of ``terms``, from the round's fit, or from ``start`` (a fit of nearly these terms:
        the search then needs fewer steps, and ends at the same least squares to its tolerance: within 2e-9
        of every figure on the bench logs)."""
        r = self.record
        rows = None if every_sample else r.screen_rows
        columns = joint_columns(terms, r.built, self.view.output_deg)
        if start is None:
            fit = fit_guarded(r.uc, r.yc, columns, self.current.params, held_mask(terms), rows, self.view.switched)
        else:
            fit = fit_guarded(r.uc, r.yc, columns, start.params, held_mask(terms), rows)
        if any(hasattr(e, "output_columns") for e in terms):  # built on the model's output: again on the refitted one
            x = simulate_backlash(r.uc, fit.params, 0.0)
            fit = fit_guarded(r.uc, r.yc, joint_columns(terms, r.built, x), fit.params, held_mask(terms), rows)
        return fit

    def walked(
        self, terms: list[Any], fit: JointFit, which: Iterable[int], *, every_sample: bool = False
    ) -> tuple[list[Any], JointFit]:
        """The settings of the terms at ``which`` walked on the joint refit linearised at ``fit``
        (:func:`linearised_refit`), then confirmed by one joint refit: kept only if it is better.
        ``fit`` is over the screen's cycles (or every sample), and so are the walk and the refit."""
        r = self.record
        for i in which:
            if not hasattr(terms[i], "neighbours"):
                continue
            folds = r.folds if every_sample or not r.screen.screened else r.screen
            walk = linearised_refit(terms, i, fit, r.uc, folds, r.built)
            moved, _ = walk_settings(terms, walk(terms), walk, [i])
            if moved[i] is not terms[i]:
                trial = self.refit(moved, every_sample=every_sample, start=fit)
                if trial.rms_deg < fit.rms_deg:
                    terms, fit = moved, trial
        return terms, fit

    def candidate(self, found: Detection) -> tuple[Detection, JointFit]:
        """The joint refit of the terms already in and the candidate ``found``, its own setting walked; its
        detection scored again on the round's data if the setting moved."""
        terms = [*self.done, found.effect]
        terms, fit = self.walked(terms, self.refit(terms), [len(self.done)])
        if terms[-1] is found.effect:
            return found, fit
        return replace(terms[-1].detection(self.data), rivals=found.rivals), fit
