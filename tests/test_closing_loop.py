"""Closing the loop on data the estimator's model did not make (issue 13).

Compliance as physics has it (two-mass rig: the twist follows from the dynamics), held-out
evidence over whole reversal cycles, no drift where time is collinear with the net rotation,
and rivals reported together.
"""

from __future__ import annotations

import numpy as np
import pytest

from online_backlash.diagnostics import synthetic
from online_backlash.diagnostics._folds import cycle_folds, reversal_cycles
from online_backlash.diagnostics._scoring import Detection, DetectionData
from online_backlash.diagnostics.effects import Drift, TransmissionError
from online_backlash.diagnostics.loop import _rivals, diagnose_arrays
from online_backlash.rig import rig_motion
from online_backlash.two_mass_rig import ARCMIN_PER_DEG


@pytest.fixture(scope="module")
def compliant_rig():
    t, m, y, q = synthetic.two_mass_compliance(seed=3, duration_s=60.0)
    return t, m, y, q


def test_compliance_on_the_two_mass_rig_is_named_in_physical_units(compliant_rig):
    t, m, y, q = compliant_rig
    d = diagnose_arrays(t, m, y, 30.0, torque_Nm=q).as_dict()
    first = d["effects"][0]
    assert first["name"] == "compliance"
    p = first["parameters"]
    assert p["proxy"] == "measured torque"
    # y = u - c - tau / k on an engaged flank: the coefficient is -1/k
    k_deg = synthetic.COMPLIANT_NM_PER_ARCMIN * ARCMIN_PER_DEG
    assert p["compliance_deg_per_Nm"] == pytest.approx(-1.0 / k_deg, rel=0.1)
    assert p["stiffness_Nm_per_arcmin"] == pytest.approx(synthetic.COMPLIANT_NM_PER_ARCMIN, rel=0.1)
    ev = first["evidence"]
    assert ev["heldout_gain"] > 0.5 and ev["heldout_gain_in_final_model"] > 0.5
    assert ev["heldout_split"]["split"] == "reversal cycles" and ev["heldout_split"]["folds"] >= 2
    assert d["backlash_after_deg"] == pytest.approx(0.5, rel=0.02)
    assert d["backlash_before_deg"] > 0.52  # the twist had inflated the play
    assert "drift" not in [e["name"] for e in d["effects"]]


def test_without_torque_a_viscous_twist_is_the_lag_b_over_k(compliant_rig):
    """Without a torque column the twist under a viscous load, ``-(b / k) dy/dt`` on an engaged
    flank, is exactly a lag of ``b / k``: the loop reports it as such (only a torque tells them apart)."""
    t, m, y, _ = compliant_rig
    d = diagnose_arrays(t, m, y, 30.0).as_dict()
    first = d["effects"][0]
    b_over_k = 0.3 / (synthetic.COMPLIANT_NM_PER_ARCMIN * ARCMIN_PER_DEG * 180.0 / np.pi)  # s (viscous 0.3 N m s/rad)
    assert first["name"] == "delay"
    assert first["parameters"]["lag_s"] == pytest.approx(b_over_k, rel=0.15)
    assert first["rms_after_deg"] < 0.3 * first["rms_before_deg"]


def test_folds_hold_out_whole_reversal_cycles():
    _, u = rig_motion(60.0, seed=2)
    folds = cycle_folds(u)
    cycle = reversal_cycles(u)
    assert folds.kind == "reversal cycles" and folds.n_folds == 5 and folds.n_cycles >= 5
    # every cycle lies in one fold, and the folds interleave in time
    for c in np.unique(cycle):
        assert np.unique(folds.fold[cycle == c]).size == 1
    assert np.all(np.bincount(folds.fold) > 0)
    steady = cycle_folds(np.linspace(0.0, 100.0, 5000))
    assert steady.kind == "time blocks"


def test_structure_in_one_stretch_only_does_not_hold_out_of_sample():
    """A harmonic of the angle present in one reversal cycle only fits in sample, and fails on the
    held-out cycles; the same harmonic present throughout holds."""
    t, u = rig_motion(60.0, seed=8)
    rng = np.random.default_rng(9)
    q = np.full(u.size, np.nan)
    column = np.sin(np.radians(3 * u))[:, None]
    cycle = reversal_cycles(u)
    burst = 0.03 * column[:, 0] * (cycle == 1)
    s = DetectionData(u, t, q, burst + rng.normal(0, 0.002, u.size), 30.0, 1e-3).score(False, column)
    assert s.gain > 0.05  # in sample it looks like a finding
    assert s.heldout_gain < 0.05 and not s.significant()
    held = DetectionData(u, t, q, 0.02 * column[:, 0] + rng.normal(0, 0.002, u.size), 30.0, 1e-3).score(False, column)
    assert held.heldout_gain > 0.9 and held.significant()


def test_no_drift_when_time_is_collinear_with_the_net_rotation():
    """A rig that turns steadily while it reverses: an error that grows with the angle is not a drift."""
    t, u = rig_motion(120.0, seed=4, forward_bias=4.0)
    span = np.ptp(u)
    rng = np.random.default_rng(5)
    r = 0.05 * ((u - u[0]) / span) ** 2 + rng.normal(0, 0.002, u.size)
    data = DetectionData(u, t, np.full(u.size, np.nan), r, 30.0, 1e-3)
    # in time alone it looks like a drift (the control: this test can fail) ...
    naive = data.score(False, Drift(2, float(t[-1])).terms(u, t, np.full(u.size, np.nan)))
    assert naive.significant()
    # ... but beyond the net rotation, time carries nothing of its own
    det = Drift.detect(data)
    assert det is not None and det.rivals == ("net_rotation",)  # reported as not separable, never as a drift
    # while a real drift is still found where the motion does not creep one way
    t, u = rig_motion(120.0, seed=4, forward_bias=1.0)
    drifting = DetectionData(u, t, np.full(u.size, np.nan), 0.05 * np.sin(t / 20.0) + rng.normal(0, 0.002, u.size), 30.0, 1e-3)
    found = Drift.detect(drifting)
    assert found is not None and found.score.significant() and found.rivals == ()
    # and on the creeping motion too, when the residual follows time and not the angle
    t, u = rig_motion(120.0, seed=4, forward_bias=4.0)
    creeping = DetectionData(u, t, np.full(u.size, np.nan), 0.05 * np.sin(t / 20.0) + rng.normal(0, 0.002, u.size), 30.0, 1e-3)
    found = Drift.detect(creeping)
    assert found is not None and found.score.significant() and found.rivals == ()


def test_two_effects_that_explain_the_same_part_are_reported_as_rivals():
    t, u = rig_motion(60.0, seed=6)
    rng = np.random.default_rng(7)
    q = np.full(u.size, np.nan)
    r = 0.03 * t / t[-1] + rng.normal(0, 0.002, u.size)
    data = DetectionData(u, t, q, r, 30.0, 1e-3, model_output_deg=u)
    engaged = np.ones(u.size, dtype=bool)
    one, two = Drift(1, float(t[-1])), Drift(2, float(t[-1]))
    d1 = Detection(one, data.score(False, one.terms(u, t, q)), "")
    d2 = Detection(two, data.score(False, two.terms(u, t, q)), "")
    assert _rivals(data, d1, [d1, d2], engaged, 0.05) == ("drift",)
    # a term that adds its own part is no rival
    other = DetectionData(u, t, q, r + 0.03 * np.sin(np.radians(3 * u)), 30.0, 1e-3, model_output_deg=u)
    te = TransmissionError((3,), (), 30.0)
    d3 = Detection(te, other.score(True, te.terms(u, t, q)), "")
    assert _rivals(other, Detection(one, other.score(False, one.terms(u, t, q)), ""), [d3], engaged, 0.05) == ()
