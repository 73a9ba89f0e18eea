"""The three-segment torsional stiffness of gear data sheets (issue 27 item 3): K1 up to T1, K2 up to T2, K3 above.

Harmonic Drive, Nabtesco and Wittenstein characterise a gear's wind-up by three stiffnesses (N m/arcmin):
the torsion angle grows by ``1/K1`` per N m up to the torque ``T1``, by ``1/K2`` from ``T1`` to ``T2``,
and by ``1/K3`` above (a hardening spring: the teeth bed in). On one flank, with ``tau >= 0`` the torque
it carries (the measured torque less the torque at which it engages, :mod:`.engagement`)::

    y = m u - a0 - sign (s1 h1(tau) + s2 h2(tau) + s3 h3(tau))          sign: +1 right flank, -1 left
    h1 = min(tau, T1),   h2 = min(max(tau - T1, 0), T2 - T1),   h3 = max(tau - T2, 0),   s_k = 1 / K_k

which is linear in ``a0`` and the compliances ``s_k`` (the hinge columns ``h_k`` are known once the knots
are), so one least-squares solve per flank fits it, the slope ``m`` held at the flank line's
(:mod:`.flank_fit`). Only the segments the flank's torque covers (at least
:data:`~.flank_fit.MIN_FLANK_SAMPLES` of its samples in them) are fitted; the others are reported as
not fitted. ``a0`` is the flank where it carries no torque, so the play follows from it as from the
straight lines (:func:`~.flank_lines.play_between`), now without the bias a straight line through a
hardening spring carries into zero torque (where the torque never falls into ``K1``'s range, the wind-up
over it is not measured and stays in ``a0``: the play then holds it).

Units: degrees (load side), N m; stiffness in N m/arcmin at the API.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..output_columns import ARCMIN_PER_DEG
from ..physical import figure_verdict
from .flank_lines import FlankLine

__all__ = ["SEGMENTS", "SegmentFit", "check_knots", "fit_segments", "hinge_columns", "segment_keys"]

#: The segments' names, as data sheets write them.
SEGMENTS = ("K1", "K2", "K3")


def check_knots(knots_Nm: Any) -> tuple[float, float]:
    """``(T1, T2)`` as floats, or InvalidParameterError unless ``0 < T1 < T2`` (finite, N m)."""
    try:
        t1, t2 = (float(v) for v in knots_Nm)
    except (TypeError, ValueError):
        raise InvalidParameterError(
            f"the stiffness torques must be two numbers T1,T2 in N m, got {knots_Nm!r}"
        ) from None
    if not (math.isfinite(t2) and 0 < t1 < t2):
        raise InvalidParameterError(f"the stiffness torques must satisfy 0 < T1 < T2 (N m), got {t1!r}, {t2!r}")
    return t1, t2


def hinge_columns(carried_Nm: np.ndarray, knots_Nm: tuple[float, float]) -> np.ndarray:
    """The wind-up's regressors ``h1, h2, h3`` (module docstring) of torques ``carried_Nm >= 0``, shape (3, n), N m."""
    t1, t2 = knots_Nm
    tau = np.asarray(carried_Nm, dtype=float)
    return np.vstack((np.minimum(tau, t1), np.clip(tau - t1, 0.0, t2 - t1), np.maximum(tau - t2, 0.0)))


@dataclass(frozen=True)
class SegmentFit:
    """One flank's three-segment fit: its line (``m`` held, the offset where it carries no torque, the
    first fitted segment's compliance), the compliances (deg per N m; None: segment not covered) with
    their unscaled variances, the unscaled covariance of the line's ``[m, a, s]``, residual sum of squares
    and sample count."""

    line: FlankLine
    compliance: tuple[float | None, float | None, float | None]
    variance: tuple[float, float, float]
    cov: np.ndarray
    rss: float
    n: int


def fit_segments(
    u: np.ndarray,
    y: np.ndarray,
    carried_Nm: np.ndarray,
    sign: float,
    knots_Nm: tuple[float, float],
    slope: float,
    engaged_at: float,
    min_samples: int,
) -> SegmentFit | None:
    """Fit the module docstring's model to one flank's samples (``u``, ``y`` degrees in the lines'
    coordinates; ``carried_Nm`` the torque it carries, >= 0; ``sign`` +1 right, -1 left; ``engaged_at`` the
    measured torque at which it engages, oriented). None where no segment is covered."""
    h = hinge_columns(carried_Nm, knots_Nm)
    t1, t2 = knots_Nm
    tau = np.asarray(carried_Nm, dtype=float)
    covered = [
        int(np.count_nonzero(sel)) >= min_samples
        for sel in ((tau > 0) & (tau <= t1), (tau > t1) & (tau <= t2), tau > t2)
    ]
    if not any(covered):
        return None
    idx = [k for k in range(3) if covered[k]]
    X = np.column_stack([-np.ones_like(tau), *(-sign * h[k] for k in idx)])
    target = np.asarray(y, dtype=float) - slope * np.asarray(u, dtype=float)
    info = X.T @ X
    try:
        cov_local = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return None
    coef = cov_local @ (X.T @ target)
    resid = target - X @ coef
    compliance: list[float | None] = [None, None, None]
    variance = [math.nan, math.nan, math.nan]
    for j, k in enumerate(idx, start=1):
        compliance[k], variance[k] = float(coef[j]), float(cov_local[j, j])
    a0, s_first = float(coef[0]), float(coef[1])
    # near no torque the wind-up is sign s_first (q - T) on either flank: y = m u - (a0 - s_first T) - s_first q
    line = FlankLine(float(slope), a0 - s_first * engaged_at, s_first)
    J = np.array([[0.0, 0.0], [1.0, -engaged_at], [0.0, 1.0]])  # [m, a, s] from [a0, s_first]
    cov = J @ cov_local[:2, :2] @ J.T
    return SegmentFit(
        line,
        (compliance[0], compliance[1], compliance[2]),
        (variance[0], variance[1], variance[2]),
        cov,
        float(resid @ resid),
        int(tau.size),
    )


def segment_keys(
    fits: tuple[SegmentFit | None, SegmentFit | None], knots_Nm: tuple[float, float] | None, noise_var: float
) -> dict[str, Any]:
    """The keys of ``estimate --json`` for the three segments: ``stiffness_k1_nm_per_arcmin`` .. ``k3``
    (both flanks' compliances inverse-variance weighted, then :func:`~online_backlash.physical.figure_verdict`),
    ``stiffness_segments_fitted`` (the segments either flank covered) and ``stiffness_torques_Nm``."""
    out: dict[str, Any] = {
        "stiffness_torques_Nm": None if knots_Nm is None else list(knots_Nm),
        "stiffness_segments_fitted": [],
    }
    for k, name in enumerate(SEGMENTS):
        pairs: list[tuple[float, float]] = []
        for f in fits:
            compliance = None if f is None else f.compliance[k]
            var = math.nan if f is None else noise_var * f.variance[k]
            if compliance is not None and var > 0 and math.isfinite(var):
                pairs.append((compliance, var))
        key = f"stiffness_{name.lower()}_nm_per_arcmin"
        if not pairs:
            out[key] = None
            continue
        out["stiffness_segments_fitted"].append(name)
        weight = sum(1.0 / v for _, v in pairs)
        s = sum(c / v for c, v in pairs) / weight
        k_value = 1.0 / (s * ARCMIN_PER_DEG) if s > 0 else -math.inf
        std = abs(k_value) * math.sqrt(1.0 / weight) / abs(s) if s != 0 else math.nan
        out[key] = figure_verdict(
            k_value if math.isfinite(k_value) else -1.0, std, "N m/arcmin", f"stiffness {name}"
        ).value
    return out
