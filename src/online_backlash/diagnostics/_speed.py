"""Smooth functions of the speed: knots over each direction's speeds and the cardinal cubic splines.

Shared by the generic :class:`~.generic.VelocityFunction` and by the drift's test of what a
function of the speed could explain instead (:meth:`~.effects.Drift.detect`). Velocity in deg/s.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from ._causal import velocity_deg_s

#: the outer knot of each direction is this percentile of the speed in that direction (beyond it
#: the function is held constant), %
OUTER_PERCENTILE = 99.5
#: most inner knots per direction of motion (the generic velocity function tries 1 to this many)
MAX_INNER_KNOTS = 5
#: span of the difference that gives the velocity, samples
VELOCITY_WINDOW = 10


def speed_knots(velocity_deg_s: np.ndarray, inner: int) -> tuple[float, ...]:
    """0 and, for each direction of motion, ``inner + 1`` knots evenly spaced up to the
    :data:`OUTER_PERCENTILE` percentile of the speed in that direction, deg/s, increasing.

    Each direction has its own outer knot, so every knot lies within the speeds of its
    direction: the reversals pass through every speed below the outer knot in every cycle, so
    each knot's value is pinned down on held-out cycles too. (An even grid to the 99th
    percentile of both directions pooled left knots beyond the slower direction's speeds, with
    samples in one cycle or none: the fits without that cycle were undetermined there.) A
    direction with fewer than 10 samples gets none.
    """
    v = np.asarray(velocity_deg_s, dtype=float)
    knots = [0.0]
    for sign in (-1.0, 1.0):
        speed = np.abs(v[np.sign(v) == sign])
        if speed.size < 10:
            continue
        top = float(np.percentile(speed, OUTER_PERCENTILE))
        if top > 0:
            knots += [sign * top * j / (inner + 1) for j in range(1, inner + 2)]
    return tuple(sorted(knots))


def cardinal_splines(knots_deg_s: tuple[float, ...], velocity: np.ndarray) -> np.ndarray:
    """``(n, len(knots))``: the cubic splines through 1 at one knot and 0 at the others, at
    ``velocity`` (deg/s) clipped to the outer knots (constant beyond them).

    "Not-a-knot" end conditions: the outer two pieces on each side are one cubic, so a cubic law
    of the speed is reproduced exactly (a natural spline forces zero curvature at the outer
    knots, where a lag growing with the square of the speed has the most). Two knots give a
    straight line, three a parabola.
    """
    k = np.asarray(knots_deg_s, dtype=float)
    v = np.clip(np.asarray(velocity, dtype=float), k[0], k[-1])
    return np.asarray(CubicSpline(k, np.eye(k.size), bc_type="not-a-knot")(v))


def zero_knot(knots_deg_s: tuple[float, ...]) -> int:
    """Index of the knot nearest 0 (the function is 0 there: its column is left out)."""
    return int(np.argmin(np.abs(np.asarray(knots_deg_s, dtype=float))))


def speed_columns(u_deg: np.ndarray, time_s: np.ndarray, inner: int = MAX_INNER_KNOTS) -> np.ndarray:
    """The columns of the most flexible smooth function of speed that is 0 at rest, for this record
    (knots by :func:`speed_knots`; velocity of ``u_deg`` over :data:`VELOCITY_WINDOW` samples)."""
    v = velocity_deg_s(np.asarray(u_deg, dtype=float), np.asarray(time_s, dtype=float), VELOCITY_WINDOW)
    knots = speed_knots(v, inner)
    if len(knots) < 2:
        return np.empty((v.size, 0))
    return np.delete(cardinal_splines(knots, v), zero_knot(knots), axis=1)
