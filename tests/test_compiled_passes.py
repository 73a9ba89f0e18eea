"""The joint fit's compiled passes give the numbers of the array code they stand for.

``diagnostics.joint`` simulates the backlash (eq. 1-7) and forms what its least squares need in
one compiled pass each: the Gram matrix of ``[1, dx/dp, y - x]`` summed as the model runs
(``_sensitivity_gram``), the model view's directions (``play_sensitivity``) and the last engaged
sample (``_switched``). Each is held here against the model's own simulations and plain NumPy on
inputs they were not shaped for (a quantised input that stands still for runs of samples, both
flanks engaged, a piece of the record run from a span's start).
"""

from __future__ import annotations

import numpy as np

from online_backlash.diagnostics._normal_equations import Projector, left_sum_of_squares
from online_backlash.diagnostics._scoring import effective_samples
from online_backlash.diagnostics.joint import (
    BACKLASH_DIRECTIONS,
    _sensitivity_gram,
    _spans,
    _switched,
    fit_joint,
    play_sensitivity,
)
from online_backlash.model import (
    BacklashParams,
    backlash_sensitivity,
    backlash_sensitivity_spans,
    simulate_backlash,
    simulate_switching,
)

PARAMS = BacklashParams(1.03, 0.21, 0.97, 0.27)


def _quantised_input(n: int = 20000, seed: int = 3) -> np.ndarray:
    """Reversals of a few degrees on an encoder of 2^14 counts per turn: runs of equal samples."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    u = 2.0 * np.sin(2 * np.pi * 0.7 * t) + 0.4 * np.sin(2 * np.pi * 2.3 * t) + np.cumsum(rng.normal(0, 2e-3, n))
    step = 360.0 / 2**14
    return np.round(u / step) * step


def _directions(dx: np.ndarray) -> np.ndarray:
    """``[1, dx/dmL, dx/dmR, dx/d(play)]`` written out from ``dx = d x / d [mL, cL, mR, cR]``."""
    return np.column_stack((np.ones(dx.shape[0]), dx[:, 0], dx[:, 2], 0.5 * (dx[:, 1] + dx[:, 3])))


def test_sensitivity_gram_is_the_gram_of_the_simulated_rows():
    u = _quantised_input()
    rng = np.random.default_rng(0)
    y = simulate_backlash(u, PARAMS) + rng.normal(0, 1e-3, u.size)
    rows = np.sort(rng.choice(u.size, u.size // 3, replace=False))
    rows = np.unique(np.concatenate([np.arange(a, a + 400) for a in rows[::200]]))  # runs of rows
    rows = rows[rows < u.size]
    whole = (np.zeros(1, np.int64), np.zeros(1, np.int64), np.full(1, u.size, np.int64), np.zeros(1))
    for spans, target in ((whole, y), (_spans(rows, _switched(u, PARAMS)), y[rows])):
        x, dx = backlash_sensitivity_spans(u, PARAMS, *spans)
        a = np.empty((target.size, 5))
        gram = _sensitivity_gram(u, target, PARAMS.m_left, PARAMS.c_left, PARAMS.m_right, PARAMS.c_right, *spans, a)
        assert np.array_equal(a[:, :4], dx) and np.array_equal(a[:, 4], target - x)  # bit for bit
        w = np.column_stack((np.ones(target.size), a))
        np.testing.assert_allclose(gram, w.T @ w, rtol=1e-11, atol=1e-11 * np.abs(w.T @ w).max())


def test_switched_is_the_switching_simulation_and_its_last_engaged_sample():
    u = _quantised_input()
    for params in (PARAMS, BacklashParams(-0.9, 0.1, -1.1, 0.3), BacklashParams(1.0, 0.0, 1.0, 0.0)):
        x, f1, f2 = simulate_switching(u, params, 0.0)
        want = np.maximum.accumulate(np.where((f1 + f2) > 0, np.arange(u.size), 0))
        got_x, got_index = _switched(u, params)
        assert np.array_equal(got_x, x) and np.array_equal(got_index, want)
        assert got_index.dtype == np.int64


def test_play_sensitivity_writes_the_backlash_directions_of_the_sensitivities():
    u = _quantised_input()
    x, dx = backlash_sensitivity(u, PARAMS)
    g, others, got_x = play_sensitivity(u, PARAMS)
    directions = _directions(dx)
    assert np.array_equal(got_x, x)
    assert np.array_equal(others, directions[:, :3]) and np.array_equal(g, directions[:, 3])
    assert others.flags.c_contiguous
    # the same directions as combinations of the columns of the kernel's Gram matrix
    w = np.column_stack((np.ones(u.size), dx, np.zeros(u.size)))
    np.testing.assert_allclose(w @ BACKLASH_DIRECTIONS, directions, rtol=0, atol=1e-15)


def test_projector_from_cross_products_equals_the_projector_on_the_array():
    rng = np.random.default_rng(5)
    c, a = rng.normal(size=(3000, 4)), rng.normal(size=(3000, 3))
    proj = Projector(c)
    assert np.array_equal(proj.left_of(a.T @ a, c.T @ a), proj.left_gram(a))
    assert np.array_equal(proj.coef_of(c.T @ a[:, 0]), proj.coef(a[:, 0]))


def test_play_guard_figures_equal_those_of_the_full_length_directions():
    """The joint fit's play inflation and standard error, formed from the kernel's Gram matrix and the
    columns' products with it, equal those from the directions written out over every sample."""
    rng = np.random.default_rng(11)
    u = _quantised_input(30000, 9)
    cols = np.column_stack((np.sin(np.radians(37 * u)), np.cos(np.radians(11 * u))))
    y = simulate_backlash(u, PARAMS) + cols @ np.array([0.003, -0.002]) + rng.normal(0, 1e-3, u.size)
    fit = fit_joint(u, y, cols, BacklashParams(1.0, 0.2, 1.0, 0.3))
    _, dx = backlash_sensitivity(u, fit.params)
    basis = _directions(dx)
    g2 = float(basis[:, 3] @ basis[:, 3])
    base = left_sum_of_squares(basis.T @ basis)
    joint = left_sum_of_squares(Projector(cols).left_gram(basis))
    np.testing.assert_allclose(fit.play_inflation, (base / g2) / (joint / g2), rtol=1e-8)
    left = fit.residual_deg
    np.testing.assert_allclose(
        fit.play_std_deg, np.sqrt(float(left @ left) / effective_samples(left) / joint), rtol=1e-8
    )
