"""Wear trend as a local linear trend: a Kalman filter and RTS smoother over the estimates (filterpy).

The state at use ``x`` (operating hours) is ``s = [level, rate]``: the true play (degrees) and
its wear rate (degrees per operating hour). Between estimates ``dx`` apart the rate takes a
random walk (an integrated random walk for the level)::

    s_k = F s_{k-1} + w,   F = [[1, dx], [0, 1]],   Q = q [[dx^3/3, dx^2/2], [dx^2/2, dx]]

and each stored estimate ``z_k`` of the recursive estimator is a lagged, noisy reading of it::

    z_k = level(x_k - lag_k) + v_k = [1, -lag_k] s_k + v_k,   var(v_k) = backlash_std_deg_k^2 + (g * m)^2

The lag: a recursive estimator with exponential forgetting (``memory_reversals`` per reversal,
``memory_s`` per second of motion) reports a weighted mean of the play over its memory, whose
mean age is the memory; on a play growing at ``rate`` it reads ``rate * lag`` low. In
operating hours ``lag = 1 / (1 / (memory_s / 3600) + 1 / (memory_reversals * hours per
reversal))`` (:func:`estimator_lag_hours`); with ``H = [1, -lag]`` the filter corrects the
level for it and the lag's effect on the uncertainty is in the covariance.

Process noise and measurement noise: ``q = (f * rate_scale)^2 / span`` (the rate may drift by
a fraction ``f`` of its typical size, one standard deviation, over the span of the history)
and a noise floor ``g * m`` added to each estimate's own standard deviation (``m`` the median
std; the estimator's std is a lower bound: it is tiny while the estimator settles, and
consecutive estimates of a recursive estimator share most of their data) are chosen by maximum
likelihood over the grid :data:`DRIFT_FRACTIONS` x :data:`NOISE_FLOORS` (the first two
innovations, which depend on the diffuse start, are left out of the likelihood). Correlated
scatter that the floor does not explain is read as movement of the level (a larger ``q``):
the bands then widen rather than lie.

The forecast extrapolates the filtered state at the last estimate: ``level + rate h`` with
variance ``[1, h] P [1, h]' + q h^3 / 3``; its interval is where ``mean +- z sd`` reaches the
limit. Filtering: filterpy's :class:`~filterpy.kalman.KalmanFilter` (``predict``/``update`` with
per-step ``F``, ``Q``, ``H``, ``R``); smoothing: its ``rts_smoother`` (Rauch, Tung and Striebel 1965).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy import stats

from ..errors import InvalidParameterError

#: Grid of ``f`` (rate drift over the history's span, as a fraction of the rate scale).
DRIFT_FRACTIONS = (0.0, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0)
#: Grid of ``g`` (noise floor, in units of the median std of the estimates).
NOISE_FLOORS = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0)
#: Above this many estimates the filter runs on means of consecutive groups.
MAX_KALMAN_POINTS = 400
#: Smallest measurement standard deviation, degrees (a zero std would pin the filter).
MIN_STD_DEG = 1e-6


def estimator_lag_hours(
    memory_reversals: float | None, memory_s: float | None, hours_per_reversal: float | None
) -> float:
    """Mean age of a recursive estimator's memory in operating hours (0 without forgetting).

    ``memory_reversals`` and ``memory_s`` are :class:`~online_backlash.estimators.BacklashRLS`'s
    settings; ``hours_per_reversal`` the gearbox's use per reversal (None: unknown, that memory
    is ignored). Forgetting rates add: ``1 / lag = sum of 1 / memory``.

    >>> estimator_lag_hours(5.0, None, 0.002)
    0.01
    """
    rates = []
    if memory_s:
        rates.append(3600.0 / memory_s)
    if memory_reversals and hours_per_reversal and hours_per_reversal > 0:
        rates.append(1.0 / (memory_reversals * hours_per_reversal))
    return 1.0 / sum(rates) if rates else 0.0


def _transition(dx: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """``F`` and ``Q`` of the local linear trend over ``dx`` (see the module docstring)."""
    return np.array([[1.0, dx], [0.0, 1.0]]), q * np.array([[dx**3 / 3.0, dx**2 / 2.0], [dx**2 / 2.0, dx]])


@dataclass
class _FilterRun:
    xs: np.ndarray  # filtered means, (n, 2, 1)
    ps: np.ndarray  # filtered covariances, (n, 2, 2)
    fs: np.ndarray  # fs[k]: transition from k-1 to k
    qs: np.ndarray
    log_likelihood: float


def _run_filter(x: np.ndarray, z: np.ndarray, std: np.ndarray, lag: np.ndarray, q: float, floor: float) -> _FilterRun:
    n = x.size
    kf = KalmanFilter(dim_x=2, dim_z=1)
    span_z = float(np.ptp(z)) + float(np.max(std))
    kf.x = np.array([[z[0]], [0.0]])
    kf.P = np.diag([1e4 * span_z**2, 1e4 * (span_z / float(np.ptp(x))) ** 2])  # diffuse start
    xs, ps = np.empty((n, 2, 1)), np.empty((n, 2, 2))
    fs, qs = np.empty((n, 2, 2)), np.empty((n, 2, 2))
    fs[0], qs[0] = np.eye(2), np.zeros((2, 2))
    log_likelihood = 0.0
    for k in range(n):
        if k:
            fs[k], qs[k] = _transition(float(x[k] - x[k - 1]), q)
            kf.predict(F=fs[k], Q=qs[k])
        kf.update(z[k], R=std[k] ** 2 + floor**2, H=np.array([[1.0, -lag[k]]]))
        if k >= 2:  # log N(y; 0, S) of the scalar innovation (kf.log_likelihood, without scipy's overhead)
            log_likelihood -= 0.5 * (math.log(2.0 * math.pi * kf.S[0, 0]) + kf.y[0, 0] ** 2 / kf.S[0, 0])
        xs[k], ps[k] = kf.x, kf.P
    return _FilterRun(xs, ps, fs, qs, log_likelihood)


@dataclass(frozen=True, eq=False)
class KalmanTrend:
    """A smoothed local linear trend of the play against use, with its forecast.

    Attributes
    ----------
    x : array
        Use at the (possibly grouped) estimates, operating hours.
    level_deg, rate_deg_per_x : array
        Smoothed play (lag-corrected, degrees) and wear rate (degrees per unit of ``x``) there.
    cov : array
        Smoothed state covariances, shape ``(n, 2, 2)``.
    q : float
        Process noise density on the rate, deg^2 per unit of ``x``^3.
    noise_floor_deg : float
        The noise floor ``g * m`` added (in quadrature) to each estimate's std, degrees.
    lag_x : float
        The estimator's lag at the last estimate, units of ``x``.
    measurement_var_deg2 : float
        Typical variance of one estimate about the lagged level (median ``std^2 + floor^2``), deg^2.
    log_likelihood : float
        Of the chosen ``(q, floor)``.
    confidence : float
        Of the bands and intervals.
    """

    x: np.ndarray
    level_deg: np.ndarray
    rate_deg_per_x: np.ndarray
    cov: np.ndarray
    q: float
    noise_floor_deg: float
    lag_x: float
    measurement_var_deg2: float
    log_likelihood: float
    confidence: float
    method: str = "kalman"

    @property
    def n_points(self) -> int:
        return int(self.x.size)

    @property
    def _z(self) -> float:
        return float(stats.norm.ppf(0.5 + self.confidence / 2))

    @property
    def slope(self) -> float:
        """The wear rate now (at the last estimate), degrees per unit of ``x``."""
        return float(self.rate_deg_per_x[-1])

    @property
    def slope_low(self) -> float:
        return self.slope - self._z * math.sqrt(self.cov[-1, 1, 1])

    @property
    def slope_high(self) -> float:
        return self.slope + self._z * math.sqrt(self.cov[-1, 1, 1])

    def parameters(self) -> dict:
        """The fitted numbers (not the arrays) as a JSON-ready dict."""
        return {
            "slope": self.slope,
            "slope_low": self.slope_low,
            "slope_high": self.slope_high,
            "level_deg_now": float(self.level_deg[-1]),
            "q": self.q,
            "noise_floor_deg": self.noise_floor_deg,
            "lag_x": self.lag_x,
            "log_likelihood": self.log_likelihood,
            "confidence": self.confidence,
            "n_points": self.n_points,
        }

    def _mean_var(self, x: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Level and its variance at ``x``: smoothed inside the data, extrapolated outside."""
        shape = np.shape(x)
        x = np.atleast_1d(np.asarray(x, dtype=float))
        mean = np.interp(x, self.x, self.level_deg)
        var = np.interp(x, self.x, self.cov[:, 0, 0])
        for end, outside in ((0, x < self.x[0]), (-1, x > self.x[-1])):
            h = x[outside] - self.x[end]
            p = self.cov[end]
            mean[outside] = self.level_deg[end] + self.rate_deg_per_x[end] * h
            var[outside] = p[0, 0] + 2 * h * p[0, 1] + h**2 * p[1, 1] + self.q * np.abs(h) ** 3 / 3.0
        return mean.reshape(shape), var.reshape(shape)

    def line(self, x: np.ndarray | float) -> np.ndarray | float:
        """The play (lag-corrected level) at ``x``, degrees."""
        return self._mean_var(x)[0]

    def band(self, x: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Confidence band of the level at ``x``, degrees."""
        mean, var = self._mean_var(x)
        half = self._z * np.sqrt(var)
        return mean - half, mean + half

    def prediction_band(self, x: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Where a new estimate at ``x`` falls: the lagged level ``+- z sqrt(var + measurement var)``."""
        mean, var = self._mean_var(x)
        rate = np.interp(np.asarray(x, dtype=float), self.x, self.rate_deg_per_x)
        centre = mean - rate * self.lag_x
        half = self._z * np.sqrt(var + self.measurement_var_deg2)
        return centre - half, centre + half

    def crossing(self, limit_deg: float) -> tuple[float, float, float]:
        """``x`` where the level (and the band's upper and lower edges) reach ``limit_deg``.

        Past the last estimate: the first ``x`` where each reaches the limit (``inf`` if never,
        searched up to 1000 spans ahead). If the level is already above the limit at the last
        estimate: the start of its trailing run above the limit (the first estimate's ``x``
        if it was always above).
        """
        span = float(self.x[-1] - self.x[0]) or 1.0
        future = self.x[-1] + span * np.geomspace(1e-6, 1e3, 4000)
        grid = np.concatenate((self.x, future))
        mean, var = self._mean_var(grid)
        half = self._z * np.sqrt(var)
        n = self.x.size
        return (
            _reach(grid, mean, limit_deg, n),
            _reach(grid, mean + half, limit_deg, n),
            _reach(grid, mean - half, limit_deg, n),
        )


def _reach(grid: np.ndarray, curve: np.ndarray, limit: float, n_data: int) -> float:
    """First reach of ``limit`` after the data, or the start of the trailing run above it inside."""
    if curve[n_data - 1] >= limit:
        below = np.flatnonzero(curve[:n_data] < limit)
        if below.size == 0:
            return float(grid[0])
        i = int(below[-1])
    else:
        above = np.flatnonzero(curve[n_data:] >= limit)
        if above.size == 0:
            return math.inf
        i = n_data + int(above[0]) - 1
    x0, x1, c0, c1 = grid[i], grid[i + 1], curve[i], curve[i + 1]
    return float(x0 + (limit - c0) / (c1 - c0) * (x1 - x0))


def _group(x: np.ndarray, *columns: np.ndarray, max_points: int) -> list[np.ndarray]:
    """Means of ``max_points`` groups of consecutive points (the std column: root mean square)."""
    if x.size <= max_points:
        return [x, *columns]
    groups = np.array_split(np.arange(x.size), max_points)
    return [np.array([np.mean(c[g]) for g in groups]) for c in (x, *columns)]


def fit_kalman_trend(
    x: np.ndarray,
    backlash_deg: np.ndarray,
    backlash_std_deg: np.ndarray,
    lag_x: np.ndarray | float = 0.0,
    confidence: float = 0.95,
    drift_fractions: tuple[float, ...] = DRIFT_FRACTIONS,
    noise_floors: tuple[float, ...] = NOISE_FLOORS,
) -> KalmanTrend | None:
    """Fit the local linear trend (module docstring); None with under 3 usable estimates.

    Parameters
    ----------
    x : array
        Use at each estimate (operating hours), non-decreasing.
    backlash_deg, backlash_std_deg : array
        The estimates and their standard deviations, degrees; an estimate with a non-finite
        value or std is left out.
    lag_x : float or array
        The recursive estimator's lag at each estimate, units of ``x``
        (:func:`estimator_lag_hours`).
    confidence : float
        Of the bands and intervals, in (0, 1).
    drift_fractions, noise_floors : tuple of float
        The grids of ``f`` and ``g`` searched by maximum likelihood (one value each: fixed).

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> x = np.linspace(0.0, 100.0, 60)
    >>> z = 0.2 + 0.001 * x + rng.normal(0.0, 0.002, x.size)
    >>> trend = fit_kalman_trend(x, z, np.full(x.size, 0.002))
    >>> round(trend.slope, 4), round(float(trend.line(100.0)), 3)
    (0.001, 0.3)
    """
    if not 0 < confidence < 1:
        raise InvalidParameterError(f"confidence must be in (0, 1), got {confidence!r}")
    x = np.asarray(x, dtype=float)
    z = np.asarray(backlash_deg, dtype=float)
    std = np.asarray(backlash_std_deg, dtype=float)
    lag = np.broadcast_to(np.asarray(lag_x, dtype=float), x.shape)
    keep = np.isfinite(x) & np.isfinite(z) & np.isfinite(std) & np.isfinite(lag)
    order = np.argsort(x[keep], kind="stable")
    columns = [c[keep][order] for c in (x, z, std**2, lag)]
    x, z, var, lag = _group(*columns[:1], *columns[1:], max_points=MAX_KALMAN_POINTS)
    std = np.maximum(np.sqrt(var), MIN_STD_DEG)
    if x.size < 3 or np.ptp(x) == 0:
        return None
    span = float(np.ptp(x))
    rate_scale = max(abs(float(np.polyfit(x, z, 1)[0])), float(np.median(std)) / span)
    best: tuple[float, float, float, _FilterRun] | None = None
    if min(drift_fractions, default=-1.0) < 0 or min(noise_floors, default=-1.0) < 0:  # also refuses an empty grid
        raise InvalidParameterError(
            f"drift fractions and noise floors must be >= 0, got {drift_fractions!r}, {noise_floors!r}"
        )
    median_std = float(np.median(std))
    for f in drift_fractions:
        q = (f * rate_scale) ** 2 / span
        for g in noise_floors:
            run = _run_filter(x, z, std, lag, q, g * median_std)
            if best is None or run.log_likelihood > best[2]:
                best = (q, g * median_std, run.log_likelihood, run)
    if best is None:  # not reached: the grids are not empty
        raise InvalidParameterError("empty grid of drift fractions or noise floors")
    q, floor, log_likelihood, run = best
    kf = KalmanFilter(dim_x=2, dim_z=1)
    smoothed, cov, _, _ = kf.rts_smoother(run.xs, run.ps, run.fs, run.qs)
    return KalmanTrend(
        x=x,
        level_deg=smoothed[:, 0, 0].copy(),
        rate_deg_per_x=smoothed[:, 1, 0].copy(),
        cov=cov,
        q=q,
        noise_floor_deg=floor,
        lag_x=float(lag[-1]),
        measurement_var_deg2=float(np.median(std**2 + floor**2)),
        log_likelihood=log_likelihood,
        confidence=confidence,
    )
