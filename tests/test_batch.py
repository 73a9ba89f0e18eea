"""The paper's batch estimators: settings, errors, offsets, signs, the stopping rule, predict."""

from __future__ import annotations

import numpy as np
import pytest
from davinci_runs import DAVINCI, READ

from online_backlash import VorosBacklash, VorosCascade
from online_backlash.errors import ConvergenceWarning, InvalidParameterError, NotExcitedError, NotFittedError
from online_backlash.model import PAPER_EXAMPLES, BacklashParams, simulate_backlash, simulate_cascade
from online_backlash.replay import read_csv_arrays
from online_backlash.simulation.rig import simulate_rig
from online_backlash.stream import refer_to_load

ESTIMATORS = [VorosBacklash, VorosCascade]


def _params(est) -> np.ndarray:
    return np.array([est.m_left_, est.c_left_, est.m_right_, est.c_right_])


@pytest.fixture(scope="module")
def rig():
    """12 s of a 30:1 rig with 0.5 deg play, quantised encoders and arbitrary encoder zeros."""
    return simulate_rig(duration_s=12.0, ratio=30.0, play_deg=0.5, seed=4)


@pytest.mark.parametrize("cls", ESTIMATORS)
@pytest.mark.parametrize(
    "setting",
    [
        {"max_iter": 0},
        {"max_iter": 2.5},
        {"max_iter": True},
        {"tol": 0.0},
        {"tol": -1.0},
        {"tol": float("nan")},
        {"tol": "small"},
        {"refine": "yes"},
        {"origin": "middle"},
    ],
)
def test_invalid_settings_raise_at_fit(cls, setting):
    u, y = PAPER_EXAMPLES[1].generate(0)
    est = cls(**setting)  # __init__ only stores
    with pytest.raises(InvalidParameterError):
        est.fit(u, y)


@pytest.mark.parametrize("setting", [{"n_a": 0}, {"n_b": -1}, {"n_a": 1.0}])
def test_invalid_orders_of_the_linear_block(setting):
    u, y = PAPER_EXAMPLES[3].generate(0)
    with pytest.raises(InvalidParameterError):
        VorosCascade(**setting).fit(u, y)


@pytest.mark.parametrize("cls", ESTIMATORS)
def test_invalid_data(cls):
    u, y = PAPER_EXAMPLES[1].generate(0)
    with pytest.raises(InvalidParameterError, match="equal length"):
        cls().fit(u, y[:-1])
    with pytest.raises(InvalidParameterError, match="1-D"):
        cls().fit(u.reshape(-1, 2), y.reshape(-1, 2))
    with pytest.raises(InvalidParameterError, match="at least"):
        cls().fit(u[:3], y[:3])
    bad = y.copy()
    bad[17] = np.nan
    with pytest.raises(InvalidParameterError, match="index 17"):
        cls().fit(u, bad)


@pytest.mark.parametrize("cls", ESTIMATORS)
def test_no_reversal_is_not_excited(cls):
    u = np.linspace(0.0, 10.0, 500)
    with pytest.raises(NotExcitedError, match="never reverses"):
        cls().fit(u, u - 0.2)


def test_one_flank_never_engaged_is_not_excited():
    # the input wiggles inside the band after one ramp: the left flank is never touched
    u = np.concatenate((np.linspace(0, 1, 50), 1 - 0.01 * np.abs(np.sin(np.arange(200)))))
    x = simulate_backlash(u, BacklashParams(1.0, 0.5, 1.0, 0.5))
    with pytest.raises(NotExcitedError, match="both sides"):
        VorosBacklash().fit(u, x)


@pytest.mark.parametrize("slope", [0.9, 0.97, 1.0, 1.03])
def test_rig_slope_off_one_starts_from_the_direction_of_motion(slope):
    # a 280 deg stroke at slope 0.97 ends 8 deg below the paper's start line (slopes +-1):
    # from there every sample lies on the right flank and the left is empty
    rec = simulate_rig(duration_s=10.0, slope=slope, play_deg=0.5, seed=0)
    u = refer_to_load(rec.motor_deg, rec.ratio)
    est = VorosBacklash(origin="first").fit(u, rec.load_deg)
    assert est.start_ == ("paper" if slope == 1.0 else "direction")
    assert est.backlash_ == pytest.approx(0.5, rel=0.02)
    assert est.m_left_ == pytest.approx(slope, rel=1e-3) and est.m_right_ == pytest.approx(slope, rel=1e-3)


def test_paper_examples_keep_the_paper_start():
    for number in (1, 2):
        u, x = PAPER_EXAMPLES[number].generate(seed=0)
        assert VorosBacklash(origin="zero").fit(u, x).start_ == "paper"


def test_stretch_moving_one_way_is_not_excited():
    # the last 4977 samples of a measured gearhead run: one reversal, but the input falls on
    # only 7 samples (never with the load), so no start engages the left flank
    chunk = read_csv_arrays(DAVINCI / "tool4_L_run00_0.1Hz_torque10pct.csv", **READ)
    u, y = chunk.motor_deg[-4977:] / -35.0, chunk.load_deg[-4977:]
    with pytest.raises(NotExcitedError, match="1366 samples with the input rising and 0 with it falling"):
        VorosBacklash(origin="first").fit(u, y)


def test_thousand_degree_offsets_change_no_estimate(rig):
    u = refer_to_load(rig.motor_deg, rig.ratio)
    y = rig.load_deg
    base = VorosBacklash(origin="first").fit(u, y)
    assert base.backlash_ == pytest.approx(0.5, rel=0.02)
    for du, dy in ((1000.0, 0.0), (0.0, 1000.0), (-1000.0, 1000.0)):
        moved = VorosBacklash(origin="first").fit(u + du, y + dy)
        assert np.allclose(_params(moved), _params(base), rtol=0, atol=1e-9)
        assert moved.n_iter_ == base.n_iter_
        assert moved.u_ref_ == pytest.approx(base.u_ref_ + du) and moved.y_ref_ == pytest.approx(base.y_ref_ + dy)


def test_cascade_offsets_change_no_estimate():
    ex = PAPER_EXAMPLES[3]
    u, y = ex.generate(1)
    base = VorosCascade(origin="first").fit(u, y)
    moved = VorosCascade(origin="first").fit(u + 1000.0, y - 1000.0)
    assert np.allclose(_params(moved), _params(base), atol=1e-9)
    assert np.allclose(moved.b_, base.b_, atol=1e-9)


def test_negative_ratio_and_negative_slopes():
    rec = simulate_rig(duration_s=12.0, ratio=-30.0, play_deg=0.5, seed=5)
    est = VorosBacklash(origin="first").fit(refer_to_load(rec.motor_deg, -30.0), rec.load_deg)
    assert est.m_left_ == pytest.approx(1.0, rel=0.01) and est.backlash_ == pytest.approx(0.5, rel=0.02)
    # the load turning the other way (both slopes negative, eq. 1): same play, slopes -1
    flipped = VorosBacklash(origin="first").fit(refer_to_load(rec.motor_deg, -30.0), -rec.load_deg)
    assert flipped.m_left_ == pytest.approx(-1.0, rel=0.01) and flipped.m_right_ == pytest.approx(-1.0, rel=0.01)
    assert flipped.backlash_ == pytest.approx(0.5, rel=0.02)


@pytest.mark.parametrize("number", [1, 5])
def test_noise_free_data_give_the_true_parameters(number):
    ex = PAPER_EXAMPLES[number]
    p = ex.params
    truth = [p.m_left, p.c_left, p.m_right, p.c_right]
    u = np.random.default_rng(2).uniform(-1, 1, ex.samples)
    if ex.cascade:
        y = simulate_cascade(u, ex.params, np.array(ex.a), np.array(ex.b))[0]
        est = VorosCascade(origin="zero").fit(u, y)
        assert np.allclose(est.a_, [1.0, *ex.a]) and np.allclose(est.b_, ex.b)
        # the paper's iteration alone, on the estimated x of eq. (23), may settle one switch off
        eq = est.equation_error_params_
        assert np.allclose([eq.m_left, eq.c_left, eq.m_right, eq.c_right], truth, rtol=1e-4)
    else:
        y = simulate_backlash(u, ex.params)
        est = VorosBacklash(origin="zero", refine=False).fit(u, y)
    assert np.allclose(_params(est), truth, rtol=1e-9)
    assert est.converged_ and est.residual_rms_ < 1e-9


def test_max_iter_reached_warns():
    u, y = PAPER_EXAMPLES[1].generate(0)
    with pytest.warns(ConvergenceWarning, match="max_iter=2"):
        est = VorosBacklash(max_iter=2, origin="zero", refine=False).fit(u, y)
    assert est.n_iter_ == 2 and not est.converged_ and est.stop_reason_ == "max_iter"


@pytest.mark.parametrize("number", [2, 4])
def test_the_stop_is_as_good_as_iterating_on(number):
    """The stopping rule (``tol`` standard errors) stops no earlier than it should: iterating on
    until an estimate repeats exactly gives the same accuracy, parameter by parameter."""
    ex = PAPER_EXAMPLES[number]
    cls = VorosCascade if ex.cascade else VorosBacklash
    truth = ex.parameters()
    at_stop, iterated = [], []
    for seed in range(10):
        u, y = ex.generate(seed)
        stop = cls(origin="zero", refine=False).fit(u, y)
        on = cls(origin="zero", refine=False, tol=1e-12, max_iter=200).fit(u, y)
        assert on.n_iter_ >= stop.n_iter_ and on.converged_
        at_stop.append([abs(stop.estimates()[k] / v - 1) for k, v in truth.items()])
        iterated.append([abs(on.estimates()[k] / v - 1) for k, v in truth.items()])
    gap = np.abs(np.median(at_stop, axis=0) - np.median(iterated, axis=0))
    assert np.all(gap < 0.0025), dict(zip(truth, gap))


def test_history_and_stages():
    u, y = PAPER_EXAMPLES[3].generate(0)
    est = VorosCascade(origin="zero").fit(u, y)
    assert len(est.history_) == est.n_iter_
    assert est.history_[-1].backlash == est.equation_error_params_
    assert est.a_[0] == 1.0 and est.a_.shape == (2,) and est.b_.shape == (2,)
    plain = VorosCascade(origin="zero", refine=False).fit(u, y)
    assert plain.equation_error_params_ == est.equation_error_params_
    assert np.allclose(_params(plain), plain.equation_error_params_.theta / [1, plain.m_left_, 1, plain.m_right_])
    # the refinement minimises the simulation error, so it can only lower it
    assert est.residual_rms_ <= plain.residual_rms_


@pytest.mark.parametrize("cls", ESTIMATORS)
def test_not_fitted(cls):
    est = cls()
    with pytest.raises(NotFittedError):
        est.predict(np.zeros(10))
    with pytest.raises(NotFittedError):
        _ = est.backlash_
    assert not hasattr(est, "backlash_")  # NotFittedError is an AttributeError


def test_backlash_predict_reproduces_the_data():
    p = BacklashParams(1.0, 0.2, 1.0, 0.3)
    u = 5.0 + np.sin(np.linspace(0, 20, 800))
    x = simulate_backlash(u, p, x0=4.8) + 100.0
    est = VorosBacklash(origin="first").fit(u, x)
    assert est.backlash_ == pytest.approx(0.5, rel=1e-6)
    assert np.allclose(est.predict(u[1:], x0=x[0]), x[1:], atol=1e-9)


def test_cascade_predict_reproduces_the_data():
    ex = PAPER_EXAMPLES[5]
    u = np.random.default_rng(9).uniform(-1, 1, 600)
    y = simulate_cascade(u, ex.params, np.array(ex.a), np.array(ex.b))[0]
    est = VorosCascade(origin="zero").fit(u, y)
    assert np.allclose(est.predict(u), y, atol=1e-9)


@pytest.mark.parametrize("number", sorted(PAPER_EXAMPLES))
def test_default_estimators_fit_the_papers_examples_as_given(number):
    """The library fits data as given (``origin="zero"`` by default): default-constructed
    estimators return the paper's parameters on the paper's data (the 3 % median bar over 20 seeds of
    ``tests/test_paper_examples.py``; referring to the first sample moved c by 50-900 %)."""
    ex = PAPER_EXAMPLES[number]
    cls = VorosCascade if ex.cascade else VorosBacklash
    truth = ex.parameters()
    errors = np.array(
        [[abs(cls().fit(*ex.generate(seed)).estimates()[k] / v - 1) for k, v in truth.items()] for seed in range(20)]
    )
    medians = dict(zip(truth, np.median(errors, axis=0)))
    assert all(m < 0.03 for m in medians.values()), medians


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_compiled_eq14_step_is_the_least_squares_of_eq14(seed):
    """``_equation_error_step`` (two compiled passes, no regressor formed) against eq. (8)-(14) written
    out with numpy: the regressor of the engaged samples and its least squares."""
    from online_backlash.estimators.batch import _equation_error_step, _solve
    from online_backlash.model import switching_functions

    rng = np.random.default_rng(seed)
    u = np.round(np.cumsum(rng.normal(0.0, 0.3, 3000)) / 0.01) * 0.01  # quantised: repeated samples too
    x = simulate_backlash(u, BacklashParams(1.1, 0.4, 0.9, 0.3)) + rng.normal(0.0, 0.01, u.size)
    p = BacklashParams(*rng.uniform([0.8, 0.2, 0.8, 0.2], [1.2, 0.6, 1.2, 0.6]))
    u_t, x_t, x_prev = u[1:], x[1:], x[:-1]
    f1, f2 = switching_functions(u_t, x_prev, p)  # eq. (12)-(13)
    active = (f1 + f2) > 0
    phi = np.column_stack((u_t * f1, f1, u_t * f2, -f2))[active]  # eq. (8)
    target = (x_t - x_prev * (1 - f1) * (1 - f2))[active]  # eq. (11)
    expected = _solve(phi, target)
    step = _equation_error_step(u_t, x_prev, x_t, p)
    np.testing.assert_allclose(step.theta, expected.theta, rtol=1e-9)
    np.testing.assert_allclose(step.se, expected.se, rtol=1e-7)


def test_the_compiled_eq14_step_refuses_a_record_that_engages_one_flank():
    from online_backlash.estimators.batch import _equation_error_step

    u = np.linspace(0.0, 10.0, 200)  # only ever pushed up: the right flank
    x = simulate_backlash(u, BacklashParams(1.0, 0.2, 1.0, 0.2))
    with pytest.raises(NotExcitedError, match="engage the left flank"):
        _equation_error_step(u[1:], x[:-1], x[1:], BacklashParams(1.0, 0.2, 1.0, 0.2))
