"""How large a screen is, and what the whole record decides after it (issue 13, "Speed").

A long record's candidates are scored and refitted on a screen of its cycles
(``_folds.Folds.screen``); the screen must hold enough samples for a term with many columns to hold
out, and it only chooses which effect comes next: the effect's configuration and the settings of
every term (the compliance's torque average) are the whole record's. Each loop test here failed on
the code before this change (``tests/test_screen.py`` tests what a screen computes).
"""

from __future__ import annotations

import numpy as np
import pytest
from same_answer import assert_same_answer

from online_backlash.diagnostics._folds import SCREEN_CYCLES, SCREEN_FACTOR, SCREEN_MIN_SAMPLES, cycle_folds
from online_backlash.diagnostics.loop import diagnose_arrays
from online_backlash.simulation.two_mass_rig import simulate_two_mass


def _strokes(cycles: int, per_cycle: int) -> np.ndarray:
    """``cycles`` up-and-down strokes of ``per_cycle`` samples each (deg)."""
    t = np.arange(cycles * per_cycle)
    return 20.0 * np.sin(2 * np.pi * t / per_cycle - np.pi / 2) + 1e-3 * t


def test_a_record_of_short_cycles_is_screened_on_as_many_as_hold_the_minimum_of_samples():
    folds = cycle_folds(_strokes(400, 1000))  # 1 Hz at 1 kHz: 400 cycles, 400,000 samples
    screen = folds.screen()
    assert screen.screened
    kept = screen.cycle_rows.size
    assert (
        SCREEN_MIN_SAMPLES <= kept < SCREEN_MIN_SAMPLES + 5 * 1000
    )  # whole groups of five cycles: at most one group more
    assert len(screen.segments) > SCREEN_CYCLES


def test_a_record_of_long_cycles_keeps_the_cycles_asked_for():
    folds = cycle_folds(_strokes(60, 12000))  # 60 cycles of 12,000 samples
    screen = folds.screen()
    assert screen.screened and len(screen.segments) == SCREEN_CYCLES
    assert screen.cycle_rows.size >= SCREEN_MIN_SAMPLES


def test_a_record_without_three_times_the_screens_samples_is_not_screened():
    """Many cycles, too few samples: 250 cycles of 1,000 samples are not three screens of 100,000."""
    folds = cycle_folds(_strokes(250, 1000))
    assert folds.n_cycles >= SCREEN_FACTOR * SCREEN_CYCLES
    assert not folds.screen().screened
    assert folds.screen(min_samples=0).screened  # what the cycle count alone did


def _as_found(d) -> dict:
    out = d.as_dict()
    out.pop("screened_cycles")
    return out


def test_a_short_record_of_many_reversals_finds_what_every_cycle_shows():
    """60 s of 1 Hz reversals on the two-mass rig (60 cycles): screened on 15 of them (15,000 samples,
    the rule before), the dead band's motion held out at -0.61 there and the loop stopped after the
    delay; the whole record finds it (and the velocity function after it)."""
    rec = simulate_two_mass(duration_s=60.0, motion="sine", frequency_hz=1.0, coulomb_nm=0.05, seed=0)
    screened = diagnose_arrays(rec.time_s, rec.motor_deg, rec.load_deg, 30.0, torque_Nm=rec.torque_Nm)
    plain = diagnose_arrays(rec.time_s, rec.motor_deg, rec.load_deg, 30.0, torque_Nm=rec.torque_Nm, screen_cycles=0)
    assert screened.screened_cycles is None
    assert [s.effect.name for s in plain.steps] == ["delay", "dead_band_motion", "velocity_function"]
    assert_same_answer(_as_found(screened), _as_found(plain))


@pytest.mark.slow
def test_the_compliance_torque_average_is_the_whole_records_not_the_screens():
    """5.5 minutes of the two-mass rig (33 cycles: screened on 10). On the screen the torque average
    walked to 6 samples; on every sample (and without the screen) it is 8, and the record's answer is
    the unscreened one in every figure."""
    rec = simulate_two_mass(duration_s=330.0, motion="rig", coulomb_nm=0.05, seed=3)
    screened = diagnose_arrays(rec.time_s, rec.motor_deg, rec.load_deg, 30.0, torque_Nm=rec.torque_Nm)
    plain = diagnose_arrays(rec.time_s, rec.motor_deg, rec.load_deg, 30.0, torque_Nm=rec.torque_Nm, screen_cycles=0)
    assert screened.screened_cycles == SCREEN_CYCLES and plain.screened_cycles is None
    assert [s.effect.name for s in screened.steps] == ["compliance", "dead_band_motion"]
    assert screened.steps[0].effect.smooth_samples == 8
    assert_same_answer(_as_found(screened), _as_found(plain))
