"""Wear trend and forecast: a robust line through backlash against use, and when it crosses a limit.

The trend is the Theil-Sen line (Sen 1968, the form of :func:`scipy.stats.theilslopes`): the
slope is the median of the slopes between all pairs of estimates, so a minority of bad estimates
(a log that barely reversed, an estimator still settling) cannot tilt it. Given each estimate's
standard deviation, the median is a weighted one (Sievers 1978): a pair weighs ``w_i w_j`` with
``w = 1 / (std^2 + floor^2)``, where ``floor^2`` is the scatter about the unweighted line that
the stated stds do not explain (a DerSimonian-Laird moment estimate), so an estimate from a log
that showed little weighs less, while estimates of equal uncertainty weigh the same however much
data their log held; the slope interval takes the same ranks of the weighted distribution of
the pair slopes as Sen's (1968, eq. 2.6) of the unweighted one (with equal weights both are
scipy's). Its band is the set of lines that pass within ``level_halfwidth_deg`` of the centre
point ``(median x, line at median x)`` with a slope in the confidence interval of the slope:

    low(x)  = c - e + min(s_lo dx, s_hi dx),   high(x) = c + e + max(s_lo dx, s_hi dx),   dx = x - x_med

where ``e = z * 1.2533 * 1.4826 * MAD(residuals) / sqrt(n)`` is the half-width of the interval
of the line's level at its centre (1.4826 MAD estimates the residual standard deviation,
1.2533 is the standard error of a median relative to a mean, z the Student-t quantile of the
confidence with n - 2 degrees of freedom; with weights, ``n`` is their effective number
``(sum w)^2 / sum w^2``). On independent normal scatter the slope interval
holds its confidence and the level interval slightly less (about 93 % for a stated 95 %, from
the scatter of the MAD; see ``tests/test_trend.py``). Both assume independent estimates;
consecutive estimates of a recursive estimator are correlated, so read the band as a lower
bound on the uncertainty.

The band above is a *confidence* band of the line: where the line is, not where the next
estimate falls. The *prediction* band (:meth:`WearTrend.prediction_band`) widens it by the
scatter of the estimates about the line, ``z * 1.4826 MAD`` combined in quadrature with each
edge's distance from the line; it is the band the estimates should mostly fall in.

The forecast is where the line meets the limit, with the interval where the band does
(``high`` first, ``low`` last), on the trend's clock (:mod:`.clock`: machine hours, calendar
days, load revolutions or logged operating hours) and in calendar time: ahead of the last
estimate at the recent rate of use (:func:`usage_per_day`: the clock's advance per calendar day,
machine hours per day from the hour meter); before it (a trend that has already crossed) read
off the estimates' own clock, never extrapolated backwards.

``summarise(..., method="kalman")`` fits the local linear trend of :mod:`.kalman` instead
(same interface: ``line``, ``band``, ``prediction_band``, ``crossing``, ``slope``).
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

from ..errors import InvalidParameterError
from .clock import (
    CALENDAR_DAYS,
    OPERATING_HOURS,
    Recording,
    TrendClock,
    choose_clock,
    clock_values,
    lag_on_clock,
    snapshot_points,
)
from .kalman import KalmanTrend, fit_kalman_trend

#: Above this many estimates the trend is fitted to medians of consecutive groups (Theil-Sen
#: compares all pairs, so memory grows with the square of the count).
MAX_TREND_POINTS = 1000

#: The trend methods of :func:`summarise`.
TREND_METHODS = ("theil-sen", "kalman")


@dataclass(frozen=True)
class WearTrend:
    """A Theil-Sen line of backlash (degrees) against a measure of use ``x`` (hours or revolutions).

    Attributes
    ----------
    slope, slope_low, slope_high : float
        Slope and its confidence interval, degrees per unit of ``x``.
    center_x, center_deg : float
        The centre of the line: median ``x`` and the line's value there, degrees.
    level_halfwidth_deg : float
        Half-width ``e`` of the interval of the line's level at its centre, degrees.
    confidence : float
        Confidence of both intervals (0.95: 95 %).
    n_points : int
        Estimates fitted (or groups of them, see :data:`MAX_TREND_POINTS`).
    residual_std_deg : float
        Scatter of the estimates about the line (1.4826 MAD of the residuals), degrees.
    """

    slope: float
    slope_low: float
    slope_high: float
    center_x: float
    center_deg: float
    level_halfwidth_deg: float
    confidence: float
    n_points: int
    residual_std_deg: float = 0.0
    method = "theil-sen"

    def parameters(self) -> dict:
        """The fitted numbers as a JSON-ready dict."""
        return asdict(self)

    def line(self, x: np.ndarray | float) -> np.ndarray | float:
        """The trend at ``x``, degrees."""
        return self.center_deg + self.slope * (np.asarray(x, dtype=float) - self.center_x)

    def band(self, x: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper edges of the band at ``x``, degrees."""
        dx = np.asarray(x, dtype=float) - self.center_x
        a, b = self.slope_low * dx, self.slope_high * dx
        e = self.level_halfwidth_deg
        return self.center_deg - e + np.minimum(a, b), self.center_deg + e + np.maximum(a, b)

    def prediction_band(self, x: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Where a new estimate at ``x`` falls (module docstring), degrees."""
        low, high = self.band(x)
        line = self.line(x)
        scatter = float(stats.t.ppf(0.5 + self.confidence / 2, max(self.n_points - 2, 1))) * self.residual_std_deg
        return line - np.hypot(line - low, scatter), line + np.hypot(high - line, scatter)

    def crossing(self, limit_deg: float) -> tuple[float, float, float]:
        """``x`` where the line, the band's upper edge and its lower edge reach ``limit_deg``.

        Returns ``(x, x_early, x_late)``; ``inf`` where an edge never reaches the limit (a
        slope that is not positive).
        """
        e = self.level_halfwidth_deg
        return (
            self._reach(limit_deg, self.center_deg, self.slope, self.slope),
            self._reach(limit_deg, self.center_deg + e, self.slope_high, self.slope_low),
            self._reach(limit_deg, self.center_deg - e, self.slope_low, self.slope_high),
        )

    def _reach(self, limit_deg: float, level: float, slope_after: float, slope_before: float) -> float:
        """Solve ``level + s dx = limit`` with ``s`` the slope on the side of the centre where it lies."""
        slope = slope_after if limit_deg >= level else slope_before
        if slope <= 0:
            return math.inf
        return self.center_x + (limit_deg - level) / slope


def _thin(x: np.ndarray, y: np.ndarray, w: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Medians of ``max_points`` groups of consecutive points (x sorted; the weight: their sum), or the points."""
    if x.size <= max_points:
        return x, y, w
    groups = np.array_split(np.arange(x.size), max_points)
    medians = [np.array([np.median(c[g]) for g in groups]) for c in (x, y)]
    return medians[0], medians[1], np.array([w[g].sum() for g in groups])


def weighted_quantile(values: np.ndarray, weights: np.ndarray, fraction: float) -> float:
    """The smallest of ``values`` whose cumulative share of ``weights`` (values sorted) reaches
    ``fraction``; the median (``fraction`` 0.5) is the midpoint where the share is exactly one half,
    so that equal weights give :func:`numpy.median`.

    >>> weighted_quantile(np.array([1.0, 2.0, 3.0, 4.0]), np.ones(4), 0.5)
    2.5
    >>> weighted_quantile(np.array([1.0, 2.0, 3.0]), np.array([1.0, 1.0, 4.0]), 0.5)
    3.0
    """
    order = np.argsort(values, kind="stable")
    v, cum = values[order], np.cumsum(weights[order])
    share = cum / cum[-1]
    k = int(np.searchsorted(share, fraction * (1.0 - 1e-12)))
    k = min(k, v.size - 1)
    if fraction == 0.5 and k + 1 < v.size and math.isclose(share[k], 0.5, rel_tol=1e-9):
        return float(0.5 * (v[k] + v[k + 1]))
    return float(v[k])


def _ties(values: np.ndarray) -> float:
    """Sen's (1968) correction of the variance of Kendall's S for tied values: sum of ``k (k - 1) (2k + 5)``."""
    _, counts = np.unique(values, return_counts=True)
    counts = counts[counts > 1].astype(float)
    return float(np.sum(counts * (counts - 1) * (2 * counts + 5)))


def _theil_sen(x: np.ndarray, y: np.ndarray, w: np.ndarray, confidence: float) -> tuple[float, float, float, float]:
    """Slope, intercept and the slope's confidence interval of the (weighted) Theil-Sen line (module docstring)."""
    i, j = np.triu_indices(x.size, 1)
    dx = x[j] - x[i]
    pair = dx != 0
    slopes = (y[j] - y[i])[pair] / dx[pair]
    weights = (w[i] * w[j])[pair]
    slope = weighted_quantile(slopes, weights, 0.5)
    intercept = weighted_quantile(y - slope * x, w, 0.5)
    n, nt = x.size, slopes.size
    sigma = math.sqrt(max((n * (n - 1) * (2 * n + 5) - _ties(x) - _ties(y)) / 18.0, 0.0))
    z = float(stats.norm.ppf(0.5 + confidence / 2))
    upper = min(int(np.round((nt + z * sigma) / 2.0)), nt - 1)
    lower = max(int(np.round((nt - z * sigma) / 2.0)) - 1, 0)
    low, high = (weighted_quantile(slopes, weights, (r + 1) / nt) for r in (lower, upper))
    return slope, intercept, low, high


def _mad_std(residuals: np.ndarray) -> float:
    """1.4826 MAD: a robust standard deviation."""
    return 1.4826 * float(np.median(np.abs(residuals - np.median(residuals))))


def fit_trend(
    x: np.ndarray, backlash_deg: np.ndarray, confidence: float = 0.95, backlash_std_deg: np.ndarray | None = None
) -> WearTrend | None:
    """Theil-Sen trend of ``backlash_deg`` against ``x`` with its band; None if under 3 usable points.

    Parameters
    ----------
    x : array
        Use at each estimate (operating hours, load revolutions, days), non-decreasing.
    backlash_deg : array
        The estimates, degrees; non-finite ones are left out.
    confidence : float
        Confidence of the slope and level intervals, in (0, 1).
    backlash_std_deg : array, optional
        Each estimate's standard deviation, degrees: the estimates are weighted by it (module
        docstring; a missing one counts as the median). Without it all weigh the same.
    """
    if not 0 < confidence < 1:
        raise InvalidParameterError(f"confidence must be in (0, 1), got {confidence!r}")
    x = np.asarray(x, dtype=float)
    y = np.asarray(backlash_deg, dtype=float)
    std = np.full(x.shape, np.nan) if backlash_std_deg is None else np.asarray(backlash_std_deg, dtype=float)
    keep = np.isfinite(x) & np.isfinite(y)
    x, y, std = x[keep], y[keep], std[keep]
    order = np.argsort(x, kind="stable")
    x, y, std = x[order], y[order], std[order]
    if x.size < 3 or np.ptp(x) == 0:
        return None
    equal = np.ones(x.size)
    slope, intercept, low, high = _theil_sen(*_thin(x, y, equal, MAX_TREND_POINTS), confidence)
    sigma = _mad_std(y - (intercept + slope * x))
    if np.isfinite(std).any():
        var = np.where(np.isfinite(std), std, np.nanmedian(std)) ** 2
        floor_var = max(sigma**2 - float(np.median(var)), 0.0)  # the scatter the stated stds do not explain
        weights = 1.0 / np.maximum(var + floor_var, 1e-24)
        x, y, weights = _thin(x, y, weights / weights.max(), MAX_TREND_POINTS)
        slope, intercept, low, high = _theil_sen(x, y, weights, confidence)
        sigma = _mad_std(y - (intercept + slope * x))
    else:
        x, y, weights = _thin(x, y, equal, MAX_TREND_POINTS)
    n_eff = float(weights.sum() ** 2 / np.sum(weights**2))
    center_x = float(np.median(x))
    z = float(stats.t.ppf(0.5 + confidence / 2, x.size - 2))
    return WearTrend(
        slope=slope,
        slope_low=low,
        slope_high=high,
        center_x=center_x,
        center_deg=intercept + slope * center_x,
        level_halfwidth_deg=z * 1.2533 * sigma / math.sqrt(n_eff),
        confidence=confidence,
        n_points=int(x.size),
        residual_std_deg=sigma,
    )


def usage_per_day(time_unix_s: np.ndarray, use: np.ndarray, recent_days: float = 7.0) -> float | None:
    """Recent rate of use: the clock ``use`` (machine hours, operating hours, revolutions) per calendar day
    over the last ``recent_days``.

    The least-squares slope of operating hours against calendar time over the estimates of
    the window (which ends at the last estimate); a slope rather than the difference of the
    end points, since use comes in bursts (a log a day) and the end points fall anywhere in
    them. The whole history if the window holds fewer than three estimates. None without
    elapsed time.
    """
    t = np.asarray(time_unix_s, dtype=float)
    h = np.asarray(use, dtype=float)
    ok = np.isfinite(t) & np.isfinite(h)
    t, h = t[ok], h[ok]
    if t.size < 2:
        return None
    inside = t >= t.max() - recent_days * 86400.0
    if inside.sum() < 3:
        inside = np.ones(t.size, dtype=bool)
    days = (t[inside] - t.max()) / 86400.0
    if np.ptp(days) <= 0:
        return None
    return float(np.polyfit(days, h[inside], 1)[0])


@dataclass(frozen=True)
class WearForecast:
    """When the trend crosses the limit, on the trend's clock and in calendar time.

    Attributes
    ----------
    limit_deg : float
        The limit, degrees.
    to_limit, to_limit_low, to_limit_high : float
        The clock's advance (hours, days or revolutions: ``clock.unit``) from the last estimate
        until the line (and the band's upper and lower edges) reach the limit; negative when
        already past it, ``inf`` when never.
    usage_per_day : float or None
        The recent rate of use the dates assume, clock units per calendar day.
    date_unix_s, date_low_unix_s, date_high_unix_s : float or None
        Calendar time of the crossings at that rate (None when never or the rate is unknown).
    clock : TrendClock
        The clock of the trend.
    """

    limit_deg: float
    to_limit: float
    to_limit_low: float
    to_limit_high: float
    usage_per_day: float | None
    date_unix_s: float | None
    date_low_unix_s: float | None
    date_high_unix_s: float | None
    clock: TrendClock = OPERATING_HOURS


def forecast(
    trend: Trend,
    limit_deg: float,
    last_hours: float,
    last_time_unix_s: float,
    usage_per_day: float | None,
    history: tuple[np.ndarray, np.ndarray] | None = None,
    clock: TrendClock = OPERATING_HOURS,
) -> WearForecast:
    """Forecast the crossing of ``limit_deg`` from the trend against its clock (``last_hours``: the last
    estimate's reading of it, whatever its unit).

    A crossing after the last estimate is dated at ``usage_per_day``; one before it (or at it)
    on the estimates' own clock, interpolated in ``history`` = ``(clock readings, time_unix_s)``
    of the estimates (no date without it).
    """
    ahead = [x - last_hours for x in trend.crossing(limit_deg)]

    def date(h: float) -> float | None:
        if not math.isfinite(h):
            return None
        if h <= 0:
            return None if history is None else float(np.interp(last_hours + h, *history))
        if not usage_per_day or usage_per_day <= 0:
            return None
        return last_time_unix_s + h / usage_per_day * 86400.0

    now, low, high = ahead
    return WearForecast(limit_deg, now, low, high, usage_per_day, date(now), date(low), date(high), clock)


def iso_time(unix_s: float | None) -> str | None:
    """``2026-11-22T08:00:00+00:00`` (UTC, whole seconds) or None."""
    if unix_s is None or not math.isfinite(unix_s):
        return None
    return dt.datetime.fromtimestamp(round(unix_s), dt.timezone.utc).isoformat()


def iso_date(unix_s: float | None) -> str | None:
    """``2026-11-22`` (UTC) or None."""
    text = iso_time(unix_s)
    return None if text is None else text[:10]


def _interval(trend: Trend | None) -> list[float] | None:
    return [trend.slope_low, trend.slope_high] if trend else None


@dataclass(frozen=True)
class WearSummary:
    """The wear trend on its clock with the forecast (if a limit is known); the trends against hours and revolutions.

    Attributes
    ----------
    trend : Trend or None
        The trend against :attr:`clock` (the one the forecast and the dates come from).
    clock : TrendClock
        Its clock (:mod:`.clock`).
    forecast : WearForecast or None
        On that clock.
    per_hour : Trend or None
        Against hours: the trend itself on an hours clock, else against the logged operating
        hours (``trend_deg_per_hour`` in JSON, as before issue 28); ``hours_forecast`` its forecast.
    per_revolution : WearTrend or None
        Theil-Sen against load revolutions.
    usage_hours_per_day : float or None
        Hours of :attr:`per_hour`'s clock per calendar day recently.
    last_hours, last_x : float or None
        The last estimate's hours (of :attr:`per_hour`'s clock) and reading of :attr:`clock`.
    last_time_unix_s : float or None
        Its calendar time.
    n_points : int
        Trend points (one per snapshot log; every estimate otherwise).
    snapshots : bool
        The logs are snapshots (:mod:`.clock`): one point per log.
    """

    per_hour: Trend | None
    per_revolution: WearTrend | None
    forecast: WearForecast | None
    usage_hours_per_day: float | None
    last_hours: float | None
    last_time_unix_s: float | None
    trend: Trend | None = None
    clock: TrendClock = OPERATING_HOURS
    last_x: float | None = None
    hours_forecast: WearForecast | None = None
    n_points: int = 0
    snapshots: bool = False

    @property
    def wear_measured(self) -> bool:
        """The trend's rate is above zero at its confidence (the lower end of its interval is)."""
        return self.trend is not None and self.trend.slope_low > 0

    def as_dict(self) -> dict:
        """Flat JSON-ready keys: ``trend_deg_per_hour``, ``forecast_hours_to_limit``, ``forecast_date``, ..."""
        h, r, f, m, hf = self.per_hour, self.per_revolution, self.forecast, self.trend, self.hours_forecast
        dates = [iso_time(d) for d in (f.date_unix_s, f.date_low_unix_s, f.date_high_unix_s)] if f else [None] * 3
        return {
            "trend_method": m.method if m else None,
            "trend_deg_per_hour": h.slope if h else None,
            "trend_deg_per_hour_interval": _interval(h),
            "trend_deg_per_revolution": r.slope if r else None,
            "trend_deg_per_revolution_interval": _interval(r),
            "trend_confidence": m.confidence if m else None,
            "trend_backlash_deg_now": float(m.line(self.last_x)) if m and self.last_x is not None else None,
            "limit_deg": f.limit_deg if f else None,
            "limit_arcmin": f.limit_deg * 60.0 if f else None,
            "forecast_hours_to_limit": hf.to_limit if hf else None,
            "forecast_hours_to_limit_interval": [hf.to_limit_low, hf.to_limit_high] if hf else None,
            "usage_hours_per_day": self.usage_hours_per_day,
            "forecast_date": iso_date(f.date_unix_s) if f else None,
            "forecast_date_interval": [iso_date(f.date_low_unix_s), iso_date(f.date_high_unix_s)] if f else None,
            "trend_per_hour": h.parameters() if h else None,
            "trend_clock": self.clock.key,
            "trend_clock_unit": self.clock.unit,
            "trend_clock_reason": self.clock.reason,
            "snapshot_logs": self.snapshots,
            "trend_points": self.n_points,
            "trend_deg_per_clock_unit": m.slope if m else None,
            "trend_deg_per_clock_unit_interval": _interval(m),
            "wear_measured": self.wear_measured,
            "forecast_to_limit": f.to_limit if f else None,
            "forecast_to_limit_interval": [f.to_limit_low, f.to_limit_high] if f else None,
            "usage_per_day": f.usage_per_day if f else None,
            "forecast_date_utc": dates[0],
            "forecast_date_utc_interval": dates[1:] if f else None,
        }


def summarise(
    time_unix_s: np.ndarray,
    operating_hours: np.ndarray,
    load_revolutions: np.ndarray,
    backlash_deg: np.ndarray,
    limit_deg: float | None = None,
    confidence: float = 0.95,
    recent_days: float = 7.0,
    backlash_std_deg: np.ndarray | None = None,
    method: str = "theil-sen",
    lag_hours: float = 0.0,
    observable: np.ndarray | None = None,
    machine_hours: np.ndarray | None = None,
    recorded: Recording | None = None,
    group: np.ndarray | None = None,
) -> WearSummary:
    """The trend on its clock, the trends against hours and revolutions, and the forecast of ``limit_deg`` (degrees).

    ``method`` picks the trend: ``"theil-sen"`` (:func:`fit_trend`, weighted by
    ``backlash_std_deg`` where given) or ``"kalman"``
    (:func:`~online_backlash.history.kalman.fit_kalman_trend`, which needs ``backlash_std_deg``
    and corrects for the estimator's ``lag_hours``, logged operating hours, carried onto the
    trend's clock by :func:`~.clock.lag_on_clock`). The trend against revolutions is Theil-Sen.

    The clock (:func:`~.clock.choose_clock`): machine hours where every trend estimate has
    ``machine_hours``; else, knowing how much of the calendar the logs ``recorded``, calendar days
    for snapshot logs and load revolutions otherwise; else the logged operating hours. Snapshot
    logs make one trend point per log (the last estimate of each ``group``, a run id).

    ``observable`` (bool per estimate, default all) marks the estimates whose data showed the
    play (issue 12: a preloaded drive hides it, and its apparent play is not wear): only those
    enter the trends and the forecast's line. The use (rate of use, the last reading of the
    clock) is read from every estimate: the gearbox ran, observable or not.
    """
    if method not in TREND_METHODS:
        raise InvalidParameterError(f"trend method must be one of {', '.join(TREND_METHODS)}, got {method!r}")
    if limit_deg is not None and (not math.isfinite(limit_deg) or limit_deg <= 0):
        raise InvalidParameterError(f"the limit must be a positive angle, got {limit_deg!r} deg")
    t = np.asarray(time_unix_s, dtype=float)
    hours = np.asarray(operating_hours, dtype=float)
    revs = np.asarray(load_revolutions, dtype=float)
    machine = np.full(hours.shape, np.nan) if machine_hours is None else np.asarray(machine_hours, dtype=float)
    keep = np.ones(hours.shape, dtype=bool) if observable is None else np.asarray(observable, dtype=bool)
    if keep.shape != hours.shape:
        raise InvalidParameterError(
            f"observable must have one flag per estimate ({hours.size}), got shape {keep.shape}"
        )
    play = np.asarray(backlash_deg, dtype=float)
    std = np.full(hours.shape, np.nan) if backlash_std_deg is None else np.asarray(backlash_std_deg, dtype=float)
    keep = keep & np.isfinite(play)
    snapshots = recorded is not None and recorded.snapshots and group is not None
    points = snapshot_points(group, keep) if snapshots else np.flatnonzero(keep)  # type: ignore[arg-type]
    clock = choose_clock(machine[points], recorded)
    x = clock_values(clock, t, hours, revs, machine)

    def fit(on: np.ndarray) -> Trend | None:
        if method == "kalman":
            lag = lag_on_clock(on, hours, lag_hours)[points]
            return fit_kalman_trend(on[points], play[points], std[points], lag, confidence)
        return fit_trend(on[points], play[points], confidence, std[points] if backlash_std_deg is not None else None)

    main = fit(x)
    per_hour = main if clock.counts_hours else fit(hours)
    per_rev = fit_trend(revs[points], play[points], confidence, std[points] if backlash_std_deg is not None else None)
    hour_clock = clock if clock.counts_hours else OPERATING_HOURS
    hour_values = x if clock.counts_hours else hours
    last = int(np.nanargmax(hour_values)) if np.isfinite(hour_values).any() else None
    last_time = None if last is None else float(t[last])
    last_x = None if last is None else float(x[last])
    last_hours = None if last is None else float(hour_values[last])
    per_day = usage_per_day(t, x, recent_days) if clock.key != CALENDAR_DAYS.key else 1.0
    hours_per_day = usage_per_day(t, hour_values, recent_days)
    result = hours_result = None
    if limit_deg is not None and last is not None and last_time is not None:
        dated = np.isfinite(x) & np.isfinite(t)
        if main is not None and last_x is not None:
            result = forecast(main, limit_deg, last_x, last_time, per_day, (x[dated], t[dated]), clock)
        if per_hour is main:
            hours_result = result
        elif per_hour is not None and last_hours is not None:
            hours_result = forecast(per_hour, limit_deg, last_hours, last_time, hours_per_day, None, hour_clock)
    return WearSummary(
        per_hour,
        per_rev,
        result,
        hours_per_day,
        last_hours,
        last_time,
        main,
        clock,
        last_x,
        hours_result,
        int(points.size),
        snapshots,
    )


#: A wear trend: Theil-Sen or the Kalman local linear trend (same interface).
Trend = WearTrend | KalmanTrend
