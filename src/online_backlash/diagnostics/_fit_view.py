"""What the detectors and the joint refits of :func:`.loop.diagnose` see of one backlash fit.

:class:`FitView` holds the fit's directions and output (eq. 1-6); the functions below give the
terms' columns as that fit sees them (a term built on the model's output on it, the input-side ones
held through its dead band) and :func:`detection_data`, what the detectors score a round's residual
with. Centred frame, angles in degrees on the load side.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._folds import Folds
from ._record_cache import RecordCache
from ._scoring import DetectionData
from ._term_columns import TermColumns
from .joint import ColumnParts, JointFit, Support, _switched, hold_columns, play_sensitivity
from .residuals import NoiseFloor


@dataclass(frozen=True)
class FitView:
    """What the detectors need of one backlash fit (eq. 1-6), centred frame, degrees: the play's
    sensitivity and the other directions (:func:`.joint.play_sensitivity`), the model's output, and
    ``switched``: the output by the switching functions and the last engaged sample of every sample
    (:func:`.joint._switched`, what a joint fit started from these parameters plans with)."""

    #: ``dx/d(play)`` of the model's output, per sample
    play_direction: np.ndarray
    #: the backlash's other directions (a constant, ``dx/dmL``, ``dx/dmR``), one column each
    other_directions: np.ndarray
    switched: tuple[np.ndarray, np.ndarray]
    #: the model's output (free run from rest), deg
    output_deg: np.ndarray

    @classmethod
    def of(cls, uc: np.ndarray, params: Any) -> FitView:
        play_direction, other_directions, output_deg = play_sensitivity(uc, params)
        return cls(play_direction, other_directions, _switched(uc, params), output_deg)

    @property
    def engaged_index(self) -> np.ndarray:
        """For every sample, the last sample with a flank engaged (:func:`.joint.engaged_index`)."""
        return self.switched[1]


def columns_per_term(terms: Sequence[Any], built: TermColumns, output_deg: np.ndarray) -> tuple[np.ndarray, ...]:
    """The terms' columns, an ``(n, n_terms)`` array per term: an effect defined on the model's output
    (``output_columns``, the delay) is built on ``output_deg``, the current backlash output; the others come
    from ``built`` (once per record)."""
    n = built.u_deg.size
    return tuple(
        np.reshape(e.output_columns(output_deg) if hasattr(e, "output_columns") else built.get(e), (n, e.n_terms))
        for e in terms
    )


def joint_columns(terms: Sequence[Any], built: TermColumns, output_deg: np.ndarray) -> ColumnParts:
    """The terms' columns, as parts (:class:`.joint.ColumnParts`, :func:`columns_per_term`), with their support
    when they are zero on most samples (:class:`.joint.Support`, the dead band's motion), for the joint fits."""
    columns = columns_per_term(terms, built, output_deg)
    return ColumnParts(columns, tuple(None if hasattr(e, "output_columns") else built.support(e) for e in terms))


def stacked_columns(terms: Sequence[Any], built: TermColumns, output_deg: np.ndarray) -> np.ndarray:
    """The terms' columns (:func:`columns_per_term` side by side; a term's own read-only columns when it is
    the only one)."""
    return ColumnParts(columns_per_term(terms, built, output_deg)).block()


def held_mask(terms: Sequence[Any]) -> np.ndarray:
    """Which columns are held through the dead band (input-side effects not built on the model's output)."""
    if not terms:
        return np.zeros(0, bool)
    return np.concatenate([np.full(e.n_terms, bool(e.input_side) and not hasattr(e, "output_columns")) for e in terms])


def own_support(effect: Any, built: TermColumns) -> Support | None:
    """The :class:`.joint.Support` of a term whose columns are read as they are built (neither held
    through the dead band nor built on the model's output; what :func:`held_columns_per_term` hands out
    for it is its own columns), when they are zero on most samples."""
    plain = not (hasattr(effect, "output_columns") or held_mask([effect]).any())
    return built.support(effect) if plain else None


def held_columns_per_term(terms: Sequence[Any], built: TermColumns, view: FitView) -> list[np.ndarray]:
    """Each term's columns as the model of ``view`` sees them (:func:`columns_per_term`, the input-side ones
    held through its dead band, :func:`.joint.hold_columns`): one array per term, a term's own read-only
    columns where that does not apply (no block of all of them is formed)."""
    parts = columns_per_term(terms, built, view.output_deg)
    return [hold_columns(part, held_mask([term]), view.engaged_index) for part, term in zip(parts, terms)]


def scored_columns(data: DetectionData, effect: Any, built: TermColumns) -> np.ndarray:
    """An effect's columns as the scoring sees them: the input-side ones held through the dead band."""
    assert data.model_output_deg is not None
    x = stacked_columns([effect], built, data.model_output_deg)
    return data.hold(x) if held_mask([effect]).any() else x


def detection_data(
    u: np.ndarray,
    t: np.ndarray,
    q: np.ndarray,
    uc: np.ndarray,
    current: JointFit,
    done: list[Any],
    ratio: float,
    period: float,
    folds: Folds,
    built: TermColumns,
    cache: RecordCache | None = None,
    view: FitView | None = None,
    done_columns: Sequence[np.ndarray] | None = None,
    noise: NoiseFloor | None = None,
) -> DetectionData:
    """What the detectors see given the current fit.

    The nuisance columns are the backlash's own directions (a constant, ``dx/dmL``,
    ``dx/dmR``, ``dx/d(play)``) and the terms already added (they may move too). ``view`` is
    :class:`FitView` of ``current.params`` and ``done_columns`` the held columns of ``done`` (in parts, side by
    side), when already at hand (the same numbers; formed here otherwise). ``noise``: the record's noise floor,
    for the detectors' physical bounds (none: 0).
    """
    view = FitView.of(uc, current.params) if view is None else view
    parts = [view.other_directions, view.play_direction]
    if done:
        parts.extend(held_columns_per_term(done, built, view) if done_columns is None else done_columns)
    return DetectionData.stacked(
        parts,
        current.residual_deg,
        u_deg=u,
        time_s=t,
        torque_Nm=q,
        ratio=ratio,
        sample_period_s=period,
        engaged_index=view.engaged_index,
        n_backlash=view.other_directions.shape[1] + 1,
        folds=folds,
        model_output_deg=view.output_deg,
        backlash_params=current.params,
        cache=cache,
        noise_floor_deg=0.0 if noise is None else noise.floor_deg,
        term_columns=built,
    )
