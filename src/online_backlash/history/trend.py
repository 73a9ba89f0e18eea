"""Wear trend and forecast: a robust line through backlash against use, and when it crosses a limit.

The trend is the Theil-Sen line (Sen 1968; :func:`scipy.stats.theilslopes`): the slope is the
median of the slopes between all pairs of estimates, so a minority of bad estimates (a log
that barely reversed, an estimator still settling) cannot tilt it. Its band is the set of
lines that pass within ``level_halfwidth_deg`` of the centre point ``(median x, line at median
x)`` with a slope in scipy's confidence interval of the slope:

    low(x)  = c - e + min(s_lo dx, s_hi dx),   high(x) = c + e + max(s_lo dx, s_hi dx),   dx = x - x_med

where ``e = z * 1.2533 * 1.4826 * MAD(residuals) / sqrt(n)`` is the half-width of the interval
of the line's level at its centre (1.4826 MAD estimates the residual standard deviation,
1.2533 is the standard error of a median relative to a mean, z the Student-t quantile of the
confidence with n - 2 degrees of freedom). On independent normal scatter the slope interval
holds its confidence and the level interval slightly less (about 93 % for a stated 95 %, from
the scatter of the MAD; see ``tests/test_trend.py``). Both assume independent estimates;
consecutive estimates of a recursive estimator are correlated, so read the band as a lower
bound on the uncertainty.

The band above is a *confidence* band of the line: where the line is, not where the next
estimate falls. The *prediction* band (:meth:`WearTrend.prediction_band`) widens it by the
scatter of the estimates about the line, ``z * 1.4826 MAD`` combined in quadrature with each
edge's distance from the line; it is the band the estimates should mostly fall in.

The forecast is where the line meets the limit, with the interval where the band does
(``high`` first, ``low`` last), in operating hours and in calendar time: ahead of the last
estimate at the recent rate of use (:func:`usage_hours_per_day`); before it (a trend that has
already crossed) read off the estimates' own clock, never extrapolated backwards.

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


def _thin(x: np.ndarray, y: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Medians of ``max_points`` groups of consecutive points (x sorted), or the points themselves."""
    if x.size <= max_points:
        return x, y
    groups = np.array_split(np.arange(x.size), max_points)
    return np.array([np.median(x[g]) for g in groups]), np.array([np.median(y[g]) for g in groups])


def fit_trend(x: np.ndarray, backlash_deg: np.ndarray, confidence: float = 0.95) -> WearTrend | None:
    """Theil-Sen trend of ``backlash_deg`` against ``x`` with its band; None if under 3 usable points.

    Parameters
    ----------
    x : array
        Use at each estimate (operating hours, load revolutions), non-decreasing.
    backlash_deg : array
        The estimates, degrees; non-finite ones are left out.
    confidence : float
        Confidence of the slope and level intervals, in (0, 1).
    """
    if not 0 < confidence < 1:
        raise InvalidParameterError(f"confidence must be in (0, 1), got {confidence!r}")
    x = np.asarray(x, dtype=float)
    y = np.asarray(backlash_deg, dtype=float)
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    order = np.argsort(x, kind="stable")
    x, y = _thin(x[order], y[order], MAX_TREND_POINTS)
    if x.size < 3 or np.ptp(x) == 0:
        return None
    fit = stats.theilslopes(y, x, alpha=confidence, method="joint")
    center_x = float(np.median(x))
    center_deg = float(fit.intercept + fit.slope * center_x)
    residuals = y - (fit.intercept + fit.slope * x)
    sigma = 1.4826 * float(np.median(np.abs(residuals - np.median(residuals))))
    z = float(stats.t.ppf(0.5 + confidence / 2, x.size - 2))
    return WearTrend(
        slope=float(fit.slope),
        slope_low=float(fit.low_slope),
        slope_high=float(fit.high_slope),
        center_x=center_x,
        center_deg=center_deg,
        level_halfwidth_deg=z * 1.2533 * sigma / math.sqrt(x.size),
        confidence=confidence,
        n_points=int(x.size),
        residual_std_deg=sigma,
    )


def usage_hours_per_day(time_unix_s: np.ndarray, operating_hours: np.ndarray, recent_days: float = 7.0) -> float | None:
    """Recent rate of use: operating hours per calendar day over the last ``recent_days``.

    The least-squares slope of operating hours against calendar time over the estimates of
    the window (which ends at the last estimate); a slope rather than the difference of the
    end points, since use comes in bursts (a log a day) and the end points fall anywhere in
    them. The whole history if the window holds fewer than three estimates. None without
    elapsed time.
    """
    t = np.asarray(time_unix_s, dtype=float)
    h = np.asarray(operating_hours, dtype=float)
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
    """When the trend crosses the limit.

    Attributes
    ----------
    limit_deg : float
        The limit, degrees.
    hours_to_limit, hours_to_limit_low, hours_to_limit_high : float
        Operating hours from the last estimate until the line (and the band's upper and lower
        edges) reach the limit; negative when already past it, ``inf`` when never.
    usage_hours_per_day : float or None
        The recent rate of use the dates assume.
    date_unix_s, date_low_unix_s, date_high_unix_s : float or None
        Calendar time of the crossings at that rate (None when never or the rate is unknown).
    """

    limit_deg: float
    hours_to_limit: float
    hours_to_limit_low: float
    hours_to_limit_high: float
    usage_hours_per_day: float | None
    date_unix_s: float | None
    date_low_unix_s: float | None
    date_high_unix_s: float | None


def forecast(
    trend: Trend,
    limit_deg: float,
    last_hours: float,
    last_time_unix_s: float,
    usage_per_day: float | None,
    history: tuple[np.ndarray, np.ndarray] | None = None,
) -> WearForecast:
    """Forecast the crossing of ``limit_deg`` from the trend against operating hours.

    A crossing after the last estimate is dated at ``usage_per_day``; one before it (or at it)
    on the estimates' own clock, interpolated in ``history`` = ``(operating_hours,
    time_unix_s)`` of the estimates (no date without it).
    """
    hours = [x - last_hours for x in trend.crossing(limit_deg)]

    def date(h: float) -> float | None:
        if not math.isfinite(h):
            return None
        if h <= 0:
            return None if history is None else float(np.interp(last_hours + h, *history))
        if not usage_per_day or usage_per_day <= 0:
            return None
        return last_time_unix_s + h / usage_per_day * 86400.0

    now, low, high = hours
    return WearForecast(limit_deg, now, low, high, usage_per_day, date(now), date(low), date(high))


def iso_time(unix_s: float | None) -> str | None:
    """``2026-11-22T08:00:00+00:00`` (UTC, whole seconds) or None."""
    if unix_s is None or not math.isfinite(unix_s):
        return None
    return dt.datetime.fromtimestamp(round(unix_s), dt.timezone.utc).isoformat()


def iso_date(unix_s: float | None) -> str | None:
    """``2026-11-22`` (UTC) or None."""
    text = iso_time(unix_s)
    return None if text is None else text[:10]


@dataclass(frozen=True)
class WearSummary:
    """Trend against operating hours and load revolutions, and the forecast (if a limit is known)."""

    per_hour: Trend | None
    per_revolution: WearTrend | None
    forecast: WearForecast | None
    usage_hours_per_day: float | None
    last_hours: float | None
    last_time_unix_s: float | None

    def as_dict(self) -> dict:
        """Flat JSON-ready keys: ``trend_deg_per_hour``, ``forecast_hours_to_limit``, ``forecast_date``, ..."""
        h, r, f = self.per_hour, self.per_revolution, self.forecast
        return {
            "trend_method": h.method if h else None,
            "trend_deg_per_hour": h.slope if h else None,
            "trend_deg_per_hour_interval": [h.slope_low, h.slope_high] if h else None,
            "trend_deg_per_revolution": r.slope if r else None,
            "trend_deg_per_revolution_interval": [r.slope_low, r.slope_high] if r else None,
            "trend_confidence": h.confidence if h else None,
            "trend_backlash_deg_now": float(h.line(self.last_hours)) if h and self.last_hours is not None else None,
            "limit_deg": f.limit_deg if f else None,
            "limit_arcmin": f.limit_deg * 60.0 if f else None,
            "forecast_hours_to_limit": f.hours_to_limit if f else None,
            "forecast_hours_to_limit_interval": [f.hours_to_limit_low, f.hours_to_limit_high] if f else None,
            "usage_hours_per_day": self.usage_hours_per_day,
            "forecast_date": iso_date(f.date_unix_s) if f else None,
            "forecast_date_interval": [iso_date(f.date_low_unix_s), iso_date(f.date_high_unix_s)] if f else None,
            "trend_per_hour": h.parameters() if h else None,
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
) -> WearSummary:
    """Trends against hours and revolutions, and the forecast of ``limit_deg`` (degrees) if given.

    ``method`` picks the trend against hours: ``"theil-sen"`` (:func:`fit_trend`) or
    ``"kalman"`` (:func:`~online_backlash.history.kalman.fit_kalman_trend`, which needs
    ``backlash_std_deg`` and corrects for the estimator's ``lag_hours``). The trend against
    revolutions is Theil-Sen.

    ``observable`` (bool per estimate, default all) marks the estimates whose data showed the
    play (issue 12: a preloaded drive hides it, and its apparent play is not wear): only those
    enter the trends and the forecast's line. The use (rate of use, the last operating hour) is
    read from every estimate: the gearbox ran, observable or not.
    """
    if method not in TREND_METHODS:
        raise InvalidParameterError(f"trend method must be one of {', '.join(TREND_METHODS)}, got {method!r}")
    if limit_deg is not None and (not math.isfinite(limit_deg) or limit_deg <= 0):
        raise InvalidParameterError(f"the limit must be a positive angle, got {limit_deg!r} deg")
    t = np.asarray(time_unix_s, dtype=float)
    hours = np.asarray(operating_hours, dtype=float)
    keep = np.ones(hours.shape, dtype=bool) if observable is None else np.asarray(observable, dtype=bool)
    if keep.shape != hours.shape:
        raise InvalidParameterError(f"observable must have one flag per estimate ({hours.size}), got shape {keep.shape}")
    play = np.asarray(backlash_deg, dtype=float)[keep]
    per_hour: Trend | None
    if method == "kalman":
        std = np.full(hours.shape, np.nan) if backlash_std_deg is None else np.asarray(backlash_std_deg, dtype=float)
        per_hour = fit_kalman_trend(hours[keep], play, std[keep], lag_hours, confidence)
    else:
        per_hour = fit_trend(hours[keep], play, confidence)
    per_rev = fit_trend(np.asarray(load_revolutions, dtype=float)[keep], play, confidence)
    last = int(np.argmax(hours)) if hours.size else None
    last_hours = None if last is None else float(hours[last])
    last_time = None if last is None else float(t[last])
    usage = usage_hours_per_day(t, hours, recent_days)
    result = None
    if per_hour is not None and limit_deg is not None and last_hours is not None and last_time is not None:
        dated = np.isfinite(hours) & np.isfinite(t)
        result = forecast(per_hour, limit_deg, last_hours, last_time, usage, (hours[dated], t[dated]))
    return WearSummary(per_hour, per_rev, result, usage, last_hours, last_time)


#: A wear trend: Theil-Sen or the Kalman local linear trend (same interface).
Trend = WearTrend | KalmanTrend
