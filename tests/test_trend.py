"""Wear trend (Theil-Sen line and band) and forecast, on synthetic points with a known answer."""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
import pytest

from online_backlash.errors import InvalidParameterError
from online_backlash.history import trend as trend_module
from online_backlash.history.trend import fit_trend, forecast, iso_date, summarise, usage_per_day

DAY = 86400.0


def noisy_line(n=40, slope=0.004, intercept=0.2, noise=0.002, seed=0):
    rng = np.random.default_rng(seed)
    x = np.sort(rng.uniform(0, 25, n))
    return x, intercept + slope * x + rng.normal(0, noise, n)


def test_robust_to_a_minority_of_wild_estimates():
    x = np.linspace(0, 20, 50)
    y = 0.2 + 0.005 * x
    y[::6] += np.random.default_rng(1).uniform(-0.2, 0.3, y[::6].size)  # 9 of 50 estimates are garbage
    trend = fit_trend(x, y)
    assert trend.slope == pytest.approx(0.005, rel=1e-9)
    assert float(trend.line(10.0)) == pytest.approx(0.25, rel=1e-9)


def test_interval_and_band_contain_the_true_line_about_as_often_as_stated():
    slope_hits = level_hits = 0
    trials = 300
    for seed in range(trials):
        x, y = noisy_line(n=30, seed=seed)
        trend = fit_trend(x, y, confidence=0.9)
        slope_hits += trend.slope_low <= 0.004 <= trend.slope_high
        low, high = trend.band(trend.center_x)
        level_hits += low <= 0.2 + 0.004 * trend.center_x <= high
    assert 0.84 <= slope_hits / trials <= 0.96
    assert 0.84 <= level_hits / trials <= 0.96


def test_band_widens_away_from_the_centre():
    trend = fit_trend(*noisy_line())
    widths = [
        float(np.subtract(*trend.band(x))[()]) * -1 for x in (trend.center_x, trend.center_x + 10, trend.center_x + 50)
    ]
    assert widths[0] == pytest.approx(2 * trend.level_halfwidth_deg)
    assert widths[0] < widths[1] < widths[2]
    low, high = trend.band(np.linspace(0, 60, 7))
    assert np.all(low <= trend.line(np.linspace(0, 60, 7))) and np.all(trend.line(np.linspace(0, 60, 7)) <= high)


def test_crossing_of_the_line_and_of_the_band_edges():
    trend = fit_trend(*noisy_line(noise=0.003))
    x, early, late = trend.crossing(0.35)
    assert float(trend.line(x)) == pytest.approx(0.35)
    assert float(trend.band(early)[1]) == pytest.approx(0.35)
    assert float(trend.band(late)[0]) == pytest.approx(0.35)
    assert early < x < late
    assert x == pytest.approx((0.35 - 0.2) / 0.004, rel=0.1)


def test_no_crossing_when_the_trend_does_not_grow():
    x = np.linspace(0, 10, 20)
    trend = fit_trend(x, 0.3 - 0.001 * x + 0.0001 * np.sin(x))
    crossing, _, late = trend.crossing(0.35)
    assert math.isinf(crossing) and math.isinf(late)


def test_too_few_points_give_no_trend():
    assert fit_trend([1.0, 2.0], [0.2, 0.21]) is None
    assert fit_trend([1.0, 1.0, 1.0, 1.0], [0.2, 0.21, 0.22, 0.2]) is None
    assert fit_trend([1.0, 2.0, np.nan, 3.0], [0.2, np.nan, 0.2, 0.21]) is None  # two usable points


def test_many_points_are_thinned_to_group_medians(monkeypatch):
    monkeypatch.setattr(trend_module, "MAX_TREND_POINTS", 50)
    x, y = noisy_line(n=2000, noise=0.004)
    trend = fit_trend(x, y)
    assert trend.n_points == 50
    assert trend.slope == pytest.approx(0.004, rel=0.05)


def test_bad_confidence_is_refused():
    with pytest.raises(InvalidParameterError, match="confidence"):
        fit_trend(*noisy_line(), confidence=95)


def test_recent_rate_of_use():
    days = np.arange(30.0)
    hours = np.where(days < 20, 2.0 * days, 40.0 + 5.0 * (days - 20))  # 2 h/day, then 5 h/day
    t = 1.7e9 + days * DAY
    assert usage_per_day(t, hours, recent_days=7) == pytest.approx(5.0)
    assert usage_per_day(t, hours, recent_days=100) == pytest.approx(np.polyfit(days, hours, 1)[0])
    # a log a day: the rate over whole days, wherever in its log each estimate falls
    bursts_t = np.concatenate([T + np.array([0.01, 0.02]) for T in days]) * DAY
    bursts_h = np.concatenate([0.05 * k + np.array([0.025, 0.05]) for k in days])
    assert usage_per_day(bursts_t, bursts_h, recent_days=7) == pytest.approx(0.05, rel=0.05)
    assert usage_per_day(t[:1], hours[:1]) is None
    assert usage_per_day(np.full(3, 1.7e9), np.arange(3.0)) is None


def test_forecast_in_hours_and_calendar_time():
    x, y = noisy_line()
    trend = fit_trend(x, y)
    f = forecast(trend, 0.35, last_hours=25.0, last_time_unix_s=1.7e9, usage_per_day=2.5)
    central, early, late = trend.crossing(0.35)
    assert f.to_limit == pytest.approx(central - 25.0)
    assert (f.to_limit_low, f.to_limit_high) == pytest.approx((early - 25.0, late - 25.0))
    assert f.date_unix_s == pytest.approx(1.7e9 + f.to_limit / 2.5 * DAY)
    assert f.date_low_unix_s < f.date_unix_s < f.date_high_unix_s
    assert forecast(trend, 0.35, 25.0, 1.7e9, None).date_unix_s is None


def test_summary_keys_and_values():
    days = np.arange(20.0)
    hours = 1.5 * days
    t = 1.7e9 + days * DAY
    backlash = 0.2 + 0.004 * hours
    s = summarise(t, hours, 100.0 * hours, backlash, limit_deg=0.35)
    d = s.as_dict()
    assert d["trend_deg_per_hour"] == pytest.approx(0.004)
    assert d["trend_deg_per_revolution"] == pytest.approx(0.00004)
    assert d["usage_hours_per_day"] == pytest.approx(1.5)
    assert d["forecast_hours_to_limit"] == pytest.approx(37.5 - hours[-1])
    expected = dt.datetime.fromtimestamp(t[-1] + (37.5 - hours[-1]) / 1.5 * DAY, dt.timezone.utc).date().isoformat()
    assert d["forecast_date"] == expected
    assert iso_date(None) is None
    no_limit = summarise(t, hours, hours, backlash).as_dict()
    assert no_limit["forecast_hours_to_limit"] is None and no_limit["trend_deg_per_hour"] == pytest.approx(0.004)
    with pytest.raises(InvalidParameterError, match="positive angle"):
        summarise(t, hours, hours, backlash, limit_deg=-1.0)
