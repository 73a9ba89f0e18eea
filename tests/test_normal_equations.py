"""The loop's least squares from cross-products give what the full-length computations give.

The diagnostics loop scores candidates and refits the backlash with effect columns from Gram
matrices (``diagnostics._normal_equations``, ``_scoring``, ``joint``) instead of full-length
QR, SVD and refits; these tests hold each shortcut against the direct computation on data it
was not shaped for (random columns, a simulated backlash with an effect and noise).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from online_backlash.diagnostics._normal_equations import Projector, left_sum_of_squares
from online_backlash.diagnostics._scoring import DetectionData, effective_samples, score_columns
from online_backlash.diagnostics.joint import fit_joint
from online_backlash.model import BacklashParams, backlash_sensitivity, simulate_backlash


def _random(n: int, k: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, k)) @ rng.normal(size=(k, k))  # correlated columns


def test_projector_matches_lstsq():
    c, a = _random(3000, 5, 0), _random(3000, 3, 1)
    proj = Projector(c)
    coef, *_ = np.linalg.lstsq(c, a[:, 0], rcond=None)
    left = a - c @ np.linalg.lstsq(c, a, rcond=None)[0]
    np.testing.assert_allclose(proj.coef(a[:, 0]), coef, rtol=1e-9)
    np.testing.assert_allclose(proj.leave(a[:, 0]), left[:, 0], atol=1e-9 * np.abs(a).max())
    np.testing.assert_allclose(proj.left_gram(a), left.T @ left, rtol=1e-8)
    w = np.column_stack((c, a[:, :1]))
    assert np.isclose(left_sum_of_squares(w.T @ w), float(left[:, 0] @ left[:, 0]), rtol=1e-8)


def test_score_lag_and_rss_match_the_explicit_residual():
    rng = np.random.default_rng(2)
    n = 4000
    t = np.arange(n) * 1e-3
    cols = np.column_stack((np.sin(7 * t), np.cos(3 * t)))
    r = 0.01 * cols[:, 0] + np.cumsum(rng.normal(0, 1e-4, n))  # autocorrelated: n_eff well below n
    s = score_columns(r, cols)
    w = np.column_stack((np.ones(n), cols))
    e = r - w @ np.linalg.lstsq(w, r, rcond=None)[0]
    assert np.isclose(s.rss_after, float(e @ e), rtol=1e-9)
    assert np.isclose(s.n_eff, effective_samples(e), rtol=1e-9)
    assert s.n_eff < 0.5 * n


def test_with_nuisance_updates_the_grams_as_a_fresh_build_would():
    rng = np.random.default_rng(3)
    n = 6000
    u = 20 * np.sin(np.linspace(0, 12 * np.pi, n))  # six reversal cycles: five folds
    t = np.arange(n) * 1e-3
    r = 0.01 * np.sin(np.radians(5 * u)) + rng.normal(0, 1e-3, n)
    extra, cand = np.column_stack((np.sin(np.radians(2 * u)), u)), np.sin(np.radians(5 * u))[:, None]
    data = DetectionData(u, t, np.full(n, np.nan), r, 30.0, 1e-3)
    updated = data.with_nuisance(extra)
    fresh = DetectionData(u, t, np.full(n, np.nan), r, 30.0, 1e-3, nuisance=np.column_stack((np.ones(n), extra)))
    a, b = updated.score(False, cand), fresh.score(False, cand)
    assert a.heldout_folds == b.heldout_folds == 5
    assert all(np.array_equal(getattr(a, k), getattr(b, k)) for k in vars(a))  # bit for bit
    # the cross-products formed by with_nuisance are the ones used (not thrown away and formed again)
    assert updated.grams is not None and np.shares_memory(updated.grams.z, updated.nuisance)
    for name in ("rss_before", "rss_after", "n_eff", "delta_bic", "own_share", "heldout_gain"):
        assert np.isclose(getattr(a, name), getattr(b, name), rtol=1e-9), name


def test_scores_left_out_equal_the_scores_of_data_made_without_each_group():
    """Each group of nuisance columns left out in turn, its part put back into the residual: from one
    set of cross-products, every figure of the score is that of detection data made for the case."""
    rng = np.random.default_rng(4)
    n = 6000
    u = 20 * np.sin(np.linspace(0, 12 * np.pi, n))  # six reversal cycles: five folds
    t = np.arange(n) * 1e-3
    backlash = np.column_stack((np.ones(n), u, np.cos(np.radians(u))))  # stands for the backlash's own directions
    a, b = np.column_stack((np.sin(np.radians(2 * u)), np.cos(np.radians(2 * u)))), np.sin(np.radians(5 * u))[:, None]
    r = np.cumsum(rng.normal(0, 1e-4, n)) + rng.normal(0, 1e-3, n)
    coefs = [np.array([0.02, -0.01]), np.array([0.005])]
    nuisance = np.column_stack((backlash, a, b))
    data = DetectionData(u, t, np.full(n, np.nan), r, 30.0, 1e-3, nuisance=nuisance, n_backlash=3)
    shared = data.scores_left_out([np.array([3, 4]), np.array([5])], coefs)
    for mine, others, coef, got in ((a, b, coefs[0], shared[0]), (b, a, coefs[1], shared[1])):
        case = DetectionData(
            u,
            t,
            np.full(n, np.nan),
            r + mine @ coef,
            30.0,
            1e-3,
            nuisance=np.column_stack((backlash, others)),
            n_backlash=3,
        )
        want = case.score(False, mine)
        assert got.heldout_folds == want.heldout_folds == 5
        for name in ("rss_before", "rss_after", "n_eff", "delta_bic", "own_share", "heldout_gain"):
            assert np.isclose(getattr(got, name), getattr(want, name), rtol=1e-8), name
        np.testing.assert_allclose(
            got.coef, want.coef, rtol=1e-6
        )  # solved from a Gram formed otherwise: a nearly collinear basis


def test_scores_left_out_with_columns_read_on_their_support_equal_those_of_the_block():
    """Nuisance columns zero outside a few rows, handed on as their values there (``extra``,
    ``support``), give the scores of the same columns in the block of nuisance columns."""
    rng = np.random.default_rng(6)
    n = 6000
    u = 20 * np.sin(np.linspace(0, 12 * np.pi, n))
    t = np.arange(n) * 1e-3
    backlash = np.column_stack((np.ones(n), u, np.cos(np.radians(u))))
    a = np.sin(np.radians(2 * u))[:, None]
    rows = np.flatnonzero(np.abs(np.diff(u, prepend=u[0])) < 0.01)  # near the reversals
    sparse = np.zeros((n, 2))
    sparse[rows] = rng.normal(size=(rows.size, 2))
    r = sparse @ np.array([0.01, -0.02]) + 0.003 * a[:, 0] + rng.normal(0, 1e-3, n)
    coefs = [np.array([0.003]), np.array([0.01, -0.02])]
    block = DetectionData(
        u, t, np.full(n, np.nan), r, 30.0, 1e-3, nuisance=np.column_stack((backlash, a, sparse)), n_backlash=3
    )
    want = block.scores_left_out([np.array([3]), np.array([4, 5])], coefs)
    parted = DetectionData(
        u, t, np.full(n, np.nan), r, 30.0, 1e-3, nuisance=np.column_stack((backlash, a)), n_backlash=3
    )
    got = parted.scores_left_out([np.array([3]), np.array([4, 5])], coefs, sparse[rows], rows)
    for g, w in zip(got, want):
        for name in ("rss_before", "rss_after", "n_eff", "delta_bic", "own_share", "heldout_gain"):
            assert np.isclose(getattr(g, name), getattr(w, name), rtol=1e-9), name


def test_joint_fit_equals_the_full_length_search():
    """The search handed the (k + 1)-row factor stops where least squares on all n rows stops."""
    rng = np.random.default_rng(4)
    n = 20000
    uc = 3.0 * np.sin(np.linspace(0, 16 * np.pi, n)) + 0.3 * np.sin(np.linspace(0, 5 * np.pi, n))
    true = BacklashParams(1.02, 0.21, 0.98, 0.29)
    cols = np.column_stack((np.sin(np.radians(40 * uc)), np.cos(np.radians(17 * uc))))
    yc = simulate_backlash(uc, true) + cols @ np.array([0.004, -0.002]) + rng.normal(0, 2e-3, n)
    start = BacklashParams(1.0, 0.2, 1.0, 0.3)
    fit = fit_joint(uc, yc, cols, start)

    q, rr = np.linalg.qr(cols)

    def residual(p: np.ndarray) -> np.ndarray:
        e = yc - backlash_sensitivity(uc, BacklashParams(*p))[0]
        return e - q @ (q.T @ e)

    def jacobian(p: np.ndarray) -> np.ndarray:
        dx = backlash_sensitivity(uc, BacklashParams(*p))[1]
        return -(dx - q @ (q.T @ dx))

    p0 = np.array([start.m_left, start.c_left, start.m_right, start.c_right])
    ref = least_squares(residual, p0, jac=jacobian, x_scale="jac")
    got = np.array([fit.params.m_left, fit.params.c_left, fit.params.m_right, fit.params.c_right])
    np.testing.assert_allclose(got, ref.x, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(fit.residual_deg, residual(ref.x), atol=1e-8)
    np.testing.assert_allclose(
        fit.coef, np.linalg.solve(rr, q.T @ (yc - simulate_backlash(uc, BacklashParams(*ref.x)))), rtol=1e-6
    )
    assert abs(fit.params.play - true.play) < 0.01


def test_columns_in_parts_give_the_cross_products_of_their_block():
    """``ColumnParts.gram`` / ``t_dot`` / ``held_at`` (least squares without a block of all the parts)
    against the same on the block itself; one part gives the block's numbers bit for bit."""
    from online_backlash.diagnostics.joint import ColumnParts, hold_columns

    rng = np.random.default_rng(7)
    n = 5000
    a, b, c = rng.normal(size=(n, 2)), rng.normal(size=(n, 3)), rng.normal(size=(n, 1))
    parts = ColumnParts((a, b, c))
    block = parts.dense()
    v = rng.normal(size=(n, 4))
    np.testing.assert_allclose(parts.gram(), block.T @ block, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(parts.t_dot(v), block.T @ v, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(parts.t_dot(v[:, 0]), block.T @ v[:, 0], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(Projector(parts).coef(v[:, 1]), Projector(block).coef(v[:, 1]), rtol=1e-9)
    held = np.array([False, False, True, True, True, False])
    index = np.maximum.accumulate(np.where(rng.random(n) > 0.5, np.arange(n), 0))
    np.testing.assert_array_equal(parts.held_at(held, index).dense(), hold_columns(block, held, index))
    one = ColumnParts((b,))
    assert np.array_equal(one.gram(), b.T @ b) and np.array_equal(one.t_dot(v), b.T @ v)
