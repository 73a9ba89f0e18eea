"""The compliance's torque average is fitted in the joint refit (issue 13, "Measure").

On the compliant two-mass rig the twist follows the measured torque through the contact's
damping (``tau = k theta + d theta'``: a lag of ``d / k``, about 1 ms there), while a causal mean
of ``w`` torque samples delays the column by ``(w - 1) / 2`` samples and averages the sensor's
noise away. A fixed mean of 5 samples lagged every flank's torque step by 2 ms; on seed 0 that
let a pure lag of the model's output (``delay``) refit 0.2 % better and be named instead. The
loop now walks the average over ``Compliance.SMOOTHING_GRID`` in the joint refit, as it fits the
delay's lag, and retunes it when a later term comes in.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from online_backlash.diagnostics import _refits
from online_backlash.diagnostics._fit_view import FitView, detection_data, held_mask, stacked_columns
from online_backlash.diagnostics._folds import cycle_folds
from online_backlash.diagnostics._normal_equations import Projector
from online_backlash.diagnostics._refits import linearised_refit, walk_settings
from online_backlash.diagnostics._term_columns import TermColumns
from online_backlash.diagnostics.dead_band import DeadBandMotion
from online_backlash.diagnostics.effects import Compliance, Drift
from online_backlash.diagnostics.joint import fit_guarded
from online_backlash.diagnostics.loop import diagnose_arrays
from online_backlash.estimators.batch import VorosBacklash
from online_backlash.load_aware.engagement import torque_deadband
from online_backlash.simulation import synthetic
from online_backlash.simulation.two_mass_rig import ARCMIN_PER_DEG, simulate_two_mass


@pytest.mark.parametrize(("w", "near"), [(5, [4, 6]), (1, [2]), (16, [11]), (7, [6, 8]), (40, [16])])
def test_the_torque_average_has_the_grid_neighbours(w, near):
    effect = Compliance("torque", deadband_Nm=0.02, smooth_samples=w)
    found = effect.neighbours()
    assert [e.smooth_samples for e in found] == near
    assert all(e.proxy == "torque" and e.deadband_Nm == 0.02 for e in found)


@pytest.mark.parametrize(
    ("proxy", "w", "near"),
    [("acceleration", 61, [41, 81]), ("motion", 11, [15]), ("acceleration", 161, [121]), ("motion", 50, [41, 61])],
)
def test_the_motion_proxies_walk_their_differentiator_window(proxy, w, near):
    """Without a torque column the setting the joint refit walks is the Savitzky-Golay window (the trade
    between the encoder's steps and the motion's curvature), from ``Compliance.WINDOW_GRID``."""
    found = Compliance(proxy, window_samples=w).neighbours()
    assert [e.window_samples for e in found] == near
    assert all(e.proxy == proxy for e in found)


def test_the_torque_average_and_its_lag_are_reported():
    p = Compliance("torque", smooth_samples=4).describe([-0.2])
    assert p["torque_smoothing_samples"] == 4
    assert p["torque_column_lag_samples"] == 1.5


def test_the_walk_moves_to_the_setting_the_refit_prefers_and_keeps_the_others():
    calls = []

    def refit_with(terms):
        w = next(e.smooth_samples for e in terms if isinstance(e, Compliance))
        calls.append(w)
        return SimpleNamespace(rms_deg=1.0 + (w - 3) ** 2)

    drift = Drift(1)
    terms = [drift, Compliance("torque", smooth_samples=6)]
    terms, fit = walk_settings(terms, refit_with(terms), refit_with, range(2))
    assert terms[0] is drift  # no setting: the same object
    assert terms[1].smooth_samples == 3 and fit.rms_deg == 1.0
    assert sorted(calls) == sorted(set(calls))  # no setting refitted twice
    assert calls[0] == 6 and set(calls) == {2, 3, 4, 5, 6, 8}


def test_only_the_terms_asked_for_are_tuned():
    terms = [Compliance("torque", smooth_samples=6), Compliance("torque", smooth_samples=6)]
    tuned, fit = walk_settings(
        terms,
        SimpleNamespace(rms_deg=12.0),
        lambda ts: SimpleNamespace(rms_deg=float(sum(e.smooth_samples for e in ts))),
        [1],
    )
    assert tuned[0] is terms[0] and tuned[1].smooth_samples == 1 and fit.rms_deg == 7.0


def test_the_walk_stays_where_no_neighbour_is_better():
    effect = Compliance("torque", smooth_samples=5)
    terms, fit = walk_settings(
        [effect],
        SimpleNamespace(rms_deg=1.0),
        lambda terms: SimpleNamespace(rms_deg=1.0 + abs(terms[0].smooth_samples - 5)),
        [0],
    )
    assert terms[0] is effect and fit.rms_deg == 1.0


def test_the_compliant_rig_of_seed_0_names_compliance_not_a_lag():
    """The bench's seed that named ``delay`` first with the 5-sample mean (play 0.5164 deg)."""
    t, m, y, q = synthetic.two_mass_compliance(seed=0, duration_s=120.0)
    d = diagnose_arrays(t, m, y, 30.0, torque_Nm=q).as_dict()
    names = [e["name"] for e in d["effects"]]
    assert names[0] == "compliance" and "delay" not in names
    p = d["effects"][0]["parameters"]
    k_deg = synthetic.COMPLIANT_NM_PER_ARCMIN * ARCMIN_PER_DEG
    assert p["compliance_deg_per_Nm"] == pytest.approx(-1.0 / k_deg, rel=0.05)
    assert p["torque_smoothing_samples"] in Compliance.SMOOTHING_GRID
    assert d["backlash_after_deg"] == pytest.approx(0.5, rel=0.01)
    assert d["rms_after_deg"] <= 1.5 * d["noise_floor_deg"]


def test_the_linearised_refit_orders_the_settings_as_the_joint_refits_do():
    """The loop walks the average on the joint refit linearised at the current fit (cheap), then
    confirms the setting with one joint refit: the linearised RMS must agree with the joint
    refit's at the fitted setting, and rank the neighbouring settings as the joint refits do."""
    t, m, y, q = synthetic.two_mass_compliance(seed=0, duration_s=30.0)
    u = m / 30.0
    base = VorosBacklash(refine=True, origin="first").fit(u, y)
    uc, yc = u - base.u_ref_, y - base.y_ref_
    built = TermColumns(u, t, q)
    deadband = torque_deadband(np.nan_to_num(q))

    def joint(w):
        terms = [Compliance("torque", deadband_Nm=deadband, smooth_samples=w)]
        x = FitView.of(uc, base.params_).output_deg
        return terms, fit_guarded(uc, yc, stacked_columns(terms, built, x), base.params_, held_mask(terms))

    terms, fit = joint(5)
    walk = linearised_refit(terms, 0, fit, uc, cycle_folds(u), built)
    assert walk(terms).rms_deg == pytest.approx(fit.rms_deg, rel=1e-3)
    widths = [1, 3, 5, 8, 16]
    linear = [walk([Compliance("torque", deadband_Nm=deadband, smooth_samples=w)]).rms_deg for w in widths]
    full = [joint(w)[1].rms_deg for w in widths]
    assert np.argsort(linear).tolist() == np.argsort(full).tolist()
    assert np.allclose(linear, full, rtol=0.02)


def test_the_walk_reads_the_dead_bands_motion_on_its_support(monkeypatch):
    """With the dead band's motion among the other terms, the walk's projection reads its columns on
    the rows where they are not zero (a few per cent of the record), and gives the least squares of
    every column written out."""
    t, m, y, q = synthetic.two_mass_compliance(seed=0, duration_s=30.0)
    u = m / 30.0
    base = VorosBacklash(refine=True, origin="first").fit(u, y)
    uc, yc = u - base.u_ref_, y - base.y_ref_
    p = base.params_
    built = TermColumns(u, t, q)
    view = FitView.of(uc, p)
    dead_band = DeadBandMotion(p.m_left, p.c_left, p.m_right, p.c_right, (0.004, 0.032), (0.0, 0.004, 0.016), True, ())
    terms = [Compliance("torque", deadband_Nm=torque_deadband(np.nan_to_num(q)), smooth_samples=5), dead_band]
    fit = fit_guarded(uc, yc, stacked_columns(terms, built, view.output_deg), p, held_mask(terms))
    formed = []
    monkeypatch.setattr(_refits, "Projector", lambda columns: formed.append(columns) or Projector(columns))
    walk = linearised_refit(terms, 0, fit, uc, cycle_folds(u), built)
    assert formed[0].supports[-1] is not None and formed[0].supports[-1].rows.size < 0.25 * u.size
    other = Compliance("torque", deadband_Nm=terms[0].deadband_Nm, smooth_samples=8)
    at = FitView.of(uc, fit.params)
    restored = fit.residual_deg + built.get(terms[0])[:, 0] * fit.coef[0]
    every = np.column_stack((at.other_directions, at.play_direction, built.get(dead_band), built.get(other)))
    left = restored - every @ np.linalg.lstsq(every, restored, rcond=None)[0]
    assert walk([other, dead_band]).rms_deg == pytest.approx(float(np.sqrt(np.mean(left**2))), rel=1e-9)


def test_a_retuned_term_reports_the_evidence_of_its_final_setting():
    """When a later term moves the compliance's torque average, its evidence is scored again with
    the final setting (on the residual of the step it came in at): the statistics describe the
    setting its parameters report (before, they kept the setting it came in with)."""
    rec = simulate_two_mass(
        duration_s=60.0, motion="rig", coulomb_nm=0.05, seed=1
    )  # retunes: compliance, then dead band motion
    d = diagnose_arrays(rec.time_s, rec.motor_deg, rec.load_deg, 30.0, torque_Nm=rec.torque_Nm)
    step = d.steps[0]
    assert step.effect.name == "compliance" and step.retuned and not d.steps[1].retuned
    w = step.effect.smooth_samples
    assert step.detection.effect.smooth_samples == w == step.parameters["torque_smoothing_samples"]
    evidence = step.as_dict()["evidence"]
    assert (
        evidence["retuned_by_later_terms"] is True
        and d.as_dict()["effects"][1]["evidence"]["retuned_by_later_terms"] is False
    )
    # the same statistics as the final setting scored afresh on the residual before the term, not another setting's
    before, done = step.scored_on
    u = rec.motor_deg / 30.0
    built = TermColumns(u, rec.time_s, rec.torque_Nm)
    data = detection_data(
        u, rec.time_s, rec.torque_Nm, u - d.base.u_ref_, before, list(done), 30.0, 0.001, cycle_folds(u), built
    )
    again = step.effect.detection(data).score
    assert evidence["delta_bic_eff"] == pytest.approx(again.delta_bic, rel=1e-9)
    assert evidence["heldout_gain"] == pytest.approx(again.heldout_gain, rel=1e-9)
    other = next(e for e in step.effect.neighbours())
    assert other.detection(data).score.delta_bic != pytest.approx(again.delta_bic, rel=1e-6)
