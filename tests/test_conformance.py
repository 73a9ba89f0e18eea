"""The conformance suite (:mod:`online_backlash.estimators.conformance`, river's ``check_estimator`` habit) on
every recursive estimator of the package: each check of :data:`~online_backlash.estimators.conformance.CHECKS`
is one test per case.

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

import inspect
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import pytest

from online_backlash import BacklashRLS, CascadeRLS
from online_backlash.diagnostics.effects import Delay, Drift
from online_backlash.estimators import RecursiveEstimator
from online_backlash.estimators.base import SHARED_DEFAULTS, TORQUE_DEFAULTS
from online_backlash.estimators.conformance import CHECKS, Case, check_estimator
from online_backlash.estimators.layout import offsets
from online_backlash.load_aware import TorqueBacklashRLS
from online_backlash.model import BacklashParams, simulate_cascade
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.two_mass_rig import simulate_two_mass


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


@pytest.mark.parametrize("check", CHECKS, ids=[c.__name__.removeprefix("check_") for c in CHECKS])
def test_conformance(case, check):
    check(case)


def test_check_estimator_runs_every_check_on_the_paper_example():
    """:func:`check_estimator` on a factory alone: the paper's example 1 (what a third party points at its class)."""
    check_estimator(lambda: BacklashRLS(warm_start_samples=400, memory_s=0.5))
    with pytest.raises(AssertionError, match="check_a_gap_is_not_read_as_motion"):
        check_estimator(lambda: _GapBlind(warm_start_samples=400, memory_s=0.5))


class _GapBlind(BacklashRLS):
    """Reads a gap as motion: the suite must catch it."""

    def _gap_now(self) -> None:
        pass


# -- the contract's declarations ---------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", [BacklashRLS, CascadeRLS, TorqueBacklashRLS], ids=lambda c: c.__name__)
def test_the_shared_parameters_are_declared_once_and_each_class_lists_them(cls):
    """Each class's signature (what ``get_params``, ``clone`` and ``help`` read) lists its own parameters and the
    shared ones it takes, with the defaults of :data:`~online_backlash.estimators.base.SHARED_DEFAULTS` or of its
    declared departure (:data:`~online_backlash.estimators.base.TORQUE_DEFAULTS`); a fixed one is refused."""
    params = inspect.signature(cls).parameters
    shared = {n: params[n].default for n in SHARED_DEFAULTS if n in params}
    assert shared == {n: cls.shared_defaults[n] for n in SHARED_DEFAULTS if n not in cls.fixed_params}
    assert list(cls().get_params()) == list(params)
    for name in cls.fixed_params:
        with pytest.raises(TypeError, match=name):
            cls(**{name: SHARED_DEFAULTS[name]})
    with pytest.raises(TypeError, match="memory_days"):
        cls(memory_days=3)


def test_torque_departs_from_the_shared_defaults_only_where_declared():
    departures = {n for n in SHARED_DEFAULTS if TORQUE_DEFAULTS[n] != SHARED_DEFAULTS[n]}
    assert departures == {"memory_reversals", "start", "warm_start_samples"}
    assert TorqueBacklashRLS.fixed_params == ("start", "warm_start_samples")
    assert TorqueBacklashRLS().memory_reversals is None and BacklashRLS().memory_reversals == 10.0


def test_a_layout_without_the_fields_the_base_reads_is_refused_when_the_class_is_defined():
    class NoOrigin(NamedTuple):
        N_SEEN: int = 1
        NOISE_VAR: int = 1
        N_REV: int = 1

    layout, _ = offsets(NoOrigin())
    with pytest.raises(TypeError, match="U0, Y0"):
        type("Originless", (RecursiveEstimator,), {"_layout": layout})
