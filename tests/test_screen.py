"""A long record's candidates are scored and refitted on a screen of its cycles (issue 13, "Speed").

``Folds.screen`` keeps groups of ``n_folds`` consecutive reversal cycles spread over the record;
the detectors' least squares, their held-out folds and the candidates' joint refits then run on
those samples only, and the effect chosen is detected again, and the terms fitted, on every
sample (``_search_round.confirmed_on_every_sample``). What the screen computes must be the plain computation
on its rows, and the loop's answer must be the one without the screen.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from same_answer import assert_same_answer

from online_backlash.cli import main as cli
from online_backlash.diagnostics import _folds
from online_backlash.diagnostics._folds import N_FOLDS, SCREEN_CYCLES, SCREEN_FACTOR, SCREEN_STRIDE, cycle_folds
from online_backlash.diagnostics._harmonics import (
    harmonic_at_sources,
    harmonic_columns,
    held_harmonic,
    held_per_flank,
    shaft_harmonic,
)
from online_backlash.diagnostics._record_cache import RecordCache
from online_backlash.diagnostics._scoring import DetectionData
from online_backlash.diagnostics._speed import held_spline_columns, record_velocity, speed_knots
from online_backlash.diagnostics.joint import ColumnParts, Support, _spans, _switched, engaged_index, fit_guarded
from online_backlash.diagnostics.loop import diagnose_arrays
from online_backlash.diagnostics.report import markdown_report
from online_backlash.errors import InvalidParameterError
from online_backlash.estimators.batch import VorosBacklash
from online_backlash.model import BacklashParams, backlash_sensitivity, backlash_sensitivity_spans, simulate_backlash
from online_backlash.simulation import synthetic
from online_backlash.simulation.rig import simulate_rig


@pytest.fixture(autouse=True)
def _no_sample_minimum(monkeypatch: pytest.MonkeyPatch) -> None:
    """These tests are of what a screen computes, on records short enough for a unit test: the screen's
    minimum size in samples (``_folds.SCREEN_MIN_SAMPLES``, ``tests/test_screen_size.py``) is lifted."""
    monkeypatch.setattr(_folds, "SCREEN_MIN_SAMPLES", 0)


def _reversing(cycles: int, per_cycle: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A motion of ``cycles`` up-and-down strokes (deg, load side) and its time (s)."""
    rng = np.random.default_rng(seed)
    n = cycles * per_cycle
    t = np.arange(n) * 1e-3
    u = 20.0 * np.sin(2 * np.pi * t / (per_cycle * 1e-3) - np.pi / 2) + 0.5 * t + rng.normal(0, 1e-4, n)
    return u, t


def test_the_screen_keeps_whole_cycles_one_of_each_fold_spread_over_the_record():
    u, _ = _reversing(64)
    folds = cycle_folds(u)
    screen = folds.screen()
    assert folds.n_cycles >= SCREEN_FACTOR * SCREEN_CYCLES and screen.screened and not folds.screened
    kept = screen.kept
    assert kept is not None and len(kept) == SCREEN_CYCLES
    groups = [kept[i : i + N_FOLDS] for i in range(0, len(kept), N_FOLDS)]
    assert all(
        list(g) == list(range(g[0], g[0] + N_FOLDS)) and g[0] % N_FOLDS == 0 for g in groups
    )  # one cycle of each fold
    assert groups[0][0] == 0 and groups[-1][0] == N_FOLDS * (
        folds.n_cycles // N_FOLDS - 1
    )  # the first and the last group
    assert [f for f, _, _ in screen.segments] == [c % N_FOLDS for c in kept]
    assert screen.segments == [folds.segments[c] for c in kept]
    every = np.concatenate([np.arange(a, b) for _, a, b in screen.segments])
    np.testing.assert_array_equal(screen.cycle_rows, every)  # the candidates' refits: every sample of those cycles
    # the scores: every SCREEN_STRIDE-th sample of each cycle, from its first
    assert SCREEN_STRIDE > 1 and screen.stride == SCREEN_STRIDE and folds.stride == 1
    rows = np.concatenate([np.arange(a, b)[::SCREEN_STRIDE] for _, a, b in screen.segments])
    np.testing.assert_array_equal(screen.row_index, rows)
    assert screen.rows == rows.size < every.size < u.size
    assert [b - a for _, a, b in screen.compact_segments] == [
        len(range(a, b, SCREEN_STRIDE)) for _, a, b in screen.segments
    ]
    assert [k for k, _, _ in screen.compact_segments] == [k for k, _, _ in screen.segments]
    assert all(s[2] == t[1] for s, t in zip(screen.compact_segments, screen.compact_segments[1:]))  # side by side
    assert screen.compact_segments[0][1] == 0 and screen.compact_segments[-1][2] == rows.size
    assert screen.as_dict() == folds.as_dict()
    whole = folds.screen(stride=1)  # without the stride: the scores read every sample of the cycles
    np.testing.assert_array_equal(whole.row_index, every)
    np.testing.assert_array_equal(whole.cycle_rows, every)


@pytest.mark.parametrize("cycles", [12, SCREEN_FACTOR * SCREEN_CYCLES - 2])
def test_a_record_of_few_cycles_is_not_screened(cycles):
    folds = cycle_folds(_reversing(cycles)[0])
    assert folds.screen() is folds and folds.row_index.size == folds.fold.size
    blocks = cycle_folds(np.linspace(0.0, 10.0, 5000))  # one stroke: time blocks
    assert blocks.kind == "time blocks" and blocks.screen() is blocks
    few = cycle_folds(_reversing(12)[0])
    assert few.screen(cycles=3) is few  # asked for so few that two groups of five would be every cycle


def _screened_data(
    cycles: int = 64, index: bool = True, cache: RecordCache | None = None
) -> tuple[DetectionData, DetectionData]:
    """The same record and residual scored over every cycle and over a screen."""
    u, t = _reversing(cycles)
    rng = np.random.default_rng(1)
    r = 0.01 * np.sin(np.radians(3 * u)) + 0.003 * np.sin(0.002 * np.arange(u.size)) + rng.normal(0, 1e-3, u.size)
    idx = np.maximum.accumulate(np.where(rng.random(u.size) < 0.8, np.arange(u.size), 0)) if index else None
    folds = cycle_folds(u)
    nuisance = [np.ones_like(u), u / 20.0]
    fields = {
        "u_deg": u,
        "time_s": t,
        "torque_Nm": np.full(u.size, np.nan),
        "ratio": 30.0,
        "sample_period_s": 1e-3,
        "engaged_index": idx,
    }
    full = DetectionData.stacked(nuisance, r, folds=folds, cache=cache, **fields)
    return full, DetectionData.stacked(nuisance, r, folds=folds.screen(), cache=cache, **fields)


def test_a_screened_score_is_the_least_squares_and_the_held_out_folds_of_its_rows():
    full, screen = _screened_data()
    assert screen.folds is not None and screen.folds.screened
    rows = screen.folds.row_index
    x = harmonic_columns(full.u_deg, [3])
    s = screen.score(False, x)
    # in sample: the least squares of the residual on [nuisance, x] over the screen's rows
    n = np.column_stack((np.ones(rows.size), full.u_deg[rows] / 20.0))
    r = full.residual_deg[rows]
    rss0 = float(np.sum((r - n @ np.linalg.lstsq(n, r, rcond=None)[0]) ** 2))
    w = np.column_stack((n, x[rows]))
    c = np.linalg.lstsq(w, r, rcond=None)[0]
    e = r - w @ c
    assert s.rss_before == pytest.approx(rss0, rel=1e-9) and s.rss_after == pytest.approx(float(e @ e), rel=1e-9)
    np.testing.assert_allclose(s.coef, c[2:], rtol=1e-8)
    # the lag-1 autocorrelation within the screen's cycles only (no product across a gap)
    lag = sum(float(e[a + 1 : b] @ e[a : b - 1]) for _, a, b in screen.folds.compact_segments)
    rho = lag / float(e @ e)
    assert s.n_eff == pytest.approx(rows.size * (1 - rho) / (1 + rho), rel=1e-9)
    # held out: fitted on the screen's other folds, scored on each
    fold = screen.folds.fold[rows]
    sse0 = sse1 = 0.0
    for k in range(screen.folds.n_folds):
        train, test = fold != k, fold == k
        c0 = np.linalg.lstsq(n[train], r[train], rcond=None)[0]
        c1 = np.linalg.lstsq(w[train], r[train], rcond=None)[0]
        sse0 += float(np.sum((r[test] - n[test] @ c0) ** 2))
        sse1 += float(np.sum((r[test] - w[test] @ c1) ** 2))
    assert s.heldout_gain == pytest.approx(1 - sse1 / sse0, rel=1e-8)
    # the screen sees less of the record than the whole
    assert s.n_eff < full.score(False, x).n_eff


def test_held_columns_on_a_screen_are_the_held_columns_of_its_rows():
    full, screen = _screened_data()
    rows = screen.folds.row_index
    x = harmonic_columns(full.u_deg, [2, 5])
    np.testing.assert_array_equal(screen.hold(x), full.hold(x)[rows])
    v = record_velocity(full)
    knots = speed_knots(v, 3)
    np.testing.assert_array_equal(held_spline_columns(screen, knots), held_spline_columns(full, knots)[rows])
    up, down = np.diff(full.u_deg, prepend=full.u_deg[0]) > 0, np.diff(full.u_deg, prepend=full.u_deg[0]) < 0
    np.testing.assert_array_equal(
        held_per_flank(x, up, down, full.engaged_index, rows), held_per_flank(x, up, down, full.engaged_index)[rows]
    )
    # a score takes held columns of either length alike, and nuisance columns too
    a, b = screen.score(True, x), screen.score(False, screen.hold(x))
    assert (a.rss_after, a.delta_bic, a.heldout_gain) == (b.rss_after, b.delta_bic, b.heldout_gain)
    y = harmonic_columns(full.u_deg, [7])
    a, b = screen.with_nuisance(screen.hold(x)).score(True, y), screen.with_nuisance(full.hold(x)).score(True, y)
    assert (a.rss_after, a.heldout_gain) == (b.rss_after, b.heldout_gain)


@pytest.mark.parametrize("budget", [None, 2 * 2**20, 1000])
def test_a_screen_holds_harmonics_from_the_stack_at_the_rows_its_scores_read(budget):
    """The stack of orders formed at those rows only (a budget too small for the whole record's but
    large enough for the screen's), or each order alone there (too small for either)."""
    full, screen = _screened_data(cache=None if budget is None else RecordCache(budget_bytes=budget))
    u = full.u_deg
    need = screen.needed_rows
    assert need is not None and need.size < u.size
    columns, positions, rows = harmonic_at_sources(screen, "load", u, 5, 24)
    assert rows is not None and np.array_equal(rows, need) and columns.shape == (need.size, 2)
    plain = full.hold(harmonic_columns(u, [5]))[screen.folds.row_index]
    np.testing.assert_allclose(held_harmonic(screen, "load", u, 5, 24), plain, rtol=0, atol=1e-12)
    np.testing.assert_allclose(columns[positions], plain, rtol=0, atol=1e-12)
    # every sample scored: the record's stack and the engaged index
    columns, positions, rows = harmonic_at_sources(full, "load", u, 5, 24)
    assert rows is None and np.array_equal(positions, full.engaged_index)
    np.testing.assert_array_equal(
        held_harmonic(full, "load", u, 5, 24), full.hold(shaft_harmonic(full, "load", u, 5, 24))
    )


def test_a_joint_fit_over_rows_is_the_least_squares_of_those_rows_and_reports_the_whole_residual():
    rec = simulate_rig(duration_s=20.0, reversal_s=(0.3, 0.8), seed=2)
    _, m, y, _ = synthetic.transmission_error(rec)
    u = m / 30.0
    base = VorosBacklash(refine=True, origin="first").fit(u, y)
    uc, yc = u - base.u_ref_, y - base.y_ref_
    cols = harmonic_columns(u, [2])
    every = fit_guarded(uc, yc, cols, base.params_)
    same = fit_guarded(uc, yc, cols, base.params_, rows=np.arange(u.size))

    def p(fit):
        return [fit.params.m_left, fit.params.c_left, fit.params.m_right, fit.params.c_right]

    assert p(same) == pytest.approx(p(every), rel=1e-9) and same.rms_deg == pytest.approx(every.rms_deg, rel=1e-9)
    rows = cycle_folds(u).segments[2][1:]
    part = np.arange(*rows)
    fit = fit_guarded(uc, yc, cols, base.params_, rows=part)
    assert fit.residual_deg.size == u.size  # the whole record's residual
    # at its backlash parameters the coefficients are the least squares of those rows
    x = simulate_backlash(uc, fit.params, 0.0)
    c = np.linalg.lstsq(cols[part], (yc - x)[part], rcond=None)[0]
    np.testing.assert_allclose(fit.coef, c, rtol=1e-7)
    np.testing.assert_allclose(fit.residual_deg, yc - x - cols @ fit.coef, rtol=0, atol=1e-12)
    assert engaged_index(uc, fit.params).size == u.size


def _long_record(seed: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """49 reversal cycles (enough to be screened), a load and a motor harmonic (synthetic.transmission_error)."""
    rec = simulate_rig(duration_s=85.0, reversal_s=(0.4, 1.0), seed=seed)
    return synthetic.transmission_error(rec)


def test_the_loop_on_a_screen_finds_what_it_finds_on_every_cycle():
    """Seed 5 is one where the screen alone keeps a spurious load order (23) that the whole record
    does not (so do seeds 6-8): the chosen effect is detected again on every sample."""
    t, m, y, q = _long_record()
    assert cycle_folds(m / 30.0).n_cycles >= SCREEN_FACTOR * SCREEN_CYCLES
    screened = diagnose_arrays(t, m, y, 30.0, torque_Nm=q)
    plain = diagnose_arrays(t, m, y, 30.0, torque_Nm=q, screen_cycles=0)
    assert screened.screened_cycles == SCREEN_CYCLES and plain.screened_cycles is None
    a, b = screened.as_dict(), plain.as_dict()
    assert [e["name"] for e in a["effects"]] == [e["name"] for e in b["effects"]] == ["transmission_error"]
    assert (
        a["effects"][0]["parameters"]["harmonics"][0]["order_per_rev"]
        == b["effects"][0]["parameters"]["harmonics"][0]["order_per_rev"]
    )
    assert (
        a["effects"][0]["evidence"]["delta_bic_eff"] == b["effects"][0]["evidence"]["delta_bic_eff"]
    )  # scored on every cycle, bit for bit
    assert a.pop("screened_cycles") == SCREEN_CYCLES and b.pop("screened_cycles") is None
    # the same orders, amplitudes and phases, evidence, RMS and play: the fit on every sample starts at the
    # screen's, so it ends at the same least squares to the search's tolerance
    assert_same_answer(a, b)


def test_the_cli_takes_the_screen_and_refuses_a_negative_one(tmp_path, capsys):
    t, m, y, _ = _long_record()
    path = tmp_path / "long.csv"
    np.savetxt(path, np.column_stack((t, m, y)), delimiter=",", header="time,motor,load", comments="", fmt="%.9f")
    assert cli(["diagnose", str(path), "--ratio", "30", "--screen-cycles", "0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["screened_cycles"] is None
    with pytest.raises(SystemExit) as usage:  # argparse's error for the option (issue 26)
        cli(["diagnose", str(path), "--ratio", "30", "--screen-cycles", "-1", "--json"])
    assert usage.value.code == 2 and "argument --screen-cycles: expected a number 0.." in capsys.readouterr().err
    with pytest.raises(InvalidParameterError, match="screen_cycles"):
        diagnose_arrays(t, m, y, 30.0, screen_cycles=-1)


def test_the_model_on_runs_of_rows_started_before_a_flank_engages_is_the_whole_records():
    """The play operator forgets its state once a flank engages: each run of the screen's rows,
    simulated from a little before the flank last engaged ahead of it, gives the whole record's
    output and derivatives there, also for parameters near the ones the runs were planned with."""
    rec = simulate_rig(duration_s=30.0, reversal_s=(0.3, 0.8), seed=4)
    u = rec.motor_deg / 30.0
    uc = u - u[0]
    start = BacklashParams(1.0, 0.26, 1.0, 0.24)
    x, dx = backlash_sensitivity(uc, start)
    one = backlash_sensitivity_spans(uc, start, [0], [0], [uc.size], [0.0])
    np.testing.assert_array_equal(one[0], x)
    np.testing.assert_array_equal(one[1], dx)
    rows = cycle_folds(u).screen(cycles=10, factor=1).cycle_rows
    assert 0 < rows.size < uc.size
    spans = _spans(rows, _switched(uc, start))
    for p in (start, BacklashParams(1.002, 0.262, 0.999, 0.238)):
        x, dx = backlash_sensitivity(uc, p)
        xs, dxs = backlash_sensitivity_spans(uc, p, *spans)
        np.testing.assert_array_equal(xs, x[rows])
        np.testing.assert_array_equal(dxs, dx[rows])


def test_the_report_says_the_search_ran_on_a_screen():
    t, m, y, q = _long_record()
    d = diagnose_arrays(t, m, y, 30.0, torque_Nm=q)
    text = markdown_report(d)
    assert f"scored and refitted on {SCREEN_CYCLES} of the record's {d.cycles} reversal cycles" in text
    assert d.cycles == cycle_folds(m / 30.0).n_cycles
    assert "Search:" not in markdown_report(diagnose_arrays(t, m, y, 30.0, torque_Nm=q, screen_cycles=0))


def test_column_parts_are_the_block_whole_at_rows_and_times_coefficients():
    rng = np.random.default_rng(7)
    n = 500
    a, b = rng.normal(size=(n, 2)), rng.normal(size=(n, 3))
    parts = ColumnParts((a, b))
    block = np.column_stack((a, b))
    assert parts.shape == (n, 5)
    np.testing.assert_array_equal(parts.dense(), block)
    rows = np.sort(rng.choice(n, 120, replace=False))
    np.testing.assert_array_equal(parts.at(rows), block[rows])
    coef = rng.normal(size=5)
    np.testing.assert_allclose(parts.dot(coef), block @ coef, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(parts.dot(np.r_[0.0, 0.0, coef[2:]]), block[:, 2:] @ coef[2:], rtol=1e-12, atol=1e-12)


def test_a_part_zero_on_most_samples_gives_the_products_of_its_whole_columns():
    """``joint.Support``: a part's cross-products, its products with a vector and with coefficients, read
    its support's rows only; they are the whole block's (to rounding), held or not."""
    rng = np.random.default_rng(11)
    n = 4000
    dense = rng.normal(size=(n, 2))
    sparse = np.zeros((n, 3))
    at = np.sort(rng.choice(n, 150, replace=False))
    sparse[at] = rng.normal(size=(150, 3))
    support = Support.of(sparse)
    assert support is not None and np.array_equal(support.rows, at) and Support.of(dense) is None
    plain = ColumnParts((dense, sparse))
    kept = ColumnParts((dense, sparse), (None, support))
    block = plain.dense()
    np.testing.assert_allclose(kept.gram(), block.T @ block, rtol=1e-12, atol=1e-9)
    a = rng.normal(size=(n, 4))
    np.testing.assert_allclose(kept.t_dot(a), block.T @ a, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(kept.t_dot(a[:, 0]), block.T @ a[:, 0], rtol=1e-12, atol=1e-9)
    coef = rng.normal(size=5)
    np.testing.assert_allclose(kept.dot(coef), block @ coef, rtol=1e-12, atol=1e-12)
    index = np.maximum.accumulate(np.where(rng.random(n) < 0.5, np.arange(n), 0))  # the last engaged sample
    held = np.array([False, False, True, False, True])
    np.testing.assert_allclose(kept.held_at(held, index).dense(), plain.held_at(held, index).dense())
    assert kept.held_at(held, index).supports[1] is None  # held through the dead band: nonzero elsewhere too
    assert kept.held_at(np.r_[True, False, False, False, False], index).supports[1] is support
