"""The public contract of a recursive (online) estimator, river style: ``learn_one`` / ``learn_many``.

:class:`RecursiveEstimator` holds what every recursive estimator shares: the parameters
(:class:`SharedParams`, their defaults in :data:`SHARED_DEFAULTS`: declared here once), the warm-up buffer,
the dispatch of ``learn_one`` (interpreted) and ``learn_many`` (compiled where the estimator has a compiled
loop), gaps (which are bridged and which restart: ``gap_policy``, :class:`~online_backlash.gap_policy.GapPolicy`;
the tally ``gaps_``), ``snapshot_at``, the saved state, ``clone`` and the fitted figures derived from the
paper's parameter vector. All state is created in :meth:`RecursiveEstimator.reset` (called by ``__init__``);
the parameters are validated on the first ``learn_one`` / ``learn_many`` (scikit-learn style).

**What a new estimator writes** (:class:`~.regressor_rls.RegressorRLS` writes them once for a recursive least
squares on a regressor of its own, ``docs/estimators.md``; the definition of done is
:func:`online_backlash.estimators.conformance.check_estimator`):

* ``_layout``: its state vector's fields (a :mod:`.layout` of offsets), with at least ``N_SEEN`` (samples
  learned), ``U0``, ``Y0`` (the reference origin), ``NOISE_VAR`` (the residual variance) and ``N_REV``
  (reversals seen), which the base reads;
* :meth:`~RecursiveEstimator._initial_state`: the state vector from start values (those of
  :meth:`~RecursiveEstimator._warm_fit` or :meth:`~RecursiveEstimator._cold_params`);
* :meth:`~RecursiveEstimator._learn_py`: one sample (reading the constants ``self._c``, :data:`SHARED_CONSTS`
  by default, and holding its parameters while ``FREEZE`` is set: the warm start's replay);
* :meth:`~RecursiveEstimator._gap_now`: the next sample is not read as motion from the last one;
* ``theta_`` (eq. 8's ``[mL, mL cL, mR, mR cR]``, then any parameters of its own) and ``P_``, its unscaled
  covariance.

Everything else is derived or defaulted and may be overridden: its own parameters' checks
(``_validate``), the warm start (:class:`~.batch.VorosBacklash` on the buffer) and the cold start (the
direction of motion), the constants (:data:`SHARED_CONSTS`), the compiled loop (``_learn_arrays``: by
default a loop of ``_learn_py``), state beside the vector (``_reset_own``, ``_extra_state``,
``_restore_extra``), ``c_left_``, ``c_right_`` and ``backlash_`` (eq. 9), ``backlash_std_`` (the delta
method on ``P_``) and ``predict_one`` (eq. 1-3).

Start: the paper's batch algorithm fitted on the first stretch of data that reverses (a *warm
start*), or a saved state (:meth:`~RecursiveEstimator.state_dict` /
:meth:`~RecursiveEstimator.from_state`). Samples buffered during the warm-up are then replayed
with the parameters held at the batch estimate, which gathers their information (covariance,
residual variance, reversals): none is lost or counted twice, and a few slow, coarsely quantised
first samples cannot override the fit of the whole buffer.

References: J. Vörös, Automatica 46 (2010) 369-374 (eq. 1-14); the recursive form: J. Vörös, ASME J. Dyn.
Sys. Meas. Control 135(1) 014504 (2013).

Units: ``u`` and ``y`` share one unit (degrees, load side, in this package); times in seconds;
torque in N m.
"""

from __future__ import annotations

import copy
import inspect
import itertools
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, ClassVar, Generic, NamedTuple, TypedDict, TypeVar

import numpy as np

from ..effect_terms import EffectTerms
from ..errors import InvalidParameterError, NotExcitedError, NotFittedError
from ..gap_policy import UNKNOWN, GapPolicy, GapTally
from ..model import BacklashParams
from ._effect_stream import EffectStream, check_effects, effects_from_records
from .batch import VorosBacklash, _direction_guess, _start_params
from .layout import offsets, pack
from .snapshots import NOT_STARTED, EstimateAt
from .validation import check_int, check_magnitude, check_option, check_real, finite, finite_array

if TYPE_CHECKING:
    from typing_extensions import Unpack

__all__ = [
    "NOT_STARTED",
    "SHARED_CONSTS",
    "SHARED_DEFAULTS",
    "TORQUE_DEFAULTS",
    "EstimateAt",
    "RecursiveEstimator",
    "SharedParams",
    "StateField",
    "WarmStartParams",
    "finite",
    "finite_array",
    "memory_factors",
]

_STARTS = ("batch", "cold")
_ORIGINS = ("first", "zero")
_WARM_ATTEMPTS = 4  # batch attempts (at 1x..4x warm_start_samples) before a cold start
#: The state fields the base reads (``_layout`` must have them)
_BASE_FIELDS = ("N_SEEN", "U0", "Y0", "NOISE_VAR", "N_REV")


#: 3: effects saved by name and parameters, with the samples that restore their history
#: (2, still read: effects by name only; 2 added the model's output X_HAT to the BacklashRLS state)
STATE_FORMAT = 3
_READ_FORMATS = (2, 3)
_BUFFER_KEYS = ("u", "y", "gap", "time", "torque")
_DEFAULT_GAP_POLICY = GapPolicy()

T = TypeVar("T")


# -- the shared parameters: declared once ---------------------------------------------------------
class SharedParams(TypedDict, total=False):
    """The keyword parameters every recursive estimator takes (``**shared``; defaults :data:`SHARED_DEFAULTS`).

    ``memory_s`` (s of motion; None: no forgetting per update), ``memory_reversals`` (reversals; None: no
    forgetting per reversal), ``sample_period_s`` (s), ``origin`` (``"first"``: the first sample is the
    reference origin; ``"zero"``), ``noise_window`` (updates the residual variance is averaged over),
    ``gap_policy`` (which flagged gaps are bridged; None: :class:`~online_backlash.gap_policy.GapPolicy`'s
    defaults). See :class:`~.backlash_rls.BacklashRLS` for each in full.
    """

    memory_s: float | None
    memory_reversals: float | None
    sample_period_s: float
    origin: str
    noise_window: int
    gap_policy: GapPolicy | None


class WarmStartParams(SharedParams, total=False):
    """:class:`SharedParams` and the warm start's two, for an estimator that starts from a batch fit:
    ``start`` (``"batch"``, ``"cold"``) and ``warm_start_samples`` (samples buffered for it)."""

    start: str
    warm_start_samples: int


#: The shared parameters' defaults (read-only).
SHARED_DEFAULTS: Mapping[str, Any] = MappingProxyType(
    {
        "memory_s": None,
        "memory_reversals": 10.0,
        "sample_period_s": 0.001,
        "start": "batch",
        "warm_start_samples": 10_000,
        "origin": "first",
        "noise_window": 10_000,
        "gap_policy": None,
    }
)

#: :class:`~online_backlash.load_aware.TorqueBacklashRLS`'s departures from :data:`SHARED_DEFAULTS`, declared
#: here with the reasons. ``start`` and ``warm_start_samples`` are fixed, not parameters: the torque gives the
#: switching functions, so each flank's line is linear in its parameters and one RLS per flank solves it from
#: the first sample (a cold start; no warm start). ``memory_reversals`` defaults to None (no forgetting per
#: reversal), as since the estimator was added (6f201fd): its reversals are *torque* reversals (the engaged flank
#: changing through the torque's dead band), not the motion's, so the kinematic estimators' 10 would not be the
#: same memory. Not unified: ``estimate``, ``track`` and ``listen`` always pass ``--memory-reversals`` (their
#: outputs would not change), but ``TorqueBacklashRLS()`` in a user's code would forget where it did not.
TORQUE_DEFAULTS: Mapping[str, Any] = MappingProxyType(
    {**SHARED_DEFAULTS, "memory_reversals": None, "start": "cold", "warm_start_samples": 8}
)


def memory_factors(
    memory_s: float | None, memory_reversals: float | None, sample_period_s: float
) -> tuple[float, float]:
    """Forgetting factors per update and per reversal: ``exp(-dt / memory_s)``, ``exp(-1 / memory_reversals)``."""
    lam = 1.0 if memory_s is None else math.exp(-sample_period_s / memory_s)
    lam_rev = 1.0 if memory_reversals is None else math.exp(-1.0 / memory_reversals)
    return lam, lam_rev


class SharedConstants(NamedTuple):
    """The constants vector of an estimator that keeps the default :meth:`RecursiveEstimator._constants`
    (field sizes; :data:`SHARED_CONSTS` holds the offsets)."""

    LAM: int = 1  # forgetting per update, exp(-sample_period_s / memory_s)
    LAM_REV: int = 1  # forgetting per reversal, exp(-1 / memory_reversals)
    NOISE_WINDOW: int = 1  # updates averaged by the residual variance
    ORIGIN_FIRST: int = 1  # 1: the first sample is the reference origin
    FREEZE: int = 1  # 1 during the warm start's replay: the parameters held, the information gathered


SHARED_CONSTS, N_SHARED_CONSTS = offsets(SharedConstants())


def _failure_reason(exc: Exception, n_gaps: int, stretch: int, buffered: int) -> str:
    """Why a warm start failed: the batch fit's reason, led by the gaps when they cut the buffer
    (the fit sees only the longest gap-free stretch, ``stretch`` of ``buffered`` samples)."""
    if not n_gaps:
        return str(exc)
    return (
        f"{n_gaps} gaps in the data cut the {buffered} buffered samples into stretches of at most {stretch}, "
        f"too short to fit (on the longest: {exc})"
    )


class StateField(Generic[T]):
    """A fitted attribute that reads one named field of the compiled state vector.

    The field's offset comes from the estimator class's ``_layout`` (:mod:`.layout`), so one
    declaration serves estimators whose state vectors differ; reading it before the estimator
    has started raises NotFittedError.
    """

    def __init__(self, field: str, cast: Callable[[float], T], doc: str) -> None:
        self.field = field
        self.cast = cast
        self.__doc__ = doc

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, obj: RecursiveEstimator | None, owner: Any) -> Any:
        if obj is None:
            return self
        obj._check_started()
        return self.cast(obj._st[getattr(owner._layout, self.field)])


class RecursiveEstimator(ABC):
    """Warm-up buffer, learn_one/learn_many dispatch, gaps, saved state and clone.

    Parameters shared by every recursive estimator (:class:`SharedParams`, :class:`WarmStartParams`; see
    :class:`~.backlash_rls.BacklashRLS`): ``memory_s``, ``memory_reversals``, ``sample_period_s``, ``start``,
    ``warm_start_samples``, ``origin``, ``noise_window``, ``gap_policy``. A subclass stores its own
    parameters in ``__init__``, then hands the shared ones (``**shared``) to this ``__init__`` (which calls
    :meth:`reset`); its signature (``inspect.signature``, ``get_params``) lists its own and the shared ones
    with their defaults (:data:`SHARED_DEFAULTS`, or the class's ``shared_defaults``; ``fixed_params`` are
    shared ones it does not take). It declares ``_layout`` (the module docstring lists the hooks).

    Attributes
    ----------
    gaps_ : GapTally
        The gaps flagged (``after_gap``) since the estimator was made, reset or restored from a
        saved state (like a source's counters, a run's own): count, longest and total time step
        across them (s) and how many were bridged (:class:`~online_backlash.gap_policy.GapTally`).
        The last sample's time and angles, which decide whether the next gap is bridged, are
        saved with the state (:meth:`state_dict`), so a resumed run bridges a gap right after
        its checkpoint.
    """

    memory_s: float | None
    memory_reversals: float | None
    sample_period_s: float
    start: str
    warm_start_samples: int
    origin: str
    noise_window: int
    #: Which gaps are bridged (None: the default :class:`~online_backlash.gap_policy.GapPolicy`)
    gap_policy: GapPolicy | None = None
    effects: Sequence[EffectTerms] | None = None
    #: True for an estimator whose model needs the torque of every sample (``_learn_arrays`` then gets it
    #: without effects)
    takes_torque: bool = False
    #: The shared parameters' defaults for this class (:data:`SHARED_DEFAULTS`, :data:`TORQUE_DEFAULTS`)
    shared_defaults: ClassVar[Mapping[str, Any]] = SHARED_DEFAULTS
    #: Shared parameters this class fixes at their ``shared_defaults`` (not constructor arguments)
    fixed_params: ClassVar[tuple[str, ...]] = ()
    _layout: Any
    _consts: Any = SHARED_CONSTS

    u_ref_ = StateField("U0", float, 'Reference origin of the input (first input with ``origin="first"``, else 0).')
    y_ref_ = StateField("Y0", float, "Reference origin of the output.")
    noise_var_ = StateField("NOISE_VAR", float, "Online estimate of the output noise variance, output units squared.")
    n_reversals_ = StateField("N_REV", int, "Reversals of the input seen so far.")

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """The class's signature: its own ``__init__`` parameters, then the shared ones it takes (keyword-only,
        with its defaults); and a check that its ``_layout`` has the fields the base reads."""
        super().__init_subclass__(**kwargs)
        own = [
            p
            for p in inspect.signature(cls.__init__).parameters.values()
            if p.name != "self" and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)
        ]
        taken = [n for n in cls.shared_defaults if n not in cls.fixed_params and n not in {p.name for p in own}]
        shared = [inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=cls.shared_defaults[n]) for n in taken]
        cls.__signature__ = inspect.Signature([*own, *shared])  # type: ignore[attr-defined]
        layout = getattr(cls, "_layout", None)
        missing = [f for f in _BASE_FIELDS if layout is not None and not hasattr(layout, f)]
        if missing:
            raise TypeError(f"{cls.__name__}._layout lacks the fields the base reads: {', '.join(missing)}")

    def __init__(self, **shared: Unpack[WarmStartParams]) -> None:
        """Store the shared parameters (after the subclass stored its own) and :meth:`reset`."""
        unknown = [n for n in shared if n not in self.shared_defaults or n in self.fixed_params]
        if unknown:
            raise TypeError(f"{type(self).__name__}() got an unexpected keyword argument {unknown[0]!r}")
        values = {**self.shared_defaults, **shared}
        self.gap_policy = values["gap_policy"]
        self.memory_s = values["memory_s"]
        self.memory_reversals = values["memory_reversals"]
        self.sample_period_s = values["sample_period_s"]
        self.start = values["start"]
        self.warm_start_samples = values["warm_start_samples"]
        self.origin = values["origin"]
        self.noise_window = values["noise_window"]
        self.reset()

    # -- hooks a new estimator writes --------------------------------------------------------------
    @abstractmethod
    def _initial_state(self, start: Any) -> list[float]:
        """The state vector at the start, from start values (those of :meth:`_warm_fit` or :meth:`_cold_params`;
        reference-origin coordinates)."""

    @abstractmethod
    def _learn_py(self, u: float, y: float, t: float, q: float) -> None:
        """One sample (the readable reference): input ``u``, output ``y`` (the caller's frame; the step refers
        them to the origin ``U0``, ``Y0`` and counts ``N_SEEN``), time ``t`` (s) and torque ``q`` (N m; NaN
        without one)."""

    @abstractmethod
    def _gap_now(self) -> None:
        """The next sample is not read as motion from the previous one."""

    @property
    @abstractmethod
    def theta_(self) -> np.ndarray:
        """The parameter vector of the paper, eq. (8) ``[mL, mL cL, mR, mR cR]`` first (reference-origin
        coordinates)."""

    @property
    @abstractmethod
    def P_(self) -> np.ndarray:
        """Unscaled covariance of ``theta_`` (times ``noise_var_``: the covariance)."""

    # -- hooks with defaults -------------------------------------------------------------------------
    def _validate(self) -> None:  # noqa: B027 (a default hook: nothing to check)
        """Check the estimator's own parameters (after :meth:`_validate_common`); none by default."""

    def _reset_own(self) -> None:  # noqa: B027 (a default hook: no own state)
        """Create the estimator's own state beside the shared one; none by default."""

    def _warm_fit(self, uc: np.ndarray, yc: np.ndarray, terms: np.ndarray) -> tuple[Any, int, bool]:
        """The batch fit on the buffer (reference-origin coordinates): ``(start values, n_iter, converged)``,
        issuing no ConvergenceWarning (see :class:`~online_backlash.estimators.batch.VorosBacklash`'s
        ``warn_unconverged``: the warnings settings are the process's, not this thread's). By default the
        paper's batch algorithm, :class:`~.batch.VorosBacklash` (eq. 12-14), and its ``params_`` (``terms``:
        the effects' columns, none unless the estimator takes effects)."""
        batch = VorosBacklash(origin="zero")
        batch.warn_unconverged = False  # told by converged_ (warm_start_)
        batch.fit(uc, yc)
        return batch.params_, int(batch.n_iter_), bool(batch.converged_)

    def _cold_params(self, u: np.ndarray | None, y: np.ndarray | None) -> Any:
        """Start values without a batch fit (``start="cold"``, or the warm start failed; ``u``, ``y`` None:
        no data, as when a saved state is restored). By default the paper's start values
        ``mL = mR = 1, cL = cR = 0.001`` without data, else from the direction of motion."""
        if u is None or y is None or u.size < 2:
            return BacklashParams(1.0, 1e-3, 1.0, 1e-3)
        try:
            return _direction_guess(u, y)
        except NotExcitedError:
            return _start_params(u, y)

    def _constants(self) -> list[float]:
        """The constants vector of the kernels, from the parameters (by default :data:`SHARED_CONSTS`)."""
        lam, lam_rev = memory_factors(self.memory_s, self.memory_reversals, self.sample_period_s)
        return pack(
            SHARED_CONSTS, N_SHARED_CONSTS, LAM=lam, LAM_REV=lam_rev, NOISE_WINDOW=self.noise_window,
            ORIGIN_FIRST=self.origin == "first",
        )  # fmt: skip

    def _learn_arrays(
        self, u: np.ndarray, y: np.ndarray, gap: np.ndarray, t: np.ndarray | None, q: np.ndarray | None
    ) -> None:
        """Consecutive samples (a compiled loop where the estimator has one); the same estimates as
        :meth:`_learn_py` (time ``t`` and torque ``q`` are given where there are effects or the estimator
        takes torque, else None). By default :meth:`_learn_py` sample by sample."""
        for i in range(u.size):
            if gap[i]:
                self._gap_now()
            ti = math.nan if t is None else float(t[i])
            self._learn_py(float(u[i]), float(y[i]), ti, math.nan if q is None else float(q[i]))

    def _learn_arrays_marked(
        self,
        u: np.ndarray,
        y: np.ndarray,
        gap: np.ndarray,
        t: np.ndarray | None,
        q: np.ndarray | None,
        marks: np.ndarray,
    ) -> list[EstimateAt]:
        """:meth:`_learn_arrays` (the estimator has started) with the estimate after the first
        ``marks[k]`` samples (strictly ascending, 1..n): here by learning up to each mark in turn and reading
        the estimate there; an estimator with a compiled loop overrides it to record the marks inside it."""
        out: list[EstimateAt] = []
        lo = 0
        for hi in [*marks.tolist(), u.size]:
            if hi > lo:
                self._learn_arrays(
                    u[lo:hi], y[lo:hi], gap[lo:hi], None if t is None else t[lo:hi], None if q is None else q[lo:hi]
                )
            if len(out) < marks.size:
                out.append(self.estimate_now())
            lo = hi
        return out

    # -- parameters and state --------------------------------------------------------------------
    def get_params(self) -> dict[str, Any]:
        """The constructor arguments (river's parameters, read from the class's signature: its own, then the
        shared ones it takes)."""
        names = list(inspect.signature(type(self)).parameters)
        return {name: getattr(self, name) for name in names}

    def clone(self) -> RecursiveEstimator:
        """A fresh, unfitted estimator with the same settings (river's ``clone``); effects are
        copied fresh (same parameters, no stream history)."""
        params = self.get_params()
        if params.get("effects"):
            params["effects"] = [_fresh(e) for e in params["effects"]]
        return type(self)(**params)

    def reset(self) -> None:
        """Forget everything learned: the state after ``__init__`` (parameters kept)."""
        self._validated = False
        self._started = False
        self._st: list[float] = []
        self._c: list[float] = []
        self._c_arr = np.empty(0)
        self._fx = EffectStream(list(self.effects or []))  # checked with the parameters
        self._pending_gap = False
        self._last = UNKNOWN  # (time_s, u, y) of the last sample learned, for the gap rule
        self.gaps_ = GapTally()
        self._buf: dict[str, list] = {k: [] for k in _BUFFER_KEYS}
        self._next_attempt = self.warm_start_samples
        self._attempts = 0
        self.warm_start_: dict[str, Any] = {}
        self._reset_own()

    def _validate_common(self) -> None:
        if self.memory_s is not None:
            check_real("memory_s", self.memory_s, 0.0)
        if self.memory_reversals is not None:
            check_real("memory_reversals", self.memory_reversals, 0.0)
        check_real("sample_period_s", self.sample_period_s, 0.0)
        check_option("start", self.start, _STARTS)
        check_option("origin", self.origin, _ORIGINS)
        check_int("warm_start_samples", self.warm_start_samples, 8)
        check_int("noise_window", self.noise_window, 1)
        if self.gap_policy is not None and not isinstance(self.gap_policy, GapPolicy):
            raise InvalidParameterError(f"gap_policy must be a GapPolicy or None, got {self.gap_policy!r}")

    def _ensure_valid(self) -> None:
        """Validate the parameters on the first call that learns (a cold start begins then)."""
        if self._validated:
            return
        self._validate_common()
        self._validate()
        check_effects(self._fx.effects)
        self._validated = True
        if self.start == "cold" and not self._started:
            self._begin(self._cold_params(None, None))

    def _begin(self, start: Any) -> None:
        """Set the constants and the state from start values, and start."""
        self._c = self._constants()
        self._c_arr = np.asarray(self._c)
        self._st = self._initial_state(start)
        self._started = True

    # -- public learning API ---------------------------------------------------------------------
    def mark_gap(self) -> None:
        """The next sample does not continue the last one (a new log, a resumed stream): it is not read
        as motion from the previous one, whatever ``gap_policy`` says (a short gap of one stream is
        flagged with ``after_gap`` instead, and may be bridged)."""
        self._ensure_valid()
        self._last = UNKNOWN
        if self._started:
            self._gap_now()
        else:
            self._pending_gap = True

    def learn_one(
        self,
        u: float,
        y: float,
        *,
        time_s: float | None = None,
        torque_Nm: float | None = None,
        after_gap: bool = False,
    ) -> None:
        """Learn one sample: input ``u`` (motor angle referred to the load side) and output ``y`` (load angle).

        ``time_s`` (s) and ``torque_Nm`` (N m) are passed to the effects (if any); without
        ``time_s`` the time is ``n_samples_seen_ * sample_period_s``. ``after_gap`` True: samples
        are missing just before this one; :attr:`gap_policy` bridges the gap (the sample is
        learned from the one before it) if it is short (from ``time_s``) and neither angle jumps,
        else it restarts the reading of the motion (as :meth:`mark_gap`). Tallied in ``gaps_``.

        Raises
        ------
        InvalidParameterError
            If ``u`` or ``y`` is not finite (NaN is never absorbed).
        """
        self._ensure_valid()
        u, y = finite("u", u), finite("y", y)
        t = self._time(time_s)
        q = math.nan if torque_Nm is None else float(torque_Nm)
        restart = False
        if after_gap:
            restart = bool(
                self._bridge(np.array([True]), None if time_s is None else np.array([t]), np.array([u]), np.array([y]))[
                    0
                ]
            )
        else:
            self._remember(math.nan if time_s is None else t, u, y)
        if not self._started:
            self._buffer([u], [y], [restart or self._pending_gap], [t], [q])
            self._pending_gap = False
            if len(self._buf["u"]) >= self._next_attempt:
                self._try_start(compiled=False)
            return
        if restart:
            self._gap_now()
        self._learn_py(u, y, t, q)

    def learn_many(
        self,
        u: np.ndarray,
        y: np.ndarray,
        after_gap: np.ndarray | None = None,
        *,
        time_s: np.ndarray | None = None,
        torque_Nm: np.ndarray | None = None,
        assume_finite: bool = False,
        snapshot_at: np.ndarray | None = None,
    ) -> list[EstimateAt] | None:
        """Learn consecutive samples (arrays); the same estimates as a loop of :meth:`learn_one`.

        ``after_gap[i]`` True means samples are missing just before ``i``: :attr:`gap_policy`
        bridges a short gap without a jump (the time step from ``time_s``, s; the angle steps, deg)
        and restarts the reading of the motion at any other (as :meth:`mark_gap`); ``gaps_`` tallies
        them. Without ``time_s`` no gap is bridged. Runs compiled (numba) where the estimator has a
        compiled loop. ``assume_finite=True`` skips the check that ``u`` and ``y`` are finite
        (scikit-learn's ``assume_finite``), for a caller that checked them already
        (:class:`~online_backlash.pipeline.Pipeline` checks each chunk once, not each block).

        ``snapshot_at`` (strictly ascending sample counts, each in ``1..len(u)``): also return the estimate
        after the first ``snapshot_at[k]`` samples of this call (:class:`EstimateAt`; not started
        before the warm start), the same as learning the block cut at those counts and reading
        :meth:`estimate_now` after each piece, but in one compiled loop where the estimator has one
        (the play's scatter measures at data-clock ticks without cutting the estimator's block).

        Raises
        ------
        InvalidParameterError
            If the arrays differ in shape, ``u`` or ``y`` has a non-finite value, or
            ``snapshot_at`` is not strictly ascending within ``1..len(u)``.
        """
        self._ensure_valid()
        u = np.ascontiguousarray(u, dtype=float) if assume_finite else finite_array("u", u)
        y = np.ascontiguousarray(y, dtype=float) if assume_finite else finite_array("y", y)
        if u.ndim != 1 or u.shape != y.shape:
            raise InvalidParameterError(
                f"u and y must be 1-D arrays of equal length, got shapes {u.shape} and {y.shape}"
            )
        n = u.size
        gap = np.zeros(n, dtype=bool) if after_gap is None else np.ascontiguousarray(after_gap, dtype=bool)
        if gap.shape != u.shape:
            raise InvalidParameterError(f"after_gap must be as long as u, got {gap.size} and {n}")
        time: np.ndarray | None = None if time_s is None else np.ascontiguousarray(time_s, dtype=float)
        if time is not None and time.shape != u.shape:
            raise InvalidParameterError(f"time_s must be as long as u, got {time.size} and {n}")
        if n:
            gap = self._bridge(gap, time, u, y)
        if n and self._pending_gap:
            gap = gap.copy()
            gap[0] = True
            self._pending_gap = False
        n0 = self._n_seen_total()
        torque: np.ndarray | None = None if torque_Nm is None else np.ascontiguousarray(torque_Nm, dtype=float)
        marks = None if snapshot_at is None else _marks(snapshot_at, n)
        found: list[EstimateAt] = []

        def times(lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
            """Time (default: ``n_samples_seen_ * sample_period_s``) and torque (default: NaN) of
            samples ``lo:hi``, made only where the buffer or the effects need them."""
            t = (n0 + np.arange(lo, hi, dtype=float)) * self.sample_period_s if time is None else time[lo:hi]
            return t, np.full(hi - lo, np.nan) if torque is None else torque[lo:hi]

        i = 0
        while not self._started and i < n:
            take = min(n - i, self._next_attempt - len(self._buf["u"]))
            sl = slice(i, i + take)
            t, q = times(i, i + take)
            self._buffer(u[sl].tolist(), y[sl].tolist(), gap[sl].tolist(), t.tolist(), q.tolist())
            i += take
            if len(self._buf["u"]) >= self._next_attempt:
                self._try_start(compiled=True)
            if marks is not None:  # the marks inside this piece fell before any start; one at its end sees the attempt
                reached = int(np.searchsorted(marks, i, side="right"))
                at_end = reached > len(found) and int(marks[reached - 1]) == i
                found += [NOT_STARTED] * (reached - len(found) - at_end) + [self.estimate_now()] * at_end
        if i < n:
            rest_t, rest_q = times(i, n) if self._fx.effects or self.takes_torque else (None, None)
            if marks is None:
                self._learn_arrays(u[i:], y[i:], gap[i:], rest_t, rest_q)
            else:
                found += self._learn_arrays_marked(u[i:], y[i:], gap[i:], rest_t, rest_q, marks[len(found) :] - i)
        return None if marks is None else found

    def force_start(self) -> None:
        """Run the warm start now on the samples buffered so far (e.g. at the end of a short log).

        Raises
        ------
        NotExcitedError
            When the buffered data do not excite both flanks.
        """
        self._ensure_valid()
        if self._started:
            return
        if len(self._buf["u"]) < 8:
            raise NotExcitedError(f"only {len(self._buf['u'])} samples buffered; need at least 8 to start")
        self._try_start(compiled=True, fallback=False)

    # -- gaps --------------------------------------------------------------------------------------
    def _bridge(self, gap: np.ndarray, time: np.ndarray | None, u: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``gap`` without the gaps :attr:`gap_policy` bridges (the one rule, :meth:`GapPolicy.split`);
        tallies them in ``gaps_`` and remembers the block's last sample. ``gap`` is not modified."""
        if gap.any():
            policy = self.gap_policy if self.gap_policy is not None else _DEFAULT_GAP_POLICY
            gap, dt, bridged = policy.split(gap, time, u, y, self._last)
            self.gaps_.add(dt, bridged)
        self._remember(math.nan if time is None else float(time[-1]), float(u[-1]), float(y[-1]))
        return gap

    def _remember(self, time_s: float, u: float, y: float) -> None:
        """The last sample learned: its time (s; NaN if none was given) and angles, for the next gap."""
        self._last = (time_s, u, y)

    # -- warm start ------------------------------------------------------------------------------
    def _n_seen_total(self) -> int:
        return int(self._st[self._layout.N_SEEN]) if self._started else len(self._buf["u"])

    def _time(self, time_s: float | None) -> float:
        return self._n_seen_total() * self.sample_period_s if time_s is None else float(time_s)

    def _buffer(self, u: list, y: list, gap: list, t: list, q: list) -> None:
        for key, values in zip(_BUFFER_KEYS, (u, y, gap, t, q)):
            self._buf[key].extend(values)

    def _origin_of(self, u: np.ndarray, y: np.ndarray) -> tuple[float, float]:
        return (float(u[0]), float(y[0])) if self.origin == "first" else (0.0, 0.0)

    def _try_start(self, compiled: bool, fallback: bool = True) -> None:
        """Fit the paper's batch algorithm to the buffer, start from it and learn the buffer recursively."""
        u, y, t, q = (np.asarray(self._buf[k], dtype=float) for k in ("u", "y", "time", "torque"))
        check_magnitude(u=u, y=y)  # refused, not fallen back from: no start copes with 1e300
        u0, y0 = self._origin_of(u, y)
        # the longest gap-free stretch of the buffer
        cuts = [0, *np.flatnonzero(np.asarray(self._buf["gap"][1:])) + 1, u.size]
        lo, hi = max(itertools.pairwise(cuts), key=lambda ab: ab[1] - ab[0])
        self._attempts += 1
        terms = self._fx.terms(u[lo:hi], t[lo:hi], q[lo:hi])
        self._fx.reset()  # the replay computes the terms again from the buffer's start
        start: Any
        try:
            start, n_iter, converged = self._warm_fit(u[lo:hi] - u0, y[lo:hi] - y0, terms)
            self.warm_start_ = {"method": "batch", "samples": int(hi - lo), "n_iter": n_iter, "converged": converged}
        except (NotExcitedError, InvalidParameterError) as exc:
            reason = _failure_reason(exc, len(cuts) - 2, hi - lo, u.size)
            if not fallback:
                raise NotExcitedError(f"warm start failed on {hi - lo} buffered samples: {reason}") from exc
            if self._attempts < _WARM_ATTEMPTS:
                self._next_attempt += self.warm_start_samples
                return
            start = self._cold_params(u[lo:hi] - u0, y[lo:hi] - y0)
            self.warm_start_ = {"method": "cold", "samples": 0, "reason": reason, "gaps": len(cuts) - 2}
        self._begin(start)
        buf = self._buf
        self._buf = {k: [] for k in buf}
        self._replay(buf, compiled)

    def _replay(self, buf: dict[str, list], compiled: bool) -> None:
        """Learn the buffered samples (by the path of the call that triggered the start) with the
        parameters held at the warm start: the replay only gathers their information (the
        covariance, residual variance, reversals), so a few early samples cannot override the
        fit of the whole buffer."""
        self._set_freeze(True)
        try:
            if compiled:
                u, y, gap, t, q = (np.asarray(buf[k], dtype=bool if k == "gap" else float) for k in _BUFFER_KEYS)
                self._learn_arrays(u, y, gap, *((t, q) if self._fx.effects else (None, None)))
            else:
                for u, y, gap, t, q in zip(*(buf[k] for k in _BUFFER_KEYS)):
                    if gap:
                        self._gap_now()
                    self._learn_py(u, y, t, q)
        finally:
            self._set_freeze(False)

    def _set_freeze(self, freeze: bool) -> None:
        self._c[self._consts.FREEZE] = 1.0 if freeze else 0.0
        self._c_arr = np.asarray(self._c)

    # -- saved state -----------------------------------------------------------------------------
    def _extra_state(self) -> dict[str, Any]:
        """The estimator's own state beside the state vector, JSON types (none by default)."""
        return {}

    def _restore_extra(self, d: dict[str, Any]) -> None:  # noqa: B027 (a default hook: nothing saved)
        """Restore what :meth:`_extra_state` saved."""

    def state_dict(self) -> dict[str, Any]:
        """Settings, reference origin and learned state as plain JSON-serialisable types.

        Effects are saved by name and parameters (:data:`online_backlash.effect_terms.EFFECTS`),
        with the samples that restore their stream history, so :meth:`from_state` rebuilds them.
        """
        self._ensure_valid()
        params = self.get_params()
        if "effects" in params:
            params["effects"] = self._fx.state_dict()["effects"]
        if isinstance(params.get("gap_policy"), GapPolicy):
            params["gap_policy"] = params["gap_policy"].as_dict()
        d: dict[str, Any] = {
            "estimator": type(self).__name__,
            "format": STATE_FORMAT,
            "params": params,
            "started": self._started,
            "warm_start": dict(self.warm_start_),
            # the sample before the next one, so a gap right after a checkpoint is bridged (NaN: None)
            "last_sample": [v if math.isfinite(v) else None for v in self._last],
        }
        if self._started:
            d["origin"] = {"u_ref": self.u_ref_, "y_ref": self.y_ref_}
            d["state"] = [float(v) for v in self._st]
            d.update(self._extra_state())
            if self._fx.effects:
                d["effects_stream"] = self._fx.state_dict()
        else:
            # NaN (no torque) is not JSON: saved as None
            d["buffer"] = {
                k: [bool(v) if k == "gap" else (float(v) if math.isfinite(v) else None) for v in vals]
                for k, vals in self._buf.items()
            }
            d["pending_gap"] = self._pending_gap
            d["next_attempt"] = self._next_attempt
            d["attempts"] = self._attempts
        return d

    @classmethod
    def from_state(cls, d: dict[str, Any], effects: Sequence[EffectTerms] | None = None) -> RecursiveEstimator:
        """Rebuild an estimator saved by :meth:`state_dict` (after a restart, without re-learning).

        Effects are rebuilt from the registry by name, or taken from ``effects`` (whose names
        must match the saved ones).
        """
        if d.get("estimator") != cls.__name__ or d.get("format") not in _READ_FORMATS:
            raise InvalidParameterError(
                f"not a saved {cls.__name__} state (format {STATE_FORMAT}): "
                f"estimator={d.get('estimator')!r}, format={d.get('format')!r}"
            )
        params = dict(d["params"])
        if "effects" in params:
            params["effects"] = effects_from_records(params["effects"] or [], effects)
        elif effects:
            raise InvalidParameterError(f"a saved {cls.__name__} takes no effects")
        if isinstance(params.get("gap_policy"), dict):
            params["gap_policy"] = GapPolicy(**params["gap_policy"])
        est = cls(**params)
        est._ensure_valid()
        est.warm_start_ = dict(d.get("warm_start", {}))
        t_last, u_last, y_last = (math.nan if v is None else float(v) for v in d.get("last_sample") or [None] * 3)
        est._remember(t_last, u_last, y_last)  # unknown in states saved before bridging
        if d["started"]:
            est._begin(est._cold_params(None, None))
            est._st = [float(v) for v in d["state"]]
            est._restore_extra(d)
            if "effects_stream" in d:
                est._fx.restore(d["effects_stream"])
        else:
            est._started = False
            est._buf = {k: [math.nan if v is None else v for v in vals] for k, vals in d["buffer"].items()}
            est._pending_gap = bool(d["pending_gap"])
            est._next_attempt = int(d["next_attempt"])
            est._attempts = int(d["attempts"])
        return est

    # -- fitted attributes -----------------------------------------------------------------------
    def estimate_now(self) -> EstimateAt:
        """The estimate as it is now (:class:`EstimateAt`): the play and slopes, degrees."""
        if not self._started:
            return NOT_STARTED
        play, m_left, m_right = float(self.backlash_), float(self.m_left_), float(self.m_right_)
        return EstimateAt(True, play, m_left, m_right, self._play_level_deg())

    def _play_level_deg(self) -> float:
        """The output level (the caller's frame, degrees) the play is read at for :class:`EstimateAt`: 0, where
        the estimator reads it at the frame's origin or at the current output (which per-cycle plays read as
        the origin's, the slopes being alike)."""
        return 0.0

    @property
    def started(self) -> bool:
        """True once the estimator has started (warm start done, cold start, or resumed state)."""
        return self._started

    def _check_started(self) -> None:
        if not self._started:
            raise NotFittedError(
                f"this {type(self).__name__} has not started yet: it is buffering the warm start "
                f"(warm_start_samples={self.warm_start_samples}); learn more samples or call force_start()"
            )

    @property
    def n_samples_seen_(self) -> int:
        """Samples learned so far (including those buffered for the warm start)."""
        if not self._validated:
            raise NotFittedError(f"this {type(self).__name__} has seen no sample yet")
        return self._n_seen_total()

    @property
    def residual_rms_(self) -> float:
        """``sqrt(noise_var_)``, output units."""
        return math.sqrt(self.noise_var_)

    @property
    def m_left_(self) -> float:
        """Slope of the left flank, eq. (1)."""
        return float(self.theta_[0])

    @property
    def m_right_(self) -> float:
        """Slope of the right flank, eq. (1)."""
        return float(self.theta_[2])

    @property
    def c_left_(self) -> float:
        """Distance to the left flank, input units: ``c1 / m1`` of eq. (9)."""
        th = self.theta_
        return float(th[1] / th[0])

    @property
    def c_right_(self) -> float:
        """Distance to the right flank, input units: ``c2 / m2`` of eq. (9)."""
        th = self.theta_
        return float(th[3] / th[2])

    @property
    def backlash_(self) -> float:
        """The play, ``c_left_ + c_right_``, input units."""
        return self.c_left_ + self.c_right_

    @property
    def backlash_std_(self) -> float:
        """Standard error of ``backlash_`` from ``P_`` and the residual variance (the delta method on eq. 9)."""
        th = self.theta_
        m1, c1, m2, c2 = th[:4]
        g = np.array([-c1 / m1**2, 1.0 / m1, -c2 / m2**2, 1.0 / m2])
        return math.sqrt(max(self.noise_var_ * float(g @ self.P_[:4, :4] @ g), 0.0))

    def predict_one(self, u: float) -> float:
        """One-step-ahead output for input ``u``, eq. (1)-(3) with the lines of ``theta_``, from the last
        output learned (NaN before one)."""
        m_left, c_left, m_right, c_right = self.m_left_, self.c_left_, self.m_right_, self.c_right_
        uc, x_prev = finite("u", u) - self.u_ref_, self._last[2] - self.y_ref_
        if uc <= x_prev / m_left - c_left:  # eq. (2)
            x = m_left * (uc + c_left)
        elif uc >= x_prev / m_right + c_right:  # eq. (3)
            x = m_right * (uc - c_right)
        else:
            x = x_prev
        return float(x + self.y_ref_)


def _marks(snapshot_at: Any, n: int) -> np.ndarray:
    """``snapshot_at`` as int64 sample counts, or InvalidParameterError unless strictly ascending within ``1..n``."""
    marks = np.ascontiguousarray(snapshot_at, dtype=np.int64)
    if marks.ndim != 1 or (marks.size and (marks[0] < 1 or marks[-1] > n or np.any(np.diff(marks) <= 0))):
        raise InvalidParameterError(
            f"snapshot_at must be strictly ascending sample counts within 1..{n}, got {snapshot_at!r}"
        )
    return marks


def _fresh(effect: EffectTerms) -> EffectTerms:
    """A copy of ``effect`` with no stream history (its ``clone()`` if it has one)."""
    clone = getattr(effect, "clone", None)
    if clone is not None:
        return clone()
    fresh = copy.deepcopy(effect)
    fresh.reset()
    return fresh
