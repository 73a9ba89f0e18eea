"""Flank lines that are not straight (``flank_profile``, issue 13 item 3): a deflection that depends on
the angle and differs between the flanks, found on a rig that has it as physics and nowhere else.

The rig is the two-mass rig of the load-aware issue on the measured runs' test (a 30 deg sine at
0.5 Hz) with a tight spot on the output: its Coulomb friction is four times higher around one
angle. On an engaged flank the gear twists under the friction the motor has to overcome, behind
the motor while it turns up and ahead of it while it turns down, so each flank line bends there,
in opposite directions. No torque is logged (the friction is not known to the loop).
"""

from __future__ import annotations

import numpy as np
import pytest

from online_backlash.diagnostics._scoring import DetectionData
from online_backlash.diagnostics.dead_band import DeadBandMotion
from online_backlash.diagnostics.effects import LIBRARY, VOCABULARY
from online_backlash.diagnostics.flank_profile import FlankProfile, hat_columns
from online_backlash.diagnostics.loop import diagnose_arrays
from online_backlash.effect_terms import effect_class, effect_from_dict, effect_to_dict
from online_backlash.errors import InvalidParameterError
from online_backlash.model import BacklashParams
from online_backlash.simulation import synthetic
from online_backlash.simulation.two_mass_rig import ARCMIN_PER_DEG, simulate_two_mass

STIFFNESS_NM_PER_ARCMIN = 0.1
COULOMB_NM = 0.05
SPOT_DEG, SPOT_WIDTH_DEG, SPOT_EXTRA = 10.0, 4.0, 3.0


def _spot(angle_deg: np.ndarray) -> np.ndarray:
    """The output's friction as a multiple of ``COULOMB_NM``: a tight spot around ``SPOT_DEG``."""
    return 1.0 + SPOT_EXTRA * np.exp(-(((np.asarray(angle_deg) - SPOT_DEG) / SPOT_WIDTH_DEG) ** 2))


def _tight_spot_rig(seed: int, spot: bool = True):
    return simulate_two_mass(
        duration_s=20.0,
        play_deg=0.5,
        stiffness_nm_per_arcmin=STIFFNESS_NM_PER_ARCMIN,
        viscous_nms_per_rad=0.01,
        coulomb_nm=COULOMB_NM,
        coulomb_profile=_spot if spot else None,
        motion="sine",
        amplitude_deg=30.0,
        frequency_hz=0.5,
        seed=seed,
    )


@pytest.fixture(scope="module")
def tight_spot():
    rec = _tight_spot_rig(seed=0)
    return rec, diagnose_arrays(rec.time_s, rec.motor_deg, rec.load_deg, rec.ratio)


def test_hat_columns_interpolate_and_hold_beyond_the_ends():
    knots = np.array([0.0, 1.0, 3.0])
    h = hat_columns(np.array([-1.0, 0.0, 0.5, 2.0, 3.0, 9.0]), knots)
    np.testing.assert_allclose(h.sum(axis=1), 1.0)
    np.testing.assert_allclose(h[2], [0.5, 0.5, 0.0])
    np.testing.assert_allclose(h[3], [0.0, 0.5, 0.5])
    np.testing.assert_allclose(h[[0, 5]], [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    # a value at the knots is read back by the columns
    values = np.array([0.3, -0.2, 0.1])
    np.testing.assert_allclose(h @ values, np.interp([-1.0, 0.0, 0.5, 2.0, 3.0, 9.0], knots, values))


def test_columns_are_the_inner_knots_of_the_flank_that_drives():
    """Moving up only the first half is non-zero, moving down only the second; the outer knots carry no
    column (the flank's straight part is eq. (1)'s line, not this effect's)."""
    t = np.arange(4000) * 1e-3
    u = 20.0 * np.sin(2 * np.pi * 0.5 * t)
    effect = FlankProfile((-15.0, -5.0, 5.0, 15.0))
    cols = effect.terms(u, t, np.full(t.size, np.nan))
    assert cols.shape == (t.size, 4)
    v = np.gradient(u, t)
    up, down = v > 5.0, v < -5.0
    assert np.all(cols[up][:, 2:] == 0.0) and np.all(cols[down][:, :2] == 0.0)
    assert np.count_nonzero(cols[up][:, :2]) > 500 and np.count_nonzero(cols[down][:, 2:]) > 500
    at = np.argmin(np.abs(u - 5.0) + 100.0 * ~up)  # moving up at a knot: that knot's column is 1
    assert cols[at, 1] == pytest.approx(1.0, abs=0.02) and cols[at, 0] == pytest.approx(0.0, abs=0.02)
    assert np.all(cols[np.abs(u) >= 15.0] == 0.0)


def test_registered_and_saved_by_name():
    assert FlankProfile in LIBRARY and "flank_profile" in VOCABULARY
    assert effect_class("flank_profile") is FlankProfile
    effect = FlankProfile((1.0, 2.5, 4.0, 6.0), window_samples=7, deadzone_deg=0.01)
    back = effect_from_dict(effect_to_dict(effect))
    assert isinstance(back, FlankProfile) and back.get_params() == effect.get_params()


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(knots_deg=(0.0, 1.0)),
        dict(knots_deg=(0.0, 2.0, 1.0)),
        dict(knots_deg=(0.0, np.nan, 2.0)),
        dict(window_samples=0),
        dict(deadzone_deg=-1.0),
    ],
)
def test_invalid_settings(kwargs):
    with pytest.raises(InvalidParameterError):
        FlankProfile(**kwargs)


def test_not_found_on_white_noise():
    t = np.arange(20000) * 1e-3
    u = 30.0 * np.sin(2 * np.pi * 0.5 * t) + 41.0
    for seed in range(3):
        r = np.random.default_rng(300 + seed).normal(0.0, 0.005, t.size)
        data = DetectionData(
            u, t, np.full(t.size, np.nan), r, 30.0, 1e-3, backlash_params=BacklashParams(1.0, 0.25, 1.0, 0.25)
        )
        assert FlankProfile.detect(data) is None


def test_not_found_where_both_flanks_deviate_alike():
    """A deviation common to both flanks is a transmission error's: the flank difference must hold on its own."""
    t = np.arange(20000) * 1e-3
    u = 30.0 * np.sin(2 * np.pi * 0.5 * t) + 41.0
    r = 0.02 * np.exp(-(((u - 50.0) / 4.0) ** 2)) + np.random.default_rng(7).normal(0.0, 0.002, t.size)
    assert FlankProfile.detect(DetectionData(u, t, np.full(t.size, np.nan), r, 30.0, 1e-3)) is None
    flanks = np.where(np.gradient(u) > 0, 1.0, -1.0)  # the same bump, opposite on the two flanks: found
    found = FlankProfile.detect(DetectionData(u, t, np.full(t.size, np.nan), r * flanks, 30.0, 1e-3))
    assert found is not None and found.score.significant() and found.score.heldout_gain > 0.5


def test_a_tight_spot_bends_the_flank_lines_and_is_named(tight_spot):
    rec, diagnosis = tight_spot
    d = diagnosis.as_dict()
    first = d["effects"][0]
    assert first["name"] == "flank_profile"
    assert first["evidence"]["heldout_gain"] > 0.3 and first["evidence"]["heldout_gain_in_final_model"] > 0.3
    assert first["rms_after_deg"] < 0.75 * first["rms_before_deg"]
    assert not [e for e in d["unexplained"] if e["name"] == "angle_harmonics_per_flank"]
    # the flanks' difference against the truth: y = u -/+ c -/+ F(angle) / k, so moving up minus moving
    # down is -2 F / k, less its straight part (the backlash's slopes and play take that)
    p = first["parameters"]
    knots = np.asarray(p["knots_deg"])
    angle = knots - (rec.motor_deg[0] / rec.ratio - rec.u_true_deg[0])  # the effect's frame to the rig's
    k_deg = STIFFNESS_NM_PER_ARCMIN * ARCMIN_PER_DEG
    truth = -2.0 * COULOMB_NM * _spot(angle) / k_deg
    truth -= np.interp(knots, knots[[0, -1]], truth[[0, -1]])
    fitted = np.asarray(p["flank_difference_deg"])
    assert np.corrcoef(fitted, truth)[0, 1] > 0.9
    assert np.min(fitted) == pytest.approx(np.min(truth), rel=0.3)
    assert knots[np.argmin(fitted)] == pytest.approx(knots[np.argmin(truth)], abs=p["knot_spacing_deg"])


def test_the_residual_on_the_flanks_is_closed_to_the_floor(tight_spot):
    """What the loop leaves on the engaged flanks, away from the impacts at the reversals, is at the
    load encoder's noise floor (the impacts themselves are the compliant gear's ring-down)."""
    _, diagnosis = tight_spot
    p = diagnosis.final.params
    clock = DeadBandMotion(p.m_left, p.c_left, p.m_right, p.c_right).switch_clock(
        diagnosis.u_deg - diagnosis.base.u_ref_, diagnosis.time_s
    )
    settled = clock >= 0.25  # the clock is clipped at 0.25 s
    assert settled.mean() > 0.5
    left = float(np.sqrt(np.mean(diagnosis.residual_after_deg[settled] ** 2)))
    before = float(np.sqrt(np.mean(diagnosis.residual_before_deg[settled] ** 2)))
    assert left < 2.0 * diagnosis.noise.floor_deg < 0.25 * before


@pytest.mark.parametrize("case", ["uniform_friction", *synthetic.TWO_MASS_INJECTORS])
def test_not_named_without_a_tight_spot(case):
    """The same rig with a uniform friction, and every case of the closing-loop bench: not named."""
    if case == "uniform_friction":
        rec = _tight_spot_rig(seed=1, spot=False)
        t, m, y, q, ratio = rec.time_s, rec.motor_deg, rec.load_deg, None, rec.ratio
    else:
        (t, m, y, q), ratio = synthetic.TWO_MASS_INJECTORS[case](1, 30.0), 30.0
    d = diagnose_arrays(t, m, y, ratio, torque_Nm=q).as_dict()
    assert "flank_profile" not in [e["name"] for e in d["effects"]]
    assert not any("flank_profile" in e.get("candidates", ()) for e in d["unexplained"])
