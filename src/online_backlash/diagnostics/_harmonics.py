"""Harmonic columns of every order up to some top order, in one compiled pass, built once per record.

The harmonic detectors (the transmission error's load and motor orders, the per-flank generic
term) screen every order ``1 .. top`` of the same shaft angle on the same record, round after
round. ``sin(n a)`` and ``cos(n a)`` of every order follow from ``sin a`` and ``cos a`` by the
angle-addition rule (one ``sin``/``cos`` pair per sample instead of one per order and sample).
The values differ from ``numpy.sin(n * a)`` by the rounding of the argument ``n * a`` (about
1e-16 of it) and of the recurrence (about ``n`` units in the last place): 2e-13 on 2800 deg of
load rotation up to order 24, 1e-12 on 85 000 deg of motor rotation (the 10-minute bench log);
they only rank candidate orders, the chosen terms are fitted with ``numpy.sin``. The stack is kept in
the record's cache (:meth:`._scoring.DetectionData.memo`); a record too long for the cache's budget
gets each order from ``numpy.sin``/``cos`` instead.

A screened record (:meth:`._folds.Folds.screen`) gets the stack at the rows its scores read only
(:func:`harmonic_at_sources`, :attr:`._scoring.DetectionData.needed_rows`), once a round.

Angles in degrees; orders are cycles per revolution of the angle.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from ._scoring import DetectionData

_RAD = np.pi / 180.0


def harmonic_columns(angle_deg: np.ndarray, orders: Sequence[float]) -> np.ndarray:
    """``[sin(n a), cos(n a)]`` for every order ``n`` (cycles per revolution of ``angle_deg``)."""
    a = np.asarray(angle_deg, dtype=float)[:, None] * (np.asarray(orders, dtype=float)[None, :] * _RAD)
    out = np.empty((a.shape[0], 2 * a.shape[1]))
    out[:, 0::2] = np.sin(a)
    out[:, 1::2] = np.cos(a)
    return out


def harmonic_stack(angle_deg: np.ndarray, top: int) -> np.ndarray:
    """``(top, n, 2)``: ``[sin(k a), cos(k a)]`` for ``k = 1 .. top`` (entry ``k - 1``), ``a`` = ``angle_deg``
    in radians."""
    a = np.ascontiguousarray(angle_deg, dtype=float) * _RAD
    out = np.empty((max(int(top), 0), a.size, 2))
    _stack(a, out)
    return out


@njit(cache=True)
def _stack(a, out):  # pragma: no cover - compiled
    """Angle addition: ``sin((k+1) a) = sin(k a) cos a + cos(k a) sin a``,
    ``cos((k+1) a) = cos(k a) cos a - sin(k a) sin a``."""
    for t in range(a.size):
        s1 = math.sin(a[t])
        c1 = math.cos(a[t])
        s = s1
        c = c1
        for k in range(out.shape[0]):
            if k:
                s, c = s * c1 + c * s1, c * c1 - s * s1
            out[k, t, 0] = s
            out[k, t, 1] = c


def shaft_harmonic(data: DetectionData, shaft: str, angle_deg: np.ndarray, order: int, top: int) -> np.ndarray:
    """``[sin(n a), cos(n a)]`` (n x 2) of ``angle_deg`` for the order ``n`` = ``order`` (at most ``top``),
    from the record's stack of orders ``1 .. top`` (``shaft`` names the angle in the cache: it must be
    a function of the record and ``data.ratio`` only)."""
    key = ("harmonic stack", shaft, float(data.ratio), int(top))
    if not 1 <= order <= top or not data.can_memo(key, angle_deg.size * 2 * top * 8):
        return harmonic_columns(angle_deg, [order])
    return data.memo(key, lambda: harmonic_stack(angle_deg, top))[order - 1]


def harmonic_at_sources(
    data: DetectionData, shaft: str, angle_deg: np.ndarray, order: int, top: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The order's ``[sin, cos]`` at the samples a held column reads, ``(columns, positions, rows)``:
    ``columns[positions]`` is ``data.hold(shaft_harmonic(...))`` (the rows :meth:`DetectionData.hold`
    gives); ``rows`` are the samples ``columns`` has (None: every sample). For a screen, the stack
    of orders is formed at the rows its scores read only (:attr:`DetectionData.needed_rows`), once a
    round: no full-length array."""
    rows = data.needed_rows
    scored = data.scored_rows
    if rows is None or scored is None:
        index = np.arange(angle_deg.size) if data.engaged_index is None else data.engaged_index
        return shaft_harmonic(data, shaft, angle_deg, order, top), index, None
    sources = scored if data.engaged_index is None else data.engaged_index[scored]
    positions = data.memo(("positions of the held rows",), lambda: np.searchsorted(rows, sources), held=True)
    key = ("harmonic stack at the rows scored", shaft, float(data.ratio), int(top))
    if 1 <= order <= top and data.can_memo(key, rows.size * 2 * top * 8):
        return data.memo(key, lambda: harmonic_stack(angle_deg[rows], top), held=True)[order - 1], positions, rows
    return harmonic_columns(angle_deg[rows], [order]), positions, rows


def held_harmonic(data: DetectionData, shaft: str, angle_deg: np.ndarray, order: int, top: int) -> np.ndarray:
    """``data.hold(shaft_harmonic(data, shaft, angle_deg, order, top))``, without a full-length array on a screen."""
    columns, positions, _ = harmonic_at_sources(data, shaft, angle_deg, order, top)
    return np.take(columns, positions, axis=0)


def held_per_flank(
    columns: np.ndarray, up: np.ndarray, down: np.ndarray, index: np.ndarray | None, rows: np.ndarray | None = None
) -> np.ndarray:
    """``[columns * up, columns * down]`` taken at ``index`` (held through the dead band, see
    :meth:`._scoring.DetectionData.hold`; None: not held), in one compiled pass without temporaries;
    with ``rows``, the result has those rows only (a screen's, :attr:`._scoring.DetectionData.scored_rows`).

    ``columns`` is ``(n, q)``; ``up`` and ``down`` are boolean masks of the samples (the direction
    of motion); the result is ``(n, 2 q)``, the same numbers as masking, stacking and holding.
    """
    c = np.ascontiguousarray(columns, dtype=float)
    idx = np.arange(c.shape[0]) if index is None else np.ascontiguousarray(index, dtype=np.int64)
    rows = np.arange(idx.size) if rows is None else np.ascontiguousarray(rows, dtype=np.int64)
    out = np.empty((rows.size, 2 * c.shape[1]))
    _per_flank(c, np.asarray(up, dtype=float), np.asarray(down, dtype=float), idx, rows, out)
    return out


@njit(cache=True)
def _per_flank(c, up, down, idx, rows, out):  # pragma: no cover - compiled
    q = c.shape[1]
    for r in range(rows.size):
        i = idx[rows[r]]
        for j in range(q):
            out[r, j] = c[i, j] * up[i]
            out[r, q + j] = c[i, j] * down[i]
