"""Recursive identification of input backlash followed by a linear system (:class:`CascadeRLS`).

Regressor eq. (19), target eq. (24), internal variable propagated by eq. (23) with the current
estimates: the recursive form of J. Vörös, ASME J. Dyn. Sys. Meas. Control 135(1) 014504,
2013. ``learn_one`` runs :func:`._rls_kernels.cascade_step` in plain Python, ``learn_many``
the same source compiled by numba.

Units: ``u`` and ``y`` share one unit (degrees, load side, in this package); slopes are
dimensionless; ``c_left_``, ``c_right_``, ``backlash_`` are in input units.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import NotFittedError
from ..gap_policy import GapPolicy
from ..model import BacklashParams
from . import _rls_kernels as K
from ._base import RecursiveEstimator, finite, memory_factors
from ._layout import pack
from ._validation import check_int, check_option, check_real
from .batch import VorosCascade, _start_params

CS, QC = K.CS, K.QC


class CascadeRLS(RecursiveEstimator):
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
    memory_s, memory_reversals, sample_period_s, start, warm_start_samples, origin, noise_window, gap_policy
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

    _layout = K.CS
    _consts = K.QC

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
        gap_policy: GapPolicy | None = None,
    ) -> None:
        self.n_a = n_a
        self.n_b = n_b
        self.p0 = p0
        self.trace_max = trace_max
        self.regressor = regressor
        super().__init__(
            memory_s, memory_reversals, sample_period_s, start, warm_start_samples, origin, noise_window, gap_policy
        )

    def _reset_own(self) -> None:
        """No state beside the state vector."""

    def _extra_state(self) -> dict[str, Any]:
        return {}

    def _restore_extra(self, d: dict[str, Any]) -> None:
        """Nothing beside the state vector."""

    def _validate(self) -> None:
        check_int("n_a", self.n_a, 1)
        check_int("n_b", self.n_b, 0)
        check_real("p0", self.p0, 0.0)
        check_option("regressor", self.regressor, ("prediction_error", "output_error", "equation_error"))
        if self.trace_max is not None:
            check_real("trace_max", self.trace_max, 0.0)

    def _warm_fit(self, uc: np.ndarray, yc: np.ndarray, terms: np.ndarray) -> tuple[np.ndarray, int, bool]:
        """:class:`VorosCascade` on the buffer; returns the start ``theta`` of eq. (20).
        ``terms`` has no columns here (CascadeRLS takes no effects)."""
        batch = VorosCascade(n_a=self.n_a, n_b=self.n_b, origin="zero")
        batch.warn_unconverged = False  # told by converged_ (warm_start_)
        batch.fit(uc, yc)
        return np.concatenate((batch.params_.theta, batch.a_[1:], batch.b_)), int(batch.n_iter_), bool(batch.converged_)

    def _cold_params(self, u: np.ndarray | None, y: np.ndarray | None) -> np.ndarray:
        start = BacklashParams(1.0, 1e-3, 1.0, 1e-3) if u is None or y is None or u.size < 2 else _start_params(u, y)
        return np.concatenate((start.theta, np.zeros(self.n_a - 1 + self.n_b)))

    def _offsets(self) -> tuple[int, ...]:
        """:func:`._rls_kernels.cascade_offsets` for this ``n_a``, ``n_b``."""
        return tuple(K.cascade_offsets(self.n_a, self.n_b))

    def _constants(self) -> list[float]:
        lam, lam_rev = memory_factors(self.memory_s, self.memory_reversals, self.sample_period_s)
        p = self._offsets()[0]
        return pack(
            QC, K.N_CASCADE_CONSTS, LAM=lam, LAM_REV=lam_rev,
            TRACE_MAX=self.p0 * p if self.trace_max is None else self.trace_max,
            NOISE_WINDOW=self.noise_window, ORIGIN_FIRST=self.origin == "first", NA=self.n_a, NB=self.n_b,
            OUTPUT_ERROR=self.regressor != "equation_error", PRED_ERROR=self.regressor == "prediction_error",
        )  # fmt: skip

    def _initial_state(self, theta0: np.ndarray) -> list[float]:
        """``theta`` of eq. (20) from the start values, ``P = p0 I``."""
        p, op, *_, size = self._offsets()
        st = [0.0] * size
        st[K.C_THETA : K.C_THETA + p] = [float(v) for v in theta0]
        for i in range(p):
            st[op + i * p + i] = float(self.p0)
        return st

    def _gap_now(self) -> None:
        self._st[CS.K] = 0.0

    def _learn_py(self, u: float, y: float, t: float, q: float) -> None:
        p = self._offsets()[0]
        K.cascade_step(self._st, self._c, u, y, [0.0] * p, [0.0] * p)

    def _learn_arrays(
        self, u: np.ndarray, y: np.ndarray, gap: np.ndarray, t: np.ndarray | None, q: np.ndarray | None
    ) -> None:
        p = self._offsets()[0]
        st = np.asarray(self._st, dtype=float)
        K.cascade_run(st, self._c_arr, u, y, gap, np.zeros(p), np.zeros(p))
        self._st = st.tolist()

    # -- fitted attributes -----------------------------------------------------------------------
    @property
    def theta_(self) -> np.ndarray:
        """``[m1, c1, m2, c2, a2.., b1..]`` of eq. (20), reference-origin coordinates."""
        self._check_started()
        p = self._offsets()[0]
        return np.array(self._st[K.C_THETA : K.C_THETA + p])

    @property
    def P_(self) -> np.ndarray:
        """Unscaled covariance of ``theta_``."""
        self._check_started()
        p, op = self._offsets()[:2]
        return np.array(self._st[op : op + p * p]).reshape(p, p)

    @property
    def c_left_(self) -> float:
        """``c1 / m1`` of eq. (20), input units."""
        th = self.theta_
        return float(th[1] / th[0])

    @property
    def c_right_(self) -> float:
        """``c2 / m2`` of eq. (20), input units."""
        th = self.theta_
        return float(th[3] / th[2])

    @property
    def backlash_(self) -> float:
        """``c_left_ + c_right_``, input units."""
        return self.c_left_ + self.c_right_

    @property
    def a_(self) -> np.ndarray:
        """``[1, a2, ..., a_{n_a}]``."""
        return np.concatenate(([1.0], self.theta_[4 : 4 + self.n_a - 1]))

    @property
    def b_(self) -> np.ndarray:
        """``[b1, ..., b_{n_b}]``."""
        return self.theta_[4 + self.n_a - 1 :].copy()

    @property
    def backlash_std_(self) -> float:
        """Standard error of ``backlash_`` from ``P`` and the residual variance."""
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
        finite("u", u)
        st = self._st
        if st[CS.K] == 0.0:
            raise NotFittedError("predict_one needs a learned sample before (the system's history)")
        _, _, ox, _, oy, *_ = self._offsets()
        a, b = self.a_, self.b_
        out = sum(a[i] * st[ox + i] for i in range(self.n_a))  # x_hat(t), x_hat(t-1), ...
        out -= sum(b[j] * st[oy + j] for j in range(self.n_b))  # y(t), y(t-1), ...
        return float(out + st[CS.Y0])
