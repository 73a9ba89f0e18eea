"""What the loop builds once and reuses gives the very numbers it would form afresh.

The term columns (:class:`TermColumns`), the columns held through the dead band (``hold_columns``'
compiled pass), the first hold shared by the two fits of ``fit_guarded``: each is compared bit for
bit with the direct computation it replaces; the final model's held-out gains, scored from one set
of cross-products by ``_final_model.hold_out_each``, to rounding.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from online_backlash import VorosBacklash
from online_backlash.diagnostics._causal import motion_direction
from online_backlash.diagnostics._fit_view import detection_data, held_mask, stacked_columns
from online_backlash.diagnostics._folds import cycle_folds
from online_backlash.diagnostics._scoring import DetectionData
from online_backlash.diagnostics._term_columns import TermColumns
from online_backlash.diagnostics.dead_band import DeadBandMotion
from online_backlash.diagnostics.effects import Compliance, Drift
from online_backlash.diagnostics.joint import engaged_index, fit_guarded, fit_joint, hold_columns, separable
from online_backlash.diagnostics.loop import diagnose_arrays
from online_backlash.model import BacklashParams, simulate_backlash
from online_backlash.simulation import synthetic


@pytest.fixture(scope="module")
def two_steps():
    """A compliant two-mass log on which the loop adds two terms (compliance, dead band motion)."""
    t, m, y, q = synthetic.TWO_MASS_INJECTORS["compliance"](seed=1, duration_s=60.0)
    return diagnose_arrays(t, m, y, 30.0, torque_Nm=q)


def test_term_columns_are_built_once_per_effects_settings_and_equal_a_fresh_build() -> None:
    """Built once per effect's parameters: the walk of a setting and the next round make new objects of
    settings already built (on the 10-minute bench log six of the compliance's and the velocity function's
    columns were built again), and they get the same array."""
    rng = np.random.default_rng(3)
    t = np.arange(4000) * 1e-3
    u = np.cumsum(rng.normal(0, 0.01, t.size))
    q = rng.normal(0, 1, t.size)
    built = TermColumns(u, t, q)
    effect = DeadBandMotion()
    first = built.get(effect)
    np.testing.assert_array_equal(first, effect.clone().terms(u, t, q))
    assert built.get(effect) is first and not first.flags.writeable
    twin = DeadBandMotion()  # the same settings, another object: the same columns, not built again
    assert built.get(twin) is first
    assert built.get(DeadBandMotion(c_left_deg=0.3)) is not first  # another setting: its own
    walked = Compliance("torque", smooth_samples=4)
    assert built.get(Compliance("torque", smooth_samples=4)) is built.get(walked)
    assert built.get(Compliance("torque", smooth_samples=5)) is not built.get(walked)
    np.testing.assert_array_equal(built.get(Drift(2, 4.0)), Drift(2, 4.0).terms(u, t, q))


def test_term_columns_forget_every_effect_but_the_terms_kept_and_the_last_within_the_spare_bytes() -> None:
    """After a round the loop keeps the columns of the terms taken, and of the others only the last built
    within ``spare_bytes`` (on a 60-minute log the candidates' and the walked settings' columns came to over a
    gigabyte; the next round refits the same candidates and walks the same settings, on the 10-minute bench
    log 4 of 13 builds)."""
    rng = np.random.default_rng(6)
    t = np.arange(3000) * 1e-3
    u, q = np.cumsum(rng.normal(0, 0.01, t.size)), rng.normal(0, 1, t.size)
    built = TermColumns(u, t, q)
    taken, tried = Compliance("torque", smooth_samples=4), Compliance("torque", smooth_samples=8)
    kept, dropped = built.get(taken), built.get(tried)
    built.support(taken)
    built.keep_only([taken], spare_bytes=0)
    assert built.get(taken) is kept  # not built again
    again = built.get(tried)
    assert again is not dropped  # built afresh: the same numbers
    np.testing.assert_array_equal(again, dropped)
    older, newer = Compliance("torque", smooth_samples=2), Compliance("torque", smooth_samples=3)
    first, last = built.get(older), built.get(newer)
    built.keep_only([taken], spare_bytes=first.nbytes + last.nbytes - 1)  # room for one: the last built
    assert built.get(taken) is kept and built.get(newer) is last
    assert built.get(older) is not first and built.get(tried) is not again
    built.keep_only([taken])  # the default keeps every one of this size
    assert built.get(newer) is last and built.get(tried) is built.get(Compliance("torque", smooth_samples=8))


def test_the_dead_band_motions_columns_are_fitted_on_their_support(two_steps) -> None:
    """The dead band's motion is zero outside a few per cent of the samples: the loop hands its fits
    the rows where it is not (``TermColumns.support``, found once per effect), a drift everywhere."""
    d = two_steps
    built = TermColumns(d.u_deg, d.time_s, d.torque_Nm)
    dead_band = next(s.effect for s in d.steps if s.effect.name == "dead_band_motion")
    support = built.support(dead_band)
    columns = built.get(dead_band)
    assert support is not None and built.support(dead_band) is support
    assert support.rows.size < 0.25 * d.u_deg.size
    np.testing.assert_array_equal(np.flatnonzero(np.any(columns != 0, axis=1)), support.rows)
    np.testing.assert_array_equal(support.values, columns[support.rows])
    assert built.support(Drift(2, 4.0)) is None


def test_columns_stack_the_terms_in_order() -> None:
    rng = np.random.default_rng(4)
    n = 3000
    t = np.arange(n) * 1e-3
    u = np.cumsum(rng.normal(0, 0.01, n))
    q = rng.normal(0, 1, n)
    terms = [Drift(2, 3.0), Compliance("torque"), Compliance("acceleration")]
    got = stacked_columns(terms, TermColumns(u, t, q), np.zeros(n))
    expected = np.column_stack([e.clone().terms(u, t, q) for e in terms])
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("order", ["C", "F"])
def test_hold_columns_of_some_held_columns_equals_the_gather(order: str) -> None:
    rng = np.random.default_rng(5)
    cols = np.asarray(rng.normal(size=(2000, 5)), order=order)
    index = np.maximum.accumulate(np.where(rng.random(2000) < 0.4, np.arange(2000), 0))
    held = np.array([True, False, True, True, False])
    expected = cols.copy()
    expected[:, held] = np.take(cols[:, held], index, axis=0)
    np.testing.assert_array_equal(hold_columns(cols, held, index), expected)
    np.testing.assert_array_equal(hold_columns(cols, np.ones(5, bool), index), np.take(cols, index, axis=0))
    assert hold_columns(cols, np.zeros(5, bool), index) is cols


def test_fit_guarded_with_held_columns_equals_its_two_fits() -> None:
    """The play-held refit reuses the first fit's held columns: the same result as fitting from scratch."""
    t = np.arange(20000) * 1e-3
    u = 30 * np.sin(2 * np.pi * 0.5 * t)
    x = simulate_backlash(u, BacklashParams(1.0, 0.25, 1.0, 0.25), 0.0)
    switching = motion_direction(x, 1, 0.0, 1.0)
    y = x - 0.02 * switching + 0.003 * np.sin(np.radians(3 * u)) + np.random.default_rng(1).normal(0, 0.002, t.size)
    base = VorosBacklash().fit(u, y)
    uc, yc = u - base.u_ref_, y - base.y_ref_
    cols = np.column_stack((switching, np.sin(np.radians(3 * uc))))
    held = np.array([False, True])
    free = fit_joint(uc, yc, cols, base.params_, held=held)
    assert not separable(free, base.params_)  # the held path is the one exercised
    kept = fit_joint(uc, yc, cols, base.params_, hold_play=base.params_.play, held=held)
    guarded = fit_guarded(uc, yc, cols, base.params_, held)
    assert guarded.play_held
    assert guarded.params == kept.params
    np.testing.assert_array_equal(guarded.coef, kept.coef)
    np.testing.assert_array_equal(guarded.residual_deg, kept.residual_deg)
    assert (guarded.play_inflation, guarded.play_std_deg) == (free.play_inflation, free.play_std_deg)


def test_final_heldout_gains_equal_those_formed_afresh(two_steps) -> None:
    """``_final_model.hold_out_each`` scores every term from one set of cross-products of the final model
    (``DetectionData.scores_left_out``): the gains are those of a detection data formed from scratch
    for every term, to rounding (on one BLAS thread, as the loop's)."""
    with threadpool_limits(limits=1, user_api="blas"):
        _check_final_heldout_gains(two_steps)


def _check_final_heldout_gains(d) -> None:
    assert len(d.steps) >= 2
    u, t, q = d.u_deg, d.time_s, d.torque_Nm
    uc = u - d.base.u_ref_
    period = round(float(np.median(np.diff(t))), 12)
    folds = cycle_folds(u)
    final = d.final
    index = engaged_index(uc, final.params)
    terms = [s.effect for s in d.steps]
    fresh = TermColumns(u, t, q)
    x = simulate_backlash(uc, final.params, 0.0)
    start = 0
    for i, s in enumerate(d.steps):
        n = s.effect.n_terms
        mine = hold_columns(stacked_columns([s.effect], fresh, x), held_mask([s.effect]), index)
        restored = final.residual_deg + mine @ final.coef[start : start + n]
        others = [*terms[:i], *terms[i + 1 :]]
        data = detection_data(
            u, t, q, uc, replace(final, residual_deg=restored), others, d.ratio, period, folds, TermColumns(u, t, q)
        )
        assert s.heldout_gain_final == pytest.approx(data.score(False, mine).heldout_gain, rel=1e-9, abs=1e-12)
        assert np.isfinite(s.heldout_gain_final)
        start += n


def test_term_columns_taken_from_a_detector_must_have_the_effects_shape() -> None:
    rng = np.random.default_rng(5)
    t = np.arange(300) * 1e-3
    u, q = np.cumsum(rng.normal(0, 0.01, t.size)), rng.normal(0, 1, t.size)
    built = TermColumns(u, t, q)
    effect = Drift(2, 1.0)
    with pytest.raises(ValueError, match="expected"):
        built.put(effect, np.zeros((t.size, 3)))
    mine = effect.clone().terms(u, t, q)
    built.put(effect, mine)
    assert built.get(effect) is mine and not mine.flags.writeable


def test_the_compliances_detection_reads_its_columns_from_the_loops_store() -> None:
    """A detector that scores its effect's columns over the whole record takes them from the loop's store of
    term columns when the data carry it (``DetectionData.record_columns``): the joint refit then finds them
    built, and the score is the one on a fresh build, bit for bit."""
    rng = np.random.default_rng(8)
    t = np.arange(6000) * 1e-3
    u = 20.0 * np.sin(2 * np.pi * 0.9 * t)
    q = np.cos(2 * np.pi * 0.9 * t) + rng.normal(0, 0.01, t.size)
    r = 0.01 * q + rng.normal(0, 1e-3, t.size)
    built = TermColumns(u, t, q)
    stored = DetectionData(u, t, q, r, 30.0, 1e-3, term_columns=built)
    alone = DetectionData(u, t, q, r, 30.0, 1e-3)
    effect = Compliance("torque", smooth_samples=3)
    got, fresh = effect.detection(stored), effect.detection(alone)
    assert built.get(Compliance("torque", smooth_samples=3)) is stored.record_columns(effect)  # built once, kept
    assert (got.score.delta_bic, got.score.rss_after, got.score.heldout_gain) == (
        fresh.score.delta_bic,
        fresh.score.rss_after,
        fresh.score.heldout_gain,
    )
    other = TermColumns(u.copy(), t, q)  # another record's store: not read
    assert DetectionData(u, t, q, r, 30.0, 1e-3, term_columns=other).record_columns(effect) is not other.get(effect)
