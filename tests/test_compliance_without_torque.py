"""Compliance found without a torque column (issue 27, item 6): the load's acceleration stands in for the torque.

The logs come from :func:`online_backlash.simulation.synthetic.inertial_twist`: a prescribed smooth motion,
a load that twists by ``-(J / k)`` times the motion's *analytic* acceleration while a flank is engaged,
encoders quantised afterwards. The tool reads only the quantised angles and differentiates them its own way
(a causal Savitzky-Golay filter), so it cannot succeed by inverting the simulator's arithmetic.
"""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from online_backlash import BacklashRLS
from online_backlash.diagnostics._causal import START_SAMPLES, CausalWindow, savgol_derivative
from online_backlash.diagnostics._fit_view import held_mask
from online_backlash.diagnostics.effects import Compliance
from online_backlash.diagnostics.loop import diagnose_arrays
from online_backlash.simulation import synthetic

#: the default twist of the simulator, s^2 (J / k)
J_OVER_K = synthetic.INERTIA_OVER_STIFFNESS_S2


def _names(d: dict) -> list[str]:
    return [e["name"] for e in d["effects"]] + [e["name"] for e in d["unexplained"]]


# --- the simulator ---------------------------------------------------------------------------------


@pytest.mark.parametrize("motion", sorted(synthetic.MOTIONS))
def test_the_prescribed_motion_has_the_acceleration_it_states(motion):
    """The closed-form acceleration is the second derivative of the closed-form angle (checked at 10 kHz
    against central differences)."""
    t, u, a = synthetic.MOTIONS[motion](10.0, rate_hz=10000.0, seed=2)
    numeric = (u[2:] - 2.0 * u[1:-1] + u[:-2]) / (t[1] - t[0]) ** 2
    assert np.max(np.abs(a)) > 100.0
    np.testing.assert_allclose(numeric, a[1:-1], rtol=0, atol=2e-3 * np.max(np.abs(a)))


@pytest.mark.parametrize("motion", sorted(synthetic.MOTIONS))
def test_the_load_twists_by_the_analytic_acceleration_on_an_engaged_flank(motion):
    """On an engaged flank the load is ``u - (J / k) a`` minus the flank's half play (eq. 1, slopes 1);
    the load the simulator writes does not depend on how coarse the motor encoder is (the twist comes
    from the prescribed motion, not from the angles the tool reads)."""
    _, motor, load, q = synthetic.inertial_twist(seed=1, duration_s=20.0, motion=motion, motor_bits=40, load_bits=40)
    _, u, a = synthetic.MOTIONS[motion](20.0, seed=1)
    assert np.all(np.isnan(q))
    y = load + 321.0  # the simulator's load-encoder zero
    twisted = u - J_OVER_K * a
    right, left = np.abs(y - (twisted - 0.25)) < 1e-6, np.abs(y - (twisted + 0.25)) < 1e-6
    assert (
        right.mean() > 0.15 and left.mean() > 0.15 and (right | left).mean() > 0.5
    )  # a flank carries the load most of the time
    assert np.max(np.abs(J_OVER_K * a[right | left])) > 0.01  # the twist is there, tens of microradians and more
    np.testing.assert_allclose((motor - 1234.5) / 30.0, u, atol=1e-6)
    _, _, coarse, _ = synthetic.inertial_twist(seed=1, duration_s=20.0, motion=motion, motor_bits=14, load_bits=40)
    np.testing.assert_array_equal(coarse, load)


# --- the differentiator ------------------------------------------------------------------------------


@pytest.mark.parametrize("deriv", [1, 2])
def test_the_causal_savitzky_golay_derivative_is_exact_for_a_quartic(deriv):
    """The quartic through the window evaluated at its newest sample: no lag for a quartic motion, and the
    angle's zero does not matter (a shaft that has turned 1e5 deg)."""
    t = 3.0 + np.arange(400) * 2e-3
    s = t - 3.4
    u = 1e5 + 7.0 * s + 40.0 * s**2 - 90.0 * s**3 + 120.0 * s**4
    du = 7.0 + 80.0 * s - 270.0 * s**2 + 480.0 * s**3
    d2u = 80.0 - 540.0 * s + 1440.0 * s**2
    got = savgol_derivative(u, t, 41, deriv, start=None)
    np.testing.assert_allclose(got[40:], (du if deriv == 1 else d2u)[40:], rtol=0, atol=1e-4)
    assert np.all(got[:40] == 0.0)  # a window reaching before the array: the past a streaming caller keeps


def test_a_record_starting_in_motion_gets_its_acceleration_from_its_own_samples():
    """Before its first sample a record is not at rest as far as its acceleration goes: the first samples
    get a quadratic through the samples since the start (from START_SAMPLES on), not the jump from rest
    that a difference across the record's start makes (1.4e5 deg/s^2 on this record, for a true 80)."""
    t = np.arange(200) * 1e-3
    u = 5.0 + 30.0 * t + 40.0 * t**2
    acc = savgol_derivative(u, t, 61, 2, start=0)
    assert np.all(acc[: START_SAMPLES - 1] == 0.0)
    np.testing.assert_allclose(acc[START_SAMPLES - 1 :], 80.0, rtol=1e-6)
    # from rest at the first sample, two velocities 10 samples apart (the differencing the proxy had)
    v = np.concatenate((np.zeros(1), (u[1:11] - u[0]) / t[1:11], (u[11:] - u[1:-10]) / 0.01))
    assert (v[1] - 0.0) / 1e-3 > 1e4


def test_the_window_says_where_the_record_starts():
    """``CausalWindow.record_start``: the rows before it are the rest before the record, in pieces as whole."""
    w = CausalWindow(5)
    u = np.arange(12.0)
    assert w.extend(u[:2], u[:2], u[:2])[3] == 5 and w.record_start == 5
    w.keep(*w.extend(u[:2], u[:2], u[:2])[:3])
    w.extend(u[2:4], u[2:4], u[2:4])
    assert w.record_start == 3  # two samples seen: three rows of rest left in the past kept
    w.keep(*w.extend(u[2:4], u[2:4], u[2:4])[:3])
    w.extend(u[4:5], u[4:5], u[4:5])
    assert w.record_start == 1
    w.keep(*w.extend(u[4:5], u[4:5], u[4:5])[:3])
    w.extend(u[5:6], u[5:6], u[5:6])
    assert w.record_start == 0  # five seen: the past kept is the record's first five samples
    w.keep(*w.extend(u[5:6], u[5:6], u[5:6])[:3])
    w.extend(u[6:7], u[6:7], u[6:7])
    assert w.record_start is None
    w.reset()
    w.extend(u[:1], u[:1], u[:1])
    assert w.record_start == 5


@pytest.mark.parametrize("proxy", ["acceleration", "motion"])
def test_the_motion_proxy_streams_in_pieces_as_whole(proxy):
    """The EffectTerms contract over a record's start: the same rows whole, in pieces and one at a time."""
    t, motor, _, q = synthetic.inertial_twist(seed=4, duration_s=2.0)
    u = motor / 30.0
    effect = Compliance(proxy, window_samples=21)
    whole = effect.clone().terms(u, t, q)
    e = effect.clone()
    cuts = [0, 1, 3, 9, 20, 21, 400, 1500, u.size]
    np.testing.assert_allclose(
        np.vstack([e.terms(u[a:b], t[a:b], q[a:b]) for a, b in itertools.pairwise(cuts)]), whole, rtol=0, atol=1e-9
    )
    e.reset()
    np.testing.assert_allclose(
        np.vstack([e.terms(u[i : i + 1], t[i : i + 1], q[i : i + 1]) for i in range(60)]), whole[:60], rtol=0, atol=1e-9
    )
    assert np.all(whole[: START_SAMPLES - 1] == 0.0) and np.all(whole[START_SAMPLES - 1 :, 0] != 0.0)


@pytest.mark.parametrize("stop", [15, 12000])
def test_a_tracker_with_the_motion_proxy_resumes_bit_for_bit(stop):
    """Saved within the differentiator's first window or long after, the tracker's state restores the
    proxy's stream exactly (the first sample and the last ``history`` ones, replayed): the resumed tracker
    goes on as the one that was never saved."""
    t, motor, load, _ = synthetic.inertial_twist(seed=2, duration_s=20.0)
    u = motor / 30.0

    def tracker() -> BacklashRLS:
        return BacklashRLS(warm_start_samples=3000, effects=[Compliance("acceleration", window_samples=41)])

    kept, part = tracker(), tracker()
    for est in (kept, part):
        est.learn_many(u[:stop], load[:stop], time_s=t[:stop])
    resumed = BacklashRLS.from_state(json.loads(json.dumps(part.state_dict())))
    for est in (kept, resumed):
        est.learn_many(u[stop:], load[stop:], time_s=t[stop:])
    np.testing.assert_array_equal(resumed.theta_, kept.theta_)
    np.testing.assert_array_equal(resumed.beta_, kept.beta_)
    assert resumed.beta_[0] == pytest.approx(-J_OVER_K, rel=0.1)  # the tracker finds the twist too


def test_the_motion_proxies_act_on_the_input_side_the_torque_on_the_load():
    """A load at rest in the dead band stays where the flank left it, twist and all: the motion proxies are
    held through the dead band (eq. 7) as an input-side term; the measured torque is zero there by its sign."""
    assert held_mask([Compliance("acceleration"), Compliance("motion"), Compliance("torque")]).tolist() == [
        True,
        True,
        True,
        False,
    ]


# --- the loop ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def issue_case() -> dict:
    t, m, y, q = synthetic.inertial_twist(seed=0, duration_s=120.0)
    return diagnose_arrays(t, m, y, 30.0, torque_Nm=q).as_dict()


def test_an_inertial_twist_without_torque_is_named_compliance(issue_case):
    """The issue's case: 14-bit motor, 17-bit load, no torque column, a load twisting in proportion to its
    acceleration on an engaged flank. ``compliance`` is named first by its motion proxy, the residual is at
    least halved, and no drift is claimed."""
    d = issue_case
    assert d["rms_after_deg"] <= 0.5 * d["rms_before_deg"]
    assert "drift" not in _names(d)
    first = d["effects"][0]
    assert first["name"] == "compliance"
    p = first["parameters"]
    assert p["deflection_per_acceleration_s2"] == pytest.approx(-J_OVER_K, rel=0.02)
    assert p["proxy"] == "load-side acceleration (inertial torque)"
    assert p["inertia_over_stiffness_s2"] == -p["deflection_per_acceleration_s2"]
    assert p["natural_frequency_hz"] == pytest.approx(1.0 / (2.0 * np.pi * np.sqrt(J_OVER_K)), rel=0.01)
    assert first["evidence"]["heldout_gain"] > 0.9 and first["evidence"]["heldout_gain_in_final_model"] > 0.9
    assert d["rms_after_deg"] <= 0.05 * d["rms_before_deg"]  # 0.0378 -> 0.0010 deg
    assert d["backlash_after_deg"] == pytest.approx(0.5, rel=0.005)


@pytest.mark.parametrize(
    ("kwargs", "within"),
    [
        (
            dict(motion="point_to_point", seed=3, inertia_over_stiffness_s2=4e-5),
            0.05,
        ),  # another stiffness, motion and seed
        (dict(seed=5, motor_bits=20, load_bits=20), 0.01),  # 20-bit encoders
        (dict(motion="point_to_point", seed=3, inertia_over_stiffness_s2=4e-5, motor_bits=20, load_bits=20), 0.03),
    ],
    ids=["point_to_point", "two_tone_20_bit", "point_to_point_20_bit"],
)
def test_at_settings_not_tuned_on(kwargs, within):
    t, m, y, q = synthetic.inertial_twist(duration_s=120.0, **kwargs)
    d = diagnose_arrays(t, m, y, 30.0, torque_Nm=q).as_dict()
    assert d["rms_after_deg"] <= 0.5 * d["rms_before_deg"]
    assert "drift" not in _names(d)
    first = d["effects"][0]
    assert first["name"] == "compliance" and first["parameters"]["proxy"].startswith("load-side acceleration")
    assert first["parameters"]["deflection_per_acceleration_s2"] == pytest.approx(
        -kwargs.get("inertia_over_stiffness_s2", J_OVER_K), rel=within
    )
    assert d["backlash_after_deg"] == pytest.approx(0.5, rel=0.005)
