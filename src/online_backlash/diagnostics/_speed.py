"""Smooth functions of the speed: knots over each direction's speeds and the cardinal cubic splines.

Shared by the generic :class:`~.generic_terms.VelocityFunction` and by the drift's test of what a
function of the speed could explain instead (:meth:`~.effects.Drift.detect`). Velocity in deg/s.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.interpolate import CubicSpline

from ._causal import velocity_deg_s
from ._scoring import DetectionData

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
    return knots_up_to(outer_speeds(velocity_deg_s), inner)


def outer_speeds(velocity_deg_s: np.ndarray) -> np.ndarray:
    """The outer knot of each direction, ``[down, up]``, deg/s: the :data:`OUTER_PERCENTILE`
    percentile of the speed in that direction (NaN for a direction with fewer than 10 samples)."""
    v = np.asarray(velocity_deg_s, dtype=float)
    out = np.full(2, np.nan)
    for i, sign in enumerate((-1.0, 1.0)):
        speed = np.abs(v[np.sign(v) == sign])
        if speed.size >= 10:
            out[i] = float(np.percentile(speed, OUTER_PERCENTILE))
    return out


def knots_up_to(outer: np.ndarray, inner: int) -> tuple[float, ...]:
    """:func:`speed_knots` from the outer knots of :func:`outer_speeds`."""
    knots = [0.0]
    for sign, top in zip((-1.0, 1.0), (float(v) for v in outer)):
        if top > 0:  # False for NaN: a direction without samples
            knots += [sign * top * j / (inner + 1) for j in range(1, inner + 2)]
    return tuple(sorted(knots))


def record_speed_knots(data: DetectionData, inner: int) -> tuple[float, ...]:
    """:func:`speed_knots` of :func:`record_velocity`, its outer knots found once per record."""
    return knots_up_to(data.memo(("outer speeds", VELOCITY_WINDOW), lambda: outer_speeds(record_velocity(data))), inner)


def cardinal_splines(knots_deg_s: tuple[float, ...], velocity: np.ndarray) -> np.ndarray:
    """``(n, len(knots))``: the cubic splines through 1 at one knot and 0 at the others, at
    ``velocity`` (deg/s) clipped to the outer knots (constant beyond them).

    "Not-a-knot" end conditions: the outer two pieces on each side are one cubic, so a cubic law
    of the speed is reproduced exactly (a natural spline forces zero curvature at the outer
    knots, where a lag growing with the square of the speed has the most). Two knots give a
    straight line, three a parabola. The definition, by scipy: the loop and the velocity function
    evaluate them with :func:`cardinal_columns` (the same numbers, compiled; the tests hold the two equal).
    """
    k = np.asarray(knots_deg_s, dtype=float)
    v = np.clip(np.asarray(velocity, dtype=float), k[0], k[-1])
    return np.asarray(CubicSpline(k, np.eye(k.size), bc_type="not-a-knot")(v))


def zero_knot(knots_deg_s: tuple[float, ...]) -> int:
    """Index of the knot nearest 0 (the function is 0 there: its column is left out)."""
    return int(np.argmin(np.abs(np.asarray(knots_deg_s, dtype=float))))


def record_velocity(data: DetectionData) -> np.ndarray:
    """The velocity of the record's ``u_deg`` over :data:`VELOCITY_WINDOW` samples, deg/s (built once per record)."""
    return data.memo(("velocity", VELOCITY_WINDOW), lambda: velocity_deg_s(data.u_deg, data.time_s, VELOCITY_WINDOW))


def held_spline_columns(data: DetectionData, knots_deg_s: tuple[float, ...]) -> np.ndarray:
    """:func:`cardinal_splines` of the record's velocity (:func:`record_velocity`) at ``knots_deg_s``, the
    column of the knot nearest 0 left out, held through the dead band (:meth:`DetectionData.hold`; for a
    screen, its rows only):
    the columns of the drift's speed rival and of the generic velocity function, built once per round.

    Holding a column takes its value at an earlier sample, so the splines are evaluated at the held
    velocity (:func:`cardinal_columns`).
    """

    def build() -> np.ndarray:
        return cardinal_columns(knots_deg_s, record_velocity(data), data.engaged_index, data.scored_rows)

    return data.memo(("held speed columns", tuple(knots_deg_s)), build, held=True)


def cardinal_columns(
    knots_deg_s: tuple[float, ...],
    velocity: np.ndarray,
    index: np.ndarray | None = None,
    rows: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`cardinal_splines` at ``velocity`` (deg/s) without the column of the knot nearest 0 (the
    columns of :class:`~.generic_terms.VelocityFunction`), in one compiled pass (the piecewise cubics of
    :class:`scipy.interpolate.CubicSpline` in its power form, as it evaluates them: the same numbers,
    bit for bit, on the bench and measured logs); a sample's row at the velocity of sample
    ``index[t]`` (held through the dead band; None: its own), for the samples ``rows`` only (None: all)."""
    v = np.ascontiguousarray(velocity, dtype=float)
    index = np.arange(v.size) if index is None else np.ascontiguousarray(index, dtype=np.int64)
    rows = np.arange(index.size) if rows is None else np.ascontiguousarray(rows, dtype=np.int64)
    if len(knots_deg_s) < 2:
        return np.empty((rows.size, 0))
    k = np.asarray(knots_deg_s, dtype=float)
    coef = np.ascontiguousarray(CubicSpline(k, np.eye(k.size), bc_type="not-a-knot").c)
    kept = np.delete(np.arange(k.size), zero_knot(knots_deg_s))
    out = np.empty((rows.size, kept.size))
    # the kept columns' coefficients per interval, lowest power first: (intervals, powers, columns)
    _cardinal_at(np.ascontiguousarray(coef[::-1][:, :, kept].transpose(1, 0, 2)), k, v, index, rows, out)
    return out


@njit(cache=True)
def _cardinal_at(coef, knots, v, index, rows, out):  # pragma: no cover - compiled
    """``out[i, j]`` for ``t = rows[i]``: the piecewise cubic with coefficients ``coef[:, :, j]`` (interval,
    power from the lowest, on the intervals of ``knots``) at ``v[index[t]]`` clipped to the outer knots;
    every column summed from the lowest power up, the powers formed once per sample."""
    m = knots.size
    for r in range(rows.size):
        s = min(max(v[index[rows[r]]], knots[0]), knots[m - 1])
        i = 0
        while i < m - 2 and s >= knots[i + 1]:
            i += 1
        d = s - knots[i]
        row = out[r]
        row[:] = 0.0
        z = 1.0
        for p in range(coef.shape[1]):
            for j in range(row.size):
                row[j] += coef[i, p, j] * z
            z *= d
