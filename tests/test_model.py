"""The model: eq. (1)-(3) against the switching-function form (4)-(7), the band, the cascade (15)-(17)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from online_backlash.errors import InvalidParameterError
from online_backlash.model import (
    PAPER_EXAMPLES,
    BacklashParams,
    backlash_sensitivity,
    heaviside_le0,
    linear_filter,
    simulate_backlash,
    simulate_backlash_varying,
    simulate_cascade,
    simulate_switching,
    switching_functions,
)

slope = st.floats(0.05, 5.0)
width = st.floats(1e-3, 2.0)  # the paper: cL > 0, cR > 0
sign = st.sampled_from([1.0, -1.0])
inputs = arrays(np.float64, st.integers(1, 300), elements=st.floats(-10.0, 10.0))


@st.composite
def backlash_params(draw) -> BacklashParams:
    s = draw(sign)
    m_left = draw(slope)
    m_right = m_left if draw(st.booleans()) else draw(slope)  # equal slopes (a gearbox) half the time
    return BacklashParams(s * m_left, draw(width), s * m_right, draw(width))


def _crossing_free_input(u: np.ndarray, p: BacklashParams) -> np.ndarray:
    """Scale ``u`` (|u| <= 10) so the outputs it reaches stay where the band is open.

    The band ``zL < u < zR`` of eq. (2)-(3) has width ``x (1/mR - 1/mL) + cL + cR``: with
    unequal slopes the two lines of eq. (1) cross at ``|x| = play / |1/mL - 1/mR|``, and beyond
    that the model (and the equivalence of its two forms) no longer holds.
    """
    inv = abs(1 / p.m_left - 1 / p.m_right)
    if inv == 0:
        return u
    m = max(abs(p.m_left), abs(p.m_right))
    reach = 0.5 * p.play / inv / m - max(p.c_left, p.c_right)  # |u| that keeps |x| < x_cross / 2
    return u / 10.0 * max(reach, 0.0)


@settings(max_examples=500, deadline=None)
@given(u=inputs, p=backlash_params())
def test_case_form_equals_switching_form_exactly(u, p):
    u = _crossing_free_input(u, p)
    x_case = simulate_backlash(u, p)
    x_switch, f1, f2 = simulate_switching(u, p)
    assert np.array_equal(x_case, x_switch)
    # f1 and f2 are eq. (5)-(6) evaluated with the previous output, never both active, except where
    # the input has not moved: there they keep the values of the sample before (exact arithmetic's)
    x_prev = np.concatenate(([0.0], x_case[:-1]))
    g1, g2 = switching_functions(u, x_prev, p)
    moved = np.r_[True, u[1:] != u[:-1]]
    assert np.array_equal(f1[moved], g1[moved]) and np.array_equal(f2[moved], g2[moved])
    kept = np.flatnonzero(~moved)
    assert np.array_equal(f1[kept], f1[kept - 1]) and np.array_equal(f2[kept], f2[kept - 1])
    assert not np.any((f1 == 1) & (f2 == 1))


def test_eq7_needs_an_open_band():
    """With no play at all, eq. (5) and (6) both fire on a sample that sits on the line and eq. (7)
    adds both lines: the paper's ``cL, cR > 0`` is needed, not decoration."""
    p = BacklashParams(1.0, 0.0, 1.0, 0.0)
    u = np.array([1.0])  # with the output before at 1.0: on both lines at once
    assert simulate_backlash(u, p, x0=1.0).tolist() == [1.0]
    assert simulate_switching(u, p, x0=1.0)[0].tolist() == [2.0]


@settings(max_examples=300, deadline=None)
@given(u=inputs, p=backlash_params())
def test_output_stays_between_the_band_lines(u, p):
    u = _crossing_free_input(u, p)
    x = simulate_backlash(u, p)
    z_left = x / p.m_left - p.c_left  # eq. (2) with the current output
    z_right = x / p.m_right + p.c_right  # eq. (3)
    tol = 1e-9 * (1 + np.abs(u) + np.abs(x))
    assert np.all(u >= z_left - tol) and np.all(u <= z_right + tol)
    # each sample sits on a line or holds the previous output
    x_prev = np.concatenate(([0.0], x[:-1]))
    on_left = np.isclose(x, p.m_left * (u + p.c_left), rtol=1e-12, atol=1e-12)
    on_right = np.isclose(x, p.m_right * (u - p.c_right), rtol=1e-12, atol=1e-12)
    assert np.all(on_left | on_right | (x == x_prev))


@pytest.mark.parametrize("s", [1.0, -1.0])
def test_known_trajectory_both_signs(s):
    p = BacklashParams(s * 1.0, 0.2, s * 1.0, 0.3)
    u = np.array([0.0, 0.5, 1.0, 0.9, 0.6, 0.0])
    assert np.allclose(simulate_backlash(u, p), s * np.array([0.0, 0.2, 0.7, 0.7, 0.7, 0.2]))


def test_heaviside_of_eq4():
    assert heaviside_le0(np.array([-1.0, 0.0, 1e-300])).tolist() == [1.0, 1.0, 0.0]


@pytest.mark.parametrize(
    "args",
    [(1.0, 0.1, -1.0, 0.1), (0.0, 0.1, 1.0, 0.1), (1.0, np.nan, 1.0, 0.1), (1.0, 0.1, np.inf, 0.1)],
)
def test_params_are_validated(args):
    with pytest.raises(InvalidParameterError):
        BacklashParams(*args)


def test_negative_band_and_bad_input_are_rejected():
    with pytest.raises(InvalidParameterError, match="dead band"):
        simulate_backlash(np.zeros(3), BacklashParams(1.0, 0.1, 1.0, -0.2))
    with pytest.raises(InvalidParameterError, match="non-finite"):
        simulate_backlash(np.array([0.0, np.nan]), BacklashParams(1.0, 0.1, 1.0, 0.1))
    with pytest.raises(InvalidParameterError, match="one-dimensional"):
        simulate_backlash(np.zeros((2, 2)), BacklashParams(1.0, 0.1, 1.0, 0.1))


def test_theta_round_trip_eq8_eq9():
    p = BacklashParams(-1.3, 0.2, -1.1, 0.4)
    assert np.allclose(p.theta, [-1.3, -0.26, -1.1, -0.44])
    q = BacklashParams.from_theta(p.theta)
    assert np.allclose([q.m_left, q.c_left, q.m_right, q.c_right], [-1.3, 0.2, -1.1, 0.4])
    assert p.play == pytest.approx(0.6)


def _linear_by_loop(x, a, b):
    """Eq. (15)-(17) as a plain loop: y(t) = x(t-1) + sum a_i x(t-i) - sum b_j y(t-j), zero before the start."""
    y = np.zeros(x.size)
    coef_a = [1.0, *a]  # a1 = 1
    for t in range(x.size):
        acc = sum(coef_a[i - 1] * x[t - i] for i in range(1, len(coef_a) + 1) if t - i >= 0)
        acc -= sum(b[j - 1] * y[t - j] for j in range(1, len(b) + 1) if t - j >= 0)
        y[t] = acc
    return y


@settings(max_examples=50, deadline=None)
@given(
    u=arrays(np.float64, st.integers(1, 120), elements=st.floats(-1.0, 1.0)),
    p=backlash_params(),
    a=st.lists(st.floats(-0.9, 0.9), max_size=3),
    b=st.lists(st.floats(-0.4, 0.4), max_size=3),
)
def test_cascade_matches_direct_loop_of_eq15_17(u, p, a, b):
    y, x = simulate_cascade(u, p, np.array(a), np.array(b))
    assert np.array_equal(x, simulate_backlash(u, p))  # the internal variable is eq. (1)-(3)
    assert np.allclose(y, _linear_by_loop(x, a, b), rtol=1e-9, atol=1e-9)
    assert np.array_equal(linear_filter(x, np.array(a), np.array(b)), y)


def test_paper_linear_block():
    # y(t) = x(t-1) + 0.5 x(t-2) + 0.2 y(t-1) - 0.35 y(t-2) on a unit impulse
    y = linear_filter(np.array([1.0, 0, 0, 0]), np.array([0.5]), np.array([-0.2, 0.35]))
    assert np.allclose(y, [0.0, 1.0, 0.7, -0.21])


def test_varying_backlash_with_constant_widths_equals_eq1():
    u = np.random.default_rng(3).uniform(-1, 1, 400)
    p = BacklashParams(1.2, 0.1, 0.9, 0.3)
    xv = simulate_backlash_varying(u, 1.2, np.full(400, 0.1), 0.9, np.full(400, 0.3))
    assert np.array_equal(xv, simulate_backlash(u, p))
    with pytest.raises(InvalidParameterError):
        simulate_backlash_varying(u, 1.2, np.full(3, 0.1), 0.9, np.full(400, 0.3))


@pytest.mark.parametrize("s", [1.0, -1.0])
def test_sensitivity_matches_finite_differences(s):
    u = np.random.default_rng(7).uniform(-1, 1, 500)
    v = np.array([s * 1.3, 0.25, s * 0.8, 0.35])
    x, dx = backlash_sensitivity(u, BacklashParams(*v), 0.1)
    assert np.array_equal(x, simulate_backlash(u, BacklashParams(*v), 0.1))
    h = 1e-7
    for k in range(4):
        step = np.eye(4)[k] * h
        fd = (
            simulate_backlash(u, BacklashParams(*(v + step)), 0.1)
            - simulate_backlash(u, BacklashParams(*(v - step)), 0.1)
        ) / (2 * h)
        assert np.allclose(dx[:, k], fd, atol=1e-6), k


@pytest.mark.parametrize("number", sorted(PAPER_EXAMPLES))
def test_paper_example_data_have_the_stated_snr(number):
    ex = PAPER_EXAMPLES[number]
    u, y = ex.generate(seed=11)
    assert u.shape == y.shape == (ex.samples,) and np.all(np.abs(u) < 1)
    clean = (
        simulate_cascade(u, ex.params, np.array(ex.a), np.array(ex.b))[0]
        if ex.cascade
        else simulate_backlash(u, ex.params)
    )
    snr = np.std(clean) / np.std(y - clean)
    assert snr == pytest.approx(ex.snr, rel=0.1)
    assert np.array_equal(ex.generate(seed=11)[1], y)


#: a quantised input (steps of 0.011 deg): it repeats samples at every reversal
QUANTISED = np.round(30 * np.sin(np.linspace(0, 8 * np.pi, 4000)) / 0.011) * 0.011
#: parameters with which eq. (5)-(6) in floating point flicker on ``QUANTISED`` (found by search; equal
#: slopes: the band stays open, so the two forms of the model agree)
FLICKERING = BacklashParams(1.4554425309821815, 0.3428080423874833, 1.4554425309821815, 0.13687617154257523)


def test_a_repeated_input_keeps_its_switching_functions_whatever_the_last_bit_of_the_parameters():
    """Where the input has not moved, eq. (5)-(6) are a tie on a flank (``x(t-1) / mL - cL = u(t-1)``
    in exact arithmetic) that floating point decides either way; the simulation keeps the engaged
    state there, so the engaged samples do not move with the parameters' last bits."""
    x, f1, f2 = simulate_switching(QUANTISED, FLICKERING)
    g1, g2 = switching_functions(QUANTISED, np.r_[0.0, x[:-1]], FLICKERING)
    assert np.any((g1 + g2 > 0) != (f1 + f2 > 0))  # the plain test flickers on this record
    assert np.array_equal(x, simulate_backlash(QUANTISED, FLICKERING))  # the output is the same either way
    p = FLICKERING
    for q in (
        BacklashParams(p.m_left * (1 + 1e-12), p.c_left, p.m_right, p.c_right),
        BacklashParams(p.m_left, p.c_left * (1 - 1e-12), p.m_right, p.c_right),
        BacklashParams(p.m_left, p.c_left, p.m_right, p.c_right * (1 + 1e-12)),
    ):
        _, h1, h2 = simulate_switching(QUANTISED, q)
        assert np.array_equal(f1, h1) and np.array_equal(f2, h2)


def test_the_switching_simulation_continued_in_pieces_equals_the_whole():
    x, f1, f2 = simulate_switching(QUANTISED, FLICKERING)
    cut = int(np.flatnonzero(np.r_[False, QUANTISED[1:] == QUANTISED[:-1]])[5])  # a piece starts on a repeated sample
    a = simulate_switching(QUANTISED[:cut], FLICKERING)
    b = simulate_switching(QUANTISED[cut:], FLICKERING, float(a[0][-1]), (QUANTISED[cut - 1], a[1][-1], a[2][-1]))
    for whole, first, second in zip((x, f1, f2), a, b):
        assert np.array_equal(whole, np.r_[first, second])


def test_the_sensitivities_written_into_given_arrays_are_the_returned_ones():
    u = QUANTISED
    x, dx = backlash_sensitivity(u, FLICKERING, 0.3)
    bigger_x, bigger_dx = np.full(u.size + 1, np.nan), np.full((u.size + 1, 4), np.nan)
    got = backlash_sensitivity(u, FLICKERING, 0.3, out=(bigger_x[1:], bigger_dx[1:]))
    assert got[0].base is bigger_x and np.array_equal(bigger_x[1:], x) and np.array_equal(bigger_dx[1:], dx)
    with pytest.raises(InvalidParameterError, match="out must be"):
        backlash_sensitivity(u, FLICKERING, 0.3, out=(bigger_x, bigger_dx))
