"""Joint output-error fit of the backlash and the effect terms, and the play's identifiability.

The augmented model is ``y(t) = x(t) + T(t) beta`` with ``x`` the backlash of eq. (1)-(3)
run freely on ``u`` and ``T`` the effect columns. Columns of effects that act on the input
side of the backlash (transmission error, delay, the generic terms in angle and velocity:
``input_side = True``) are *held through the dead band*: while neither flank is engaged
(``f1 = f2 = 0`` in eq. 5-6) the load does not move, so such a column keeps its value from the
last engaged sample, exactly as ``x(t) = x(t-1)`` holds the flank terms ``u f1``, ``u f2`` of
eq. (7). In the equation-error form (eq. 14, and the recursive estimator) the same happens by
itself, since only engaged samples carry the flank regressors. For fixed backlash parameters the output is
linear in ``beta`` (the quasi-linear structure of eq. 8 and 14 carried over), so ``beta`` is
projected out exactly by least squares (variable projection) and only the four backlash
parameters ``[mL, cL, mR, cR]`` are searched, by the same output-error refinement the batch
estimator ends with (``VorosBacklash(refine=True)``).

Identifiability. A column that switches with the direction of motion (a velocity or torque
term on a test with one speed) moves both flank lines apart just as the play does. The
variance inflation of the play, ``(1 - R2_base) / (1 - R2_joint)`` where ``R2`` is the share of
the play's sensitivity ``dx/d(play)`` explained by the other backlash sensitivities (and, for
``R2_joint``, the effect columns), says how much the effect blurs the play, and the play's
standard error in the joint fit (corrected for the residual's autocorrelation) says whether
the data still pin it down. When the inflation exceeds :data:`MAX_PLAY_INFLATION` or that
error exceeds :data:`MAX_PLAY_STD_SHARE` of the play, the data cannot tell the effect and the
play apart and :func:`fit_guarded` holds the play at
its value without the effect. (A direction-switching torque term that also varies in size is
separable: its size sets the coefficient, which then fixes its switching part.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from ..model import BacklashParams, sensitivity_step, simulate_backlash, switching_step
from ._normal_equations import Projector, left_sum_of_squares, nonzero_rows
from ._scoring import effective_samples

#: an effect may move the play only if the play's standard error stays below this share of it
MAX_PLAY_STD_SHARE = 0.005
#: and only if it inflates the play's variance by at most this factor (beyond it, the play
#: would rest on a handful of samples near the reversals)
MAX_PLAY_INFLATION = 100.0
#: a fit over some rows simulates each run of them from this many samples before the flank last
#: engaged ahead of it (under the start parameters): the model forgets its state at an engagement
SPAN_LEAD = 256


@dataclass(frozen=True)
class JointFit:
    """Backlash and effect coefficients fitted together, in the centred frame (degrees).

    Attributes
    ----------
    params : BacklashParams
    coef : array
        Coefficients of all effect columns, in column order.
    residual_deg : array
        Simulation residual of the augmented model.
    play_inflation : float
        Variance inflation of the play caused by the effect columns (1 = none).
    play_std_deg : float
        Standard error of the play, corrected for the residual's autocorrelation, deg.
    play_held : bool
        True when the play was held fixed because the effects and the play are not separable.
    """

    params: BacklashParams
    coef: np.ndarray
    residual_deg: np.ndarray
    play_inflation: float
    play_std_deg: float
    play_held: bool

    @property
    def rms_deg(self) -> float:
        """RMS of the residual, deg."""
        return float(np.sqrt(np.mean(self.residual_deg**2)))


def _spans(
    rows: np.ndarray, switched: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(starts, firsts, stops, x0s)`` of :func:`~online_backlash.model.backlash_sensitivity_spans` for the
    runs of consecutive ``rows``: each started :data:`SPAN_LEAD` samples before the last sample ahead
    of it with a flank engaged, from the output there; ``switched`` is :func:`_switched` of the
    parameters the fit starts from."""
    x, index = switched
    cuts = np.flatnonzero(np.diff(rows) != 1) + 1
    firsts = rows[np.r_[0, cuts]]
    stops = rows[np.r_[cuts - 1, rows.size - 1]] + 1
    starts = np.maximum(index[firsts] - SPAN_LEAD, 0)
    x0s = np.where(starts > 0, x[np.maximum(starts - 1, 0)], 0.0)  # x(-1) = 0 at the record's start
    return starts, firsts, stops, x0s


@njit(cache=True, nogil=True)
def _sensitivity_gram(u, y, mL, cL, mR, cR, starts, firsts, stops, x0s, a):  # pragma: no cover - compiled
    """:func:`~online_backlash.model.backlash_sensitivity_spans` (eq. 1-3 and ``dx = d x / d [mL, cL,
    mR, cR]``) with, at the rows it returns (``y``: a value per row), ``a = [dx, y - x]`` written and
    the Gram matrix of ``[1, dx, y - x]`` (6 x 6) returned, from one pass: its sums are kept in
    registers as the rows are formed (a second pass over ``a``, or a product of it with itself, cost
    more than the simulation)."""
    at = 0
    count = 0.0
    g01 = g02 = g03 = g04 = g05 = g11 = g12 = g13 = g14 = g15 = g22 = g23 = g24 = g25 = g33 = g34 = g35 = g44 = g45 = (
        g55
    ) = 0.0
    for k in range(starts.size):
        prev = x0s[k]
        d0 = d1 = d2 = d3 = 0.0
        for t in range(starts[k], stops[k]):
            prev, d0, d1, d2, d3 = sensitivity_step(u[t], prev, mL, cL, mR, cR, d0, d1, d2, d3)
            if t >= firsts[k]:
                v1, v2, v3, v4, v5 = d0, d1, d2, d3, y[at] - prev
                a[at, 0], a[at, 1], a[at, 2], a[at, 3], a[at, 4] = v1, v2, v3, v4, v5
                count += 1.0
                g01 += v1
                g02 += v2
                g03 += v3
                g04 += v4
                g05 += v5
                g11 += v1 * v1
                g12 += v1 * v2
                g13 += v1 * v3
                g14 += v1 * v4
                g15 += v1 * v5
                g22 += v2 * v2
                g23 += v2 * v3
                g24 += v2 * v4
                g25 += v2 * v5
                g33 += v3 * v3
                g34 += v3 * v4
                g35 += v3 * v5
                g44 += v4 * v4
                g45 += v4 * v5
                g55 += v5 * v5
                at += 1
    return np.array(
        (
            (count, g01, g02, g03, g04, g05),
            (g01, g11, g12, g13, g14, g15),
            (g02, g12, g22, g23, g24, g25),
            (g03, g13, g23, g33, g34, g35),
            (g04, g14, g24, g34, g44, g45),
            (g05, g15, g25, g35, g45, g55),
        )
    )


def _switched(uc: np.ndarray, params: BacklashParams) -> tuple[np.ndarray, np.ndarray]:
    """The output from rest at the origin (eq. 4-7, :func:`~online_backlash.model.simulate_switching`)
    and :func:`engaged_index`, from one simulation."""
    u = np.ascontiguousarray(uc, dtype=float)
    x, index = np.empty(u.size), np.empty(u.size, dtype=np.int64)
    _switched_loop(u, params.m_left, params.c_left, params.m_right, params.c_right, x, index)
    return x, index


@njit(cache=True, nogil=True)
def _switched_loop(u, mL, cL, mR, cR, x, index):  # pragma: no cover - compiled
    """:func:`~online_backlash.model.simulate_switching` from rest at the origin into ``x``, and into
    ``index`` the last sample up to each with ``f1 + f2 > 0`` (0 before the first)."""
    prev, last, a, b = 0.0, np.nan, 0.0, 0.0
    engaged = 0
    for t in range(u.size):
        prev, a, b = switching_step(u[t], last, prev, a, b, mL, cL, mR, cR)
        last = u[t]
        if a + b > 0:
            engaged = t
        x[t] = prev
        index[t] = engaged


def engaged_index(uc: np.ndarray, params: BacklashParams) -> np.ndarray:
    """For every sample, the index of the last sample with a flank engaged (eq. 5-6), itself if engaged."""
    return _switched(uc, params)[1]


def hold_columns(columns: np.ndarray, held: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``columns`` with the ``held`` ones (boolean per column) taken at ``index`` (see :func:`engaged_index`)."""
    if not np.any(held):
        return columns
    if np.all(held):
        return np.take(columns, index, axis=0)
    return _hold_some(
        np.asarray(columns, dtype=float), np.asarray(held, dtype=np.bool_), np.asarray(index, dtype=np.int64)
    )


@njit(cache=True)
def _hold_some(columns, held, index):  # pragma: no cover - compiled
    """``out[t, j] = columns[index[t], j]`` for the held columns ``j``, ``columns[t, j]`` for the others (one pass)."""
    n, k = columns.shape
    out = np.empty((n, k))
    for t in range(n):
        s = index[t]
        for j in range(k):
            out[t, j] = columns[s, j] if held[j] else columns[t, j]
    return out


def play_sensitivity(uc: np.ndarray, params: BacklashParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``dx/d(play)`` (both widths grown by half), the other directions (a constant, ``dx/dmL``,
    ``dx/dmR``) and the output ``x`` itself (eq. 1-3, from rest at the origin), from one simulation.

    Moving ``cL`` and ``cR`` the same way shifts both flank lines, which is (up to the slopes) a
    constant offset of ``x``; the constant stands for that direction, so the four columns span
    what the four parameters can do without a near-duplicate.
    """
    u = np.ascontiguousarray(uc, dtype=float)
    g, others, x = np.empty(u.size), np.empty((u.size, 3)), np.empty(u.size)
    _directions_loop(u, params.m_left, params.c_left, params.m_right, params.c_right, g, others, x)
    return g, others, x


@njit(cache=True, nogil=True)
def _directions_loop(u, mL, cL, mR, cR, g, others, x):  # pragma: no cover - compiled
    """:func:`play_sensitivity` from rest at the origin, into ``g``, ``others`` and ``x``, written as the
    model is simulated (the combinations of ``dx/d[mL, cL, mR, cR]`` of :data:`BACKLASH_DIRECTIONS`)."""
    prev = d0 = d1 = d2 = d3 = 0.0
    for t in range(u.size):
        prev, d0, d1, d2, d3 = sensitivity_step(u[t], prev, mL, cL, mR, cR, d0, d1, d2, d3)
        x[t] = prev
        others[t, 0], others[t, 1], others[t, 2] = 1.0, d0, d2
        g[t] = 0.5 * (d1 + d3)


#: The backlash's own directions ``[1, dx/dmL, dx/dmR, dx/d(play)]`` of :func:`play_sensitivity` (the
#: play's last: both widths grown by half), as combinations of the columns ``[1, dx/dmL, dx/dcL,
#: dx/dmR, dx/dcR, y - x]`` of :func:`_sensitivity_gram`'s Gram matrix (one column per direction)
BACKLASH_DIRECTIONS = np.array(
    [[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0.5], [0, 0, 1, 0], [0, 0, 0, 0.5], [0, 0, 0, 0]]
)


def fit_joint(
    uc: np.ndarray,
    yc: np.ndarray,
    columns: np.ndarray,
    start: BacklashParams,
    hold_play: float | None = None,
    held: np.ndarray | None = None,
) -> JointFit:
    """Minimise the simulation error of ``x(u) + columns @ coef`` over the backlash and ``coef``.

    ``uc`` and ``yc`` are the referred motor angle and the load angle in the estimator's centred
    frame (``VorosBacklash(origin="first")``: both minus their first sample). With
    ``hold_play`` the play ``cL + cR`` is held at that value (degrees). ``held`` marks the
    columns held through the dead band (input-side effects); the dead band is taken from the
    start parameters, refreshed once after the first search.
    """
    held = np.zeros(columns.shape[1], dtype=bool) if held is None else np.asarray(held, dtype=bool)
    parts = ColumnParts((np.asarray(columns, dtype=float),))
    return _fit_held(uc, yc, parts, held, start, hold_play, parts.held_at(held, engaged_index(uc, start)))


#: a part whose columns are zero outside at most this share of the samples is kept with its
#: :class:`Support` too (the dead band's motion: 3 % of the 10-minute bench log)
SPARSE_SHARE = 0.25


@dataclass(frozen=True)
class Support:
    """The samples outside which some columns are zero (``rows``, increasing) and the columns there
    (``values``, ``(rows.size, k)``): their cross-products and their products with coefficients
    read those rows only."""

    rows: np.ndarray
    values: np.ndarray

    @classmethod
    def of(cls, columns: np.ndarray, share: float = SPARSE_SHARE, rows: np.ndarray | None = None) -> Support | None:
        """The support of ``columns`` (``(n, k)``), or None when it is more than ``share`` of the rows;
        ``rows``: the rows with a value other than zero, when known (else found here)."""
        most = int(share * columns.shape[0])
        rows = nonzero_rows(columns, most) if rows is None else (rows if rows.size <= most else None)
        if rows is None:
            return None
        values = np.take(columns, rows, axis=0)
        values.flags.writeable = False
        return cls(rows, values)


@dataclass(frozen=True)
class ColumnParts:
    """Full-length columns side by side, kept as parts: one ``(n, k_i)`` array per part. The
    block is formed only where needed: whole (:meth:`dense`), at some rows (:meth:`at`), as its
    product with coefficients (:meth:`dot`), or as the cross-products least squares need
    (:meth:`gram`, :meth:`t_dot`: :class:`._normal_equations.Columns`, no block of all the parts).
    ``supports``: for every part its :class:`Support` or None; the products of a part with one read
    its support's rows only (empty: None for every part)."""

    parts: tuple[np.ndarray, ...]
    supports: tuple[Support | None, ...] = ()

    def _support(self, i: int) -> Support | None:
        return self.supports[i] if self.supports else None

    def _at_rows(self, i: int, rows: np.ndarray) -> np.ndarray:
        """Part ``i``'s columns at ``rows``."""
        mine = self._support(i)
        return mine.values if mine is not None and mine.rows is rows else np.take(self.parts[i], rows, axis=0)

    @property
    def shape(self) -> tuple[int, int]:
        n = self.parts[0].shape[0] if self.parts else 0
        return n, sum(c.shape[1] for c in self.parts)

    def dense(self) -> np.ndarray:
        """The whole block (a new array)."""
        return np.column_stack(self.parts) if self.parts else np.empty(self.shape)

    def block(self) -> np.ndarray:
        """The whole block: the one part itself when there is a single part (not a copy: read it only),
        else :meth:`dense`."""
        return self.parts[0] if len(self.parts) == 1 else self.dense()

    def at(self, rows: np.ndarray) -> np.ndarray:
        """The block's ``rows``."""
        out = np.empty((rows.size, self.shape[1]))
        j = 0
        for c in self.parts:
            k = c.shape[1]
            out[:, j : j + k] = np.take(c, rows, axis=0)
            j += k
        return out

    def gram(self) -> np.ndarray:
        """``B^T B`` of the block ``B``, part by part (a pair with a support over the rows of the smaller one)."""
        ends = np.cumsum([0, *(c.shape[1] for c in self.parts)])
        out = np.empty((ends[-1], ends[-1]))
        for i in range(len(self.parts)):
            for j in range(i, len(self.parts)):
                sparse = [m for m in (self._support(i), self._support(j)) if m is not None]
                if sparse:
                    rows = min(sparse, key=lambda m: m.rows.size).rows
                    product = self._at_rows(i, rows).T @ self._at_rows(j, rows)
                else:
                    product = self.parts[i].T @ self.parts[j]
                out[ends[i] : ends[i + 1], ends[j] : ends[j + 1]] = product
                out[ends[j] : ends[j + 1], ends[i] : ends[i + 1]] = product.T
        return out

    def t_dot(self, a: np.ndarray) -> np.ndarray:
        """``B^T a`` of the block ``B`` for ``a`` with a row per sample, part by part (a part with a
        support over its rows)."""
        out = []
        for i, c in enumerate(self.parts):
            mine = self._support(i)
            out.append(c.T @ a if mine is None else mine.values.T @ np.take(a, mine.rows, axis=0))
        return np.concatenate(out)

    def held_at(self, held: np.ndarray, index: np.ndarray) -> ColumnParts:
        """The parts with the ``held`` columns (boolean per column) taken at ``index``
        (:func:`hold_columns`); the others as they are."""
        if not np.any(held):
            return self
        out, supports, j = [], [], 0
        for i, c in enumerate(self.parts):
            mine = held[j : j + c.shape[1]]
            j += c.shape[1]
            if not np.any(mine):
                out.append(c)
                supports.append(self._support(i))
                continue
            out.append(hold_columns(c, mine, index))
            supports.append(None)  # held through the dead band: nonzero elsewhere too
        return ColumnParts(tuple(out), tuple(supports))

    def dot(self, coef: np.ndarray) -> np.ndarray:
        """The block times ``coef``, an ``n``-vector (a part with a support written at its rows only)."""
        out = np.zeros(self.shape[0])
        j = 0
        for i, c in enumerate(self.parts):
            k = c.shape[1]
            if np.any(coef[j : j + k]):
                mine = self._support(i)
                if mine is None:
                    out += c @ coef[j : j + k]
                else:
                    out[mine.rows] += mine.values @ coef[j : j + k]
            j += k
        return out


@dataclass(frozen=True)
class _HeldAt:
    """Columns with the ``held`` ones taken at ``index`` (:func:`hold_columns`), formed only where
    needed: at some rows (:meth:`rows`), or as the product with coefficients (:meth:`times`)."""

    columns: ColumnParts
    held: np.ndarray
    index: np.ndarray

    def rows(self, rows: np.ndarray) -> np.ndarray:
        out = self.columns.at(rows)
        if np.any(self.held):
            out[:, self.held] = self.columns.at(self.index[rows])[:, self.held]
        return out

    def times(self, coef: np.ndarray) -> np.ndarray:
        out = self.columns.dot(np.where(self.held, 0.0, coef))
        return out + np.take(self.columns.dot(np.where(self.held, coef, 0.0)), self.index) if np.any(self.held) else out


def _fit_held(
    uc: np.ndarray,
    yc: np.ndarray,
    columns: ColumnParts,
    held: np.ndarray,
    start: BacklashParams,
    hold_play: float | None,
    first: ColumnParts | None,
    rows: np.ndarray | None = None,
    planned: tuple[np.ndarray, np.ndarray] | None = None,
) -> JointFit:
    """:func:`fit_joint` given ``first``, the columns held through the dead band of ``start`` (the
    first search's; :func:`fit_guarded` hands the same to its second fit instead of forming it again).
    With ``rows`` the held columns are formed at those rows only (``first`` unused), and ``planned`` is
    :func:`_switched` of ``start`` (formed here if None)."""
    if rows is not None:
        switched = _switched(uc, start) if planned is None else planned
        fit = _fit_fixed_columns(uc, yc, _HeldAt(columns, held, switched[1]), start, hold_play, rows, switched)
        if np.any(held):
            switched = _switched(uc, fit.params)
            fit = _fit_fixed_columns(uc, yc, _HeldAt(columns, held, switched[1]), fit.params, hold_play, rows, switched)
        return fit
    assert first is not None
    fit = _fit_fixed_columns(uc, yc, first, start, hold_play)
    if np.any(held):  # once more through the dead band of the fitted model
        fit = _fit_fixed_columns(uc, yc, columns.held_at(held, engaged_index(uc, fit.params)), fit.params, hold_play)
    return fit


def _fit_fixed_columns(
    uc: np.ndarray,
    yc: np.ndarray,
    columns: ColumnParts | _HeldAt,
    start: BacklashParams,
    hold_play: float | None,
    rows: np.ndarray | None = None,
    switched: tuple[np.ndarray, np.ndarray] | None = None,
) -> JointFit:
    """:func:`fit_joint` for columns that do not depend on the backlash parameters.

    With ``rows`` (sample indices) the least squares, and the play's inflation and standard error,
    run over those samples only, the model simulated on their runs, each from a little before a flank
    engages ahead of it (:func:`_spans`, :func:`~online_backlash.model.backlash_sensitivity_spans`;
    ``switched``: :func:`_switched` of ``start``, when at hand); the residual and its RMS are the
    whole record's (one simulation of it at the end).

    The search is scipy's trust-region least squares on the variable-projection residual
    ``r = P (yc - x(p))`` (``P`` projects off ``columns``) with Jacobian ``-P dx/dp``. It uses them
    only through ``J^T J``, ``J^T r`` and ``|r|^2``, so each point is handed to it as a factor
    ``R`` of ``k + 1`` rows with ``R^T R`` the Gram matrix of ``P [dx/dp, yc - x]`` (``k`` searched
    parameters): the same steps and the same stopping as on all ``n`` rows, at ``O(n q k)``
    per point for ``q`` columns, with no ``n``-row SVD. The Gram matrix of ``[1, dx/dp, yc - x]`` is
    summed as the model is simulated (:func:`_sensitivity_gram`); the play guard's directions
    (:data:`BACKLASH_DIRECTIONS`) and the coefficients at the end come from it and from the columns'
    products with those rows. (trf's full-rank test of ``J`` scales with
    the row count: the two differ only for a Jacobian singular to about 1e-10 of its largest value.)
    """
    fitted: np.ndarray | ColumnParts
    if isinstance(columns, _HeldAt):
        assert rows is not None
        fitted, times = columns.rows(rows), columns.times
    else:
        assert rows is None
        fitted, times = columns, columns.dot  # the parts as they are: no block of all of them

    yc_fitted = yc if rows is None else yc[rows]
    u = np.ascontiguousarray(uc, dtype=float)
    if rows is None:  # one span: the whole record from rest at the origin
        spans = (np.zeros(1, np.int64), np.zeros(1, np.int64), np.full(1, u.size, np.int64), np.zeros(1))
    else:
        spans = _spans(rows, _switched(uc, start) if switched is None else switched)
    search = _ProjectedSearch(u, yc_fitted, spans, Projector(fitted), hold_play)
    proj, q, a = search.proj, search.q, search.a

    p0 = np.array([start.m_left, start.c_left, start.m_right, start.c_right])
    v0 = p0[:3] if hold_play is not None else p0
    cost0 = float(np.sum(search.residual(v0) ** 2))
    result = least_squares(search.residual, v0, jac=search.jacobian, x_scale="jac")
    v = result.x if np.sum(result.fun**2) < cost0 else v0
    p = search.unpack(v)
    params = BacklashParams(*p)
    ended = search.last.get(v.tobytes())
    # a: [dx/dp, yc - x] at the fit
    gram, cross = ended[2] if ended is not None and ended[2] is not None else search.point(p)
    coef = proj.coef_of(cross[:, 4]) if q else np.empty(0)
    if rows is None:
        left = a[:, 4] - times(coef) if q else a[:, 4].copy()
    else:  # the output over the whole record (the search simulated the runs of the rows fitted)
        left = yc - simulate_backlash(uc, params, 0.0)
        left = left - times(coef) if q else left
    left_fitted = left if rows is None else left[rows]
    inflation, play_std = _play_guard(gram, cross, proj, left_fitted)
    return JointFit(params, coef, left, inflation, play_std, hold_play is not None)


class _ProjectedSearch:
    """What :func:`_fit_fixed_columns` hands scipy's least squares at every point ``v`` of the searched
    parameters (``k`` of them: the four of eq. 1, or three with the play held at ``hold_play``, deg): a factor
    ``(r, J)`` of ``k + 1`` rows with the ``J^T J``, ``J^T r`` and ``|r|^2`` of the variable-projection problem
    on every fitted row. ``u``: the referred motor angle, centred (deg); ``yc_fitted``: the load angle at the
    rows fitted (deg); ``spans``: the runs the model is simulated on (:func:`_spans`); ``proj``: the
    projection off the columns."""

    def __init__(
        self,
        u: np.ndarray,
        yc_fitted: np.ndarray,
        spans: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        proj: Projector,
        hold_play: float | None,
    ) -> None:
        self.u, self.yc_fitted, self.spans, self.proj, self.hold_play = u, yc_fitted, spans, proj, hold_play
        self.n, self.q = yc_fitted.size, proj.columns.shape[1]
        # p = dp_dv @ v (+ the held play on cR)
        self.dp_dv = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0]]) if hold_play is not None else np.eye(4)
        self.k = k = self.dp_dv.shape[1]
        self.to_search = np.zeros((6, k + 1))  # [1, dx/dp, yc - x] -> [dx/dv, yc - x]
        self.to_search[1:5, :k], self.to_search[5, k] = self.dp_dv, 1.0
        # [dx/dp, yc - x] at the rows fitted, rewritten at every point (not allocated anew)
        self.a = np.empty((self.n, 5))
        # the last point asked for: its key, (r, J), and its point (None where invalid); ``a`` holds the
        # last valid point simulated, so a hit with a point is what ``a`` holds
        self.last: dict[bytes, tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray] | None]] = {}

    def unpack(self, v: np.ndarray) -> np.ndarray:
        """The four parameters of eq. (1) at the searched ``v``."""
        return self.dp_dv @ v + (np.array([0, 0, 0, self.hold_play]) if self.hold_play is not None else 0.0)

    def point(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The Gram matrix of ``[1, dx/dp, yc - x]`` at ``p`` and the columns' products ``C^T [dx/dp, yc - x]``
        (``a`` rewritten)."""
        starts, firsts, stops, x0s = self.spans
        p0, p1, p2, p3 = float(p[0]), float(p[1]), float(p[2]), float(p[3])
        gram = _sensitivity_gram(self.u, self.yc_fitted, p0, p1, p2, p3, starts, firsts, stops, x0s, self.a)
        return gram, self.proj.columns.t_dot(self.a) if self.q else np.empty((0, 5))

    def factor(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
        """``(r, J)`` of ``k + 1`` rows with the ``J^T J``, ``J^T r`` and ``|r|^2`` of the full problem,
        and :meth:`point` of ``v`` (None where invalid)."""
        key, k, last = v.tobytes(), self.k, self.last
        if key not in last:
            last.clear()
            p = self.unpack(v)
            if not (p[0] * p[2] > 0 and p[1] + p[3] >= 0):
                # the same cost as n rows of 1e6
                last[key] = (np.full(k + 1, 1e6 * np.sqrt(self.n / (k + 1))), np.zeros((k + 1, k)), None)
            else:
                gram, cross = self.point(p)
                to_search = self.to_search
                w, vec = np.linalg.eigh(self.proj.left_of(to_search.T @ gram @ to_search, cross @ to_search[1:]))
                r = np.sqrt(np.maximum(w, 0.0))[:, None] * vec.T  # r^T r = the Gram of P [dx/dv, yc - x]
                last[key] = (r[:, k], -r[:, :k], (gram, cross))
        return last[key]

    def residual(self, v: np.ndarray) -> np.ndarray:
        return self.factor(v)[0]

    def jacobian(self, v: np.ndarray) -> np.ndarray:
        return self.factor(v)[1]


def _play_guard(gram: np.ndarray, cross: np.ndarray, proj: Projector, left_fitted: np.ndarray) -> tuple[float, float]:
    """The play's variance inflation and standard error (deg) at the fit: its direction beyond the other backlash
    directions, and beyond the columns too (``gram``: the Gram matrix of ``[1, dx/dp, yc - x]`` at the fit;
    ``cross``: the columns' products with ``[dx/dp, yc - x]``; ``left_fitted``: the residual at the rows fitted)."""
    n, q = left_fitted.size, proj.columns.shape[1]
    basis_gram = BACKLASH_DIRECTIONS.T @ gram @ BACKLASH_DIRECTIONS
    g2 = float(basis_gram[3, 3])
    g_left_base = left_sum_of_squares(basis_gram)
    if q:
        basis_cross = np.column_stack((proj.columns.t_dot(np.ones(n)), cross[:, :4])) @ BACKLASH_DIRECTIONS[:5]
        g_left_joint = left_sum_of_squares(proj.left_of(basis_gram, basis_cross))
    else:
        g_left_joint = g_left_base
    inflation = (g_left_base / g2) / max(g_left_joint / g2, 1e-12)
    sigma2 = float(np.dot(left_fitted, left_fitted)) / effective_samples(left_fitted)
    play_std = float(np.sqrt(sigma2 / max(g_left_joint, 1e-300)))
    return float(inflation), play_std


def separable(fit: JointFit, start: BacklashParams) -> bool:
    """True when the joint fit pins the play down: inflation at most :data:`MAX_PLAY_INFLATION`
    and standard error at most :data:`MAX_PLAY_STD_SHARE` of the play."""
    return fit.play_inflation <= MAX_PLAY_INFLATION and fit.play_std_deg <= MAX_PLAY_STD_SHARE * max(
        fit.params.play, start.play
    )


def fit_guarded(
    uc: np.ndarray,
    yc: np.ndarray,
    columns: np.ndarray | ColumnParts,
    start: BacklashParams,
    held: np.ndarray | None = None,
    rows: np.ndarray | None = None,
    planned: tuple[np.ndarray, np.ndarray] | None = None,
) -> JointFit:
    """:func:`fit_joint` with the play free; if the play is not :func:`separable` from the columns, hold it at
    ``start.play``.

    The held fit keeps the variance inflation and standard error measured with the play free.
    With ``rows`` (sample indices: a screen of the record's cycles, :meth:`._folds.Folds.screen`)
    the least squares run over those samples only, the model simulated over the whole record; the
    residual (and its RMS) is the whole record's, so fits over the same rows compare on all samples.
    The columns may come as :class:`ColumnParts` (formed only at those rows, then). ``planned``:
    :func:`_switched` of ``start`` when at hand (the candidates of a round all start from its fit).
    """
    held = np.zeros(columns.shape[1], dtype=bool) if held is None else np.asarray(held, dtype=bool)
    parts = columns if isinstance(columns, ColumnParts) else ColumnParts((np.asarray(columns, dtype=float),))
    first = None
    if rows is None:
        first = (
            parts.held_at(held, engaged_index(uc, start) if planned is None else planned[1]) if np.any(held) else parts
        )
    planned = (
        _switched(uc, start) if rows is not None and planned is None else planned
    )  # the play-held fit starts there too
    fit = _fit_held(uc, yc, parts, held, start, None, first, rows, planned)
    if separable(fit, start):
        return fit
    kept = _fit_held(uc, yc, parts, held, start, start.play, first, rows, planned)
    return JointFit(kept.params, kept.coef, kept.residual_deg, fit.play_inflation, fit.play_std_deg, True)
