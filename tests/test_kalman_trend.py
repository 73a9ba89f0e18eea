"""The Kalman local linear wear trend (filterpy), its forecast, and the two bands of both trends."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from online_backlash.cli import main
from online_backlash.errors import InvalidParameterError
from online_backlash.history.kalman import estimator_lag_hours, fit_kalman_trend
from online_backlash.history.store import HistoryStore
from online_backlash.history.trend import fit_trend, summarise

RATE = 0.001  # deg per operating hour
NOISE = 0.002  # deg


def ramp(seed, n=60, span=100.0, lag=0.0, rate=RATE, noise=NOISE):
    rng = np.random.default_rng(seed)
    x = np.linspace(1.0, span, n)
    z = 0.2 + rate * (x - lag) + rng.normal(0.0, noise, n)
    return x, z, np.full(n, noise)


def test_with_q_zero_it_is_the_weighted_least_squares_line():
    """Independent formulation: with no process noise the smoothed state is the WLS line."""
    rng = np.random.default_rng(3)
    x = np.sort(rng.uniform(0.0, 50.0, 40))
    std = rng.uniform(0.001, 0.004, 40)
    z = 0.3 + 0.002 * x + rng.normal(0.0, std)
    trend = fit_kalman_trend(x, z, std, drift_fractions=(0.0,), noise_floors=(0.0,))
    design = np.column_stack([np.ones_like(x), x]) / std[:, None]
    coef, *_ = np.linalg.lstsq(design, z / std, rcond=None)
    cov = np.linalg.inv(design.T @ design)
    np.testing.assert_allclose(trend.rate_deg_per_x, coef[1], rtol=1e-6)
    np.testing.assert_allclose(trend.level_deg, coef[0] + coef[1] * x, atol=1e-8)
    assert trend.slope_high - trend.slope == pytest.approx(1.959964 * math.sqrt(cov[1, 1]), rel=1e-4)


def test_lag_in_the_measurement_model_removes_the_estimators_bias():
    lag = 8.0  # operating hours: the estimates read the play of 8 h ago
    x, z, std = ramp(1, lag=lag)
    corrected = fit_kalman_trend(x, z, std, lag_x=lag)
    naive = fit_kalman_trend(x, z, std)
    truth_now = 0.2 + RATE * x[-1]
    _, high = corrected.band(x[-1])
    assert abs(corrected.line(x[-1]) - truth_now) < high - corrected.line(x[-1])  # inside its band
    assert truth_now - naive.line(x[-1]) == pytest.approx(RATE * lag, rel=0.5)  # reads low by rate * lag
    limit = 0.35
    true_crossing = (limit - 0.2) / RATE
    x_mid, x_early, x_late = corrected.crossing(limit)
    assert x_early <= true_crossing <= x_late and x_early < x_mid < x_late


def test_rate_interval_coverage_on_independent_scatter():
    hits = 0
    for seed in range(40):
        trend = fit_kalman_trend(*ramp(seed))
        hits += trend.slope_low <= RATE <= trend.slope_high
    assert hits >= 34  # 95 % stated; at least 85 % of 40


def test_a_change_of_wear_rate_is_followed():
    rng = np.random.default_rng(5)
    x = np.linspace(0.0, 365 * 2.0, 365)  # a year, 2 operating hours a day
    bend = x[240]
    true = 0.2 + 1e-4 * x + np.where(x > bend, 2e-4 * (x - bend), 0.0)  # rate 1e-4 then 3e-4 deg/h
    z = true + rng.normal(0.0, 0.002, x.size)
    kalman = fit_kalman_trend(x, z, np.full(x.size, 0.002))
    theil_sen = fit_trend(x, z)
    assert kalman.slope == pytest.approx(3e-4, rel=0.25)
    assert kalman.slope_low <= 3e-4 <= kalman.slope_high
    assert theil_sen.slope < 2e-4  # the line through the whole year is not the rate now
    limit = true[-1] + 0.02
    true_crossing = x[-1] + 0.02 / 3e-4
    assert abs(kalman.crossing(limit)[0] - true_crossing) < abs(theil_sen.crossing(limit)[0] - true_crossing) / 3


def test_a_level_already_over_the_limit_crossed_in_the_past():
    x, z, std = ramp(2)
    trend = fit_kalman_trend(x, z, std)
    limit = 0.25  # crossed at x = 50
    x_mid, x_early, x_late = trend.crossing(limit)
    assert 40.0 < x_early <= x_mid <= x_late < 60.0
    s = summarise(x * 3600.0, x, x, z, limit, backlash_std_deg=std, method="kalman")
    assert -60.0 < s.forecast.to_limit < -40.0
    assert s.forecast.date_unix_s == pytest.approx(np.interp(x_mid, x, x * 3600.0))  # on the estimates' clock


def test_bands_are_honest_for_both_trends():
    """The prediction band holds about 95 % of the estimates, the confidence band far fewer."""
    x, z, std = ramp(4, n=200)
    for trend in (fit_trend(x, z), fit_kalman_trend(x, z, std)):
        lo_p, hi_p = trend.prediction_band(x)
        lo_c, hi_c = trend.band(x)
        inside_p = np.mean((z >= lo_p) & (z <= hi_p))
        inside_c = np.mean((z >= lo_c) & (z <= hi_c))
        assert inside_p >= 0.9 and inside_c < 0.6, (trend.method, inside_p, inside_c)
        assert np.all(hi_p - lo_p > hi_c - lo_c)


def test_bad_and_missing_input():
    x, z, std = ramp(0, n=10)
    z[2], std[5] = np.nan, np.inf
    assert fit_kalman_trend(x, z, std).n_points == 8
    assert fit_kalman_trend(x[:2], z[:2], std[:2]) is None
    with pytest.raises(InvalidParameterError, match="confidence"):
        fit_kalman_trend(x, z, std, confidence=1.0)
    with pytest.raises(InvalidParameterError, match="trend method must be one of theil-sen, kalman"):
        summarise(x, x, x, z, method="spline")


def test_estimator_lag_hours():
    assert estimator_lag_hours(None, None, 0.01) == 0.0
    assert estimator_lag_hours(10.0, None, 0.01) == pytest.approx(0.1)
    assert estimator_lag_hours(10.0, 360.0, 0.01) == pytest.approx(1 / (10 + 10))
    assert estimator_lag_hours(10.0, None, None) == 0.0


def test_history_trend_kalman_from_the_command_line(capsys, tmp_path):
    db = tmp_path / "w.db"
    x, z, std = ramp(6, n=30, span=30.0)
    with HistoryStore(db, create=True) as store:
        gearbox, run = store.begin_run("g1", 30.0, "a.csv", "a" * 64, 1.7e9, limit_arcmin=21.0)
        rows = [
            dict(
                sample_index=i + 1,
                time_unix_s=1.7e9 + i * 86400.0,
                backlash_deg=zi,
                backlash_std_deg=si,
                c_left_deg=None,
                c_right_deg=None,
                m_left=None,
                m_right=None,
                residual_rms_deg=None,
                n_samples=i + 1,
                operating_hours=xi,
                load_revolutions=10.0 * xi,
                reversals=100 * (i + 1),
            )
            for i, (xi, zi, si) in enumerate(zip(x, z, std))
        ]
        store.commit(gearbox, run, len(rows), {"format": 1}, rows)
    assert main(["history", "--db", str(db), "--gearbox", "g1", "--trend", "kalman", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["trend_method"] == "kalman" and d["trend_deg_per_hour"] == pytest.approx(RATE, rel=0.3)
    assert d["trend_per_hour"]["n_points"] == 30 and d["state"] == "unknown"  # 2023: not recent
    assert (
        main(["history", "--db", str(db), "--gearbox", "g1", "--trend", "kalman", "--plot", str(tmp_path / "k.png")])
        == 0
    )
    out = capsys.readouterr().out
    assert "(95%, Kalman local linear trend, lag-corrected, 30 estimates)" in out
    assert (tmp_path / "k.png").stat().st_size > 10_000
    assert "before today: the last estimate is from 2023-" in out  # a stale history says so
