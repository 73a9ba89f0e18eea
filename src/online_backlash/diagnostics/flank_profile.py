"""Flank lines that are not straight: a deflection that depends on the angle, different on each flank.

Eq. (1) has each flank of the dead band as a straight line, ``y = m_L (u + c_L)`` on the left
flank and ``y = m_R (u - c_R)`` on the right one. On a real transmission the contact point runs
along tooth profiles, cables and bearings whose errors and stiffness vary with the position, and
the driving and the coast flank are different surfaces under a different load: each flank line
carries its own position-dependent deviation, ``y = m_L (u + c_L) + g_L(u)`` and
``y = m_R (u - c_R) + g_R(u)``. A transmission error common to both flanks
(:class:`~.effects.TransmissionError`) is the special case ``g_L = g_R`` and periodic.

:class:`FlankProfile` describes ``g_L`` and ``g_R`` as piecewise-linear functions of ``u`` (the
load angle as the model sees it, eq. 1) through their values at evenly spaced knots: hat
functions of ``u``, one set per direction of motion (the flank that drives). The coefficients
are the deviations at the knots, in degrees, and enter linearly, so the loop's joint fit and
its held-out scoring apply unchanged; like the transmission error the columns are on the input
side of the dead band (held there by the loop's output-error fit). The deviation is 0 at the
outer knots and beyond them: a straight part of ``g`` (an offset and a slope per flank) is eq. (1)'s
own line, ``m`` and ``c``, so only the bend of each flank line is this effect's and the play stays
identifiable.

Detected only where the data tell it apart from what the library has: every knot must be crossed
on both flanks in the record (so the map is only ever fitted over a stroke the motion repeats),
it must hold out over whole reversal cycles, and its difference between the flanks must remove
a share of the residual of its own, beyond the same map common to both flanks (else it is a
transmission error, which has fewer columns and a periodic law).

Units: degrees (load side), seconds.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ._effect_base import knots_and_window
from ._folds import DEADZONE_DEG, DIRECTION_WINDOW
from ._per_flank import PerFlankTerms, record_direction
from ._scoring import BIC_THRESHOLD, MIN_GAIN, Detection, DetectionData

#: knot spacings tried by :meth:`FlankProfile.detect`, deg of load angle (an octave apart)
SPACINGS_DEG = (8.0, 4.0, 2.0, 1.0)
#: most knots per flank: a stroke longer than this many spacings is not mapped at that spacing
MAX_KNOTS = 64
#: a finer spacing is worth its columns only if it removes this much more of the held-out squared
#: error (share of the residual's) than the coarser one
SPACING_GAIN = 0.01
#: a knot's neighbourhood must be visited on each flank by at least this share of the record's samples
MIN_KNOT_SHARE = 0.001


def hat_columns(angle_deg: np.ndarray, knots_deg: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation weights of ``angle_deg`` on ``knots_deg`` (rows sum to 1;
    beyond the outer knots the end weight is 1), ``(len(angle_deg), len(knots_deg))``."""
    a = np.asarray(angle_deg, dtype=float)
    k = np.asarray(knots_deg, dtype=float)
    out = np.zeros((a.size, k.size))
    if k.size == 1:
        out[:, 0] = 1.0
        return out
    j = np.clip(np.searchsorted(k, a, side="right") - 1, 0, k.size - 2)
    w = np.clip((a - k[j]) / (k[j + 1] - k[j]), 0.0, 1.0)
    rows = np.arange(a.size)
    out[rows, j] = 1.0 - w
    out[rows, j + 1] += w
    return out


class FlankProfile(PerFlankTerms):
    """A position-dependent deviation of each flank line of eq. (1), piecewise linear in ``u``.

    Columns ``hat_j(u) * [moving up]`` for every inner knot ``j``, then ``hat_j(u) * [moving down]``
    (the direction of motion of ``u``, held inside a dead zone, as for the per-flank harmonics).
    The coefficients are the deviations of the flank that drives while ``u`` increases (moving
    up) and decreases (moving down) at the inner knots, deg (0 at the outer knots).

    Parameters
    ----------
    knots_deg : tuple of float
        Strictly increasing angles of ``u`` (the load angle of eq. 1, in the frame the effect is
        given), deg; at least two.
    window_samples, deadzone_deg : int, float
        The direction of motion (:class:`._per_flank.PerFlankTerms`), samples and deg.
    """

    name = "flank_profile"

    def __init__(
        self,
        knots_deg: tuple[float, ...] = (0.0, 1.0, 2.0),
        window_samples: int = DIRECTION_WINDOW,
        deadzone_deg: float = DEADZONE_DEG,
    ) -> None:
        knots = knots_and_window(knots_deg, 3, "angles", "knots_deg", window_samples)
        if not (np.isfinite(deadzone_deg) and deadzone_deg >= 0):
            raise InvalidParameterError(f"deadzone_deg must be finite and >= 0, got {deadzone_deg!r}")
        self.knots_deg = tuple(float(k) for k in knots)
        super().__init__(int(window_samples), float(deadzone_deg))

    @property
    def n_terms(self) -> int:
        return 2 * (len(self.knots_deg) - 2)

    def _shape(self, u: np.ndarray) -> np.ndarray:
        return hat_columns(u, np.asarray(self.knots_deg))[:, 1:-1]

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        c = np.asarray(coef, dtype=float)
        k = len(self.knots_deg) - 2
        up, down = (np.concatenate(([0.0], part, [0.0])) for part in (c[:k], c[k:]))
        diff = up - down
        return {
            "model": "piecewise-linear deviation of the flank line that drives (eq. 1) "
            "at the knots of the load angle u, "
            "one set while u increases and one while it decreases; constant beyond the outer knots",
            "knots_deg": list(self.knots_deg),
            "knot_spacing_deg": float(np.median(np.diff(self.knots_deg))),
            "moving_up_deg": [float(v) for v in up],
            "moving_down_deg": [float(v) for v in down],
            "flank_difference_deg": [float(v) for v in diff],
            "flank_difference_range_deg": float(np.ptp(diff)),
            "profile_range_deg": float(max(np.ptp(up), np.ptp(down))),
        }

    @classmethod
    def detect(cls, data: DetectionData) -> Detection | None:
        """Knots over the stroke the motion covers on both flanks, at the spacing that holds out best
        (the coarsest within :data:`SPACING_GAIN` of the best), among the spacings whose difference
        between the flanks is significant beyond the same map common to both (else the deviation is
        a transmission error's: fewer columns and a periodic law, :class:`~.effects.TransmissionError`)."""
        u = data.u_deg
        d = record_direction(data)
        engaged = data.engaged
        u_engaged, d_engaged = u[engaged], d[engaged]
        covered = _covered_range(u_engaged, d_engaged)
        found: list[tuple[Detection, float]] = []
        for spacing in SPACINGS_DEG:
            knots = None if covered is None else _covered_knots(u_engaged, d_engaged, spacing, covered)
            if knots is None:
                continue
            effect = cls(tuple(knots))
            cols = data.hold(effect.clone().terms(u, data.time_s, data.torque_Nm))
            score = data.score(False, cols)
            if not (np.isfinite(score.heldout_gain) and score.significant()):
                continue
            k = effect.n_terms // 2
            beyond = data.with_nuisance(cols[:, :k] + cols[:, k:]).score(False, cols[:, k:])
            if not (beyond.delta_bic < BIC_THRESHOLD and beyond.gain >= MIN_GAIN and beyond.heldout_gain >= MIN_GAIN):
                continue
            evidence = (
                "residual against the load angle differs between the flanks "
                f"({k} inner knots {spacing:.3g} deg apart over {knots[0]:.1f} to {knots[-1]:.1f} deg; "
                f"the flank difference alone removes {beyond.gain:.1%} in sample, "
                f"{beyond.heldout_gain:.1%} held out)"
            )
            found.append((Detection(effect, score, evidence), score.heldout_gain))
        if not found:
            return None
        best = max(g for _, g in found)
        return next(det for det, g in found if g >= best - SPACING_GAIN)


def _covered_range(u: np.ndarray, direction: np.ndarray) -> tuple[float, float] | None:
    """The range of ``u`` that both directions of motion cover (from the 0.5 to the 99.5 percentile of
    each), ``(lo, hi)``; None when a direction has no samples."""
    lo, hi = -np.inf, np.inf
    for side in (direction > 0, direction < 0):
        if not side.any():
            return None
        a = u[side]
        lo, hi = max(lo, float(np.quantile(a, 0.005))), min(hi, float(np.quantile(a, 0.995)))
    return lo, hi


def _covered_knots(
    u: np.ndarray, direction: np.ndarray, spacing: float, covered: tuple[float, float]
) -> np.ndarray | None:
    """Knots ``spacing`` apart over the range ``covered`` (:func:`_covered_range`), every knot's
    neighbourhood visited by at least :data:`MIN_KNOT_SHARE` of the samples on each flank, or None
    when that range is shorter than two spacings or needs more than :data:`MAX_KNOTS`."""
    lo, hi = covered
    if not hi - lo >= 2 * spacing:  # at least one inner knot
        return None
    n = int(np.floor((hi - lo) / spacing)) + 1
    if n > MAX_KNOTS:
        return None
    knots = lo + spacing * np.arange(n) + 0.5 * ((hi - lo) - spacing * (n - 1))
    need = MIN_KNOT_SHARE * u.size
    for side in (direction > 0, direction < 0):
        counts = np.bincount(np.clip(np.rint((u[side] - knots[0]) / spacing).astype(int), 0, n - 1), minlength=n)
        if np.any(counts < need):
            return None
    return knots
