"""The load-aware keys of a fit's report: the play's path and verdict, torque reversals, the data-sheet figures.

One place turns a fitted torque estimator (batch or recursive) into the keys ``estimate --json`` carries
beside the path's (:meth:`~.choice.PlayDecision.keys`) (:data:`online_backlash.output_columns.REPORT_KEYS`).
Lost motion and stiffness follow the play's rule (:func:`online_backlash.physical.figure_verdict`):
a figure below zero, or whose standard error (the delta method on the flank lines' covariance and
residual variance: white noise only, so it flags only figures the data plainly do not hold) exceeds
half its value, is null, and so are the torque path's figures where that path was not taken
(``figures_reason`` says why). Units: degrees, arc minutes, N m.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..output_columns import ARCMIN_PER_DEG
from ..physical import figure_verdict
from .datasheet import DatasheetFigures, datasheet_figures, line_figures
from .flank_fit import TorqueBacklash
from .segments import check_knots, segment_keys
from .torque_rls import TorqueBacklashRLS

__all__ = ["batch_keys", "has_torque", "recursive_keys"]

#: ``figures_reason`` where the torque path was not taken.
NOT_TAKEN = "the torque path was not taken (play_method_reason): its stiffness and lost motion are not the gear's"


def has_torque(torque_Nm: np.ndarray) -> bool:
    """True when the torque column is present (every value finite); False when it is absent (all NaN).

    Raises
    ------
    InvalidParameterError
        When only some values are finite (a non-finite torque must never reach an estimator).
    """
    finite = np.isfinite(np.asarray(torque_Nm, dtype=float))
    if finite.size and finite.all():
        return True
    if not finite.any():
        return False
    raise InvalidParameterError(
        f"the torque column has non-finite values, first at sample {int(np.flatnonzero(~finite)[0])}"
    )


def _stiffness_std(k: float | None, s: float, var_s: float) -> float:
    """The standard error of a stiffness ``k = 1 / (60 s)`` from its compliance's variance ``var_s`` (deg^2/N^2 m^2)."""
    return math.nan if k is None or not (s > 0 and var_s >= 0) else k * math.sqrt(var_s) / s


def _judged(
    figures: DatasheetFigures,
    engagement: tuple[float, float],
    sign: float,
    lines: tuple[Any, Any],
    covs: tuple[Any, Any],
    noise_var: float,
    taken: bool,
) -> dict[str, Any]:
    """The data-sheet figures after :func:`~online_backlash.physical.figure_verdict`, with their standard
    errors and the torques at which the flanks engage (``engagement`` times the torque ``sign``, N m; in the
    keys as the sensor reads them)."""
    given = figures.as_dict()
    out = {
        **given,
        "engagement_torque_left_Nm": sign * engagement[0],
        "engagement_torque_right_Nm": sign * engagement[1],
    }
    if not taken:
        nulled = ("stiffness", "stiffness_left", "stiffness_right", "stiffness_std")
        out.update({f"{name}_nm_per_arcmin": None for name in nulled})
        out.update(lost_motion_arcmin=None, lost_motion_std_arcmin=None, hysteresis_loss_arcmin=None)
        out["figures_reason"] = NOT_TAKEN
        return out
    reasons = []
    var_s = [noise_var * float(c[2, 2]) if c is not None and np.isfinite(c[2, 2]) else math.nan for c in covs]
    for key, line, var in (
        ("stiffness_left_nm_per_arcmin", lines[0], var_s[0]),
        ("stiffness_right_nm_per_arcmin", lines[1], var_s[1]),
    ):
        verdict = figure_verdict(
            out[key],
            _stiffness_std(out[key], line.s if line is not None else math.nan, var),
            "N m/arcmin",
            key[:-16].replace("_", " "),
        )
        out[key] = verdict.value
        reasons += [verdict.reason] if verdict.reason and given[key] is not None else []
    weights = [1.0 / v for v in var_s if v > 0 and math.isfinite(v)]
    k = out["stiffness_nm_per_arcmin"]
    mean_s = 1.0 / (k * ARCMIN_PER_DEG) if k else math.nan
    std_k = _stiffness_std(k, mean_s, 1.0 / sum(weights)) if weights else math.nan
    stiffness = figure_verdict(k, std_k, "N m/arcmin", "stiffness")
    out["stiffness_nm_per_arcmin"], out["stiffness_std_nm_per_arcmin"] = stiffness.value, stiffness.std
    reasons += [stiffness.reason] if stiffness.reason and k is not None else []
    lost, at = out["lost_motion_arcmin"], out["lost_motion_torque_Nm"]
    std_lost = math.nan
    if lost is not None and at is not None and all(c is not None for c in covs):
        t_left, t_right = engagement
        grad_left, grad_right = np.array([0.0, -1.0, -(t_left - at)]), np.array([0.0, 1.0, t_right + at])
        var_lost = noise_var * float(grad_left @ covs[0] @ grad_left + grad_right @ covs[1] @ grad_right)
        std_lost = math.sqrt(var_lost) * ARCMIN_PER_DEG if var_lost >= 0 else math.nan
    lost_verdict = figure_verdict(lost, std_lost, "arcmin", "lost motion")
    out["lost_motion_arcmin"], out["lost_motion_std_arcmin"] = lost_verdict.value, lost_verdict.std
    reasons += [lost_verdict.reason] if lost_verdict.reason and lost is not None else []
    hyst = out["hysteresis_loss_arcmin"]
    if hyst is not None and hyst < 0:
        out["hysteresis_loss_arcmin"] = None
        reasons.append(f"a hysteresis loss of {hyst:.4g} arcmin is not physical")
    out["figures_reason"] = "; ".join(reasons) if reasons else None
    return out


def batch_keys(
    est: TorqueBacklash, u: np.ndarray, y: np.ndarray, torque_Nm: np.ndarray, rated_torque_Nm: float | None, taken: bool
) -> dict[str, Any]:
    """The keys of a torque-aware batch fit: its torque reversals and every data-sheet figure (judged;
    null where the torque path was not ``taken``)."""
    figures = datasheet_figures(est, u, y, torque_Nm, rated_torque_Nm)
    covs = (None if est.fits_[-1] is None else est.fits_[-1].cov, None if est.fits_[1] is None else est.fits_[1].cov)
    judged = _judged(
        figures, est.engagement_torques_Nm_, est.torque_sign_, (est.left_, est.right_), covs, est.noise_var_, taken
    )
    knots = None if est.stiffness_torques_Nm is None else check_knots(est.stiffness_torques_Nm)
    segments = segment_keys(est.segments_ if taken else (None, None), knots, est.noise_var_)
    return {
        "torque_reversals": est.torque_reversals_,
        "windup_separable": est.windup_separable_,
        "torque_sign": est.torque_sign_,
        **judged,
        **segments,
    }


def recursive_keys(est: TorqueBacklashRLS, rated_torque_Nm: float | None, taken: bool) -> dict[str, Any]:
    """The keys of a torque-aware recursive fit (the hysteresis loss needs the whole curve: None)."""
    left, right = est.flank_lines_()
    figures = line_figures(
        left, right, est.play_observable_, est.deadband_Nm_, est.torque_peaks_Nm_, rated_torque_Nm,
        est.operating_torque_Nm_, est.compliance_var_, est.engagement_torques_Nm_,
    )  # fmt: skip
    covs = est._pair_covs() if est.play_observable_ else (None, None)
    judged = _judged(figures, est.engagement_torques_Nm_, est.torque_sign_, (left, right), covs, est.noise_var_, taken)
    segments = segment_keys((None, None), None, est.noise_var_)  # the three segments need the whole curve: batch fits
    return {
        "torque_reversals": est.n_reversals_,
        "windup_separable": est.windup_separable_,
        "torque_sign": est.torque_sign,
        **judged,
        **segments,
    }
