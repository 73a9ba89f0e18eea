"""The load creeping on while the motor rests on a flank (issue 13, item 3: run49's top reversal).

A motor that stops quickly at the end of a stroke and dwells there leaves the load moving: it
leaves the pushing flank, coasts ahead into the gap against its friction and waits there until
the other flank catches it. Eq. (7) keeps the model's output where the motor stopped, and the
dead band's coast (driven by the motor's speed when the switching functions release the load, 0
after a dwell) cannot describe it. ``DeadBandMotion``'s creep columns (``creep_at_rest``) can. The
logs come from the two-mass rig (its equations of motion, not the estimator's model).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from online_backlash.diagnostics.dead_band import DeadBandMotion
from online_backlash.diagnostics.loop import diagnose_arrays
from online_backlash.errors import InvalidParameterError
from online_backlash.two_mass_rig import simulate_two_mass


def _stroke(speed_deg_s: float, ramp_s: float, dwell_s: float = 0.08, amplitude_deg: float = 20.0) -> Callable[[float, float], tuple[np.ndarray, np.ndarray]]:
    """Strokes of ``2 amplitude_deg`` at ``speed_deg_s`` with a dwell of ``dwell_s`` at each end, the
    speed's steps smoothed over ``ramp_s`` (raised cosine): time (s) and load-side angle (deg)."""

    def motion(duration_s: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        t = np.arange(round(duration_s * rate_hz)) / rate_hz
        run = 2.0 * amplitude_deg / speed_deg_s
        phase = t % (2.0 * (run + dwell_s))
        v = np.select([phase < run, phase < run + dwell_s, phase < 2.0 * run + dwell_s], [speed_deg_s, 0.0, -speed_deg_s], 0.0)
        k = max(3, int(ramp_s * rate_hz) | 1)
        kernel = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(k) / (k - 1))
        smooth = np.convolve(np.pad(v, (k // 2, k // 2), mode="edge"), kernel / kernel.sum(), mode="valid")
        return t, np.cumsum(smooth) / rate_hz

    return motion


def _diagnose(ramp_s: float, seed: int = 0) -> dict:
    rec = simulate_two_mass(
        duration_s=30.0, seed=seed, motion=_stroke(60.0, ramp_s), play_deg=0.5, stiffness_nm_per_arcmin=10.0, substeps=40, coulomb_nm=0.05
    )
    return diagnose_arrays(rec.time_s, rec.motor_deg, rec.load_deg, rec.ratio).as_dict()


def _creep(d: dict) -> dict | None:
    found = [e for e in d["effects"] if e["name"] == "dead_band_motion" and "creep_at_rest" in e["parameters"]]
    return found[0] if found else None


def test_a_load_that_coasts_ahead_of_a_motor_at_rest_is_found_and_holds_out():
    # stopped within 20 ms from 60 deg/s: faster than the output's friction (0.05 N m on 0.002 kg m^2) stops the load
    d = _diagnose(ramp_s=0.02)
    creep = _creep(d)
    assert creep is not None, [e["evidence"]["summary"] for e in d["effects"]]
    assert "creep at rest" in creep["evidence"]["summary"]
    assert creep["evidence"]["heldout_gain"] > 0.3 and creep["evidence"]["heldout_gain_in_final_model"] > 0.3
    total = creep["parameters"]["creep_at_rest_total_deg"]
    # ahead of the motor in the direction it moved, inside the gap
    assert 0.02 < total["moving_up"] < 0.5
    assert abs(d["backlash_after_deg"] - 0.5) < 0.03


def test_a_motor_that_rests_after_a_gentle_stop_gets_no_creep():
    # the same rig and dwell, stopped over 0.3 s: the friction holds the load on the flank, nothing creeps
    d = _diagnose(ramp_s=0.3)
    assert _creep(d) is None, [e["parameters"].get("creep_at_rest_total_deg") for e in d["effects"]]


def test_the_creep_columns_rise_while_the_output_rests_in_the_direction_it_last_moved():
    effect = DeadBandMotion(1.0, 0.25, 1.0, 0.25, exit_time_constants_s=(), entry_knots_s=(), rest_time_constants_s=(0.01,))
    t = np.arange(400) * 1e-3
    u = np.concatenate((np.linspace(0.0, 1.0, 100), np.full(100, 1.0), np.linspace(1.0, 0.0, 100), np.full(100, 0.0)))
    cols = effect.terms(u, t, np.zeros_like(t))
    assert cols.shape == (400, 2)
    np.testing.assert_array_equal(cols[1:100], 0.0)  # the output moves with the motor
    np.testing.assert_allclose(cols[150, 0], -np.expm1(-0.051 / 0.01), rtol=1e-9)  # resting after moving up
    assert np.all(cols[100:200, 1] == 0.0) and np.all(cols[100:200, 0] > 0)
    # back through the dead band (0.5 deg): still resting, still after moving up; then down the other flank
    assert np.all(cols[200:249, 0] > 0)
    np.testing.assert_array_equal(cols[252:300], 0.0)
    assert np.all(cols[301:, 1] > 0) and np.all(cols[301:, 0] == 0.0)
    params = effect.describe(np.array([0.2, -0.1]))
    assert params["creep_at_rest"] == [{"time_constant_s": 0.01, "moving_up_deg": 0.2, "moving_down_deg": -0.1}]
    with pytest.raises(InvalidParameterError, match="rest_time_constants_s"):
        DeadBandMotion(rest_time_constants_s=(0.0,))
