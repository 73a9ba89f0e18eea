"""The load's state in the dead band at the record's start: estimated as the model's initial
condition (a nuisance of the base fit), taken out of the residual before and after alike, and
never claimed as an effect (issue 13, the two-mass bench's "<= 1.5 floor")."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from davinci_runs import DAVINCI, UNITS, WITH_TORQUE

from online_backlash.cli import main
from online_backlash.diagnostics import loop
from online_backlash.diagnostics._initial_state import InitialState, estimate_initial_state, simulate_with_coast
from online_backlash.diagnostics.loop import diagnose_arrays
from online_backlash.diagnostics.residuals import simulation_residual
from online_backlash.estimators import VorosBacklash
from online_backlash.model import BacklashParams, simulate_backlash
from online_backlash.simulation import synthetic
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.two_mass_rig import simulate_two_mass

#: the first samples of a record, where the two-mass rig's load coasts from mid-gap (about 15 ms)
START = 50


def _today(monkeypatch: pytest.MonkeyPatch, *args, **kwargs):
    """The loop as it was before the start was estimated: the model at rest at the first sample."""
    with monkeypatch.context() as m:
        m.setattr(loop, "estimate_initial_state", lambda *a: InitialState())
        return diagnose_arrays(*args, **kwargs)


def _same(a: dict, b: dict) -> None:
    for key in ("rms_before_deg", "rms_after_deg", "backlash_before_deg", "backlash_after_deg"):
        assert a[key] == pytest.approx(b[key], rel=1e-9, abs=1e-12), key
    assert [e["name"] for e in a["effects"]] == [e["name"] for e in b["effects"]]
    assert [e["name"] for e in a["unexplained"]] == [e["name"] for e in b["unexplained"]]


@pytest.fixture(scope="module")
def coasting_start():
    """The stiff two-mass rig: the load starts mid-gap at the motor's speed and coasts (seed 3)."""
    return synthetic.two_mass_clean(seed=3, duration_s=20.0)


@pytest.fixture(scope="module")
def coasting_diagnosis(coasting_start):
    t, m, y, q = coasting_start
    return diagnose_arrays(t, m, y, 30.0, torque_Nm=q)


def test_a_coasting_start_is_estimated_and_taken_out_of_the_residual(coasting_start, coasting_diagnosis):
    t, m, _, _ = coasting_start
    d = coasting_diagnosis
    state = d.as_dict()["initial_state"]
    assert state["estimated"] and 5 <= state["samples"] <= 40
    # the rig starts with the load at the motor's speed, mid-gap, at the first measured angle
    u = m / 30.0
    speed = (u[5] - u[0]) / (t[5] - t[0])
    assert state["velocity_deg_s"] == pytest.approx(speed, rel=0.15)
    step = d.noise.step_deg
    assert abs(state["offset_deg"]) < 2 * step
    assert 0.5e-3 < state["time_constant_s"] < 0.05  # the rig's viscous J / b is 6.7 ms
    floor = d.noise.floor_deg
    # until the flank catches the load the residual is at the noise floor, before and after alike
    # (with the load at rest there it is 0.05-0.08 deg; the impact's ringing after it is not the start's)
    n = state["samples"]
    for r in (d.residual_before_deg, d.residual_after_deg):
        assert np.sqrt(np.mean(r[:n] ** 2)) < 2 * floor
        assert np.sqrt(np.mean(r[:START] ** 2)) < 5 * floor
    assert state["rms_at_rest_deg"] > 20 * floor and state["rms_deg"] < 2 * floor
    assert d.rms_after_deg < 1.3 * floor
    # the residual before is the simulation residual with the start's path
    uc, yc = d.u_deg - d.base.u_ref_, d.load_deg - d.base.y_ref_
    np.testing.assert_allclose(
        d.residual_before_deg, simulation_residual(d.base.params_, uc, yc, d.initial_state.path_deg)
    )
    # a nuisance, never an effect
    assert d.as_dict()["effects"] == [] and d.as_dict()["unexplained"] == []


def test_the_start_is_what_kept_the_clean_rig_above_the_floor(coasting_start, coasting_diagnosis, monkeypatch):
    t, m, y, q = coasting_start
    before = _today(monkeypatch, t, m, y, 30.0, torque_Nm=q)
    floor = before.noise.floor_deg
    assert np.sqrt(np.mean(before.residual_before_deg[:START] ** 2)) > 20 * floor
    assert coasting_diagnosis.rms_after_deg < 0.8 * before.rms_after_deg
    # past the start, the two are the same residual
    past = coasting_diagnosis.time_s >= 0.2
    np.testing.assert_allclose(
        coasting_diagnosis.residual_after_deg[past], before.residual_after_deg[past], atol=0.2 * floor
    )


def test_a_start_in_the_other_direction_gets_a_negative_velocity(coasting_start):
    t, m, y, _ = coasting_start
    base = VorosBacklash(refine=True, origin="first").fit(-m / 30.0, -y)
    state = estimate_initial_state(base.params_, -m / 30.0 - base.u_ref_, -y - base.y_ref_, t)
    assert state.estimated
    assert state.coast.velocity_deg_s == pytest.approx(-(m[5] - m[0]) / 30.0 / (t[5] - t[0]), rel=0.15)


def test_a_log_that_starts_at_rest_gets_no_correction_and_the_same_results(monkeypatch):
    # the estimator's own model: the load at rest mid-gap until the motor's flank reaches it
    rec = simulate_rig(duration_s=20.0, seed=5)
    t, m, y, q = synthetic.clean(rec)
    d = diagnose_arrays(t, m, y, rec.ratio, torque_Nm=q)
    assert not d.initial_state.estimated and d.as_dict()["initial_state"]["samples"] == 0
    _same(d.as_dict(), _today(monkeypatch, t, m, y, rec.ratio, torque_Nm=q).as_dict())


def test_a_log_that_starts_engaged_gets_no_correction_and_the_same_results(monkeypatch):
    # a load torque holds the output on a flank from the first sample (the rig starts wound up on it)
    rec = simulate_two_mass(
        duration_s=20.0,
        seed=2,
        motion="rig",
        coulomb_nm=0.05,
        play_deg=0.5,
        stiffness_nm_per_arcmin=10.0,
        substeps=40,
        external_torque_nm=0.1,
    )
    t, m, y = rec.time_s, rec.motor_deg, rec.load_deg
    assert rec.torque_true_Nm[0] > 0  # engaged at the first sample
    d = diagnose_arrays(t, m, y, rec.ratio)
    assert not d.initial_state.estimated
    _same(d.as_dict(), _today(monkeypatch, t, m, y, rec.ratio).as_dict())


def test_a_real_effect_is_still_named_first():
    t, m, y, q = synthetic.two_mass_delay(seed=1, duration_s=30.0)
    d = diagnose_arrays(t, m, y, 30.0, torque_Nm=q).as_dict()
    assert d["initial_state"]["estimated"]
    assert d["effects"][0]["name"] == "delay"
    assert d["effects"][0]["parameters"]["lag_samples"] == pytest.approx(4, abs=0.5)


def test_the_model_follows_the_path_until_a_flank_catches_the_load():
    p = BacklashParams(1.0, 0.25, 1.0, 0.25)
    u = np.linspace(0.0, 1.0, 101)
    np.testing.assert_array_equal(simulate_with_coast(u, p, np.empty(0), 0.1), simulate_backlash(u, p, 0.1))
    # the load coasts ahead at half the motor's speed: the flank catches it where u - 0.25 = u / 2
    path = 0.5 * u
    x = simulate_with_coast(u, p, path)
    k = int(np.argmax(u >= path + 0.25))
    assert 40 < k < 60
    np.testing.assert_array_equal(x[:k], path[:k])
    np.testing.assert_allclose(x[k:], u[k:] - 0.25)
    # a path that ends before any flank engages: the load stays at its last value (eq. 7)
    x = simulate_with_coast(u, p, np.full(10, 0.05))
    np.testing.assert_array_equal(x[10:29], 0.05)
    np.testing.assert_allclose(x[32:], u[32:] - 0.25)


def test_diagnose_reports_the_start_in_json_and_text(tmp_path, capsys):
    rec = simulate_two_mass(
        duration_s=20.0, seed=4, stiffness_nm_per_arcmin=10.0, substeps=40, **synthetic.TWO_MASS_RIG
    )
    path = tmp_path / "rig.csv"
    rec.write_csv(path)
    assert main(["diagnose", str(path), "--ratio", "30", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    state = out["initial_state"]
    assert {"estimated", "samples", "offset_deg", "velocity_deg_s", "time_constant_s"} <= set(state)
    assert state["estimated"] and state["samples"] > 0
    assert state["velocity_deg_s"] == pytest.approx(
        np.mean(np.diff(rec.u_true_deg[:6])) / (rec.time_s[1] - rec.time_s[0]), rel=0.15
    )
    assert out["effects"] == [] and out["rms_after_deg"] < 1.3 * out["noise_floor_deg"]
    assert main(["diagnose", str(path), "--ratio", "30"]) == 0
    assert "Record start: the load was moving in the dead band" in capsys.readouterr().out


def test_a_load_that_runs_on_with_the_motor_is_not_taken_for_a_coast():
    # the load moves with the motor in mid-gap for 2 s (no friction stops it), then stops until the flank catches it:
    # no coast lasts that long, and the estimate must not stretch its window over the record
    p = BacklashParams(1.0, 0.25, 1.0, 0.25)
    t = np.arange(6000) * 1e-3
    u = 30.0 * t
    y = np.minimum(u, u[2000])
    y = np.where(u >= y + 0.25, u - 0.25, y)
    state = estimate_initial_state(p, u, y, t)
    assert (
        state.samples <= 4 * 9 + 64
    )  # at most MAX_STRETCH times the rest model's engagement (9 samples), plus MIN_EXTRA


#: the kicked rig's record starts 2 ms before the top of its 0.5 Hz sine (motor at rest), and a
#: 3 ms torque pulse sets the resting load moving 10 ms into the record (a preload released)
_TOP_S, _KICK_S = 0.5, 0.508


def _kicked_from_rest(duration_s: float = 20.0) -> tuple[np.ndarray, ...]:
    """The stiff two-mass rig (play 1.75 deg, as the measured tool), logged from the top of a
    stroke, where the load rests on a flank, with a kick that throws it 0.5 deg into the gap:
    it stops there and waits until the other flank catches it (as the measured run49 starts)."""

    def kick(s: np.ndarray) -> np.ndarray:  # N m, pushing the load up the gap
        return np.where((s >= _KICK_S) & (s < _KICK_S + 0.003), -1.2, 0.0)

    rec = simulate_two_mass(
        duration_s=duration_s + _TOP_S,
        seed=0,
        play_deg=1.75,
        stiffness_nm_per_arcmin=10.0,
        substeps=40,
        coulomb_nm=0.05,
        external_torque_nm=kick,
        frequency_hz=0.5,
        amplitude_deg=30.0,
    )
    keep = rec.time_s >= _TOP_S - 0.002
    return rec.time_s[keep] - rec.time_s[keep][0], rec.motor_deg[keep], rec.load_deg[keep], rec.torque_Nm[keep]


def test_a_load_kicked_from_rest_is_estimated_with_the_time_it_starts_to_move(monkeypatch):
    t, m, y, q = _kicked_from_rest()
    d = diagnose_arrays(t, m, y, 30.0, torque_Nm=q)
    state, floor = d.as_dict()["initial_state"], d.noise.floor_deg
    assert state["estimated"]
    assert state["starts_moving_after_s"] == pytest.approx(_KICK_S - (_TOP_S - 0.002), abs=0.003)
    # at rest where the record starts (the pulse's 3 ms of push, taken for a kick at one sample, leave a few steps)
    assert abs(state["offset_deg"]) < 0.02
    assert state["stops_after_s"] is not None and state["velocity_deg_s"] > 0  # thrown up the gap, and stopped there
    assert state["rms_at_rest_deg"] > 300 * floor and state["rms_deg"] < 0.03 * state["rms_at_rest_deg"]
    assert d.rms_after_deg < 1.5 * floor
    # until the flank catches the load, the residual after is the start's own, the same as before
    n = state["samples"]
    np.testing.assert_array_equal(d.residual_after_deg[:n], d.residual_before_deg[:n])
    assert "initial_state" not in {e["name"] for e in d.as_dict()["effects"] + d.as_dict()["unexplained"]}
    # the start model moving from the first sample does not describe it: nothing estimated, the kick left in
    with monkeypatch.context() as ctx:
        ctx.setattr("online_backlash.diagnostics._initial_state.MAX_STARTS", 0)
        old = diagnose_arrays(t, m, y, 30.0, torque_Nm=q)
    assert not old.initial_state.estimated
    assert np.sqrt(np.mean(old.residual_after_deg[:n] ** 2)) > 10 * np.sqrt(np.mean(d.residual_after_deg[:n] ** 2))


def test_the_measured_run49_start_is_a_kick_from_rest_that_waits_in_the_gap(capsys):
    # the tool's run at full reaction torque: the spindle rests for 8 ms, is thrown 1 deg ahead of the motor,
    # stops there, and waits until the motor's reversal brings the other flank to it (0.155 s)
    path = next(DAVINCI.glob("tool4_L_run49_*.csv"))
    assert main(["diagnose", str(path), *UNITS, "--columns", WITH_TORQUE, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    state = out["initial_state"]
    assert state["estimated"] and state["delta_bic"] < -100
    assert 0.005 <= state["starts_moving_after_s"] <= 0.012
    assert state["stops_after_s"] < 0.05 and 100 <= state["samples"] <= 200
    assert state["rms_at_rest_deg"] > 0.5 and state["rms_deg"] < 0.1
    # the steps' figures take the start as the whole does: each step starts where the last ended, the last ends at the
    # whole's
    steps = out["effects"] + out["unexplained"]
    assert steps and steps[0]["rms_before_deg"] == out["rms_before_deg"]
    assert all(a["rms_after_deg"] == b["rms_before_deg"] for a, b in itertools.pairwise(steps))
    assert steps[-1]["rms_after_deg"] == pytest.approx(out["rms_after_deg"], rel=1e-12)


def test_a_load_that_starts_late_and_runs_on_until_caught_is_not_taken_for_a_kick():
    # the load rests for 20 ms, then moves at 0.8 times the motor's speed inside the gap until the flank catches it
    # (87 ms): as much a lag behind the motor as a kick, so no start later than the first sample is estimated
    p = BacklashParams(1.0, 1.0, 1.0, 1.0)
    t = np.arange(3000) * 1e-3
    u = 30.0 * t
    y = np.where(t < 0.02, 0.0, 0.8 * (u - u[20]))
    caught = int(np.argmax(u >= y + 1.0))
    y[caught:] = u[caught:] - 1.0
    assert 80 < caught < 95
    state = estimate_initial_state(p, u, y, t)
    assert not state.estimated or state.coast.start_s == 0.0
