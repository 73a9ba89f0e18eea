"""Data-sheet figures of a loaded gear from its torsion-angle/torque curve.

Gear makers (Harmonic Drive, Nabtesco, Wittenstein) characterise a gearbox by its *hysteresis
curve*: the torsion angle (output against input, arc minutes) plotted against the output torque
(N m) while the torque is swept to +rated, back through zero to -rated and back. From it:

* **torsional stiffness** (N m/arcmin): the slope of the curve on each flank, ``1 / s`` of the
  flank lines (:mod:`.flank_lines`), per direction and their mean;
* **lost motion** (arcmin): the curve's width, in angle, between ``+T`` and ``-T`` where
  ``T = 3 %`` of the rated torque (the data-sheet definition), i.e. the play plus the wind-up of
  both flanks up to ``T``: ``(a_R + s_R T) - (a_L - s_L T)``. Without a rated torque, ``T`` is the
  smallest torque both directions reach (the smaller of the two peak torques), so the figure is
  read inside the measured curve, never extrapolated;
* **hysteresis loss** (arcmin): the curve's width at zero torque when the torque is returned from
  its peak, i.e. the distance between the two *unloading* branches extrapolated to zero torque
  (friction inside a flank widens it beyond the play).

The torsion angle is ``m u - y`` on the load side (the input scaled by the flank's fitted slope,
so an imperfectly known ratio does not tilt the curve), centred between the two flanks.

Units: degrees inside, arc minutes and N m at the API.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..output_columns import ARCMIN_PER_DEG
from .flank_fit import TorqueBacklash
from .flank_lines import FlankLine
from .segments import check_knots, hinge_columns

__all__ = [
    "LOST_MOTION_FRACTION", "DatasheetFigures", "HysteresisCurve", "datasheet_figures", "hysteresis_curve",
    "line_figures", "lost_motion_deg", "torsion_curve", "unloading_mask",
]  # fmt: skip

#: Lost motion is the curve's width at +-3 % of the rated torque (data-sheet definition).
LOST_MOTION_FRACTION = 0.03


@dataclass(frozen=True)
class DatasheetFigures:
    """The data-sheet figures of one fitted log (None where the data do not show them).

    ``lost_motion_basis`` says at which torque the lost motion was taken: ``"rated torque"``
    (``+-3 %`` of ``--rated-torque``) or ``"dead band"`` (the smallest torque both directions reach).
    """

    stiffness_nm_per_arcmin: float | None
    stiffness_left_nm_per_arcmin: float | None
    stiffness_right_nm_per_arcmin: float | None
    lost_motion_arcmin: float | None
    lost_motion_torque_Nm: float | None
    lost_motion_basis: str
    hysteresis_loss_arcmin: float | None
    torque_deadband_Nm: float
    torque_peak_left_Nm: float | None
    torque_peak_right_Nm: float | None

    def as_dict(self) -> dict[str, Any]:
        """The figures as the keys of ``estimate --json``."""
        return dict(vars(self))


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def lost_motion_deg(
    left: FlankLine, right: FlankLine, at_Nm: float, engagement_Nm: tuple[float, float] = (0.0, 0.0)
) -> float:
    """The hysteresis curve's width between ``+at_Nm`` and ``-at_Nm`` carried by the flanks (deg):
    ``(a_R + s_R (T_R + T)) - (a_L + s_L (T_L - T))``, ``(T_L, T_R) = engagement_Nm`` the measured torques
    at which the flanks engage (0 where the sensor reads zero with no flank touching)."""
    t_left, t_right = engagement_Nm
    return (right.a + right.s * (t_right + at_Nm)) - (left.a + left.s * (t_left - at_Nm))


def _lost_motion_torque(rated_torque_Nm: float | None, reached_Nm: float) -> tuple[float, str]:
    """The torque at which lost motion is taken and its basis (module docstring)."""
    if rated_torque_Nm is None:
        return reached_Nm, "smallest peak torque of the two directions"
    if not (math.isfinite(rated_torque_Nm) and rated_torque_Nm > 0):
        raise InvalidParameterError(f"the rated torque must be a finite number > 0 N m, got {rated_torque_Nm!r}")
    return LOST_MOTION_FRACTION * rated_torque_Nm, "rated torque"


def line_figures(
    left: FlankLine | None,
    right: FlankLine | None,
    observable: bool,
    deadband_Nm: float,
    peaks_Nm: tuple[float | None, float | None],
    rated_torque_Nm: float | None = None,
    operating_torque_Nm: float | None = None,
    compliance_var: tuple[float, float] = (1.0, 1.0),
    engagement_Nm: tuple[float, float] = (0.0, 0.0),
) -> DatasheetFigures:
    """The figures of the flank lines: stiffness and lost motion (the hysteresis loss needs the
    whole curve, :func:`datasheet_figures`, and is None here).

    ``peaks_Nm``: the largest torque magnitude each flank (left, right) reached, or None.
    ``operating_torque_Nm``: the wind-up is not separable (the lines stand at their operating
    torques, ``s = 0``): the lost motion is the width there (basis ``"operating torque"``).
    ``compliance_var``: the (relative) variances of the left and right compliances; the combined
    stiffness is the inverse of their inverse-variance weighted mean compliance, so a flank that
    carried torque only briefly counts for little. ``engagement_Nm``: the measured torques at which
    the (left, right) flank engage; torques at the API are the flanks' own (the measured one less it).
    """
    reached = [p for p in peaks_Nm if p is not None]
    at, basis = _lost_motion_torque(rated_torque_Nm, min(reached) if len(reached) == 2 else deadband_Nm)
    if operating_torque_Nm is not None:
        at, basis = operating_torque_Nm, "operating torque (wind-up not separable)"
    k_left = _finite_or_none(left.stiffness_nm_per_arcmin) if left is not None else None
    k_right = _finite_or_none(right.stiffness_nm_per_arcmin) if right is not None else None
    lines_k = zip((left, right), (k_left, k_right), compliance_var)
    pairs = [(line.s, var) for line, k, var in lines_k if line is not None and k is not None]
    weights = [1.0 / var if var > 0 and math.isfinite(var) else 0.0 for _, var in pairs]
    mean_s = sum(w * s for w, (s, _) in zip(weights, pairs)) / sum(weights) if pairs and sum(weights) > 0 else math.nan
    both = observable and left is not None and right is not None
    lost = lost_motion_deg(left, right, at, engagement_Nm) * ARCMIN_PER_DEG if both else None  # type: ignore[arg-type]
    return DatasheetFigures(
        stiffness_nm_per_arcmin=_finite_or_none(FlankLine(1.0, 0.0, mean_s).stiffness_nm_per_arcmin)
        if math.isfinite(mean_s)
        else None,
        stiffness_left_nm_per_arcmin=k_left,
        stiffness_right_nm_per_arcmin=k_right,
        lost_motion_arcmin=lost,
        lost_motion_torque_Nm=float(at) if lost is not None else None,
        lost_motion_basis=basis,
        hysteresis_loss_arcmin=None,
        torque_deadband_Nm=float(deadband_Nm),
        torque_peak_left_Nm=peaks_Nm[0],
        torque_peak_right_Nm=peaks_Nm[1],
    )


def torsion_curve(est: TorqueBacklash, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Torsion angle ``m u - y`` (arc minutes, load side) of every sample, centred between the
    flanks' zero-torque offsets (:mod:`.datasheet`); ``u``, ``y`` in degrees as given to ``fit``."""
    lines = [ln for ln in (est.left_, est.right_) if ln is not None]
    if not lines:
        raise InvalidParameterError("no flank carried torque: there is no hysteresis curve")
    uc, yc = np.asarray(u, dtype=float) - est.u_ref_, np.asarray(y, dtype=float) - est.y_ref_
    m = np.full(uc.size, float(np.mean([ln.m for ln in lines])))
    if est.left_ is not None:
        m[est.flank_ == -1] = est.left_.m
    if est.right_ is not None:
        m[est.flank_ == 1] = est.right_.m
    centre = float(np.mean([ln.a for ln in lines]))
    return (m * uc - yc - centre) * ARCMIN_PER_DEG


def unloading_mask(flank: np.ndarray, torque_Nm: np.ndarray) -> np.ndarray:
    """True on the samples of each engagement (a run of one flank) after its torque peak: the
    branch of the curve on which the torque returns towards zero."""
    f = np.asarray(flank)
    q = np.abs(np.asarray(torque_Nm, dtype=float))
    out = np.zeros(f.size, dtype=bool)
    edges = np.flatnonzero(np.diff(f.astype(np.int16))) + 1
    for lo, hi in zip(np.concatenate(([0], edges)), np.concatenate((edges, [f.size]))):
        if f[lo] != 0 and hi > lo:
            peak = lo + int(np.argmax(q[lo:hi]))
            out[peak:hi] = True
    return out


def _unloading_offset(line: FlankLine, u: np.ndarray, y: np.ndarray, windup_deg: np.ndarray) -> float:
    """The flank's offset where it carries no torque, fitted to its unloading samples alone (slope and
    wind-up held): the mean of ``m u - y - windup``."""
    return float(np.mean(line.m * u - y - windup_deg))


def _windup_deg(est: TorqueBacklash, side: int, carried_Nm: np.ndarray) -> np.ndarray:
    """The wind-up of a flank (``side`` -1 left, +1 right) carrying ``carried_Nm >= 0``, signed as in its
    line: its three segments where they were fitted (:mod:`.segments`), else its line's compliance."""
    seg = est.segments_[0 if side < 0 else 1]
    line = est.left_ if side < 0 else est.right_
    if seg is None or est.stiffness_torques_Nm is None:
        return side * line.s * carried_Nm  # type: ignore[union-attr]
    h = hinge_columns(carried_Nm, check_knots(est.stiffness_torques_Nm))
    return side * sum((c or 0.0) * h[k] for k, c in enumerate(seg.compliance))


def datasheet_figures(
    est: TorqueBacklash, u: np.ndarray, y: np.ndarray, torque_Nm: np.ndarray, rated_torque_Nm: float | None = None
) -> DatasheetFigures:
    """Stiffness, lost motion and hysteresis loss (module docstring) of a fitted :class:`TorqueBacklash`
    on the data it was fitted to (``u``, ``y`` degrees, torque N m)."""
    q = est.torque_sign_ * np.asarray(torque_Nm, dtype=float)
    t_left, t_right = est.engagement_torques_Nm_
    carried = q - np.where(est.flank_ == 1, t_right, np.where(est.flank_ == -1, t_left, 0.0))  # the flanks' own torque
    left, right = est.left_, est.right_
    peaks = (
        float(-carried[est.flank_ == -1].min()) if left is not None else None,
        float(carried[est.flank_ == 1].max()) if right is not None else None,
    )
    var_left, var_right = (math.inf if f is None else float(f.cov[2, 2]) for f in (est.fits_[-1], est.fits_[1]))
    base = line_figures(
        left,
        right,
        est.play_observable_,
        est.deadband_Nm_,
        peaks,
        rated_torque_Nm,
        est.operating_torque_Nm_,
        (var_left, var_right),
        est.engagement_torques_Nm_,
    )
    lines = left is not None and right is not None
    if base.lost_motion_arcmin is not None and lines and est.stiffness_torques_Nm is not None:
        at = np.array([base.lost_motion_torque_Nm])  # the segments' wind-up up to the torque it is taken at
        windups = float(_windup_deg(est, 1, at)[0] - _windup_deg(est, -1, at)[0])
        width = lost_motion_deg(left, right, 0.0, est.engagement_torques_Nm_) + windups  # type: ignore[arg-type]
        base = replace(base, lost_motion_arcmin=width * ARCMIN_PER_DEG)
    hyst = None
    if base.lost_motion_arcmin is not None and left is not None and right is not None:
        uc, yc = np.asarray(u, dtype=float) - est.u_ref_, np.asarray(y, dtype=float) - est.y_ref_
        unl = unloading_mask(est.flank_, carried)
        sel_l, sel_r = unl & (est.flank_ == -1), unl & (est.flank_ == 1)
        if sel_l.any() and sel_r.any():  # each unloading branch where its flank carries no torque
            a_r = _unloading_offset(right, uc[sel_r], yc[sel_r], _windup_deg(est, 1, carried[sel_r]))
            a_l = _unloading_offset(left, uc[sel_l], yc[sel_l], _windup_deg(est, -1, -carried[sel_l]))
            hyst = (a_r - a_l) * ARCMIN_PER_DEG
    return replace(base, hysteresis_loss_arcmin=hyst)


@dataclass(frozen=True)
class HysteresisCurve:
    """What the data-sheet plot draws (:func:`online_backlash.plotting.plot_hysteresis`).

    ``torque_Nm``, ``torsion_arcmin`` and ``flank`` per sample; each fitted flank as
    ``(offset_arcmin, compliance_arcmin_per_Nm, torque range (lo, hi) N m)`` in the same centred
    torsion coordinate, or None; the lost motion and the torque it was taken at (None if not observable).
    """

    torque_Nm: np.ndarray
    torsion_arcmin: np.ndarray
    flank: np.ndarray
    left: tuple[float, float, tuple[float, float]] | None
    right: tuple[float, float, tuple[float, float]] | None
    lost_motion_arcmin: float | None
    lost_motion_torque_Nm: float | None
    lost_motion_basis: str


def hysteresis_curve(
    est: TorqueBacklash, u: np.ndarray, y: np.ndarray, torque_Nm: np.ndarray, figures: DatasheetFigures
) -> HysteresisCurve:
    """The torsion-angle/torque curve of a fitted :class:`TorqueBacklash` with its flank lines (arc minutes, N m)."""
    q = est.torque_sign_ * np.asarray(torque_Nm, dtype=float)
    lines = [ln for ln in (est.left_, est.right_) if ln is not None]
    centre = float(np.mean([ln.a for ln in lines])) if lines else 0.0

    def flank_line(line: FlankLine | None, side: int) -> tuple[float, float, tuple[float, float]] | None:
        if line is None:
            return None
        sel = q[est.flank_ == side]
        return (line.a - centre) * ARCMIN_PER_DEG, line.s * ARCMIN_PER_DEG, (float(sel.min()), float(sel.max()))

    return HysteresisCurve(
        torque_Nm=q,
        torsion_arcmin=torsion_curve(est, u, y),
        flank=est.flank_,
        left=flank_line(est.left_, -1),
        right=flank_line(est.right_, 1),
        lost_motion_arcmin=figures.lost_motion_arcmin,
        lost_motion_torque_Nm=figures.lost_motion_torque_Nm,
        lost_motion_basis=figures.lost_motion_basis,
    )
