"""The effect library: the EffectTerms protocol, causal streaming, detection and description with units."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from online_backlash.diagnostics._scoring import DetectionData, score_columns
from online_backlash.diagnostics.effects import LIBRARY, VOCABULARY, Compliance, Delay, Drift, TransmissionError
from online_backlash.diagnostics.generic import GENERIC, AngleHarmonicsPerFlank, VelocityFunction
from online_backlash.effect_terms import EffectTerms
from online_backlash.errors import InvalidParameterError

ALL = [
    TransmissionError((2, 5), (1,), 30.0),
    Delay(3, 1e-3),
    Compliance("torque"),
    Compliance("acceleration", 7),
    Drift(2, 40.0),
    AngleHarmonicsPerFlank((1, 3)),
    VelocityFunction((-40.0, -10.0, 0.0, 10.0, 40.0)),
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
    p = det.effect.describe(np.array([1e-5, 2e-3]))
    assert det.effect.proxy == "motion"
    assert p["proxy"].startswith("load-side acceleration and velocity")
    assert p["deflection_per_acceleration_s2"] == 1e-5 and p["deflection_per_velocity_s"] == 2e-3


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
