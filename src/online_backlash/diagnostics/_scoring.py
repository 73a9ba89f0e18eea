"""How much of a residual a set of regressor columns explains, in and out of sample.

The residual of a fitted backlash model is autocorrelated wherever something is missing, so
counting every sample as independent evidence would make everything look significant. The
criterion below therefore uses an effective sample size from the lag-1 autocorrelation
``rho`` of what is left after the columns are fitted, ``n_eff = n (1 - rho) / (1 + rho)``
(the AR(1) variance-inflation rule), in a Bayesian information criterion:

    delta_bic = n_eff ln(RSS_after / RSS_before) + q ln(n_eff)

``delta_bic < 0`` favours the columns; :data:`BIC_THRESHOLD` ("very strong" evidence on the
Kass-Raftery scale) keeps false alarms rare, :data:`MIN_GAIN` asks the columns to remove a
share of the residual's mean square that matters, and :data:`MIN_OWN_SHARE` refuses columns
that are nearly collinear with what the model already has.

Out of sample. The columns must also remove at least :data:`MIN_GAIN` of the residual's mean
square on reversal cycles they were not fitted on (blocked cross-validation over whole cycles,
:mod:`._folds`): for every fold, the nuisance columns with and without the candidate are fitted
on the other folds and the squared error on the fold is summed (``heldout_gain``); it gates
from :data:`MIN_FOLDS` folds on (two: a record of two cycles is held out one against the other).

Speed. Every quantity is a function of cross-products: the per-fold Gram matrices of the
nuisance columns and the residual are formed once per :class:`DetectionData` (summed over each
fold's contiguous reversal cycles, no column gathered into fold order), and a candidate only adds
its own products with them (``O(n q (p + q))`` for ``q`` columns and ``p`` nuisance columns)
before small solves (:mod:`._normal_equations`); :meth:`DetectionData.with_nuisance` writes the
new columns once into the block whose cross-products it forms (and hands on). The lag-1 autocorrelation of what is
left takes one compiled pass over one combination of the columns (``O(n (p + q))``). Nothing of
length ``n`` is refitted per candidate.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numba import njit

from ..model import BacklashParams
from ._folds import Folds, cycle_folds
from ._normal_equations import EigenSolve, fit_rss
from ._record_cache import RecordCache

#: delta_bic must fall below this for a term to count as detected
BIC_THRESHOLD = -10.0
#: and the term must remove at least this share of the residual's mean square, in sample and
#: on the held-out cycles
MIN_GAIN = 0.05
#: and every column must keep at least this share of its variance once the terms already in
#: the model are projected out; below it the term is nearly collinear with them and would only
#: trade amplitude with them (collinearity with the play is the joint fit's guard)
MIN_OWN_SHARE = 0.1
#: the held-out gain gates a term over at least this many folds (reversal cycles or time blocks)
MIN_FOLDS = 2


@dataclass(frozen=True)
class Score:
    """The fit of some columns to a residual (degrees).

    Attributes
    ----------
    rss_before, rss_after : float
        Residual sum of squares without and with the columns (plus the nuisance columns), deg^2.
    n_eff : float
        Effective number of independent samples.
    delta_bic : float
        Change of the information criterion (negative: the columns are worth their parameters).
    coef : array
        Least-squares coefficients of the columns (the nuisance coefficients dropped).
    own_share : float
        Smallest share of a column's variance left after projecting out the terms already added.
    heldout_gain : float
        Share of the held-out squared error the columns remove (blocked cross-validation over
        reversal cycles); NaN when not measured.
    """

    n_terms: int
    rss_before: float
    rss_after: float
    n_eff: float
    delta_bic: float
    coef: np.ndarray
    own_share: float = 1.0
    heldout_gain: float = float("nan")
    #: folds the held-out gain was measured over
    heldout_folds: int = 0

    @property
    def gain(self) -> float:
        """Share of the residual's sum of squares the columns remove, 0..1."""
        return 1.0 - self.rss_after / self.rss_before if self.rss_before > 0 else 0.0

    def significant(self, bic_threshold: float = BIC_THRESHOLD, min_gain: float = MIN_GAIN) -> bool:
        """True when the criterion, the size test (in sample and held out) and the collinearity test all pass."""
        gated = np.isfinite(self.heldout_gain) and self.heldout_folds >= MIN_FOLDS
        held = self.heldout_gain >= min_gain if gated else True
        return self.delta_bic < bic_threshold and self.gain >= min_gain and held and self.own_share >= MIN_OWN_SHARE


def effective_samples(residual: np.ndarray) -> float:
    """``n (1 - rho) / (1 + rho)`` with ``rho`` the lag-1 autocorrelation (clipped to [0, 0.9999])."""
    r = residual - residual.mean()
    denom = float(np.dot(r, r))
    rho = float(np.dot(r[1:], r[:-1]) / denom) if denom > 0 else 0.0
    return _n_eff(r.size, rho)


def _n_eff(n: int, rho: float) -> float:
    rho = min(max(rho, 0.0), 0.9999)
    return max(n * (1.0 - rho) / (1.0 + rho), 2.0)


class _Grams:
    """Cross-products of ``Z = [nuisance, residual]``: per fold and in total.

    A fold is a set of whole reversal cycles, each a contiguous run of samples
    (:attr:`._folds.Folds.segments`): its cross-products are summed over its runs, so no column is
    ever gathered into fold order.
    """

    def __init__(self, z: np.ndarray, folds: Folds, per_fold: np.ndarray | None = None) -> None:
        self.folds = folds
        #: the nuisance columns and the residual these are the cross-products of (set by DetectionData)
        self.nuisance: np.ndarray | None = None
        self.residual: np.ndarray | None = None
        #: ``z``'s rows: every sample, or for a screen (:meth:`._folds.Folds.screen`) its samples side by side
        self.z = z
        self.segments = folds.compact_segments if folds.screened else folds.segments
        self._bounds: np.ndarray | None = None  # the segments' row bounds, for the compiled lag product
        self.per_fold = self._per_fold(z, z) if per_fold is None else per_fold
        self.total = self.per_fold.sum(axis=0)
        self._baseline: Baseline | None = None

    def baseline(self) -> Baseline:
        """What the nuisance columns alone leave of the residual, in sample and on every held-out fold: the
        same for every candidate scored beyond them (formed once, on the first score that needs it)."""
        if self._baseline is None:
            self._baseline = Baseline(self.total, self.per_fold)
        return self._baseline

    def rows(self, a: np.ndarray) -> np.ndarray:
        """The rows of the full-length columns ``a`` that ``z`` holds (``a`` itself unless screened, or
        when it has those rows already)."""
        if not self.folds.screened or a.shape[0] == self.z.shape[0]:
            return a
        return np.take(a, self.folds.row_index, axis=0)

    def _per_fold(
        self, a: np.ndarray, b: np.ndarray, segments: Sequence[tuple[int, int, int]] | None = None
    ) -> np.ndarray:
        """``a^T b`` over the samples of every fold, ``(n_folds, a columns, b columns)``; ``segments``:
        the folds' runs of rows of ``a`` and ``b`` (default :attr:`segments`)."""
        out = np.zeros((self.folds.n_folds, a.shape[1], b.shape[1]))
        for k, start, stop in self.segments if segments is None else segments:
            out[k] += a[start:stop].T @ b[start:stop]
        return out

    def with_columns(self, parts: Sequence[np.ndarray]) -> _Grams:
        """The cross-products of ``[nuisance, x, residual]`` with ``x`` the ``parts`` side by side (each
        ``n x q_i``, full length), the parts written once, into the new block itself. They are formed over the whole
        block (one product per cycle, ``O(n (p + q)^2)``): the same numbers, bit for bit, as a
        :class:`DetectionData` made with these nuisance columns, and no slower than adding ``x``'s
        products to these (a rank-``q`` update: two products per cycle, and other rounding)."""
        m, p = self.z.shape[0], self.z.shape[1] - 1
        q = sum(a.shape[1] for a in parts)
        z = np.empty((m, p + q + 1))
        z[:, :p] = self.z[:, :p]
        j = p
        for a in parts:
            z[:, j : j + a.shape[1]] = self.rows(a)
            j += a.shape[1]
        z[:, j] = self.z[:, p]
        return _Grams(z, self.folds)

    def extended(
        self, x: np.ndarray, heldout: bool = True, support: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per-fold (empty without ``heldout``) and total Grams of ``W = [nuisance, x, residual]`` (residual
        last); ``x`` has the rows of ``z`` (see :meth:`rows`), or with ``support`` (the rows of ``z``,
        increasing, outside which ``x`` is zero) its rows there only: its products read those rows."""
        p, q, k = self.z.shape[1], x.shape[1], self.per_fold.shape[0]
        z = self.z if support is None else np.take(self.z, support, axis=0)  # the rows that carry x, side by side
        if not heldout:
            return np.empty((0, p + q, p + q)), _assemble(self.total, z.T @ x, x.T @ x)
        segments = (
            self.segments if support is None else [(f, *np.searchsorted(support, (a, b))) for f, a, b in self.segments]
        )
        zx, xx = self._per_fold(z, x, segments), self._per_fold(x, x, segments)
        out = np.empty((k, p + q, p + q))
        for j in range(k):
            out[j] = _assemble(self.per_fold[j], zx[j], xx[j])
        return out, out.sum(axis=0)

    def lag_product(self, x: np.ndarray, e: np.ndarray, support: np.ndarray | None = None) -> float:
        """``sum_t w(t+1) w(t)`` for ``w = W e``, ``W = [nuisance, x, residual]`` (``x`` with the rows of
        ``z``): the lag-1 product of a combination of W's columns, in one compiled pass (``O(n (p + q))``,
        no lag-1 Gram of ``x``); for a screen, within each of its cycles. ``x`` and ``support`` as for
        :meth:`extended` (``x``'s part added on those rows only: the same sums, bit for bit)."""
        p = self.z.shape[1] - 1
        ez, ex = np.concatenate((e[:p], e[-1:])), np.ascontiguousarray(e[p:-1])
        if self.folds.screened:
            if self._bounds is None:
                self._bounds = np.array([(a, b) for _, a, b in self.segments], dtype=np.int64).reshape(-1, 2)
            bounds = self._bounds
        else:
            bounds = np.array([[0, self.z.shape[0]]], dtype=np.int64)
        if support is None:
            return float(_lag_product_within(self.z, ez, x, ex, bounds))
        return float(_lag_product_within(self.z, ez, x, ex, bounds, np.ascontiguousarray(support, dtype=np.int64)))


@njit(cache=True)
def _lag_product_within(z, ez, x, ex, bounds, rows=None):  # pragma: no cover - compiled
    """``sum_t w(t) w(t-1)`` for ``w = z @ ez + x @ ex`` within each run of rows ``bounds[k, 0] ..
    bounds[k, 1] - 1``, summed per run and then in their order (one call, not one per run: a screen
    has thousands), without forming ``w``. With ``rows`` (increasing), ``x`` is zero outside them and
    holds its rows there only: its part is added on those rows (the same sums, bit for bit)."""
    total = 0.0
    at = 0
    for k in range(bounds.shape[0]):
        start, stop = bounds[k, 0], bounds[k, 1]
        if rows is not None:
            while at < rows.size and rows[at] < start:
                at += 1
        within = 0.0
        prev = 0.0
        for t in range(start, stop):
            w = 0.0
            for j in range(z.shape[1]):
                w += z[t, j] * ez[j]
            if rows is None:
                for j in range(x.shape[1]):
                    w += x[t, j] * ex[j]
            elif at < rows.size and rows[at] == t:
                for j in range(x.shape[1]):
                    w += x[at, j] * ex[j]
                at += 1
            if t > start:
                within += w * prev
            prev = w
        total += within
    return total


def _sorted_union(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """``np.union1d(a, b)`` of row numbers below ``n``, by marking them (one pass, no sort of the two)."""
    marked = np.zeros(n, dtype=bool)
    marked[a] = True
    marked[b] = True
    return np.flatnonzero(marked).astype(np.result_type(a, b), copy=False)


def _assemble(zz: np.ndarray, zx: np.ndarray, xx: np.ndarray) -> np.ndarray:
    """The Gram of ``[N, X, r]`` from the blocks of ``Z = [N, r]`` and ``X``."""
    p = zz.shape[0] - 1
    q = xx.shape[0]
    g = np.empty((p + q + 1, p + q + 1))
    sel = np.r_[0:p, p + q]  # positions of Z's columns in W
    g[np.ix_(sel, sel)] = zz
    g[np.ix_(sel, np.arange(p, p + q))] = zx
    g[np.ix_(np.arange(p, p + q), sel)] = zx.T
    g[p : p + q, p : p + q] = xx
    return g


def _test_sse(gram: np.ndarray, cols: np.ndarray, c: np.ndarray) -> float:
    """Squared error on a fold (its Gram ``gram``) of the residual minus ``W[:, cols] @ c``."""
    return float(gram[-1, -1] - 2.0 * c @ gram[cols, -1] + c @ gram[np.ix_(cols, cols)] @ c)


class Baseline:
    """What the nuisance columns of ``Z = [nuisance, residual]`` leave of the residual (deg^2), from the Grams of
    ``Z`` (``total``, and ``per_fold``): in sample (:attr:`rss`) and summed over the held-out folds, each fitted on
    the others (:attr:`heldout_sse`). A candidate's Gram holds ``Z``'s as its nuisance and residual rows and columns,
    value for value, so these are its ``rss_before`` and held-out reference as :func:`_score_grams` would form
    them."""

    def __init__(self, total: np.ndarray, per_fold: np.ndarray) -> None:
        self.total, self.per_fold = total, per_fold
        self.rss = fit_rss(total, np.arange(total.shape[0] - 1))[1]
        self._heldout_sse: float | None = None
        self._solvers: dict[bytes, EigenSolve] = {}

    def solver(self, cols: np.ndarray) -> EigenSolve:
        """The normal equations of the nuisance columns at ``cols`` (positions below the residual's), decomposed
        once: a candidate's Gram holds them value for value (its ``own_share`` basis)."""
        key = np.asarray(cols, dtype=np.intp).tobytes()
        if key not in self._solvers:
            self._solvers[key] = EigenSolve(self.total[np.ix_(cols, cols)])
        return self._solvers[key]

    @property
    def heldout_sse(self) -> float:
        if self._heldout_sse is None:
            self._heldout_sse = _heldout_sse(self.total, self.per_fold, np.arange(self.total.shape[0] - 1))
        return self._heldout_sse


def _heldout_sse(total: np.ndarray, per_fold: np.ndarray, cols: np.ndarray) -> float:
    """The squared error on every fold of the residual (last column) fitted on the columns ``cols`` of the
    other folds, summed over the folds."""
    sse = 0.0
    for g in per_fold:
        sse += _test_sse(g, cols, fit_rss(total - g, cols)[0])
    return sse


def _score_grams(
    per_fold: np.ndarray,
    total: np.ndarray,
    lag: Callable[[np.ndarray], float],
    n: int,
    p: int,
    terms: np.ndarray,
    baseline: Baseline | None = None,
) -> Score:
    """The :class:`Score` of the columns ``p .. end-1`` of W beyond its first ``p`` (nuisance) columns.

    ``lag(e)``: ``sum_t w(t+1) w(t)`` for ``w = W e`` (see :meth:`_Grams.lag_product`).
    ``terms``: positions of the nuisance columns that are a constant or terms already added (the
    basis of ``own_share``); column 0 must be a constant. ``baseline``: what the nuisance columns alone
    leave, when known (:meth:`_Grams.baseline`; formed here otherwise).
    """
    m = total.shape[0] - 1
    q = m - p
    base, full = np.arange(p), np.arange(m)
    rss0 = fit_rss(total, base)[1] if baseline is None else baseline.rss
    c, rss1 = fit_rss(total, full)
    rss0, rss1 = max(rss0, 0.0), max(rss1, 0.0)
    # lag-1 autocorrelation of what is left, e = r - W c (zero mean: the constant is a column)
    e = np.concatenate((-c, [1.0]))
    rho = lag(e) / rss1 if rss1 > 0 else 0.0
    n_eff = _n_eff(n, rho)
    xs = np.arange(p, m)
    own = 1.0
    if q:
        xx = total[np.ix_(xs, xs)]
        xt = total[np.ix_(xs, terms)]
        basis = EigenSolve(total[np.ix_(terms, terms)]) if baseline is None else baseline.solver(terms)
        left = np.diag(xx) - np.einsum("ij,ij->i", xt, _solve_many(basis, xt.T).T)
        mean = total[xs, 0] / n
        centred = np.diag(xx) - n * mean**2
        own = float(np.min(left / np.maximum(centred, 1e-300)))
    held = float("nan")
    if per_fold.shape[0] >= 2 and q:
        sse0 = _heldout_sse(total, per_fold, base) if baseline is None else baseline.heldout_sse
        sse1 = _heldout_sse(total, per_fold, full)
        held = 1.0 - sse1 / sse0 if sse0 > 0 else 0.0
    k = per_fold.shape[0]
    if rss0 <= 0:
        return Score(q, rss0, rss1, n_eff, 0.0, c[p:], own, held, k)
    delta = n_eff * np.log(max(rss1, 1e-300) / rss0) + q * np.log(n_eff)
    return Score(q, rss0, rss1, n_eff, float(delta), c[p:], own, held, k)


def _solve_many(equations: EigenSolve, rhs: np.ndarray) -> np.ndarray:
    return np.column_stack([equations(rhs[:, j]) for j in range(rhs.shape[1])]) if rhs.shape[1] else rhs


def score_columns(residual: np.ndarray, columns: np.ndarray, nuisance: np.ndarray | None = None) -> Score:
    """Least squares of ``residual`` on ``columns`` (n x q) plus ``nuisance`` columns, and its criterion.

    ``nuisance`` (default: an intercept; else its first column must be a constant) are
    directions the model can move anyway, here the sensitivities of the backlash output to its
    four parameters: a term is scored on what it explains beyond a shift of the backlash
    parameters, and can take back what the base fit let the play absorb. The held-out gain is
    measured over reversal cycles of the sample index (no angle is known here): time blocks.
    """
    r = np.asarray(residual, dtype=float)
    data = DetectionData(
        np.arange(r.size, dtype=float) * 0.0,
        np.arange(r.size, dtype=float),
        np.full(r.size, np.nan),
        r,
        1.0,
        1.0,
        nuisance,
    )
    return data.score(False, columns)


@dataclass(frozen=True)
class DetectionData:
    """What an effect's detector sees: the record and the current simulation residual.

    Angles in degrees (``u_deg`` is the motor angle referred to the load side), time in
    seconds, torque in N m (NaN where the log has none).
    """

    u_deg: np.ndarray
    time_s: np.ndarray
    torque_Nm: np.ndarray
    residual_deg: np.ndarray
    ratio: float
    sample_period_s: float
    #: columns the model can move anyway; the first must be a constant (default: just the constant)
    nuisance: np.ndarray | None = None
    #: for every sample, the last sample with a flank engaged by the current model (eq. 5-6)
    engaged_index: np.ndarray | None = None
    #: leading nuisance columns that are the backlash's own directions, the constant first (not
    #: counted in ``own_share``)
    n_backlash: int = 0
    #: the cross-validation folds (default: :func:`._folds.cycle_folds` of ``u_deg``)
    folds: Folds | None = None
    #: the current backlash model's output, eq. (1)-(3), deg (for effects defined on it)
    model_output_deg: np.ndarray | None = None
    #: the current backlash fit, eq. (1), in the frame of ``u_deg`` minus its first sample (for
    #: effects that run the model's switching functions themselves)
    backlash_params: BacklashParams | None = None
    #: the load reading's noise floor, deg (:func:`.residuals.noise_floor`; 0 when not known): what a
    #: detector may allow a fitted figure beyond a physical bound before it calls it unphysical
    noise_floor_deg: float = 0.0
    #: the cross-products of the nuisance columns and the residual (formed in __post_init__ unless
    #: given for exactly these nuisance columns, residual and folds, as :meth:`with_nuisance` does)
    grams: _Grams | None = field(default=None, repr=False, compare=False)
    #: columns built once per record and shared by the detectors (see :meth:`memo`; the loop
    #: passes one cache to every round)
    cache: RecordCache | None = field(default=None, repr=False, compare=False)
    #: the loop's store of the terms' columns over this record (:class:`._term_columns.TermColumns`), if any:
    #: see :meth:`record_columns`
    term_columns: Any = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        n = self.residual_deg.size
        given = self.grams
        if given is not None and not (
            given.nuisance is self.nuisance and given.residual is self.residual_deg and given.folds is self.folds
        ):
            given = None  # made for other data (a replace() of something else): formed afresh
        if self.folds is None:
            object.__setattr__(self, "folds", cycle_folds(self.u_deg))
        assert self.folds is not None
        if given is None:
            base = np.ones((n, 1)) if self.nuisance is None else np.asarray(self.nuisance, dtype=float).reshape(n, -1)
            z = np.column_stack((base, self.residual_deg))
            given = _Grams(np.take(z, self.folds.row_index, axis=0) if self.folds.screened else z, self.folds)
            given.nuisance, given.residual = base, self.residual_deg
        object.__setattr__(self, "nuisance", given.nuisance)
        object.__setattr__(self, "grams", given)
        if self.cache is None:
            object.__setattr__(self, "cache", RecordCache())

    @classmethod
    def stacked(cls, nuisance_parts: Sequence[np.ndarray], residual_deg: np.ndarray, **fields: Any) -> DetectionData:
        """The data with the nuisance columns ``nuisance_parts`` side by side (a 1-D part is one column),
        written once into the block their cross-products are formed from (no intermediate copies of
        full-length columns; for a screen, its rows only); ``fields`` are the other fields (``u_deg``,
        ``time_s``, ...)."""
        n = residual_deg.size
        folds = fields.pop("folds", None)
        folds = cycle_folds(fields["u_deg"]) if folds is None else folds
        parts = [np.asarray(a, dtype=float).reshape(n, -1) for a in nuisance_parts]
        p = sum(a.shape[1] for a in parts)
        z = np.empty((folds.rows, p + 1))
        j = 0
        for a in [*parts, residual_deg[:, None]]:
            z[:, j : j + a.shape[1]] = np.take(a, folds.row_index, axis=0) if folds.screened else a
            j += a.shape[1]
        grams = _Grams(z, folds)
        grams.nuisance, grams.residual = z[:, :p], residual_deg
        return cls(residual_deg=residual_deg, nuisance=grams.nuisance, folds=folds, grams=grams, **fields)

    def can_memo(self, key: Hashable, nbytes: int) -> bool:
        """True when :meth:`memo` keeps (or has kept) an array of ``nbytes`` for ``key``."""
        assert self.cache is not None
        return self.cache.can_hold(key, nbytes)

    def memo(self, key: Hashable, build: Callable[[], np.ndarray], held: bool = False) -> np.ndarray:
        """``build()``, computed once per record for ``key`` (a function of ``u_deg``, ``time_s`` and
        ``torque_Nm``, and with ``held`` of the engaged samples too; anything else it depends on,
        such as the ratio, belongs in ``key``); read-only."""
        assert self.cache is not None
        sources: tuple[object, ...] = (self.u_deg, self.time_s, self.torque_Nm)
        return self.cache.get(key, (*sources, self.engaged_index, self.folds) if held else sources, build)

    def record_columns(self, effect: Any) -> np.ndarray:
        """``effect.clone().terms(u_deg, time_s, torque_Nm)``, the effect's columns over the whole record (read-only):
        from :attr:`term_columns` when it holds this very record (the loop's fits then find them built)."""
        built = self.term_columns
        same = built is not None and built.u_deg is self.u_deg and built.time_s is self.time_s
        if same and built.torque_Nm is self.torque_Nm:
            return built.get(effect)
        return effect.clone().terms(self.u_deg, self.time_s, self.torque_Nm)

    @property
    def _cross(self) -> _Grams:
        assert self.grams is not None
        return self.grams

    @property
    def engaged(self) -> np.ndarray:
        """True where the current model has a flank engaged (all True when not known)."""
        n = self.residual_deg.size
        return np.ones(n, dtype=bool) if self.engaged_index is None else self.engaged_index == np.arange(n)

    @property
    def scored_rows(self) -> np.ndarray | None:
        """The samples the scores use: None for all of them, else a screen's (:meth:`._folds.Folds.screen`)."""
        assert self.folds is not None
        return self.folds.row_index if self.folds.screened else None

    @property
    def needed_rows(self) -> np.ndarray | None:
        """For a screen, every sample a score reads, itself or held through the dead band (the scored
        rows and their last engaged samples, sorted); None when every sample is scored."""
        rows, index = self.scored_rows, self.engaged_index
        if rows is None or index is None:
            return rows
        return self.memo(
            ("rows scored and held from",), lambda: _sorted_union(rows, index[rows], index.size), held=True
        )

    def scored(self, columns: np.ndarray) -> np.ndarray:
        """The rows of full-length ``columns`` that the scores use (``columns`` itself unless screened):
        :meth:`score` takes either."""
        return self._cross.rows(np.asarray(columns, dtype=float).reshape(self.residual_deg.size, -1))

    def hold(self, columns: np.ndarray) -> np.ndarray:
        """Input-side columns (a row per sample) held through the dead band of the current model (see
        :mod:`.joint`); for a screen, the rows it scores only (as :meth:`scored` gives them)."""
        columns = np.asarray(columns, dtype=float).reshape(self.residual_deg.size, -1)
        if self.engaged_index is None:
            return self.scored(columns)
        rows = self.scored_rows
        return np.take(columns, self.engaged_index if rows is None else self.engaged_index[rows], axis=0)

    def _own_share_basis(self, p: int) -> np.ndarray:
        """Positions among ``p`` nuisance columns of the constant and the terms already added: what a
        candidate's ``own_share`` is measured against (the backlash's other directions left out)."""
        return np.r_[0, np.arange(max(self.n_backlash, 1), p)] if self.n_backlash else np.arange(p)

    def score(self, input_side: bool, columns: np.ndarray, heldout: bool = True) -> Score:
        """The :class:`Score` of ``columns`` on this residual beyond the nuisance columns
        (held through the dead band when ``input_side``). Without ``heldout`` the cross-validation
        is skipped (``heldout_gain`` NaN; a cheaper screening score). ``columns`` has a row per sample
        or, not held, the rows :meth:`scored` gives."""
        x = self.hold(columns) if input_side else np.asarray(columns, dtype=float)
        x = self._cross.rows(x.reshape(x.shape[0], -1))
        per_fold, total = self._cross.extended(x, heldout)
        assert self.nuisance is not None
        p = self.nuisance.shape[1]
        terms = self._own_share_basis(p)
        assert self.folds is not None
        baseline = self._cross.baseline()
        return _score_grams(
            per_fold, total, lambda e: self._cross.lag_product(x, e), self.folds.rows, p, terms, baseline
        )

    def score_subsets(
        self,
        columns: np.ndarray,
        subsets: Sequence[Sequence[int]],
        heldout: bool = True,
        support: np.ndarray | None = None,
    ) -> list[Score]:
        """:meth:`score` of ``columns[:, s]`` (not held) for every list of column positions ``s`` in
        ``subsets``, from one set of cross-products of all the columns: each subset's normal equations,
        in sample and per fold, are a slice of them (``O(n q (p + q))`` once for ``q`` columns, not per
        subset), and its lag-1 product is the pass over all the columns with the others' weights 0.
        ``columns`` has a row per sample or the rows :meth:`scored` gives; ``support``: the rows of those
        (increasing) outside which ``columns`` are zero, if known (their products read those rows only:
        the dead band's motion)."""
        x = self._cross.rows(np.asarray(columns, dtype=float).reshape(columns.shape[0], -1))
        if support is not None:
            x = np.ascontiguousarray(np.take(x, support, axis=0))
        per_fold, total = self._cross.extended(x, heldout, support)
        assert self.nuisance is not None and self.folds is not None
        p, q = self.nuisance.shape[1], x.shape[1]
        terms = self._own_share_basis(p)
        out = []
        for subset in subsets:
            at = p + np.asarray(subset, dtype=np.intp)
            keep = np.r_[np.arange(p), at, p + q]  # [nuisance, the subset's columns, residual]

            def lag(e: np.ndarray, at: np.ndarray = at) -> float:
                whole = np.zeros(p + q + 1)
                whole[:p], whole[at], whole[-1] = e[:p], e[p:-1], e[-1]
                return self._cross.lag_product(x, whole, support)

            out.append(
                _score_grams(
                    per_fold[:, keep][:, :, keep],
                    total[np.ix_(keep, keep)],
                    lag,
                    self.folds.rows,
                    p,
                    terms,
                    self._cross.baseline(),
                )
            )
        return out

    def scores_left_out(
        self,
        groups: Sequence[np.ndarray],
        coefs: Sequence[np.ndarray],
        extra: np.ndarray | None = None,
        support: np.ndarray | None = None,
    ) -> list[Score]:
        """For every group of nuisance columns (positions ``groups[i]``, after the backlash's own
        ``n_backlash``), the :class:`Score` of those columns with their part ``W[:, groups[i]] @
        coefs[i]`` put back into the residual and the other nuisance columns kept: what :meth:`score`
        gives on data made with the others as nuisance and that residual, from this data's one set of
        cross-products (each case's Gram is ``M^T G M`` for the matrix ``M`` that forms its columns
        from these, per fold; its lag-1 product a pass over these columns with the weights ``M e``).
        ``extra``: more nuisance columns, after these (positions counted on from them), with the rows
        :meth:`score` takes, or with ``support`` (increasing) their rows there only, zero elsewhere (the
        dead band's motion): their cross-products read those rows only (:meth:`_Grams.extended`)."""
        assert self.nuisance is not None and self.folds is not None
        g = self._cross
        if extra is None:
            per_fold_all, total_all, extra = g.per_fold, g.total, np.empty((g.z.shape[0], 0))
        else:
            per_fold_all, total_all = g.extended(extra, True, support)
        p = total_all.shape[0] - 1
        out = []
        for group, coef in zip(groups, coefs):
            group = np.asarray(group, dtype=np.intp)
            kept = np.setdiff1d(np.arange(p), group)
            m = np.zeros(
                (p + 1, p + 1)
            )  # columns of [kept, group, residual + W[:, group] @ coef] from [nuisance, extra, residual]
            m[kept, np.arange(kept.size)] = 1.0
            m[group, kept.size + np.arange(group.size)] = 1.0
            m[p, p] = 1.0
            m[group, p] = coef
            per_fold = np.einsum("ji,fjk,kl->fil", m, per_fold_all, m)
            total = m.T @ total_all @ m
            q = kept.size
            terms = self._own_share_basis(q)

            def lag(e: np.ndarray, m: np.ndarray = m, extra: np.ndarray = extra) -> float:
                return g.lag_product(extra, m @ e, support)

            out.append(_score_grams(per_fold, total, lag, self.folds.rows, q, terms))
        return out

    def with_nuisance(self, *columns: np.ndarray) -> DetectionData:
        """The same data with ``columns`` (one or more arrays, side by side; each a row per sample or the
        rows :meth:`scored` gives) added to the nuisance columns (written once into the block their
        cross-products are formed from; handed on, not formed again)."""
        grams = self._cross.with_columns([np.asarray(c, dtype=float).reshape(len(c), -1) for c in columns])
        grams.nuisance = grams.z[:, :-1]  # a view: the nuisance columns are not copied twice
        grams.residual = self.residual_deg  # so that __post_init__ takes these grams as they are
        return replace(self, nuisance=grams.nuisance, grams=grams)

    def fold_info(self) -> dict[str, object]:
        """How the held-out cycles were chosen (for the evidence)."""
        assert self.folds is not None
        return self.folds.as_dict()


@dataclass(frozen=True)
class Detection:
    """An effect configured to fit the residual, its score, and a sentence of evidence."""

    effect: object
    score: Score
    evidence: str
    #: other explanations of the same part of the residual (reported as not separable)
    rivals: tuple[str, ...] = ()
    #: the effect's columns on every sample of the record (its ``terms`` on a fresh stream), when the
    #: detector formed them anyway (None otherwise): the loop keeps them for its fits
    columns: np.ndarray | None = field(default=None, repr=False, compare=False)
    #: the rows of ``columns`` with a value other than zero (increasing), when the detector knows them
    nonzero_rows: np.ndarray | None = field(default=None, repr=False, compare=False)


def best_detection(candidates: list[Detection]) -> Detection | None:
    """The candidate with the lowest information criterion, or None for an empty list."""
    return min(candidates, key=lambda d: d.score.delta_bic, default=None)
