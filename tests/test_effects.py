"""The effect library: the EffectTerms protocol, causal streaming, detection and description with units."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from online_backlash.diagnostics._folds import cycle_folds
from online_backlash.diagnostics._normal_equations import nonzero_rows
from online_backlash.diagnostics._scoring import DetectionData, score_columns
from online_backlash.diagnostics.dead_band import DeadBandMotion
from online_backlash.diagnostics.effects import LIBRARY, VOCABULARY, Compliance, Delay, Drift, TransmissionError
from online_backlash.diagnostics.flank_profile import FlankProfile
from online_backlash.diagnostics.generic_terms import GENERIC, AngleHarmonicsPerFlank, VelocityFunction
from online_backlash.effect_terms import EffectTerms
from online_backlash.errors import InvalidParameterError
from online_backlash.model import BacklashParams, simulate_switching

ALL = [
    TransmissionError((2, 5), (1,), 30.0),
    Delay(3, 1e-3),
    Compliance("torque"),
    Compliance("acceleration", 7),
    Compliance("motion", 21),
    Drift(2, 40.0),
    AngleHarmonicsPerFlank((1, 3)),
    VelocityFunction((-40.0, -10.0, 0.0, 10.0, 40.0)),
    DeadBandMotion(1.0, 0.3, 1.0, 0.3, torque=True),
    DeadBandMotion(1.0, 0.3, 1.0, 0.3, rest_time_constants_s=(0.008, 0.128)),
    DeadBandMotion(1.0, 0.3, 1.0, 0.3, rest_time_constants_s=(0.008,), creep_step=True, creep_directions=(-1,)),
    DeadBandMotion(0.98, 0.2, 1.01, 0.4, exit_time_constants_s=(), entry_knots_s=(0.0, 0.002, 0.01)),
    FlankProfile(tuple(np.linspace(-30.0, 30.0, 13))),
]


def _record(n: int = 3000, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3 + 5.0
    u = 40.0 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * rng.normal(size=n)
    q = np.cos(2 * np.pi * 0.3 * t) + 0.05 * rng.normal(size=n)
    return u, t, q


@pytest.mark.parametrize("effect", ALL, ids=lambda e: repr(e))
def test_protocol_and_streaming(effect):
    assert isinstance(effect, EffectTerms)
    u, t, q = _record()
    whole = effect.clone().terms(u, t, q)
    assert whole.shape == (u.size, effect.n_terms)
    assert np.all(np.isfinite(whole))
    # the same rows from pieces of uneven size, and one sample at a time for a stretch
    e = effect.clone()
    cuts = [0, 1, 7, 500, 501, 1999, u.size]
    parts = [e.terms(u[a:b], t[a:b], q[a:b]) for a, b in itertools.pairwise(cuts)]
    np.testing.assert_allclose(np.vstack(parts), whole, rtol=0, atol=1e-12)
    e.reset()
    singles = np.vstack([e.terms(u[i : i + 1], t[i : i + 1], q[i : i + 1]) for i in range(60)])
    np.testing.assert_allclose(singles, whole[:60], rtol=0, atol=1e-12)


@pytest.mark.parametrize("effect", ALL, ids=lambda e: repr(e))
def test_causal(effect):
    """Changing the future does not change the past rows."""
    u, t, q = _record()
    a = effect.clone().terms(u, t, q)
    u2, q2 = u.copy(), q.copy()
    u2[2000:] = 0.3 * u2[2000:] + 5.0
    q2[2000:] -= 1.0
    b = effect.clone().terms(u2, t, q2)
    np.testing.assert_array_equal(a[:2000], b[:2000])
    assert not np.array_equal(a[2000:], b[2000:]) or isinstance(effect, Drift)


@pytest.mark.parametrize("effect", ALL, ids=lambda e: repr(e))
def test_describe_has_units(effect):
    d = effect.describe(np.full(effect.n_terms, 0.01))
    text = repr(d)
    assert any(unit in text for unit in ("_deg", "_s", "_Nm", "_s2")), d


def test_names_come_from_the_vocabulary():
    assert [c.name for c in LIBRARY] == list(VOCABULARY)
    assert not {c.name for c in GENERIC} & set(VOCABULARY)


def test_invalid_settings():
    with pytest.raises(InvalidParameterError):
        Delay(0)
    with pytest.raises(InvalidParameterError):
        Compliance("speed")
    with pytest.raises(InvalidParameterError):
        Drift(0)
    with pytest.raises(InvalidParameterError):
        TransmissionError((1,)).terms(np.zeros(3), np.zeros(2), np.zeros(3))
    with pytest.raises(InvalidParameterError):
        DeadBandMotion(entry_knots_s=(0.001, 0.002))
    with pytest.raises(InvalidParameterError):
        DeadBandMotion(exit_time_constants_s=(0.0,))
    with pytest.raises(InvalidParameterError):
        DeadBandMotion(m_left=1.0, m_right=-1.0)


def _data(residual, u, t, q, ratio=30.0):
    return DetectionData(u, t, q, residual, ratio, 1e-3)


def _rig_motion(n=20000, seed=1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    speed = np.repeat(rng.uniform(15, 45, n // 2000 + 1) * np.resize([1, -1], n // 2000 + 1), 2000)[:n]
    u = np.cumsum(speed + 30.0) * 1e-3  # about 600 deg of net rotation with reversals
    return u, t, rng


def test_transmission_error_found_with_order_amplitude_and_phase():
    u, t, rng = _rig_motion()
    r = 0.02 * np.sin(np.radians(3 * u) + 0.5) + rng.normal(0, 0.005, u.size)
    det = TransmissionError.detect(_data(r, u, t, np.full(u.size, np.nan)))
    assert det is not None and det.effect.load_orders == (3,) and det.effect.motor_orders == ()
    (h,) = det.effect.describe(det.score.coef)["harmonics"]
    assert h["amplitude_deg"] == pytest.approx(0.02, rel=0.05)
    assert h["phase_deg"] == pytest.approx(np.degrees(0.5), abs=3.0)


def test_delay_lag_in_samples_and_seconds():
    u, t, rng = _rig_motion()
    x = u.copy()
    late = np.concatenate((np.full(3, x[0]), x[:-3]))
    r = late - x + rng.normal(0, 0.003, u.size)
    det = Delay.detect(_data(r, u, t, np.full(u.size, np.nan)))
    p = det.effect.describe(det.score.coef)
    assert p["lag_samples"] == pytest.approx(3.0, abs=0.15)
    assert p["lag_s"] == pytest.approx(3e-3, abs=1.5e-4)


def test_compliance_prefers_the_measured_torque():
    # the shaft twists under the true torque; the sensor adds its own noise, which twists nothing
    u, t, rng = _rig_motion()
    true = np.sin(2 * np.pi * 0.4 * t)
    torque = true + 0.03 * rng.normal(size=u.size)
    r = -0.02 * true + rng.normal(0, 0.004, u.size)
    det = Compliance.detect(_data(r, u, t, torque))
    p = det.effect.describe(det.score.coef)
    assert p["proxy"] == "measured torque"
    assert p["compliance_deg_per_Nm"] == pytest.approx(-0.02, rel=0.03)
    assert p["stiffness_Nm_per_arcmin"] == pytest.approx(1 / 0.02 / 60, rel=0.03)


def test_compliance_is_active_only_where_the_torque_engages_a_flank():
    # inside the dead band (|torque| below the sensor's noise band) the column is exactly 0
    u, t, rng = _rig_motion()
    torque = np.where(np.sin(2 * np.pi * 0.4 * t) > 0.5, 1.0, 0.0) + 0.01 * rng.normal(size=u.size)
    cols = Compliance("torque", deadband_Nm=0.05, smooth_samples=1).terms(u, t, torque)[:, 0]
    inside = np.abs(torque) <= 0.05
    assert inside.sum() > 1000
    assert np.all(cols[inside] == 0.0)
    np.testing.assert_array_equal(cols[~inside], torque[~inside])


def test_compliance_without_torque_names_its_proxy_and_units():
    u, t, rng = _rig_motion()
    det = Compliance.detect(_data(rng.normal(0, 0.004, u.size), u, t, np.full(u.size, np.nan)))
    assert det.effect.proxy == "acceleration"  # the velocity only where it adds beyond the acceleration
    p = det.effect.describe(np.array([-1e-4]))
    assert p["proxy"].startswith("load-side acceleration (inertial")
    assert p["deflection_per_acceleration_s2"] == -1e-4 and p["inertia_over_stiffness_s2"] == 1e-4
    assert p["natural_frequency_hz"] == pytest.approx(1.0 / (2.0 * np.pi * 0.01))
    assert p["differentiator_window_samples"] == det.effect.window_samples
    both = Compliance("motion").describe(np.array([1e-5, 2e-3]))
    assert both["proxy"].startswith("load-side acceleration and velocity")
    assert both["deflection_per_acceleration_s2"] == 1e-5 and both["deflection_per_velocity_s"] == 2e-3
    assert "natural_frequency_hz" not in both  # a twist along the acceleration is no inertia's


def test_drift_degree_and_size():
    u, t, rng = _rig_motion()
    r = 0.03 * t / t[-1] + rng.normal(0, 0.004, u.size)
    det = Drift.detect(_data(r, u, t, np.full(u.size, np.nan)))
    p = det.effect.describe(det.score.coef)
    assert p["offset_at_time_scale_deg"] == pytest.approx(0.03, abs=0.002)


def test_pure_noise_is_not_significant():
    """The threshold keeps false alarms rare: white noise passes none of the detectors."""
    u, t, rng = _rig_motion()
    q = rng.normal(size=u.size)
    alarms = 0
    for seed in range(3):
        r = np.random.default_rng(100 + seed).normal(0, 0.005, u.size)
        data = _data(r, u, t, q)
        for cls in LIBRARY + GENERIC:
            det = cls.detect(data)
            alarms += det is not None and det.score.significant()
    assert alarms == 0


def test_score_counts_autocorrelation():
    """A slow random walk explained by an unrelated slow column is not strong evidence."""
    rng = np.random.default_rng(3)
    walk = np.cumsum(rng.normal(0, 1e-4, 20000))
    unrelated = np.cumsum(rng.normal(0, 1e-4, 20000))
    s = score_columns(walk, unrelated)
    assert s.n_eff < 200


def test_dead_band_motion_columns_follow_the_switching_functions():
    """Coast columns only where eq. (5)-(6) engage no flank, entry columns only on engaged samples
    within the transient, each scaled by the speed of ``u`` at the exit or at the entry."""
    u, t, q = _record()
    u = 40.0 * np.sin(2 * np.pi * 0.7 * t)  # smooth, so every dead band is a reversal
    params = BacklashParams(1.0, 0.3, 1.0, 0.3)
    effect = DeadBandMotion(*params.__dict__.values(), torque=True, window_samples=1)
    cols = effect.terms(u, t, q)
    _, f1, f2 = simulate_switching(u - u[0], params, 0.0)
    engaged = (f1 + f2) > 0
    n_exit = len(effect.exit_time_constants_s) + 2
    assert np.all(cols[engaged, :n_exit] == 0.0) and np.all(cols[~engaged, n_exit:] == 0.0)
    assert np.count_nonzero(cols[~engaged, 0]) > 100 and np.count_nonzero(cols[engaged, n_exit:]) > 100
    # the first engaged sample after a dead band: the first hat is the entry speed itself
    entry = np.flatnonzero(engaged[1:] & ~engaged[:-1]) + 1
    speed = np.diff(u) / np.diff(t)
    np.testing.assert_allclose(cols[entry, n_exit], speed[entry - 1], rtol=1e-9)
    # and the torque at exit is held through the dead band
    exits = np.flatnonzero(engaged[:-1] & ~engaged[1:])
    held = cols[exits[0] + 1 : exits[0] + 20, n_exit - 2]
    assert np.ptp(held) == 0.0 and held[0] == pytest.approx(np.mean(q[exits[0] - 4 : exits[0] + 1]))


def test_dead_band_motion_needs_the_backlash_fit_and_is_not_found_on_white_noise():
    u, t, rng = _rig_motion()
    q = rng.normal(size=u.size)
    r = rng.normal(0, 0.005, u.size)
    assert DeadBandMotion.detect(_data(r, u, t, q)) is None  # no switching functions to run
    for seed in range(3):
        r = np.random.default_rng(200 + seed).normal(0, 0.005, u.size)
        data = DetectionData(u, t, q, r, 30.0, 1e-3, backlash_params=BacklashParams(1.0, 0.25, 1.0, 0.25))
        det = DeadBandMotion.detect(data)
        assert det is not None and not det.score.significant()


def test_dead_band_motion_hands_on_its_columns_on_every_sample_only():
    """On every sample the detector's columns of the parts it chose are the effect's own terms, bit for
    bit (the loop keeps them for its fits); on a screen it has them at the scored rows only: none."""
    u, t, rng = _rig_motion()
    q = rng.normal(size=u.size)
    r = np.random.default_rng(7).normal(0, 0.005, u.size)
    data = DetectionData(u, t, q, r, 30.0, 1e-3, backlash_params=BacklashParams(1.0, 0.25, 1.0, 0.25))
    det = DeadBandMotion.detect(data)
    assert det is not None and det.columns is not None
    np.testing.assert_array_equal(det.columns, det.effect.clone().terms(u, t, q))
    assert det.nonzero_rows is not None and np.array_equal(
        det.nonzero_rows, nonzero_rows(det.columns)
    )  # noted by the pass
    from online_backlash.simulation.rig import simulate_rig

    rec = simulate_rig(duration_s=85.0, reversal_s=(0.4, 1.0), seed=5)  # 49 reversal cycles: a screen of 15
    u, t = rec.motor_deg / 30.0, rec.time_s
    folds = cycle_folds(u).screen(min_samples=0)  # a unit test's record: the screen's sample minimum lifted
    assert folds.screened
    r = np.random.default_rng(8).normal(0, 0.005, u.size)
    screened = DetectionData(
        u, t, np.full(u.size, np.nan), r, 30.0, 1e-3, backlash_params=BacklashParams(1.0, 0.25, 1.0, 0.25), folds=folds
    )
    det = DeadBandMotion.detect(screened)
    assert det is not None and det.columns is None


# --- the generic velocity function: a smooth law of the speed (issue 13, item 2) -------------


def _speed_law_record(seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rig motion (speeds 15-45 deg/s, smooth reversals) and a smooth nonlinear law of the
    physical speed (``np.gradient``, not the term's causal 10-sample difference): a lag growing
    with the square of the speed plus a Stribeck-like step, deg, with 0.002 deg of white noise."""
    from online_backlash.simulation.rig import rig_motion

    t, u = rig_motion(60.0, seed=seed)
    v = np.gradient(u, t)
    law = 0.02 * np.tanh(v / 15.0) - v * 0.0015 * (v / 30.0) ** 2
    return u, t, v, law + np.random.default_rng(seed).normal(0, 0.002, u.size)


def test_velocity_function_follows_a_smooth_law_of_the_speed_to_the_noise():
    u, t, v, r = _speed_law_record()
    data = _data(r, u, t, np.full(u.size, np.nan))
    det = VelocityFunction.detect(data)
    assert det is not None and det.score.significant() and det.score.heldout_gain > 0.99
    assert np.sqrt(det.score.rss_after / u.size) < 1.1 * 0.002  # down to the noise
    # the control: the piecewise-linear function on an even grid of 9 knots over both directions'
    # speeds pooled, which it replaces, leaves the law's curvature between its knots and does
    # not hold on the cycles left out (its outer knots lie beyond the slower direction's speeds)
    top = np.percentile(np.abs(v), 99)
    knots = np.linspace(-top, top, 9)
    hats = np.column_stack([np.interp(np.clip(v, -top, top), knots, np.eye(9)[j]) for j in range(9) if j != 4])
    pl = data.score(False, hats)
    assert np.sqrt(pl.rss_after / u.size) > 1.1 * 0.002 and not pl.heldout_gain > 0.9


def test_velocity_function_knots_sit_where_the_speeds_are():
    from online_backlash.diagnostics._speed import speed_knots

    v = _speed_law_record()[2]
    knots = speed_knots(v, 3)
    assert len(knots) == 9 and knots[4] == 0.0 and np.all(np.diff(knots) > 0)
    # each direction up to its own speeds
    assert knots[-1] == pytest.approx(np.percentile(v[v > 0], 99.5)) and knots[0] == pytest.approx(
        -np.percentile(-v[v < 0], 99.5)
    )
    assert speed_knots(np.r_[np.full(100, -20.0), np.full(100, 30.0)], 1) == (-20.0, -10.0, 0.0, 15.0, 30.0)
    assert speed_knots(np.full(100, 12.0), 2) == (0.0, 4.0, 8.0, 12.0)  # one direction only
    # the values at the knots are the function's (cardinal splines), 0 at rest
    f = VelocityFunction((-30.0, -10.0, 0.0, 20.0))
    cols = f.terms(np.r_[0.0, np.cumsum(np.full(40, 0.02))], np.arange(41) * 1e-3, np.full(41, np.nan))
    assert cols[-1] @ np.array([1.0, 2.0, 3.0]) == pytest.approx(3.0)  # at 20 deg/s: the value of the knot at 20
    assert f.describe(np.array([1.0, 2.0, 3.0]))["values_deg"] == [1.0, 2.0, 0.0, 3.0]


def test_velocity_function_invalid_knots():
    for knots in ((0.0,), (0.0, 0.0, 1.0), (-1.0, np.nan, 1.0), (3.0, 1.0)):
        with pytest.raises(InvalidParameterError):
            VelocityFunction(knots)
    with pytest.raises(InvalidParameterError):
        VelocityFunction((-1.0, 1.0), window_samples=0)


def test_causal_velocity_of_a_record_that_starts_in_motion():
    """Before its first sample a record is at rest at its first value, for the velocity of a whole
    array as for the effects' streaming window: the speed is there from the second sample on."""
    from online_backlash.diagnostics._causal import CausalWindow, velocity_deg_s

    t = np.arange(40) * 1e-3
    u = 0.3 + 30.0 * t
    v = velocity_deg_s(u, t, 10)
    assert v[0] == 0.0
    np.testing.assert_allclose(v[1:], 30.0)
    window = CausalWindow(10)
    ue, te, _, n_past = window.extend(u, t, np.zeros_like(t))
    np.testing.assert_array_equal(velocity_deg_s(ue, te, 10)[n_past:], v)
