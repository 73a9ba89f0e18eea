"""Recursive (online) estimators of backlash, river style: ``learn_one`` / ``learn_many`` / ``predict_one``.

* :class:`BacklashRLS`: backlash alone, regressor eq. (8), target eq. (11), switching functions
  eq. (12)-(13) evaluated with the current estimates.
* :class:`CascadeRLS`: input backlash followed by a linear system, regressor eq. (19), target
  eq. (24), internal variable propagated by eq. (23) with the current estimates (the recursive
  form of J. Vörös, ASME J. Dyn. Sys. Meas. Control 135(1) 014504, 2013).

Both start from the paper's batch algorithm (:class:`~online_backlash.estimators.batch.VorosBacklash`,
:class:`~online_backlash.estimators.batch.VorosCascade`) fitted on the first stretch of data that
reverses (a *warm start*), or from a saved state (:meth:`state_dict` / :meth:`from_state`).
Samples buffered during the warm-up are then replayed with the parameters held at the batch
estimate, which gathers their information (covariance, residual variance, reversals): none is
lost or counted twice, and a few slow, coarsely quantised first samples cannot override the
fit of the whole buffer.

``learn_one`` runs the per-sample step in plain Python (the readable reference);
``learn_many`` runs the same source compiled by numba (``_rls_kernels``), so both give the same
estimates. Memory is flat: no per-sample history is kept.

Units: ``u`` and ``y`` share one unit (degrees, load side, in this package); slopes are
dimensionless; ``c_left_``, ``c_right_``, ``backlash_`` are in input units; times in seconds.
"""

from __future__ import annotations

import copy
import inspect
import math
import warnings
from typing import Any, Sequence

import numpy as np

from ..effect_terms import EffectTerms
from ..errors import ConvergenceWarning, InvalidParameterError, NotExcitedError, NotFittedError
from ..model import BacklashParams
from . import _rls_kernels as K
from ._validation import check_int, check_option, check_real
from .batch import VorosBacklash, VorosCascade, _direction_guess, _levenberg_marquardt, _start_params

_STARTS = ("batch", "cold")
_ORIGINS = ("first", "zero")
_SWITCHING = ("model", "measured")
_WARM_ATTEMPTS = 4  # batch attempts (at 1x..4x warm_start_samples) before a cold start
_STATE_FORMAT = 2  # 2: the model's output X_HAT joined the BacklashRLS state


def _memory_factors(memory_s: float | None, memory_reversals: float | None, sample_period_s: float) -> tuple[float, float]:
    """Forgetting factors per update and per reversal: ``exp(-dt / memory_s)``, ``exp(-1 / memory_reversals)``."""
    lam = 1.0 if memory_s is None else math.exp(-sample_period_s / memory_s)
    lam_rev = 1.0 if memory_reversals is None else math.exp(-1.0 / memory_reversals)
    return lam, lam_rev


def _check_effects(effects: Sequence[EffectTerms] | None) -> list[EffectTerms]:
    out = list(effects or [])
    for eff in out:
        if not isinstance(eff, EffectTerms):
            raise InvalidParameterError(
                f"effects must follow online_backlash.effect_terms.EffectTerms (name, n_terms, terms, reset), got {eff!r}"
            )
    return out


def _refine_with_effects(uc: np.ndarray, yc: np.ndarray, terms: np.ndarray, start: BacklashParams) -> BacklashParams:
    """The batch refinement with effect columns: minimise ``|y - x_sim(u) - terms beta|^2`` over
    ``[mL, cL, mR, cR, beta]`` jointly, from the batch estimate and ``beta = 0``.

    ``x_sim`` is eq. (1)-(3) run freely on ``u`` (the simulation error of
    :meth:`VorosBacklash._refine`); the effects enter linearly, so the Jacobian is
    ``[dx_sim/dp, terms]`` and Levenberg-Marquardt runs as for backlash alone. Returns the
    lines (``beta`` is learned again by the replay of the buffer).
    """

    def evaluate(v: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        if not (v[0] * v[2] > 0 and v[1] + v[3] >= 0):  # eq. (1) needs it
            return None
        x, dx = VorosBacklash._simulate_with_jacobian(uc, BacklashParams(*v[:4]), yc[0])
        return yc - x - terms @ v[4:], -np.hstack((dx, terms))

    v0 = np.concatenate(([start.m_left, start.c_left, start.m_right, start.c_right], np.zeros(terms.shape[1])))
    best = _levenberg_marquardt(evaluate, v0)
    return BacklashParams(*best.x[:4]) if best.improved else start


class _RecursiveBase:
    """Warm-up buffer, learn_one/learn_many dispatch, gaps, saved state and clone."""


    # -- parameters ------------------------------------------------------------------------
    def _get_params(self) -> dict[str, Any]:
        names = [p for p in inspect.signature(type(self).__init__).parameters if p != "self"]
        return {name: getattr(self, name) for name in names}

    def clone(self) -> "_RecursiveBase":
        """A fresh, unfitted estimator with the same settings (river's ``clone``); effects are deep-copied and reset."""
        params = self._get_params()
        if "effects" in params:
            params["effects"] = [copy.deepcopy(e) for e in params["effects"] or []]
            for e in params["effects"]:
                e.reset()
        return type(self)(**params)

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

    def _setup(self) -> None:
        """Validate the parameters and reset the learned state (first call of learn_one/learn_many)."""
        self._validate()
        self._effects = _check_effects(getattr(self, "effects", None))
        self._n_effect_terms = sum(int(e.n_terms) for e in self._effects)
        self._started = False
        self._st: list[float] | None = None
        self._pending_gap = False
        self._buf: dict[str, list] = {k: [] for k in ("u", "y", "gap", "time", "torque")}
        self._n_buffered_total = 0
        self._next_attempt = self.warm_start_samples
        self._attempts = 0
        self.warm_start_: dict[str, Any] = {}
        if self.start == "cold":
            self._begin(self._cold_params(None, None))

    def _ensure_setup(self) -> None:
        if not hasattr(self, "_started"):
            self._setup()

    # -- public learning API ---------------------------------------------------------------
    def mark_gap(self) -> None:
        """The source saw a gap: the next sample is not read as motion from the previous one."""
        self._ensure_setup()
        if self._started:
            self._gap_now()
        else:
            self._pending_gap = True

    def learn_one(self, u: float, y: float, *, time_s: float | None = None, torque_Nm: float | None = None) -> None:
        """Learn one sample: input ``u`` (motor angle referred to the load side) and output ``y`` (load angle).

        ``time_s`` and ``torque_Nm`` are passed to the effects (if any); without ``time_s``
        the time is ``n_samples_seen_ * sample_period_s``.
        """
        self._ensure_setup()
        u, y = _finite("u", u), _finite("y", y)
        t = self._time(time_s)
        q = math.nan if torque_Nm is None else float(torque_Nm)
        if not self._started:
            self._buffer([u], [y], [self._pending_gap], [t], [q])
            self._pending_gap = False
            if len(self._buf["u"]) >= self._next_attempt:
                self._try_start(compiled=False)
            return
        self._learn_py(u, y, t, q)

    def learn_many(
        self,
        u: np.ndarray,
        y: np.ndarray,
        after_gap: np.ndarray | None = None,
        *,
        time_s: np.ndarray | None = None,
        torque_Nm: np.ndarray | None = None,
    ) -> None:
        """Learn consecutive samples (arrays); the same estimates as a loop of :meth:`learn_one`.

        ``after_gap[i]`` True means samples are missing just before ``i`` (as :meth:`mark_gap`).
        Without effects this runs compiled (numba).
        """
        self._ensure_setup()
        u = np.ascontiguousarray(u, dtype=float)
        y = np.ascontiguousarray(y, dtype=float)
        if u.ndim != 1 or u.shape != y.shape:
            raise InvalidParameterError(f"u and y must be 1-D arrays of equal length, got shapes {u.shape} and {y.shape}")
        for name, arr in (("u", u), ("y", y)):
            if not np.all(np.isfinite(arr)):
                raise InvalidParameterError(f"{name} has non-finite values, first at index {int(np.flatnonzero(~np.isfinite(arr))[0])}")
        n = u.size
        gap = np.zeros(n, dtype=bool) if after_gap is None else np.ascontiguousarray(after_gap, dtype=bool)
        if gap.shape != u.shape:
            raise InvalidParameterError(f"after_gap must be as long as u, got {gap.size} and {n}")
        if n and self._pending_gap:
            gap = gap.copy()
            gap[0] = True
            self._pending_gap = False
        if time_s is None:
            time = self._n_seen_total() + np.arange(n, dtype=float)
            time *= self.sample_period_s
        else:
            time = np.ascontiguousarray(time_s, dtype=float)
        torque = np.full(n, np.nan) if torque_Nm is None else np.ascontiguousarray(torque_Nm, dtype=float)
        i = 0
        while not self._started and i < n:
            take = min(n - i, self._next_attempt - len(self._buf["u"]))
            sl = slice(i, i + take)
            self._buffer(u[sl].tolist(), y[sl].tolist(), gap[sl].tolist(), time[sl].tolist(), torque[sl].tolist())
            i += take
            if len(self._buf["u"]) >= self._next_attempt:
                self._try_start(compiled=True)
        if i < n:
            self._learn_arrays(u[i:], y[i:], gap[i:], time[i:], torque[i:])

    def force_start(self) -> None:
        """Run the warm start now on the samples buffered so far (e.g. at the end of a short log).

        Raises
        ------
        NotExcitedError
            When the buffered data do not excite both flanks.
        """
        self._ensure_setup()
        if self._started:
            return
        if len(self._buf["u"]) < 8:
            raise NotExcitedError(f"only {len(self._buf['u'])} samples buffered; need at least 8 to start")
        self._try_start(compiled=True, fallback=False)

    # -- warm start ------------------------------------------------------------------------
    def _n_seen_total(self) -> int:
        return int(self._st[K.N_SEEN]) if self._started else len(self._buf["u"])

    def _time(self, time_s: float | None) -> float:
        return self._n_seen_total() * self.sample_period_s if time_s is None else float(time_s)

    def _buffer(self, u, y, gap, t, q) -> None:
        for key, values in (("u", u), ("y", y), ("gap", gap), ("time", t), ("torque", q)):
            self._buf[key].extend(values)

    def _origin_of(self, u: np.ndarray, y: np.ndarray) -> tuple[float, float]:
        return (float(u[0]), float(y[0])) if self.origin == "first" else (0.0, 0.0)

    def _try_start(self, compiled: bool, fallback: bool = True) -> None:
        """Fit the paper's batch algorithm to the buffer, start from it and learn the buffer recursively."""
        u, y, t, q = (np.asarray(self._buf[k], dtype=float) for k in ("u", "y", "time", "torque"))
        u0, y0 = self._origin_of(u, y)
        # the longest gap-free stretch of the buffer
        cuts = [0, *np.flatnonzero(np.asarray(self._buf["gap"][1:])) + 1, u.size]
        lo, hi = max(zip(cuts[:-1], cuts[1:]), key=lambda ab: ab[1] - ab[0])
        self._attempts += 1
        terms = self._effect_terms(u[lo:hi], t[lo:hi], q[lo:hi])
        self._reset_effects()  # the replay computes the terms again from the buffer's start
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", ConvergenceWarning)
                start, n_iter = self._warm_fit(u[lo:hi] - u0, y[lo:hi] - y0, terms)
            self.warm_start_ = {
                "method": "batch",
                "samples": int(hi - lo),
                "n_iter": n_iter,
                "converged": not any(issubclass(w.category, ConvergenceWarning) for w in caught),
            }
        except (NotExcitedError, InvalidParameterError) as exc:
            if not fallback:
                raise NotExcitedError(f"warm start failed on {hi - lo} buffered samples: {exc}") from exc
            if self._attempts < _WARM_ATTEMPTS:
                self._next_attempt += self.warm_start_samples
                return
            start = self._cold_params(u[lo:hi] - u0, y[lo:hi] - y0)
            self.warm_start_ = {"method": "cold", "samples": 0, "reason": str(exc)}
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
            self._learn_buffer(buf, compiled)
        finally:
            self._set_freeze(False)

    def _set_freeze(self, freeze: bool) -> None:
        self._c[self._FREEZE] = 1.0 if freeze else 0.0
        self._c_arr = np.asarray(self._c)

    def _learn_buffer(self, buf: dict[str, list], compiled: bool) -> None:
        if compiled:
            self._learn_arrays(*(np.asarray(buf[k], dtype=bool if k == "gap" else float) for k in ("u", "y", "gap", "time", "torque")))
        else:
            for args in zip(buf["u"], buf["y"], buf["gap"], buf["time"], buf["torque"]):
                if args[2]:
                    self._gap_now()
                self._learn_py(*args[:2], *args[3:])

    # -- effects -----------------------------------------------------------------------------
    def _effect_terms(self, u: np.ndarray, t: np.ndarray, q: np.ndarray, effects: list | None = None) -> np.ndarray:
        cols = [np.asarray(e.terms(u, t, q), dtype=float).reshape(u.size, -1) for e in (effects or self._effects)]
        return np.concatenate(cols, axis=1) if cols else np.empty((u.size, 0))

    def _reset_effects(self) -> None:
        for e in self._effects:
            e.reset()

    # -- saved state ---------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Settings, reference origin and learned state as plain JSON-serialisable types.

        Effects are saved by name and coefficients; pass equal effect objects to :meth:`from_state`.
        """
        self._ensure_setup()
        params = self._get_params()
        if "effects" in params:
            params["effects"] = [e.name for e in self._effects]
        d: dict[str, Any] = {
            "estimator": type(self).__name__,
            "format": _STATE_FORMAT,
            "params": params,
            "started": self._started,
            "warm_start": dict(self.warm_start_),
        }
        if self._started:
            d["origin"] = {"u_ref": self._st[self._U0], "y_ref": self._st[self._Y0]}
            d["state"] = [float(v) for v in self._st]
            d.update(self._extra_state())
        else:
            # NaN (no torque) is not JSON: saved as None
            d["buffer"] = {k: [bool(v) if k == "gap" else (float(v) if math.isfinite(v) else None) for v in vals] for k, vals in self._buf.items()}
            d["pending_gap"] = self._pending_gap
            d["next_attempt"] = self._next_attempt
            d["attempts"] = self._attempts
        return d

    @classmethod
    def from_state(cls, d: dict[str, Any], effects: Sequence[EffectTerms] | None = None) -> "_RecursiveBase":
        """Rebuild an estimator saved by :meth:`state_dict` (after a restart, without re-learning)."""
        if d.get("estimator") != cls.__name__ or d.get("format") != _STATE_FORMAT:
            raise InvalidParameterError(
                f"not a saved {cls.__name__} state (format {_STATE_FORMAT}): estimator={d.get('estimator')!r}, format={d.get('format')!r}"
            )
        params = dict(d["params"])
        effects = list(effects or [])
        names = params.get("effects", [])
        if [e.name for e in effects] != list(names):
            raise InvalidParameterError(f"the saved state was learned with effects {names}; pass effects with these names")
        if "effects" in params:
            params["effects"] = effects
        est = cls(**params)
        est._setup()
        est._reset_effects()
        est.warm_start_ = dict(d.get("warm_start", {}))
        if d["started"]:
            est._started = True
            est._st = [float(v) for v in d["state"]]
            est._restore_extra(d)
        else:
            est._started = False
            est._buf = {k: [math.nan if v is None else v for v in vals] for k, vals in d["buffer"].items()}
            est._pending_gap = bool(d["pending_gap"])
            est._next_attempt = int(d["next_attempt"])
            est._attempts = int(d["attempts"])
        return est

    @property
    def started(self) -> bool:
        """True once the estimator has started (warm start done, cold start, or resumed state)."""
        return bool(getattr(self, "_started", False))

    def _check_started(self) -> None:
        if not getattr(self, "_started", False):
            raise NotFittedError(
                f"this {type(self).__name__} has not started yet: it is buffering the warm start "
                f"(warm_start_samples={self.warm_start_samples}); learn more samples or call force_start()"
            )

    @property
    def n_samples_seen_(self) -> int:
        """Samples learned so far (including those buffered for the warm start)."""
        if not hasattr(self, "_started"):
            raise NotFittedError(f"this {type(self).__name__} has seen no sample yet")
        return self._n_seen_total()

    @property
    def u_ref_(self) -> float:
        """Reference origin of the input (first input with ``origin="first"``, else 0)."""
        self._check_started()
        return self._st[self._U0]

    @property
    def y_ref_(self) -> float:
        """Reference origin of the output."""
        self._check_started()
        return self._st[self._Y0]

    @property
    def noise_var_(self) -> float:
        """Online estimate of the output noise variance, output units squared."""
        self._check_started()
        return float(self._st[self._NOISE])

    @property
    def residual_rms_(self) -> float:
        """``sqrt(noise_var_)``, output units."""
        return math.sqrt(self.noise_var_)

    @property
    def n_reversals_(self) -> int:
        """Reversals of the input seen so far."""
        self._check_started()
        return int(self._st[self._NREV])


def _finite(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise InvalidParameterError(f"{name} must be finite, got {value!r}")
    return v


class BacklashRLS(_RecursiveBase):
    """Recursive least squares for backlash alone, eq. (8)-(14), that tracks wear.

    Each flank is a straight line kept in coordinates local to its latest operating point,
    ``y = b + m (u - u_ref)``: on a rig the input runs to tens of thousands of degrees, and an
    intercept taken at ``u = 0`` would be a long extrapolation in which a tiny slope error
    swamps the play. Moving ``u_ref`` is an exact reparametrisation of eq. (8), so the
    estimates are those of eq. (11) with ``theta = [mL, mL cL, mR, mR cR]``; ``theta_`` reports
    them in the reference-origin coordinates of the paper.

    The switching functions eq. (12)-(13) are evaluated with the current estimates and, by
    default (``switching="model"``), the model's own output ``x_hat(t-1)`` (eq. 1-3 run with
    the current estimates: on the line of the flank last updated, held in the dead band), as
    in the output-error refinement of the batch estimator, rather than the measured
    ``x(t-1)``. A sample taken while the motor moves inside the model's dead band then updates
    the flank last driven at its last operating point, where eq. (1)'s third case holds the
    load (the output-error gradient; the batch refinement uses those samples too). On a real
    drive the load creeps onto the flank after each reversal (compliance) while a position
    loop jumps the motor through the gap: read through the measured output, those samples
    look like dead band and the flank's line was fitted without them, which made the play
    0.2-0.34 deg (12-20 %) larger than the batch fit on the da Vinci gearhead recordings;
    now 0.8-2.5 % (``docs/benchmarks.md``). With ``phi`` of eq. (8) only one flank is in the
    regressor at a time, so the 4-parameter RLS splits exactly into one 2-parameter RLS per
    flank.

    **Anti-windup** (what the estimator does while the rig idles). Three mechanisms:

    1. *Conditional, per-side updating* (Åström & Wittenmark 1995, ch. 11): a flank is
       updated, and its information forgotten, only on samples where the motor moved into it
       (eq. 12 and ``u`` decreasing for the left flank, eq. 13 and ``u`` increasing for the
       right), or (``switching="model"``) moved inside the dead band after driving it,
       which informs only its intercept at its last operating point. A still motor changes
       nothing.
    2. *Regularised forgetting* (Gunnarsson 1996): information decays towards a floor,
       ``R <- lam R + (1 - lam) R_floor``, so the covariance ``R^-1`` is bounded by
       ``R_floor^-1`` however long the data carry no information in some direction
       (e.g. a motor dithering by one count against a flank: no slope information).
    3. Memory counted in *motion*: per update of a flank (``memory_s``) and per reversal
       (``memory_reversals``), never per wall-clock second.

    Parameters
    ----------
    memory_s : float or None
        Memory in seconds of motion: a flank's information older than ``memory_s`` seconds of
        its own driven motion weighs ``1/e`` (per-update forgetting ``exp(-sample_period_s / memory_s)``).
        None: no such forgetting.
    memory_reversals : float or None
        Memory in reversals: at every change of the driving flank, information weighs
        ``exp(-1 / memory_reversals)`` less. None: no such forgetting. With both None the
        estimator never forgets (growing-window least squares).
    sample_period_s : float
        Sampling period, seconds (converts ``memory_s`` and counts the motion clock).
    start : {"batch", "cold"}
        ``"batch"``: warm start from :class:`VorosBacklash` on the first ``warm_start_samples``
        samples (retried on 2x, 3x, 4x as many if they do not reverse, then a start from the
        direction of motion); the buffered samples are then replayed with the lines held at the
        batch estimate, which gives them the buffer's information.
        ``"cold"``: the paper's start values ``mL = mR = 1, cL = cR = 0.001``.
    warm_start_samples : int
        Samples buffered for the warm start.
    origin : {"first", "zero"}
        Reference origin: ``"first"`` refers ``u`` and ``y`` to their first sample (encoders have
        arbitrary zeros), as the batch estimators' ``origin="first"``; ``"zero"`` takes them as they are.
    min_step_deg : float
        Input steps no larger than this (input units) carry no information (0: any motion counts).
    wear_horizon_s : float
        Time constant, seconds of motion, of the wear-rate tracker used by ``backlash_std_``.
    info_floor : float
        Floor of the information matrix, ``R_floor = info_floor * I`` (per flank, for
        ``[m, b]``); bounds the covariance by ``1 / info_floor`` (times the noise variance).
    noise_window : int
        Updates over which the residual (noise) variance is averaged.
    effects : list of EffectTerms, optional
        Extra regressor columns fitted jointly with the lines (see
        :mod:`online_backlash.effect_terms`); that path runs in Python, also in ``learn_many``.
    switching : {"model", "measured"} or None
        ``x(t-1)`` in eq. (12)-(13): ``"model"``, the model's own output (output-error
        classification); ``"measured"``, the measured output minus the effects (eq. 12-13 as
        printed). None: ``"model"`` without effects, ``"measured"`` with them (effect terms
        such as a delay describe the measured output sample by sample, and the corrected
        measurement classifies the samples around a reversal better: with a delay effect
        ``"model"`` left a 3 % bias in ``tests/test_diagnostics.py``).

    Attributes
    ----------
    m_left_, m_right_ : float
        Slopes of eq. (1).
    c_left_, c_right_ : float
        Distances, input units, from the reference point to the left and right flanks at the
        current output level; they sum to ``backlash_``. The reference point is the reference
        origin (the first sample with ``origin="first"``) carried along the band at the mean
        slope; with equal slopes, or at the origin's level, they are eq. (9)'s ``c1 / m1`` and
        ``c2 / m2``. Over a long run their split is only as good as the slopes (the origin lies
        far away), their sum is not.
    backlash_ : float
        The play: horizontal distance between the flanks at the current output level (equal
        to ``c_left_ + c_right_`` when the slopes are equal), input units.
    backlash_std_ : float
        Its standard error: the covariance of the local lines times the residual variance,
        plus the lag of each flank behind the wear (estimated wear rate times the mean age of
        the flank's information, which grows while the flank sits disengaged).
    theta_ : array, shape (4,)
        ``[mL, mL cL, mR, mR cR]`` of eq. (8) in reference-origin coordinates (extrapolated
        from the local lines: on a long run a tiny slope difference moves ``c1``, ``c2``).
    P_ : array, shape (4, 4)
        Unscaled covariance of ``theta_`` (multiply by ``noise_var_``).
    P_local_ : array, shape (4, 4)
        Unscaled covariance of the local lines ``[mL, bL, mR, bR]``.
    noise_var_, residual_rms_ : float
        Variance and RMS of the a-priori residuals of the updates.
    wear_rate_ : float
        Estimated rate of change of the play, input units per second of motion.
    n_reversals_ : int
        Changes of the driving flank seen.
    n_samples_seen_ : int
    u_ref_, y_ref_ : float
        The reference origin.
    beta_ : array
        Coefficients of the effect terms (empty without effects).
    warm_start_ : dict
        How the estimator started.

    References
    ----------
    J. Vörös, Automatica 46 (2010) 369-374 (eq. 8-14); J. Vörös, ASME J. Dyn. Sys. Meas.
    Control 135(1) 014504 (2013). K. J. Åström and B. Wittenmark, *Adaptive Control*, 2nd ed.,
    Addison-Wesley 1995, ch. 11 (estimator windup, conditional updating). S. Gunnarsson,
    "Combining tracking and regularization in recursive least squares identification",
    Proc. 35th IEEE CDC, 1996.

    Examples
    --------
    >>> from online_backlash import BacklashRLS
    >>> from online_backlash.rig import simulate_rig
    >>> rec = simulate_rig(duration_s=60.0, play_deg=0.5)
    >>> est = BacklashRLS(memory_reversals=20)
    >>> est.learn_many(rec.motor_deg / rec.ratio, rec.load_deg)
    >>> round(est.backlash_, 3)
    0.5
    """

    _U0, _Y0, _FREEZE, _NOISE, _NREV = K.U0, K.Y0, K.K_FREEZE, K.NOISE_VAR, K.N_REV

    def __init__(
        self,
        memory_s: float | None = None,
        memory_reversals: float | None = 10.0,
        sample_period_s: float = 0.001,
        start: str = "batch",
        warm_start_samples: int = 10_000,
        origin: str = "first",
        min_step_deg: float = 0.0,
        wear_horizon_s: float = 120.0,
        info_floor: float = 1e-6,
        noise_window: int = 10_000,
        effects: Sequence[EffectTerms] | None = None,
        switching: str | None = None,
    ) -> None:
        self.memory_s = memory_s
        self.memory_reversals = memory_reversals
        self.sample_period_s = sample_period_s
        self.start = start
        self.warm_start_samples = warm_start_samples
        self.origin = origin
        self.min_step_deg = min_step_deg
        self.wear_horizon_s = wear_horizon_s
        self.info_floor = info_floor
        self.noise_window = noise_window
        self.effects = effects
        self.switching = switching

    def _validate(self) -> None:
        self._validate_common()
        check_real("min_step_deg", self.min_step_deg, 0.0, low_open=False)
        check_real("wear_horizon_s", self.wear_horizon_s, 0.0)
        check_real("info_floor", self.info_floor, 0.0)
        if self.switching is not None:
            check_option("switching", self.switching, _SWITCHING)

    def _switching(self) -> str:
        """``switching``, with None resolved: ``"model"`` without effects, ``"measured"`` with them."""
        if self.switching is not None:
            return self.switching
        return "measured" if self._effects else "model"

    @staticmethod
    def _warm_fit(uc: np.ndarray, yc: np.ndarray, terms: np.ndarray) -> tuple[BacklashParams, int]:
        """:class:`VorosBacklash` on the buffer (reference-origin coordinates; on a rig whose
        slope is not 1 it starts from the direction of motion, its ``start_``), then, with
        effects, its refinement again with the effect columns ``terms`` fitted jointly
        (:func:`_refine_with_effects`).

        An effect left out of the warm start biases the slopes it correlates with: a load-angle
        transmission error of 0.03 deg left ``m_left`` at 1.0005 over a 770 deg stroke, and
        ``backlash_``, read at an output level hundreds of degrees from the origin, 0.28 deg
        (56 %) high (``bench/closing_loop.py --tracker``, seed 0); the recursion, whose replay
        of the buffer had counted its information at the biased lines, did not correct it.
        """
        batch = VorosBacklash(origin="zero").fit(uc, yc)
        if terms.shape[1] == 0:
            return batch.params_, int(batch.n_iter_)
        return _refine_with_effects(uc, yc, terms, batch.params_), int(batch.n_iter_)

    def _cold_params(self, u: np.ndarray | None, y: np.ndarray | None) -> BacklashParams:
        if u is None or u.size < 2:
            return BacklashParams(1.0, 1e-3, 1.0, 1e-3)
        try:
            return _direction_guess(u, y)
        except NotExcitedError:
            return _start_params(u, y)

    def _begin(self, start: BacklashParams) -> None:
        """Set the state from start values (eq. 1 lines through the reference origin) and start."""
        lam, lam_rev = _memory_factors(self.memory_s, self.memory_reversals, self.sample_period_s)
        self._c = [0.0] * K.N_CONSTS
        self._c[K.K_DT] = self.sample_period_s
        self._c[K.K_LAM] = lam
        self._c[K.K_LAM_REV] = lam_rev
        self._c[K.K_FLOOR_M] = self.info_floor
        self._c[K.K_FLOOR_B] = self.info_floor
        self._c[K.K_MIN_STEP] = float(self.min_step_deg)
        self._c[K.K_NOISE_WINDOW] = float(self.noise_window)
        self._c[K.K_WEAR_HORIZON] = float(self.wear_horizon_s)
        self._c[K.K_ORIGIN_FIRST] = 1.0 if self.origin == "first" else 0.0
        self._c[K.K_SWITCH_MODEL] = 1.0 if self._switching() == "model" else 0.0
        self._c_arr = np.asarray(self._c)
        st = [0.0] * K.STATE_SIZE
        st[K.LEFT + K.M] = start.m_left
        st[K.LEFT + K.B] = start.m_left * start.c_left  # line through u_ref = 0: y = mL (u + cL)
        st[K.RIGHT + K.M] = start.m_right
        st[K.RIGHT + K.B] = -start.m_right * start.c_right
        for o in (K.LEFT, K.RIGHT):
            st[o + K.R11] = self.info_floor
            st[o + K.R22] = self.info_floor
        self._st = st
        p = 4 + self._n_effect_terms
        self._R = np.diag(np.full(p, self.info_floor)) if self._effects else None
        self._beta = np.zeros(self._n_effect_terms)
        self._prev_shift = 0.0
        self._started = True

    def _gap_now(self) -> None:
        self._st[K.HAVE_PREV] = 0.0
        self._reset_effects()



    # -- the two paths -------------------------------------------------------------------------
    def _learn_py(self, u: float, y: float, t: float, q: float) -> None:
        if self._effects:
            row = self._effect_terms(np.array([u]), np.array([t]), np.array([q]))[0]
            self._step_effects(u, y, row)
        else:
            K.backlash_step(self._st, self._c, u, y)

    def _learn_arrays(self, u, y, gap, t, q) -> None:
        if self._effects:
            # segment by gap: effects keep a history that a gap must reset
            starts = [0, *np.flatnonzero(gap[1:]) + 1, u.size]
            for lo, hi in zip(starts[:-1], starts[1:]):
                if gap[lo]:
                    self._gap_now()
                rows = self._effect_terms(u[lo:hi], t[lo:hi], q[lo:hi])
                for i in range(lo, hi):
                    self._step_effects(float(u[i]), float(y[i]), rows[i - lo])
            return
        st = np.asarray(self._st, dtype=float)
        K.backlash_run(st, self._c_arr, u, y, gap)
        self._st = st.tolist()

    def _step_effects(self, u: float, y: float, terms: np.ndarray) -> None:
        """The step of :func:`_rls_kernels.backlash_step` with effect columns, jointly (Python, numpy).

        Parameters ``[mL, bL, mR, bR, beta...]`` share one information matrix; forgetting on a
        flank's update scales that flank's and the effects' rows and columns by ``sqrt(lam)``
        (with no effects this is exactly the per-flank step).
        """
        st, c, R = self._st, self._c, self._R
        uc, yc, du, y_prev = K.begin_sample(st, c, u, y)
        if du == 0.0:
            return
        # eq. (12)-(13) on x = y - beta . terms (the backlash output without the effects)
        shift = float(self._beta @ terms)
        prev_shift, self._prev_shift = self._prev_shift, shift
        model = c[K.K_SWITCH_MODEL] != 0.0
        side = K.engaged_side(st, uc, st[K.X_HAT] if model else y_prev - prev_shift, du)
        floor = np.full(R.shape[0], self.info_floor)
        if side == 0:
            if not (model and st[K.HOLD_SIDE] != 0.0):
                return
            side = int(st[K.HOLD_SIDE])  # moving in the dead band: the last flank at its reference
            j = 0 if side == K.LEFT else 2
        else:
            lam_rev = K.reversal(st, c, side, yc - shift)
            if lam_rev != 1.0:
                R *= lam_rev
                R += np.diag((1.0 - lam_rev) * floor)
                for o in (K.LEFT, K.RIGHT):
                    st[o + K.W_COUNT] *= lam_rev
                    st[o + K.W_TIME] *= lam_rev
            j = 0 if side == K.LEFT else 2
            d = K.recenter(st, side, uc)
            # information matrix under b' = b + m d: column/row j <- j - d (j+1)
            R[:, j] -= d * R[:, j + 1]
            R[j, :] -= d * R[j + 1, :]
        lam = c[K.K_LAM]
        idx = np.r_[j, j + 1, 4 : R.shape[0]]
        scale = np.ones(R.shape[0])
        scale[idx] = math.sqrt(lam)
        R *= np.outer(scale, scale)
        R[idx, idx] += (1.0 - lam) * floor[idx]
        st[side + K.W_COUNT] *= lam
        st[side + K.W_TIME] *= lam
        phi = np.zeros(R.shape[0])
        phi[j + 1] = 1.0
        phi[4:] = terms
        e = yc - st[side + K.B] - shift
        K.track_noise(st, c, e)
        R += np.outer(phi, phi)
        if c[K.K_FREEZE] != 0.0:
            # warm-start replay: the lines stay at the batch estimate; the effects learn given them
            if self._beta.size:
                self._beta += np.linalg.solve(R[4:, 4:], phi[4:]) * e
        else:
            delta = np.linalg.solve(R, phi) * e
            st[K.LEFT + K.M] += delta[0]
            st[K.LEFT + K.B] += delta[1]
            st[K.RIGHT + K.M] += delta[2]
            st[K.RIGHT + K.B] += delta[3]
            self._beta += delta[4:]
        st[side + K.W_COUNT] += 1.0
        st[side + K.W_TIME] += st[K.T_MOTION]
        st[side + K.N_UPD] += 1.0
        st[K.X_HAT] = st[side + K.B]
        st[K.HOLD_SIDE] = side

    def _extra_state(self) -> dict[str, Any]:
        if not self._effects:
            return {}
        return {"effects_R": self._R.tolist(), "beta": self._beta.tolist(), "prev_shift": self._prev_shift}

    def _restore_extra(self, d: dict[str, Any]) -> None:
        self._begin_consts_only()
        if self._effects:
            self._R = np.asarray(d["effects_R"], dtype=float)
            self._beta = np.asarray(d["beta"], dtype=float)
            self._prev_shift = float(d["prev_shift"])

    def _begin_consts_only(self) -> None:
        st = self._st
        self._begin(BacklashParams(1.0, 0.0, 1.0, 0.0))
        self._st = st

    # -- prediction ------------------------------------------------------------------------------
    def predict_one(self, u: float, *, time_s: float | None = None, torque_Nm: float | None = None) -> float:
        """One-step-ahead load angle for input ``u``, eq. (1)-(3), from the last measured output.

        Effects (if any) are evaluated on copies, so the stream history is not advanced.
        """
        self._check_started()
        st = self._st
        if st[K.N_SEEN] == 0.0:
            raise NotFittedError("predict_one needs at least one learned sample (the previous output x(t-1))")
        uc = _finite("u", u) - st[K.U0]
        shift = 0.0
        if self._effects:
            t = self._time(time_s)
            q = math.nan if torque_Nm is None else float(torque_Nm)
            rows = self._effect_terms(np.array([u]), np.array([t]), np.array([q]), [copy.deepcopy(e) for e in self._effects])
            shift = float(self._beta @ rows[0])
        x_prev = st[K.Y_PREV] - self._prev_shift
        y_left = st[K.LEFT + K.B] + st[K.LEFT + K.M] * (uc - st[K.LEFT + K.UREF])
        y_right = st[K.RIGHT + K.B] + st[K.RIGHT + K.M] * (uc - st[K.RIGHT + K.UREF])
        if (y_left - x_prev) * st[K.LEFT + K.M] <= 0.0:  # eq. (5)
            x = y_left
        elif (x_prev - y_right) * st[K.RIGHT + K.M] <= 0.0:  # eq. (6)
            x = y_right
        else:
            x = x_prev
        return float(x + shift + st[K.Y0])

    # -- fitted attributes -----------------------------------------------------------------------
    def _lines(self) -> tuple[float, float, float, float, float, float]:
        st = self._st
        return (
            st[K.LEFT + K.M], st[K.LEFT + K.B], st[K.LEFT + K.UREF],
            st[K.RIGHT + K.M], st[K.RIGHT + K.B], st[K.RIGHT + K.UREF],
        )  # fmt: skip

    @property
    def theta_(self) -> np.ndarray:
        """``[mL, mL cL, mR, mR cR]``, eq. (8), in reference-origin coordinates."""
        self._check_started()
        mL, bL, uL, mR, bR, uR = self._lines()
        return np.array([mL, bL - mL * uL, mR, -(bR - mR * uR)])

    def _local_cov(self) -> np.ndarray:
        """Unscaled covariance of ``[mL, bL, mR, bR]`` (local coordinates)."""
        if self._effects:
            return np.linalg.inv(self._R)[:4, :4]
        st = self._st
        R = np.zeros((4, 4))
        for j, o in ((0, K.LEFT), (2, K.RIGHT)):
            R[j : j + 2, j : j + 2] = [[st[o + K.R11], st[o + K.R12]], [st[o + K.R12], st[o + K.R22]]]
        return np.linalg.inv(R)

    @property
    def P_local_(self) -> np.ndarray:
        """Unscaled covariance of the local lines ``[mL, bL, mR, bR]`` (``b`` at each flank's latest operating point)."""
        self._check_started()
        return self._local_cov()

    @property
    def P_(self) -> np.ndarray:
        """Unscaled covariance of ``theta_`` (reference-origin coordinates)."""
        self._check_started()
        _, _, uL, _, _, uR = self._lines()
        T = np.array([[1, 0, 0, 0], [-uL, 1, 0, 0], [0, 0, 1, 0], [0, 0, uR, -1]], dtype=float)
        return T @ self._local_cov() @ T.T

    @property
    def m_left_(self) -> float:
        return float(self.theta_[0])

    @property
    def m_right_(self) -> float:
        return float(self.theta_[2])

    def _flank_split(self) -> tuple[float, float]:
        """Distances from the reference point to the left and right flanks at the current output level.

        The reference point is the reference origin carried along the band at the mean slope,
        ``u* = level / ((mL + mR) / 2)`` (reference-origin coordinates).
        """
        mL, bL, uL, mR, bR, uR = self._lines()
        level = self._st[K.Y_PREV]
        u_star = level / (0.5 * (mL + mR))
        return u_star - (uL + (level - bL) / mL), (uR + (level - bR) / mR) - u_star

    @property
    def c_left_(self) -> float:
        """Distance from the reference point to the left flank (eq. 9's ``c1 / m1`` at the origin's level)."""
        self._check_started()
        return float(self._flank_split()[0])

    @property
    def c_right_(self) -> float:
        """Distance from the reference point to the right flank (eq. 9's ``c2 / m2`` at the origin's level)."""
        self._check_started()
        return float(self._flank_split()[1])

    @property
    def backlash_(self) -> float:
        """Play at the current output level (local lines), input units."""
        self._check_started()
        return float(K.flank_width(self._st, self._st[K.Y_PREV]))

    @property
    def wear_rate_(self) -> float:
        self._check_started()
        return float(self._st[K.W_RATE])

    @property
    def beta_(self) -> np.ndarray:
        self._check_started()
        return self._beta.copy()

    def _flank_ages(self) -> tuple[float, float]:
        """Mean age, seconds of motion, of each flank's information (grows while it is disengaged)."""
        st = self._st
        ages = []
        for o in (K.LEFT, K.RIGHT):
            count = st[o + K.W_COUNT]
            ages.append(st[K.T_MOTION] - st[o + K.W_TIME] / count if count > 0 else 0.0)
        return ages[0], ages[1]

    @property
    def backlash_std_(self) -> float:
        """Standard error of ``backlash_``: noise through the local covariance, plus the lag behind the wear."""
        self._check_started()
        mL, bL, _, mR, bR, _ = self._lines()
        level = self._st[K.Y_PREV]
        # d width / d [mL, bL, mR, bR] with width = uR(level) - uL(level), uX = uref + (level - bX) / mX
        g = np.array([(level - bL) / mL**2, 1.0 / mL, -(level - bR) / mR**2, -1.0 / mR])
        var = self.noise_var_ * float(g @ self._local_cov() @ g)
        age_left, age_right = self._flank_ages()
        lag = abs(self.wear_rate_) * 0.5 * (age_left + age_right)
        return math.sqrt(max(var, 0.0) + lag * lag)


class CascadeRLS(_RecursiveBase):
    """Recursive identification of input backlash followed by a linear system, eq. (18)-(24).

    The regressor of eq. (19) is built from the internal variable ``x_hat`` propagated by
    eq. (23) with the current estimates, and the switching functions of ``t-1`` (eq. 12-13);
    all ``4 + (n_a - 1) + n_b`` parameters share one covariance ``P`` (covariance-form RLS).

    Anti-windup: *conditional updating* (no update once the input has been still for longer
    than the system's memory, ``n_a + n_b + 1`` samples) and a *covariance trace bound*: the
    forgetting factor is raised towards 1 whenever ``trace(P) / lam`` would exceed
    ``trace_max`` (Åström & Wittenmark 1995, ch. 11), so ``P`` stays bounded.

    Limitation: the lines are kept in reference-origin coordinates (the paper's ``theta``),
    not in coordinates local to the operating point as in :class:`BacklashRLS`. The
    intercepts ``c1 = mL cL`` and ``c2 = mR cR`` are therefore read at ``u = 0``: with the input
    at a distance ``U`` from the origin a slope error ``dm`` moves them by about ``dm U``, and
    the regressor columns ``u f1``, ``f1`` become nearly collinear, so ``P`` is badly
    conditioned. (Local coordinates would need the reparametrisation ``b = c + m u_ref``
    applied to ``theta``, to two rows and columns of the shared ``P`` and to the ``x_hat``
    of eq. 23 at every move of the reference; not done.) This estimator is meant for systems
    whose input stays within a few play widths of its origin, like the paper's examples; for
    a rig whose shaft turns many revolutions use :class:`BacklashRLS`.

    Parameters
    ----------
    n_a, n_b : int
        As in :class:`VorosCascade`: ``A = q^-1 + a2 q^-2 + ... + a_{n_a} q^-n_a``, ``B = 1 + b1 q^-1 + ... + b_{n_b} q^-n_b``.
    memory_s, memory_reversals, sample_period_s, start, warm_start_samples, origin, noise_window
        As in :class:`BacklashRLS` (``memory_s`` counts updates, ``memory_reversals`` changes of
        the active flank of ``x_hat``).
    p0 : float
        Initial covariance ``P = p0 I`` after the (warm or cold) start.
    trace_max : float or None
        Bound on ``trace(P)``; None: ``p0`` times the number of parameters.
    regressor : {"prediction_error", "output_error", "equation_error"}
        ``"equation_error"``: eq. (19) as printed, with the measured ``-y(t-j)``.
        ``"output_error"``: the model's own simulated output ``-y_hat(t-j)`` in their
        place, the pseudo-linear regression of the output-error method (Landau 1976; Ljung &
        Söderström 1983, sec. 3.7): measurement noise then does not enter the regressor (the
        equation error of eq. 24 is biased by it, like the batch iteration before its
        output-error refinement).
        ``"prediction_error"`` (default): the recursive prediction-error method for the same
        output error (Ljung & Söderström 1983, sec. 3.8): the gain follows the gradient of
        the model output, the output-error regressor with the sensitivity of ``x_hat`` held
        through the dead band and filtered by ``1 / B(q^-1)``. It minimises the criterion of
        the batch estimator's refinement, where the pseudo-linear regression stops at its own
        fixed point: on the paper's examples 3-5 streamed after a 500-sample warm start it
        lands within 3 % of :class:`VorosCascade` in 30 of 30 runs, against 27 of 30
        (``docs/benchmarks.md``).

    Attributes
    ----------
    m_left_, c_left_, m_right_, c_right_, backlash_, theta_, P_, noise_var_, residual_rms_, n_reversals_, u_ref_, y_ref_
        As in :class:`BacklashRLS`; ``theta_`` is eq. (20) ``[m1, c1, m2, c2, a2.., b1..]``
        (effect coefficients follow), ``backlash_ = c_left_ + c_right_``.
    backlash_std_ : float
        From ``P`` and the residual variance (no wear-lag term).
    a_ : array, shape (n_a,)
        ``[1, a2, ..., a_{n_a}]``.
    b_ : array, shape (n_b,)
        ``[b1, ..., b_{n_b}]``.

    References
    ----------
    J. Vörös, Automatica 46 (2010) 369-374 (eq. 15-24); J. Vörös, ASME J. Dyn. Sys. Meas.
    Control 135(1) 014504 (2013). I. D. Landau, "Unbiased recursive identification using model
    reference adaptive techniques", IEEE Trans. Autom. Control 21(2) (1976) 194-202. L. Ljung and
    T. Söderström, *Theory and Practice of Recursive Identification*, MIT Press 1983.
    K. J. Åström and B. Wittenmark, *Adaptive Control*, 2nd ed., Addison-Wesley 1995, ch. 11.

    Examples
    --------
    >>> import numpy as np
    >>> from online_backlash import CascadeRLS
    >>> from online_backlash.model import BacklashParams, simulate_cascade
    >>> u = np.random.default_rng(3).uniform(-1, 1, 1500)
    >>> y, _ = simulate_cascade(u, BacklashParams(1.3, 0.6, 2.0, 0.7), [0.5], [-0.2, 0.35])
    >>> est = CascadeRLS(memory_reversals=None, origin="zero", warm_start_samples=300)
    >>> est.learn_many(u, y)
    >>> round(est.backlash_, 3), np.round(est.b_, 3)
    (1.3, array([-0.2 ,  0.35]))
    """

    _U0, _Y0, _FREEZE, _NOISE, _NREV = K.CU0, K.CY0, K.Q_FREEZE, K.C_NOISE, K.C_NREV

    def __init__(
        self,
        n_a: int = 2,
        n_b: int = 2,
        memory_s: float | None = None,
        memory_reversals: float | None = 10.0,
        sample_period_s: float = 0.001,
        start: str = "batch",
        warm_start_samples: int = 10_000,
        origin: str = "first",
        p0: float = 1e3,
        trace_max: float | None = None,
        noise_window: int = 10_000,
        regressor: str = "prediction_error",
    ) -> None:
        self.n_a = n_a
        self.n_b = n_b
        self.memory_s = memory_s
        self.memory_reversals = memory_reversals
        self.sample_period_s = sample_period_s
        self.start = start
        self.warm_start_samples = warm_start_samples
        self.origin = origin
        self.p0 = p0
        self.trace_max = trace_max
        self.noise_window = noise_window
        self.regressor = regressor

    def _validate(self) -> None:
        self._validate_common()
        check_int("n_a", self.n_a, 1)
        check_int("n_b", self.n_b, 0)
        check_real("p0", self.p0, 0.0)
        check_option("regressor", self.regressor, ("prediction_error", "output_error", "equation_error"))
        if self.trace_max is not None:
            check_real("trace_max", self.trace_max, 0.0)

    def _warm_fit(self, uc: np.ndarray, yc: np.ndarray, terms: np.ndarray) -> tuple[np.ndarray, int]:
        """:class:`VorosCascade` on the buffer; returns the start ``theta`` of eq. (20).
        ``terms`` has no columns here (CascadeRLS takes no effects)."""
        batch = VorosCascade(n_a=self.n_a, n_b=self.n_b, origin="zero").fit(uc, yc)
        return np.concatenate((batch.params_.theta, batch.a_[1:], batch.b_)), int(batch.n_iter_)

    def _cold_params(self, u: np.ndarray | None, y: np.ndarray | None) -> np.ndarray:
        start = BacklashParams(1.0, 1e-3, 1.0, 1e-3) if u is None or u.size < 2 else _start_params(u, y)
        return np.concatenate((start.theta, np.zeros(self.n_a - 1 + self.n_b)))

    def _begin(self, theta0: np.ndarray) -> None:
        lam, lam_rev = _memory_factors(self.memory_s, self.memory_reversals, self.sample_period_s)
        p_lin = self._p()
        trace_max = float(self.p0 * p_lin if self.trace_max is None else self.trace_max)
        self._c = [
            lam, lam_rev, trace_max, float(self.noise_window), 1.0 if self.origin == "first" else 0.0,
            float(self.n_a), float(self.n_b), 0.0 if self.regressor == "equation_error" else 1.0, 0.0,
            1.0 if self.regressor == "prediction_error" else 0.0,
        ]  # fmt: skip
        self._c_arr = np.asarray(self._c)
        p_, off_p, _, _, size = K.cascade_sizes(self.n_a, self.n_b)
        st = [0.0] * size
        st[K.C_THETA : K.C_THETA + p_lin] = [float(v) for v in theta0]
        for i in range(p_lin):
            st[off_p + i * p_lin + i] = float(self.p0)
        self._st = st
        self._started = True

    def _gap_now(self) -> None:
        self._st[K.C_K] = 0.0

    def _learn_py(self, u: float, y: float, t: float, q: float) -> None:
        p = self._p()
        K.cascade_step(self._st, self._c, u, y, [0.0] * p, [0.0] * p)

    def _learn_arrays(self, u, y, gap, t, q) -> None:
        p = self._p()
        st = np.asarray(self._st, dtype=float)
        K.cascade_run(st, self._c_arr, u, y, gap, np.zeros(p), np.zeros(p))
        self._st = st.tolist()

    def _extra_state(self) -> dict[str, Any]:
        return {}

    def _restore_extra(self, d: dict[str, Any]) -> None:
        st = self._st
        self._begin(np.zeros(self._p()))
        self._st = st

    # -- fitted attributes -----------------------------------------------------------------------
    def _p(self) -> int:
        return 4 + self.n_a - 1 + self.n_b

    @property
    def theta_(self) -> np.ndarray:
        """``[m1, c1, m2, c2, a2.., b1..]`` of eq. (20), reference-origin coordinates."""
        self._check_started()
        p = self._p()
        return np.array(self._st[K.C_THETA : K.C_THETA + p])

    @property
    def P_(self) -> np.ndarray:
        self._check_started()
        p = self._p()
        _, off_p, _, _, _ = K.cascade_sizes(self.n_a, self.n_b)
        return np.array(self._st[off_p : off_p + p * p]).reshape(p, p)

    @property
    def m_left_(self) -> float:
        return float(self.theta_[0])

    @property
    def m_right_(self) -> float:
        return float(self.theta_[2])

    @property
    def c_left_(self) -> float:
        th = self.theta_
        return float(th[1] / th[0])

    @property
    def c_right_(self) -> float:
        th = self.theta_
        return float(th[3] / th[2])

    @property
    def backlash_(self) -> float:
        return self.c_left_ + self.c_right_

    @property
    def a_(self) -> np.ndarray:
        return np.concatenate(([1.0], self.theta_[4 : 4 + self.n_a - 1]))

    @property
    def b_(self) -> np.ndarray:
        return self.theta_[4 + self.n_a - 1 :].copy()


    @property
    def backlash_std_(self) -> float:
        th = self.theta_
        m1, c1, m2, c2 = th[:4]
        g = np.array([-c1 / m1**2, 1.0 / m1, -c2 / m2**2, 1.0 / m2])
        return math.sqrt(max(self.noise_var_ * float(g @ self.P_[:4, :4] @ g), 0.0))

    def predict_one(self, u: float) -> float:
        """One-step-ahead output ``y(t+1)``, eq. (15)-(18), with ``x_hat`` of eq. (23).

        The linear block delays by one sample (``a1 x(t-1)``), so ``y(t+1)`` depends on the
        inputs up to ``t``; ``u``, the input at ``t+1``, is checked but does not enter.
        """
        self._check_started()
        _finite("u", u)
        st = self._st
        if st[K.C_K] == 0.0:
            raise NotFittedError("predict_one needs a learned sample before (the system's history)")
        _, _, ox, oy, _ = K.cascade_sizes(self.n_a, self.n_b)
        a, b = self.a_, self.b_
        out = sum(a[i] * st[ox + i] for i in range(self.n_a))  # x_hat(t), x_hat(t-1), ...
        out -= sum(b[j] * st[oy + j] for j in range(self.n_b))  # y(t), y(t-1), ...
        return float(out + st[K.CY0])
