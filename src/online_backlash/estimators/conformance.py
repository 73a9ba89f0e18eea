"""The conformance suite of the recursive estimators: the definition of done for a new one (river's
``check_estimator`` habit).

Point :func:`check_estimator` at a factory of your configured estimator (a class on
:class:`~.base.RecursiveEstimator`, ``docs/estimators.md``); it raises AssertionError naming the first
check that fails. The checks, each a function of a :class:`Case` (:data:`CHECKS`, one pytest parameter
each in ``tests/test_conformance.py``):

* ``learn_many`` in chunks (edges before, inside and after the warm-up, with gaps) gives the
  estimates of a ``learn_one`` loop with ``after_gap``;
* ``learn_many(..., snapshot_at=)`` gives the estimates of cutting the block at the marks, and refuses
  marks outside the block;
* ``clone()`` is a fresh estimator with the same parameters that learns the same estimates;
* the state saved as JSON, during the warm-up or after the start, continues bit for bit (effects come
  back by name), and another estimator refuses it;
* a gap is not read as motion; a still input neither moves the estimate nor winds up the
  covariance; a non-finite sample is refused with InvalidParameterError and changes nothing.

The data: a :class:`Case`, by default :func:`paper_case` (the paper's example 1: eq. 1-3 driven by a
uniformly distributed input, J. Vörös, Automatica 46 (2010) 369-374, section 5, with output noise);
the tests add the simulated rigs, effects and the torque (``tests/test_conformance.py``).
"""

from __future__ import annotations

import itertools
import json
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..model import BacklashParams, simulate_backlash
from .backlash_rls import BacklashRLS
from .base import RecursiveEstimator
from .cascade_rls import CascadeRLS

__all__ = ["CHECKS", "Case", "check_estimator", "paper_case"]


@dataclass(frozen=True)
class Case:
    """An estimator factory and the data it learns.

    Attributes
    ----------
    make : callable
        A new configured estimator (the same each call).
    u, y : array
        Input and output, degrees (``u`` referred to the load side); at least ``warm + 2500`` samples.
    time_s : array
        The samples' times, seconds.
    warm : int
        The estimator's ``warm_start_samples`` (where the warm-up's edges lie).
    still_steps : int
        Samples of the still input in the idle check (longer than the estimator's memory).
    torque : array or None
        Torque, N m, for an estimator that takes torque.
    start : str
        How the estimator starts (its ``warm_start_["method"]``; ``"none"``: no warm start at all).
    """

    make: Callable[[], RecursiveEstimator]
    u: np.ndarray
    y: np.ndarray
    time_s: np.ndarray
    warm: int
    still_steps: int
    torque: np.ndarray | None = None
    start: str = "batch"

    def q(self, lo: int, hi: int) -> np.ndarray | None:
        return None if self.torque is None else self.torque[lo:hi]

    def q1(self, i: int) -> float | None:
        return None if self.torque is None else float(self.torque[i])


def paper_case(make: Callable[[], RecursiveEstimator], warm: int, samples: int = 4000, seed: int = 3) -> Case:
    """The paper's example 1 (``mL = 1.3, cL = 0.5, mR = 2.5, cR = 0.7``, eq. 1-3) driven by ``samples`` of
    a uniformly distributed input ``|u| < 1``, with Gaussian output noise (SNR 25), 1 ms apart; ``make`` an
    estimator whose ``warm_start_samples`` is ``warm``."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1.0, 1.0, samples)
    x = simulate_backlash(u, BacklashParams(1.3, 0.5, 2.5, 0.7))
    y = x + rng.normal(0.0, np.std(x) / 25.0, samples)
    return Case(make, u, y, np.arange(samples) * 1e-3, warm, 50_000)


def snapshot(est: RecursiveEstimator) -> np.ndarray:
    """What the checks compare: ``theta_``, ``P_``, the play and its standard error, the noise variance,
    the reversals and samples seen, and the effect coefficients ``beta_`` where the estimator has them."""
    extra = np.asarray(getattr(est, "beta_", np.empty(0)), dtype=float)
    fitted = [est.backlash_, est.backlash_std_, est.noise_var_, est.n_reversals_, est.n_samples_seen_]
    return np.concatenate((est.theta_, est.P_.ravel(), fitted, extra))


def _learn_many(est: RecursiveEstimator, case: Case, lo: int, hi: int, gap: np.ndarray | None = None) -> None:
    est.learn_many(
        case.u[lo:hi], case.y[lo:hi], None if gap is None else gap[lo:hi], time_s=case.time_s[lo:hi],
        torque_Nm=case.q(lo, hi),
    )  # fmt: skip


def _edges(n: int, warm: int) -> list[int]:
    """Chunk edges before, at, inside and after the warm-up."""
    cuts = sorted({1, warm // 2, warm - 1, warm, warm + 1, warm + 7, n // 2, n - 3})
    return [0, *cuts, n]


def _gaps(case: Case) -> np.ndarray:
    """Three 1 ms gaps (bridged on both paths): in the warm-up, after the start, near the end."""
    n = case.u.size
    gap = np.zeros(n, dtype=bool)
    gap[[case.warm // 3, case.warm + 500, n - 200]] = True
    return gap


def _state(est: RecursiveEstimator) -> dict[str, Any]:
    return json.loads(json.dumps(est.state_dict(), allow_nan=False))


def _raises(exc: type[Exception], match: str, call: Callable[..., object], *args: Any, **kwargs: Any) -> None:
    """``call(*args, **kwargs)`` raises ``exc`` with ``match`` (a regular expression) in its message, else
    AssertionError."""
    try:
        call(*args, **kwargs)
    except exc as err:
        assert re.search(match, str(err)), f"{exc.__name__} without {match!r}: {err}"
        return
    raise AssertionError(f"{exc.__name__} not raised")


def check_learn_many_in_chunks_equals_a_learn_one_loop(case: Case) -> None:
    n = case.u.size
    gap = _gaps(case)
    one = case.make()
    for i in range(n):
        one.learn_one(case.u[i], case.y[i], time_s=case.time_s[i], torque_Nm=case.q1(i), after_gap=bool(gap[i]))
    many = case.make()
    for lo, hi in itertools.pairwise(_edges(n, case.warm)):
        _learn_many(many, case, lo, hi, gap)
    assert one.started and many.started, "not started after all the samples"
    assert one.warm_start_.get("method", "none") == case.start, f"started by {one.warm_start_}, not {case.start}"
    np.testing.assert_allclose(snapshot(many), snapshot(one), rtol=1e-12, atol=1e-15)


def check_snapshots_inside_one_call_equal_cutting_the_block_at_them(case: Case) -> None:
    """``learn_many(..., snapshot_at=)`` gives the estimate after each mark (before, at and after the
    warm start, across gaps) that cutting the block there and reading ``estimate_now()`` gives, and
    the same final state."""
    n, w = case.u.size, case.warm
    gap = _gaps(case)
    marks = [1, w // 2, w - 1, w, w + 1, w + 499, w + 500, n // 2, n - 201, n - 200, n - 1, n]
    cut = case.make()
    want = []
    for lo, hi in itertools.pairwise([0, *marks]):
        _learn_many(cut, case, lo, hi, gap)
        want.append(cut.estimate_now())
    whole = case.make()
    got = whole.learn_many(case.u, case.y, gap, time_s=case.time_s, torque_Nm=case.q(0, n), snapshot_at=np.array(marks))
    assert got is not None and [a.started for a in want] == [a.started for a in got], "started at other marks"
    assert sum(a.started for a in got) >= 4, "started at fewer than 4 marks"
    assert repr(got) == repr(want), "snapshots differ from cutting the block"  # bit for bit (NaN as text)
    assert _state(whole) == _state(cut), "state differs from cutting the block"
    t_more = case.time_s[:5] + 100.0
    more = whole.learn_many(case.u[:5], case.y[:5], time_s=t_more, torque_Nm=case.q(0, 5), snapshot_at=np.empty(0))
    assert more == [], "no marks: not an empty list"
    assert cut.learn_many(case.u[:5], case.y[:5], time_s=t_more, torque_Nm=case.q(0, 5)) is None, (
        "no snapshot_at: a list"
    )
    assert _state(whole) == _state(cut), "state differs after a block without marks"


def check_snapshot_marks_outside_the_block_are_refused(case: Case) -> None:
    for marks in ([0], [5, 5], [3, 2], [10**9]):  # zero, repeated, descending, beyond
        est = case.make()
        _raises(
            InvalidParameterError, "snapshot_at", est.learn_many, case.u[:100], case.y[:100],
            time_s=case.time_s[:100], torque_Nm=case.q(0, 100), snapshot_at=np.array(marks),
        )  # fmt: skip


def check_clone_is_a_fresh_estimator_with_the_same_parameters(case: Case) -> None:
    est = case.make()
    _learn_many(est, case, 0, case.u.size)
    twin = est.clone()
    assert type(twin) is type(est) and not twin.started, "a clone is not a fresh estimator of the class"
    params, twin_params = est.get_params(), twin.get_params()
    effects, twin_effects = params.pop("effects", None) or [], twin_params.pop("effects", None) or []
    assert twin_params == params, f"clone's parameters {twin_params} != {params}"
    assert [repr(e) for e in twin_effects] == [repr(e) for e in effects], "clone's effects differ"
    assert all(a is not b for a, b in zip(twin_effects, effects)), "clone shares effect objects"
    _learn_many(twin, case, 0, case.u.size)
    np.testing.assert_array_equal(snapshot(twin), snapshot(est))


def check_a_json_saved_state_continues_bit_for_bit(case: Case) -> None:
    n = case.u.size
    whole = case.make()
    _learn_many(whole, case, 0, n)
    for where, split in (("warm-up", case.warm // 2), ("after-start", n - 1234)):
        part = case.make()
        _learn_many(part, case, 0, split)
        resumed = type(part).from_state(_state(part))  # effects (if any) come back by name
        started = where == "after-start" or case.start == "none"  # no warm start: started at once
        assert resumed.started == started, f"resumed {where}: started is {resumed.started}"
        _learn_many(resumed, case, split, n)
        np.testing.assert_array_equal(snapshot(resumed), snapshot(whole))
        assert _state(resumed) == _state(whole), f"resumed {where}: another state"


def check_a_saved_state_is_refused_by_another_estimator(case: Case) -> None:
    est = case.make()
    other = CascadeRLS if isinstance(est, BacklashRLS) else BacklashRLS
    _raises(InvalidParameterError, type(est).__name__, other.from_state, _state(est))


def check_a_gap_is_not_read_as_motion(case: Case) -> None:
    k = case.u.size - 2000  # started
    est = case.make()
    _learn_many(est, case, 0, k)
    far_u, far_y = case.u[k - 1] + 50.0, case.y[k - 1] + 50.3  # a jump that no flank explains
    blind = type(est).from_state(_state(est))
    blind.learn_one(far_u, far_y, time_s=case.time_s[k], torque_Nm=case.q1(k))
    assert not np.array_equal(blind.theta_, est.theta_), "a jump read as motion is not learned"
    before = est.theta_
    flagged = type(est).from_state(_state(est))
    flagged.learn_many(
        np.array([far_u]), np.array([far_y]), np.array([True]), time_s=case.time_s[k : k + 1],
        torque_Nm=case.q(k, k + 1),
    )  # fmt: skip
    est.mark_gap()
    est.learn_one(far_u, far_y, time_s=case.time_s[k], torque_Nm=case.q1(k))
    np.testing.assert_array_equal(est.theta_, before)
    np.testing.assert_array_equal(flagged.theta_, before)
    assert est.n_samples_seen_ == flagged.n_samples_seen_ == k + 1, "the sample after a gap is not counted"


def check_a_still_input_neither_moves_the_estimate_nor_winds_up(case: Case) -> None:
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
    assert np.all(np.isfinite(est.P_)) and float(np.trace(est.P_)) <= 1.01 * trace, "the covariance winds up"


def check_non_finite_input_is_refused_and_changes_nothing(case: Case) -> None:
    for bad in (math.nan, math.inf, -math.inf):
        est = case.make()
        _learn_many(est, case, 0, case.warm + 100)
        saved = _state(est)
        for u, y in ((bad, 0.0), (0.0, bad)):
            _raises(InvalidParameterError, "finite", est.learn_one, u, y)
        u_many, y_many = case.u[:50].copy(), case.y[:50].copy()
        y_many[17] = bad
        _raises(InvalidParameterError, "index 17", est.learn_many, u_many, y_many, time_s=case.time_s[:50])
        assert _state(est) == saved, f"a refused {bad} changed the state"


#: Every check, in order (each takes a :class:`Case` and raises AssertionError where the estimator fails it)
CHECKS: tuple[Callable[[Case], None], ...] = (
    check_learn_many_in_chunks_equals_a_learn_one_loop,
    check_snapshots_inside_one_call_equal_cutting_the_block_at_them,
    check_snapshot_marks_outside_the_block_are_refused,
    check_clone_is_a_fresh_estimator_with_the_same_parameters,
    check_a_json_saved_state_continues_bit_for_bit,
    check_a_saved_state_is_refused_by_another_estimator,
    check_a_gap_is_not_read_as_motion,
    check_a_still_input_neither_moves_the_estimate_nor_winds_up,
    check_non_finite_input_is_refused_and_changes_nothing,
)


def check_estimator(make: Callable[[], RecursiveEstimator] | Case, warm: int | None = None) -> None:
    """Run every check of :data:`CHECKS` on an estimator: ``make`` a factory of it (learning
    :func:`paper_case`; ``warm`` its ``warm_start_samples``, read from the estimator by default), or a
    :class:`Case` of your own data. Raises AssertionError naming the check that failed.

    Examples
    --------
    >>> from online_backlash.estimators import BacklashRLS
    >>> check_estimator(lambda: BacklashRLS(warm_start_samples=400, memory_s=0.5))
    """
    case = make if isinstance(make, Case) else paper_case(make, make().warm_start_samples if warm is None else warm)
    for check in CHECKS:
        try:
            check(case)
        except AssertionError as err:
            raise AssertionError(f"{check.__name__}: {err}") from err
