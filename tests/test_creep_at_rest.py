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
from functools import lru_cache

import numpy as np
import pytest

from online_backlash.diagnostics import _search_round
from online_backlash.diagnostics._scoring import DetectionData
from online_backlash.diagnostics.dead_band import DeadBandMotion
from online_backlash.diagnostics.generic_terms import VelocityFunction
from online_backlash.diagnostics.loop import Diagnosis, diagnose_arrays
from online_backlash.errors import InvalidParameterError
from online_backlash.model import BacklashParams
from online_backlash.simulation.two_mass_rig import simulate_two_mass


def _stroke(
    speed_deg_s: float, ramp_s: float, dwell_s: float = 0.08, amplitude_deg: float = 20.0
) -> Callable[[float, float], tuple[np.ndarray, np.ndarray]]:
    """Strokes of ``2 amplitude_deg`` at ``speed_deg_s`` with a dwell of ``dwell_s`` at each end, the
    speed's steps smoothed over ``ramp_s`` (raised cosine): time (s) and load-side angle (deg)."""

    def motion(duration_s: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        t = np.arange(round(duration_s * rate_hz)) / rate_hz
        run = 2.0 * amplitude_deg / speed_deg_s
        phase = t % (2.0 * (run + dwell_s))
        v = np.select(
            [phase < run, phase < run + dwell_s, phase < 2.0 * run + dwell_s], [speed_deg_s, 0.0, -speed_deg_s], 0.0
        )
        k = max(3, int(ramp_s * rate_hz) | 1)
        kernel = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(k) / (k - 1))
        smooth = np.convolve(np.pad(v, (k // 2, k // 2), mode="edge"), kernel / kernel.sum(), mode="valid")
        return t, np.cumsum(smooth) / rate_hz

    return motion


def _record(ramp_s: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    rec = simulate_two_mass(
        duration_s=30.0,
        seed=seed,
        motion=_stroke(60.0, ramp_s),
        play_deg=0.5,
        stiffness_nm_per_arcmin=10.0,
        substeps=40,
        coulomb_nm=0.05,
    )
    return rec.time_s, rec.motor_deg, rec.load_deg, rec.ratio


@lru_cache(maxsize=2)
def _diagnosis(ramp_s: float, seed: int = 0) -> Diagnosis:
    return diagnose_arrays(*_record(ramp_s, seed))


def _diagnose(ramp_s: float, seed: int = 0) -> dict:
    return _diagnosis(ramp_s, seed).as_dict()


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
    up, down = total["moving_up"], total["moving_down"]
    # ahead of the motor in the direction it moved, inside the gap, after either stroke
    assert 0.0 < up < 0.5 and -0.5 < down < 0.0
    # How far ahead. The rig's load rests 0.0225 deg ahead of where it ran, after either stroke (the load
    # minus the motor angle at rest, less that at full speed: it leaves the flank while the motor slows
    # down). The creep of one direction alone is not what the data hold once a term acts at speed in both
    # directions alike: the lead's build-up in the last ~10 samples of each deceleration, which no term of
    # the library describes, is closed by a generic velocity_function whose values at +-60 deg/s (-4.8 and
    # -5.0 mdeg), with the backlash's offset, are a creep shifted by 4.8 mdeg after both strokes (the two
    # differ on those samples only). The creep comes out +0.0166 / -0.0262 deg (+0.0221 / -0.0221 with
    # dead_band_motion alone, max_terms=1), and shifting it back, with the offset and the other terms
    # refitted, leaves 0.8 % more squared residual. Their half difference has no common shift in it:
    # 0.0214 deg, held to the bound this test always had. (The bound once held on moving_up alone through a
    # mislabelled compliance correcting an extrapolated asymptote: docs/closing-the-loop.md, "The creep's
    # asymptote".)
    assert 0.02 < (up - down) / 2 < 0.5
    assert abs(d["backlash_after_deg"] - 0.5) < 0.03


def test_the_creep_reported_is_what_its_rests_reach():
    # the rests last 80 ms (60 ms of the dwell at rest, then the way back through the gap): a time constant
    # longer than that is a ramp over every rest whose asymptote, the total reported, is an extrapolation;
    # and after stops at one crawl speed the coast's columns are the creep's scaled, so no coast beside it
    diagnosis = _diagnosis(0.02)
    effect = next(s.effect for s in diagnosis.steps if s.effect.name == "dead_band_motion")
    rest = effect.typical_rest_s(diagnosis.u_deg, diagnosis.time_s)
    assert rest == pytest.approx(0.08, abs=0.002)
    assert effect.rest_time_constants_s and max(effect.rest_time_constants_s) <= rest
    assert effect.exit_time_constants_s == ()
    p = _creep(diagnosis.as_dict())["parameters"]
    for direction in ("moving_up", "moving_down"):
        taus = np.array([c["time_constant_s"] for c in p["creep_at_rest"]])
        shares = np.where(taus == 0, 1.0, -np.expm1(-rest / np.where(taus == 0, 1.0, taus)))
        reached = float(np.dot([c[f"{direction}_deg"] for c in p["creep_at_rest"]], shares))
        assert p["creep_at_rest_total_deg"][direction] == pytest.approx(reached, rel=0.1)


def test_a_refit_that_leaves_the_creep_unphysical_is_refused(monkeypatch):
    # the loop's guard, as the play guard holds the play: a candidate whose joint refit gives a term a figure no
    # drive can have is refused and the others are tried (here every refit with the velocity function is called so)
    monkeypatch.setattr(
        _search_round, "all_physical", lambda terms, *args: not any(isinstance(e, VelocityFunction) for e in terms)
    )
    d = diagnose_arrays(*_record(0.02)).as_dict()
    assert _creep(d) is not None
    assert "velocity_function" not in [e["name"] for e in d["effects"] + d["unexplained"]]


def test_the_creep_is_physical_only_ahead_in_the_direction_the_load_moved_and_inside_the_gap():
    effect = DeadBandMotion(1.0, 0.25, 1.0, 0.25, (), (), rest_time_constants_s=(0.008, 0.064), creep_step=True)
    assert effect.creep_shapes == (0.0, 0.008, 0.064) and effect.n_rest == 6

    def physical(up: tuple[float, float, float], down: tuple[float, float, float], tolerance_deg: float = 0.0) -> bool:
        coef = np.ravel(np.column_stack((up, down)))  # per shape, up then down
        return effect.creep_is_physical(coef, 0.1, 1e-3, tolerance_deg)

    assert physical((0.01, 0.05, 0.2), (-0.02, 0.0, -0.1))
    assert not physical((0.01, 0.05, 0.5), (0.0, 0.0, 0.0))  # beyond the other flank (0.5 deg away)
    assert not physical((0.0, 0.0, 0.0), (0.0, 0.03, 0.0))  # after moving down, up: back through the flank it left
    assert physical((0.0, 0.0, 0.0), (0.0, 0.003, 0.0), tolerance_deg=0.005)  # within the noise floor
    # positive over the rests up to 0.1 s, back through the flank at its asymptote: the total reported
    assert not physical((0.0, 0.2, -0.3), (0.0, 0.0, 0.0))
    one = DeadBandMotion(1.0, 0.25, 1.0, 0.25, (), (), rest_time_constants_s=(0.008,), creep_directions=(1,))
    assert one.creep_is_physical(np.array([0.1]), 0.1, 1e-3, 0.0)
    assert not one.creep_is_physical(np.array([-0.1]), 0.1, 1e-3, 0.0)


def test_a_creep_against_the_direction_the_load_moved_is_not_claimed():
    # after moving up the load creeps 0.04 deg on ahead; after moving down it goes 0.04 deg back up, through the
    # flank it left (no load at rest in the gap can): the creep after moving up only is claimed
    t, u = _stroke(60.0, 0.02)(30.0, 1000.0)
    p = BacklashParams(1.0, 0.25, 1.0, 0.25)
    creep = DeadBandMotion(*p.__dict__.values(), (), (), rest_time_constants_s=(0.016,))
    shape = creep.terms(u, t, np.full(t.size, np.nan))
    residual = 0.04 * shape[:, 0] + 0.04 * shape[:, 1] + np.random.default_rng(0).normal(0, 0.001, t.size)
    data = DetectionData(u, t, np.full(t.size, np.nan), residual, 30.0, 1e-3, backlash_params=p, noise_floor_deg=0.001)
    found = DeadBandMotion.detect(data)
    assert found is not None and found.score.significant() and "moving up only" in found.evidence
    total = found.effect.describe(found.score.coef)["creep_at_rest_total_deg"]
    assert total["moving_down"] == 0.0 and total["moving_up"] == pytest.approx(0.04, rel=0.1)


def test_a_motor_that_rests_after_a_gentle_stop_gets_no_creep():
    # the same rig and dwell, stopped over 0.3 s: the friction holds the load on the flank, nothing creeps
    d = _diagnose(ramp_s=0.3)
    assert _creep(d) is None, [e["parameters"].get("creep_at_rest_total_deg") for e in d["effects"]]


def test_the_creep_columns_rise_while_the_output_rests_in_the_direction_it_last_moved():
    effect = DeadBandMotion(
        1.0, 0.25, 1.0, 0.25, exit_time_constants_s=(), entry_knots_s=(), rest_time_constants_s=(0.01,)
    )
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
    # the step: the lead the load already has when the output stops, 1 at once; and the creep of one direction alone
    stepped = DeadBandMotion(
        1.0, 0.25, 1.0, 0.25, (), (), rest_time_constants_s=(0.01,), creep_step=True, creep_directions=(-1,)
    )
    steps = stepped.terms(u, t, np.zeros_like(t))
    assert steps.shape == (400, 2)
    np.testing.assert_array_equal(steps[:300], 0.0)  # resting after moving up: not this direction's
    np.testing.assert_array_equal(steps[301:, 0], 1.0)
    np.testing.assert_array_equal(steps[301:, 1], cols[301:, 1])
    params = stepped.describe(np.array([-0.05, -0.1]))
    assert params["creep_at_rest"] == [
        {"time_constant_s": 0.0, "moving_up_deg": 0.0, "moving_down_deg": -0.05},
        {"time_constant_s": 0.01, "moving_up_deg": 0.0, "moving_down_deg": -0.1},
    ]
    assert params["creep_at_rest_total_deg"] == {"moving_up": 0.0, "moving_down": pytest.approx(-0.15)}
    assert params["creep_directions"] == ["moving_down"]
    for wrong in ((), (2,), (1, 1)):
        with pytest.raises(InvalidParameterError, match="creep_directions"):
            DeadBandMotion(creep_directions=wrong)
