"""The shortcuts that make ``diagnose`` fast give the numbers of the plain computations they replace."""

from __future__ import annotations

import numpy as np
import pytest

from online_backlash.diagnostics._causal import velocity_deg_s
from online_backlash.diagnostics._folds import cycle_folds
from online_backlash.diagnostics._harmonics import harmonic_columns, harmonic_stack, held_per_flank, shaft_harmonic
from online_backlash.diagnostics._normal_equations import nonzero_rows
from online_backlash.diagnostics._record_cache import RecordCache
from online_backlash.diagnostics._scoring import DetectionData, _score_grams, _sorted_union
from online_backlash.diagnostics._speed import (
    cardinal_splines,
    held_spline_columns,
    record_speed_knots,
    record_velocity,
    speed_knots,
    zero_knot,
)
from online_backlash.diagnostics._term_columns import TermColumns
from online_backlash.diagnostics.dead_band import ENTRY_KNOTS, EXIT_TIME_CONSTANTS, DeadBandMotion, _at_period
from online_backlash.diagnostics.effects import Drift
from online_backlash.diagnostics.generic_terms import VelocityFunction
from online_backlash.diagnostics.joint import Support
from online_backlash.model import BacklashParams


def _record(n: int = 4000, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A reversing motion (deg, load side), its time (s), a torque (N m) and an engaged index."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    u = 40.0 * np.sin(2 * np.pi * 0.7 * t) + 3.0 * t + rng.normal(0, 1e-3, n)
    q = np.cos(2 * np.pi * 0.7 * t) + rng.normal(0, 0.01, n)
    index = np.maximum.accumulate(np.where(rng.random(n) < 0.7, np.arange(n), 0))
    return u, t, q, index


def _stacked_data(u: np.ndarray, t: np.ndarray, q: np.ndarray, r: np.ndarray, screened: bool) -> DetectionData:
    """The residual ``r`` beyond a constant and ``u`` on the record's cycles, or on a screen of 10 of them."""
    folds = cycle_folds(u)
    folds = folds.screen(cycles=10, factor=1, min_samples=0) if screened else folds
    return DetectionData.stacked(
        [np.ones_like(u), u / 40.0], r, u_deg=u, time_s=t, torque_Nm=q, ratio=30.0, sample_period_s=1e-3, folds=folds
    )


def _data(index: np.ndarray | None = None, cache: RecordCache | None = None) -> DetectionData:
    u, t, q, _ = _record()
    return DetectionData(u, t, q, np.sin(0.01 * np.arange(u.size)), 30.0, 1e-3, engaged_index=index, cache=cache)


def test_cache_serves_only_for_the_same_sources() -> None:
    cache = RecordCache()
    a, b = np.zeros(5), np.zeros(5)
    calls = []

    def build() -> np.ndarray:
        calls.append(1)
        return np.arange(3.0)

    first = cache.get("k", (a,), build)
    assert cache.get("k", (a,), build) is first and len(calls) == 1
    assert not first.flags.writeable  # shared: nobody may write into it
    cache.get("k", (b,), build)  # equal but not the same array: built again
    assert len(calls) == 2
    assert cache.used_bytes == first.nbytes  # the stale one was replaced, not added


def test_cache_keeps_nothing_beyond_its_budget() -> None:
    cache = RecordCache(budget_bytes=100)
    big = cache.get("big", (), lambda: np.zeros(20))  # 160 bytes
    assert big.flags.writeable and cache.used_bytes == 0
    assert not cache.can_hold("big", 160) and cache.can_hold("small", 80)


def test_harmonic_stack_matches_numpy() -> None:
    u, *_ = _record()
    stack = harmonic_stack(u * 30.0, 24)
    for order in (1, 2, 7, 24):
        np.testing.assert_allclose(stack[order - 1], harmonic_columns(u * 30.0, [order]), rtol=0, atol=1e-12)


def test_shaft_harmonic_shared_and_falls_back_beyond_the_budget() -> None:
    data = _data()
    x = shaft_harmonic(data, "load", data.u_deg, 5, 24)
    assert shaft_harmonic(data, "load", data.u_deg, 5, 24).base is x.base  # one stack for the record
    np.testing.assert_allclose(x, harmonic_columns(data.u_deg, [5]), rtol=0, atol=1e-12)
    small = _data(cache=RecordCache(budget_bytes=1000))
    np.testing.assert_array_equal(shaft_harmonic(small, "load", small.u_deg, 5, 24), harmonic_columns(small.u_deg, [5]))


@pytest.mark.parametrize("held", [False, True])
def test_held_per_flank_is_mask_stack_and_hold(held: bool) -> None:
    u, _, _, index = _record()
    h = harmonic_columns(u, [3, 4])
    up, down = np.diff(u, prepend=u[0]) > 0, np.diff(u, prepend=u[0]) < 0
    plain = np.column_stack((h * up[:, None], h * down[:, None]))
    if held:
        plain = np.take(plain, index, axis=0)
    np.testing.assert_array_equal(held_per_flank(h, up, down, index if held else None), plain)


@pytest.mark.parametrize("held", [False, True])
def test_held_spline_columns_are_the_held_cardinal_splines(held: bool) -> None:
    data = _data(_record()[3] if held else None)
    v = record_velocity(data)
    for inner in (1, 3, 5):
        knots = speed_knots(v, inner)
        plain = data.hold(np.delete(cardinal_splines(knots, v), zero_knot(knots), axis=1))
        np.testing.assert_array_equal(held_spline_columns(data, knots), plain)
    assert held_spline_columns(data, (0.0,)).shape == (v.size, 0)


def test_the_records_speed_knots_are_the_speed_knots_of_its_velocity() -> None:
    """``record_speed_knots`` finds each direction's outer knot once per record: the knots of
    ``speed_knots`` for every count, and the percentiles are not formed again."""
    data = _data(None)
    v = record_velocity(data)
    for inner in (1, 2, 3, 5):
        assert record_speed_knots(data, inner) == speed_knots(v, inner)
    assert data.cache is not None and data.cache.used_bytes > 0
    before = data.cache.used_bytes
    record_speed_knots(data, 4)
    assert data.cache.used_bytes == before  # served from the record's cache


@pytest.mark.parametrize("torque", [False, True])
def test_dead_band_columns_alone_are_slices_of_both(torque: bool) -> None:
    u, t, q, _ = _record()
    taus, knots = _at_period(EXIT_TIME_CONSTANTS, 1e-3), _at_period(ENTRY_KNOTS, 1e-3)
    both = DeadBandMotion(1.0, 0.5, 1.0, 0.5, taus, knots, torque).terms(u, t, q)
    coast = DeadBandMotion(1.0, 0.5, 1.0, 0.5, taus, (), torque).terms(u, t, q)
    entry = DeadBandMotion(1.0, 0.5, 1.0, 0.5, (), knots, False).terms(u, t, q)
    assert np.abs(coast).sum() > 0 and np.abs(entry).sum() > 0
    np.testing.assert_array_equal(both[:, : coast.shape[1]], coast)
    np.testing.assert_array_equal(both[:, coast.shape[1] :], entry)


def test_stacked_data_scores_like_column_stacked_nuisance() -> None:
    u, t, q, index = _record()
    r = np.sin(0.01 * np.arange(u.size)) + 0.1 * np.cos(0.05 * u)
    parts = [np.column_stack((np.ones_like(u), u)), np.cos(u)]
    fields = {"u_deg": u, "time_s": t, "torque_Nm": q, "ratio": 30.0, "sample_period_s": 1e-3, "engaged_index": index}
    stacked = DetectionData.stacked(parts, r, **fields)
    plain = DetectionData(residual_deg=r, nuisance=np.column_stack((*parts,)), **fields)
    x = harmonic_columns(u, [2])
    a, b = stacked.score(True, x), plain.score(True, x)
    assert (a.rss_after, a.delta_bic, a.heldout_gain) == (b.rss_after, b.delta_bic, b.heldout_gain)
    np.testing.assert_array_equal(stacked.nuisance, plain.nuisance)


@pytest.mark.parametrize("screened", [False, True])
def test_subsets_scored_from_one_set_of_cross_products_score_as_each_alone(screened: bool) -> None:
    """``score_subsets``: the normal equations of every subset of the columns are slices of one set
    of cross-products (as the dead band's parts are scored); each score is the subset's own."""
    u, t, q, _ = _record(n=40000)
    rng = np.random.default_rng(3)
    r = 0.01 * np.sin(np.radians(5 * u)) + 0.002 * np.cos(0.004 * np.arange(u.size)) + rng.normal(0, 1e-3, u.size)
    folds = cycle_folds(u)
    folds = folds.screen(cycles=10, factor=1, min_samples=0) if screened else folds
    assert folds.screened == screened
    data = DetectionData.stacked(
        [np.ones_like(u), u / 40.0], r, u_deg=u, time_s=t, torque_Nm=q, ratio=30.0, sample_period_s=1e-3, folds=folds
    )
    x = np.column_stack((harmonic_columns(u, [5, 2]), np.cos(0.004 * np.arange(u.size)), rng.normal(0, 1, u.size)))
    subsets = [[0, 1], [2], [0, 1, 2], [1, 3], [3]]
    for subset, got in zip(subsets, data.score_subsets(x, subsets)):
        alone = data.score(False, x[:, subset])
        assert got.n_terms == alone.n_terms == len(subset)
        for name in ("rss_before", "rss_after", "n_eff", "delta_bic", "own_share", "heldout_gain"):
            assert getattr(got, name) == pytest.approx(getattr(alone, name), rel=1e-9, abs=1e-12), name
        np.testing.assert_allclose(got.coef, alone.coef, rtol=1e-9)
    assert np.isnan(data.score_subsets(x, [[0, 1]], heldout=False)[0].heldout_gain)  # not measured without it
    assert np.isfinite(data.score_subsets(x, [[0, 1]])[0].heldout_gain)


@pytest.mark.parametrize("screened", [False, True])
def test_columns_zero_on_most_rows_score_on_their_support_as_on_every_row(screened: bool) -> None:
    """``score_subsets(..., support=rows)``: columns zero outside ``rows`` (the dead band's motion) have
    their cross-products and lag-1 products read there only; the scores are those of every row (the
    lag-1 products bit for bit, the cross-products to rounding)."""
    u, t, q, _ = _record(n=40000)
    rng = np.random.default_rng(4)
    r = 0.01 * np.sin(np.radians(5 * u)) + rng.normal(0, 1e-3, u.size)
    data = _stacked_data(u, t, q, r, screened)
    folds = data.folds
    m = folds.rows
    x = np.zeros((m, 3))
    rows = np.sort(rng.choice(m, m // 30, replace=False))
    x[rows] = rng.normal(0, 1, (rows.size, 3)) + r[folds.row_index[rows] if screened else rows, None]
    found = nonzero_rows(x)
    assert found is not None and np.array_equal(found, rows)
    subsets = [[0], [1, 2], [0, 1, 2]]
    for dense, sparse in zip(data.score_subsets(x, subsets), data.score_subsets(x, subsets, support=rows)):
        for name in ("rss_before", "rss_after", "n_eff", "delta_bic", "own_share", "heldout_gain"):
            assert getattr(sparse, name) == pytest.approx(getattr(dense, name), rel=1e-9, abs=1e-12), name
    e = rng.normal(0, 1, data.nuisance.shape[1] + 4)
    assert data.grams.lag_product(x, e) == data.grams.lag_product(np.take(x, rows, axis=0), e, rows)


def test_nonzero_rows_are_the_rows_with_a_value_other_than_zero() -> None:
    c = np.zeros((50, 3))
    c[[3, 7, 40], [0, 2, 1]] = [1.0, -2.0, np.nan]
    c[9, 1] = -0.0
    assert nonzero_rows(c).tolist() == [3, 7, 40]
    assert nonzero_rows(c, most=3).tolist() == [3, 7, 40]
    assert nonzero_rows(c, most=2) is None  # more than two: the pass stops at the third
    assert nonzero_rows(np.zeros((0, 2))).size == 0


def test_drift_columns_at_some_rows_are_its_stream_columns_there() -> None:
    """The drift's detector forms its columns at the rows the scores read (a screen's): the record's
    stream columns at those rows."""
    u, t, q, _ = _record()
    rows = np.r_[0:500, 1700:2300:2, 3900:4000]
    for degree in (1, 2, 3):
        effect = Drift(degree, 4.0)
        np.testing.assert_array_equal(effect.powers(t[rows], float(t[0])), effect.clone().terms(u, t, q)[rows])


@pytest.mark.parametrize("torque", [False, True])
def test_dead_band_columns_at_some_rows_are_the_whole_records_there(torque: bool) -> None:
    """The dead band's detector forms its columns at the rows its scores read (a screen's): the
    pass runs over every sample for its state and writes those rows only."""
    u, t, q, _ = _record()
    taus, knots, rests = _at_period(EXIT_TIME_CONSTANTS, 1e-3), _at_period(ENTRY_KNOTS, 1e-3), _at_period((8, 32), 1e-3)
    effect = DeadBandMotion(1.0, 0.5, 1.0, 0.5, taus, knots, torque, rests)
    whole = effect.clone().terms(u, t, q)
    rows = np.r_[3:700:2, 1500:2600, 3999]
    got = effect.columns_at(u, t, q, rows)
    assert np.count_nonzero(got) > 500  # the rows cross dead bands, engagements and rests
    np.testing.assert_array_equal(got, whole[rows])
    np.testing.assert_array_equal(effect.columns_at(u, t, q, None), whole)
    # the rows with a value other than zero, noted by the pass: what a scan of the columns finds
    for at in (rows, None):
        columns, nonzero = effect.columns_and_support_at(u, t, q, at)
        assert np.array_equal(nonzero, nonzero_rows(columns)) and 0 < nonzero.size < columns.shape[0]


def test_dead_band_columns_kept_by_the_loop_carry_the_rows_they_are_not_zero_on() -> None:
    """The loop's store of term columns takes the dead band's support from its pass (no scan): the same
    :class:`Support` as a scan of the columns gives."""
    t = np.arange(8000) * 1e-3
    u = 60.0 * np.sin(2 * np.pi * 0.3 * t) + 3.0 * t  # four reversals: the motion in the dead band is rare
    q = np.cos(2 * np.pi * 0.3 * t)
    taus, knots = _at_period(EXIT_TIME_CONSTANTS, 1e-3), _at_period(ENTRY_KNOTS, 1e-3)
    effect = DeadBandMotion(1.0, 0.5, 1.0, 0.5, taus, knots, True, ())
    built = TermColumns(u, t, q)
    columns = built.get(effect)
    np.testing.assert_array_equal(columns, effect.clone().terms(u, t, q))
    want = Support.of(np.array(columns))
    got = built.support(effect)
    assert want is not None and got is not None
    assert np.array_equal(got.rows, want.rows) and np.array_equal(got.values, want.values)


def test_velocity_function_columns_are_the_cardinal_splines_without_the_zero_knot() -> None:
    """The generic velocity function's columns come from the compiled evaluation (``cardinal_columns``):
    scipy's cubic splines at the velocity, the knot nearest 0 left out, to the last bit."""
    u, t, q, _ = _record()
    v = velocity_deg_s(u, t, 10)
    for inner in (1, 2, 5):
        knots = speed_knots(v, inner)
        plain = np.delete(cardinal_splines(knots, v), zero_knot(knots), axis=1)
        np.testing.assert_array_equal(VelocityFunction(knots, 10).terms(u, t, q), plain)


@pytest.mark.parametrize("screened", [False, True])
def test_the_nuisance_baseline_formed_once_gives_every_score_bit_for_bit(screened: bool) -> None:
    """What the nuisance columns alone leave (in sample and per held-out fold) is formed once per set of
    cross-products (:meth:`_Grams.baseline`) and shared by every candidate's score: the scores are those formed
    with it afresh from the candidate's own Gram matrices, every figure bit for bit."""
    u, t, q, _ = _record(n=40000)
    rng = np.random.default_rng(5)
    r = 0.01 * np.sin(np.radians(5 * u)) + rng.normal(0, 1e-3, u.size)
    data = _stacked_data(u, t, q, r, screened)
    folds = data.folds
    grams, p = data.grams, data.nuisance.shape[1]
    for x in (harmonic_columns(u, [5, 2]), rng.normal(0, 1, (u.size, 1))):
        x = data.scored(x)
        per_fold, total = grams.extended(x)
        terms = data._own_share_basis(p)
        lag = lambda e, x=x: grams.lag_product(x, e)  # noqa: E731
        fresh = _score_grams(per_fold, total, lag, folds.rows, p, terms)
        shared = _score_grams(per_fold, total, lag, folds.rows, p, terms, grams.baseline())
        assert fresh.heldout_folds >= 2 and np.isfinite(fresh.heldout_gain)
        for name in ("rss_before", "rss_after", "n_eff", "delta_bic", "own_share", "heldout_gain"):
            assert getattr(shared, name) == getattr(fresh, name), name
        np.testing.assert_array_equal(shared.coef, fresh.coef)
        assert data.score(False, x).delta_bic == fresh.delta_bic  # what the detectors call uses it
    assert grams.baseline() is grams.baseline()  # formed once


def test_the_rows_a_screen_reads_are_the_union_of_its_rows_and_where_they_are_held_from() -> None:
    rng = np.random.default_rng(6)
    for n in (1, 50, 5000):
        rows = np.sort(rng.choice(n, max(n // 3, 1), replace=False))
        index = rng.integers(0, n, n)
        expected = np.union1d(rows, index[rows])
        got = _sorted_union(rows, index[rows], n)
        assert got.dtype == expected.dtype
        np.testing.assert_array_equal(got, expected)


def test_the_records_typical_rest_is_formed_once_per_fit_and_is_the_effects_own() -> None:
    """The dead band's detector reads how long the output rests from the record's cache: a round's detection
    on its screen and its confirmation on every sample share one pass; the value is the effect's own."""
    u, t, q, _ = _record(n=20000)
    params = BacklashParams(1.0, 0.4, 1.0, 0.3)
    data = DetectionData(u, t, q, np.zeros(u.size), 30.0, 1e-3, backlash_params=params)
    expected = DeadBandMotion(1.0, 0.4, 1.0, 0.3).typical_rest_s(u, t)
    assert expected > 0
    calls = []
    original = DeadBandMotion.typical_rest_s

    def counted(self, u_deg, time_s):
        calls.append(1)
        return original(self, u_deg, time_s)

    DeadBandMotion.typical_rest_s = counted
    try:
        assert DeadBandMotion.record_rest_s(data, params) == expected
        assert DeadBandMotion.record_rest_s(data, params) == expected and len(calls) == 1
        other = BacklashParams(1.0, 0.1, 1.0, 0.1)
        assert DeadBandMotion.record_rest_s(data, other) == DeadBandMotion(1.0, 0.1, 1.0, 0.1).typical_rest_s(u, t)
    finally:
        DeadBandMotion.typical_rest_s = original
