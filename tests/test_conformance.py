"""One conformance suite for every recursive estimator (river's ``check_estimator`` habit).

Each case is a factory of a configured estimator and the data it learns: BacklashRLS alone,
BacklashRLS with effects (a delay, whose columns need a window of past samples, and a drift,
which keeps the first time seen: both must survive a saved state), BacklashRLS fitting its lines where
the flanks are fully engaged on a train with two gaps (issue 27: its judgement of the motion is state
too), CascadeRLS, and TorqueBacklashRLS on a two-mass rig with its torque column (no warm start). Every
estimator on :class:`~online_backlash.estimators.RecursiveEstimator` must pass all of it:

* ``learn_many`` in chunks (edges before, inside and after the warm-up, with gaps) gives the
  estimates of a ``learn_one`` loop with ``after_gap``;
* ``clone()`` is a fresh estimator with the same parameters that learns the same estimates;
* the state saved as JSON, during the warm-up or after the start, continues bit for bit, and
  effects come back by name (no effect objects passed);
* a gap is not read as motion; a still input neither moves the estimate nor winds up the
  covariance; a non-finite sample is refused with InvalidParameterError and changes nothing.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest

from online_backlash import BacklashRLS, CascadeRLS
from online_backlash.diagnostics.effects import Delay, Drift
from online_backlash.errors import InvalidParameterError
from online_backlash.estimators import RecursiveEstimator
from online_backlash.load_aware import TorqueBacklashRLS
from online_backlash.model import BacklashParams, simulate_cascade
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.two_mass_rig import simulate_two_mass


@dataclass(frozen=True)
class Case:
    make: Callable[[], RecursiveEstimator]
    u: np.ndarray
    y: np.ndarray
    time_s: np.ndarray
    warm: int  # warm_start_samples of the estimator made
    still_steps: int  # samples of the still input in the idle check
    torque: np.ndarray | None = None  # N m, for an estimator that takes torque
    start: str = "batch"  # how it starts ("none": no warm start at all)

    def q(self, lo: int, hi: int) -> np.ndarray | None:
        return None if self.torque is None else self.torque[lo:hi]

    def q1(self, i: int) -> float | None:
        return None if self.torque is None else float(self.torque[i])


def _rig_case(make: Callable[[], RecursiveEstimator], warm: int) -> Case:
    rec = simulate_rig(duration_s=16.0, play_deg=0.5, seed=4)
    return Case(make, rec.motor_deg / rec.ratio, rec.load_deg, rec.time_s, warm, 200_000)


def _two_gap_case() -> Case:
    """A train with two gaps whose load an overrunning torque holds across the second one for part of every
    rising stroke (:mod:`online_backlash.simulation.two_mass_rig`): partial crossings the estimator leaves out."""
    rec = simulate_two_mass(
        duration_s=16.0, play_deg=0.4, second_gap_deg=0.15, stiffness_nm_per_arcmin=1.0, viscous_nms_per_rad=0.05,
        external_torque_nm=lambda t: -0.15 * (1.0 - np.sin(np.pi * t)), seed=4,
    )  # fmt: skip
    make = lambda: BacklashRLS(warm_start_samples=3000, memory_s=2.0, full_engagement=True)  # noqa: E731
    return Case(make, rec.motor_deg / rec.ratio, rec.load_deg, rec.time_s, 3000, 200_000)


def _cascade_case() -> Case:
    rng = np.random.default_rng(3)
    u = rng.uniform(-1, 1, 2500)
    y, _ = simulate_cascade(u, BacklashParams(1.3, 0.6, 2.0, 0.7), [0.5], [-0.2, 0.35])
    y = y + rng.normal(0, np.std(y) / 25, y.size)
    make = lambda: CascadeRLS(origin="zero", warm_start_samples=400, memory_s=0.5, memory_reversals=50)  # noqa: E731
    return Case(make, u, y, np.arange(u.size) * 1e-3, 400, 50_000)


def _torque_case() -> Case:
    rec = simulate_two_mass(duration_s=16.0, play_deg=0.4, external_torque_nm=0.2, seed=4)
    make = lambda: TorqueBacklashRLS(memory_s=2.0, memory_reversals=20)  # noqa: E731
    return Case(make, rec.motor_deg / rec.ratio, rec.load_deg, rec.time_s, 3000, 200_000, rec.torque_Nm, "none")


CASES = {
    "BacklashRLS": lambda: _rig_case(lambda: BacklashRLS(warm_start_samples=3000, memory_s=2.0), 3000),
    "BacklashRLS+effects": lambda: _rig_case(
        lambda: BacklashRLS(warm_start_samples=3000, memory_s=2.0, effects=[Delay(lag_step_samples=3), Drift(1, 30.0)]),
        3000,
    ),
    "BacklashRLS+full_engagement": _two_gap_case,
    "CascadeRLS": _cascade_case,
    "TorqueBacklashRLS": _torque_case,
}


@pytest.fixture(scope="module", params=sorted(CASES))
def case(request) -> Case:
    return CASES[request.param]()


def _snapshot(est: RecursiveEstimator) -> np.ndarray:
    extra = est.beta_ if isinstance(est, BacklashRLS) else np.empty(0)
    fitted = [est.backlash_, est.backlash_std_, est.noise_var_, est.n_reversals_, est.n_samples_seen_]
    return np.concatenate((est.theta_, est.P_.ravel(), fitted, extra))


def _learn_many(est: RecursiveEstimator, case: Case, lo: int, hi: int, gap: np.ndarray | None = None) -> None:
    est.learn_many(
        case.u[lo:hi],
        case.y[lo:hi],
        None if gap is None else gap[lo:hi],
        time_s=case.time_s[lo:hi],
        torque_Nm=case.q(lo, hi),
    )


def _edges(n: int, warm: int) -> list[int]:
    """Chunk edges before, at, inside and after the warm-up."""
    cuts = sorted({1, warm // 2, warm - 1, warm, warm + 1, warm + 7, n // 2, n - 3})
    return [0, *cuts, n]


def _state(est: RecursiveEstimator) -> dict:
    return json.loads(json.dumps(est.state_dict(), allow_nan=False))


def test_learn_many_in_chunks_equals_a_learn_one_loop(case):
    n = case.u.size
    gap = np.zeros(n, dtype=bool)
    gap[[case.warm // 3, case.warm + 500, n - 200]] = True
    one = case.make()
    for i in range(n):  # these 1 ms gaps are bridged on both paths (restarts: tests/test_gap_bridging.py)
        one.learn_one(case.u[i], case.y[i], time_s=case.time_s[i], torque_Nm=case.q1(i), after_gap=bool(gap[i]))
    many = case.make()
    edges = _edges(n, case.warm)
    for lo, hi in itertools.pairwise(edges):
        _learn_many(many, case, lo, hi, gap)
    assert one.started and many.started and one.warm_start_.get("method", "none") == case.start
    np.testing.assert_allclose(_snapshot(many), _snapshot(one), rtol=1e-12, atol=1e-15)


def test_snapshots_inside_one_call_equal_cutting_the_block_at_them(case):
    """``learn_many(..., snapshot_at=)`` gives the estimate after each mark (before, at and after the
    warm start, across gaps) that cutting the block there and reading ``estimate_now()`` gives, and
    the same final state (the compiled BacklashRLS records them inside its loop)."""
    n = case.u.size
    gap = np.zeros(n, dtype=bool)
    gap[[case.warm // 3, case.warm + 500, n - 200]] = True
    marks = [
        1,
        case.warm // 2,
        case.warm - 1,
        case.warm,
        case.warm + 1,
        case.warm + 499,
        case.warm + 500,
        n // 2,
        n - 201,
        n - 200,
        n - 1,
        n,
    ]
    cut = case.make()
    want = []
    for lo, hi in itertools.pairwise([0, *marks]):
        _learn_many(cut, case, lo, hi, gap)
        want.append(cut.estimate_now())
    whole = case.make()
    got = whole.learn_many(case.u, case.y, gap, time_s=case.time_s, torque_Nm=case.q(0, n), snapshot_at=np.array(marks))
    assert [a.started for a in want] == [a.started for a in got] and sum(a.started for a in got) >= 4
    assert repr(got) == repr(want)  # bit for bit (NaN before the start compared as text)
    assert _state(whole) == _state(cut)
    more = whole.learn_many(
        case.u[:5], case.y[:5], time_s=case.time_s[:5] + 100.0, torque_Nm=case.q(0, 5), snapshot_at=[]
    )
    assert (
        more == []
        and cut.learn_many(case.u[:5], case.y[:5], time_s=case.time_s[:5] + 100.0, torque_Nm=case.q(0, 5)) is None
    )
    assert _state(whole) == _state(cut)


@pytest.mark.parametrize("marks", [[0], [5, 5], [3, 2], [10**9]], ids=["zero", "repeated", "descending", "beyond"])
def test_snapshot_marks_outside_the_block_are_refused(case, marks):
    est = case.make()
    with pytest.raises(InvalidParameterError, match="snapshot_at"):
        est.learn_many(
            case.u[:100], case.y[:100], time_s=case.time_s[:100], torque_Nm=case.q(0, 100), snapshot_at=marks
        )


def test_clone_is_a_fresh_estimator_with_the_same_parameters(case):
    est = case.make()
    _learn_many(est, case, 0, case.u.size)
    twin = est.clone()
    assert type(twin) is type(est) and not twin.started
    params, twin_params = est.get_params(), twin.get_params()
    effects, twin_effects = params.pop("effects", None) or [], twin_params.pop("effects", None) or []
    assert twin_params == params
    assert [repr(e) for e in twin_effects] == [repr(e) for e in effects]
    assert all(a is not b for a, b in zip(twin_effects, effects))
    _learn_many(twin, case, 0, case.u.size)
    np.testing.assert_array_equal(_snapshot(twin), _snapshot(est))


@pytest.mark.parametrize("where", ["warm-up", "after-start"])
def test_a_json_saved_state_continues_bit_for_bit(case, where):
    n = case.u.size
    split = case.warm // 2 if where == "warm-up" else case.u.size - 1234
    whole = case.make()
    _learn_many(whole, case, 0, n)
    part = case.make()
    _learn_many(part, case, 0, split)
    resumed = type(part).from_state(_state(part))  # effects (if any) come back by name
    assert resumed.started == (where == "after-start" or case.start == "none")  # no warm start: started at once
    _learn_many(resumed, case, split, n)
    np.testing.assert_array_equal(_snapshot(resumed), _snapshot(whole))
    assert _state(resumed) == _state(whole)


def test_a_saved_state_is_refused_by_another_estimator(case):
    est = case.make()
    other = CascadeRLS if isinstance(est, BacklashRLS) else BacklashRLS
    with pytest.raises(InvalidParameterError, match=type(est).__name__):
        other.from_state(_state(est))


def test_a_gap_is_not_read_as_motion(case):
    k = case.u.size - 2000  # started
    est = case.make()
    _learn_many(est, case, 0, k)
    far_u, far_y = case.u[k - 1] + 50.0, case.y[k - 1] + 50.3  # a jump that no flank explains
    blind = type(est).from_state(_state(est))
    blind.learn_one(far_u, far_y, time_s=case.time_s[k], torque_Nm=case.q1(k))
    assert not np.array_equal(blind.theta_, est.theta_)  # read as motion, the jump is learned
    before = est.theta_
    flagged = type(est).from_state(_state(est))
    flagged.learn_many(
        np.array([far_u]),
        np.array([far_y]),
        np.array([True]),
        time_s=case.time_s[k : k + 1],
        torque_Nm=case.q(k, k + 1),
    )
    est.mark_gap()
    est.learn_one(far_u, far_y, time_s=case.time_s[k], torque_Nm=case.q1(k))
    np.testing.assert_array_equal(est.theta_, before)
    np.testing.assert_array_equal(flagged.theta_, before)
    assert est.n_samples_seen_ == flagged.n_samples_seen_ == k + 1


def test_a_still_input_neither_moves_the_estimate_nor_winds_up(case):
    est = case.make()
    _learn_many(est, case, 0, case.u.size)

    def still(m: int) -> None:
        t = est.n_samples_seen_ * 1e-3 + np.arange(m) * 1e-3
        q = None if case.torque is None else np.full(m, case.torque[-1])
        est.learn_many(np.full(m, case.u[-1]), np.full(m, case.y[-1]), time_s=t, torque_Nm=q)

    still(100)  # longer than any estimator's memory of the motion (the cascade's n_a + n_b + 1 samples)
    theta, trace = est.theta_, float(np.trace(est.P_))
    still(case.still_steps)  # minutes: with forgetting per update on it, P would grow by e^100
    np.testing.assert_array_equal(est.theta_, theta)
    assert np.all(np.isfinite(est.P_)) and float(np.trace(est.P_)) <= 1.01 * trace


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_input_is_refused_and_changes_nothing(case, bad):
    est = case.make()
    _learn_many(est, case, 0, case.warm + 100)
    saved = _state(est)
    for u, y in ((bad, 0.0), (0.0, bad)):
        with pytest.raises(InvalidParameterError, match="finite"):
            est.learn_one(u, y)
    u, y = case.u[:50].copy(), case.y[:50].copy()
    y[17] = bad
    with pytest.raises(InvalidParameterError, match="index 17"):
        est.learn_many(u, y, time_s=case.time_s[:50])
    assert _state(est) == saved
