"""The batch iterative estimators of Vörös (2010), scikit-learn style.

* :class:`VorosBacklash` identifies backlash alone, eq. (8)-(14).
* :class:`VorosCascade` identifies input backlash followed by a linear system, eq. (19)-(24),
  with the unmeasured internal variable estimated by eq. (23).

Each runs the paper's iteration (the *equation-error* stage: least squares on eq. 14 or 24 with
the switching functions re-evaluated from the previous estimate), then, with ``refine=True``,
a final refinement that minimises the *simulation* (output) error, the model run freely on
the input, with the paper's estimate as the start. The equation error of eq. (14) puts the
noisy ``x(t-1)`` into the regressor (errors in variables), which biases narrow dead bands; the
output error has no such bias. Both stages are kept: ``equation_error_params_`` and the final
``m_left_`` ...

Offsets. Encoders have arbitrary zeros. With ``origin="first"`` (the default) both signals are
referred to their first sample, ``u - u[0]`` and ``y - y[0]``, so a constant offset on either
changes no estimate; ``c_left_`` and ``c_right_`` are then the distances, in input units, from
the starting position to the left and right flanks, and their sum, the play, keeps its
meaning. With ``origin="zero"`` the data are taken as they are (simulations, the paper's
examples, where ``x = 0`` at ``u = 0`` is known).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..errors import ConvergenceWarning, InvalidParameterError, NotExcitedError
from ..model import BacklashParams, linear_filter, simulate_backlash, simulate_switching, switching_functions
from ._validation import check_int, check_is_fitted, check_option, check_real, check_pair, check_reverses

_ORIGINS = ("first", "zero")


@dataclass(frozen=True)
class CascadeParams:
    """Backlash parameters plus the linear block: ``a = [a2..am]`` (``a1 = 1``), ``b = [b1..bn]``."""

    backlash: BacklashParams
    a: tuple[float, ...]
    b: tuple[float, ...]


def _solve(phi: np.ndarray, target: np.ndarray) -> np.ndarray:
    theta, *_ = np.linalg.lstsq(phi, target, rcond=None)
    return theta


def _start_params(u: np.ndarray, y: np.ndarray) -> BacklashParams:
    """The paper's start: ``mL = mR = +-1`` (sign of the input-output correlation), ``cL = cR = 0.001``."""
    sign = 1.0 if np.dot(np.diff(u), np.diff(y)) >= 0 else -1.0
    return BacklashParams(sign, 1e-3, sign, 1e-3)


def _relative_change(new: np.ndarray, old: np.ndarray) -> float:
    return float(np.max(np.abs(new - old) / np.maximum(np.abs(old), 1e-12)))


def _check_sides(f1: np.ndarray, f2: np.ndarray) -> None:
    if f1.sum() < 2 or f2.sum() < 2:
        raise NotExcitedError(
            f"only {int(f1.sum())} samples engage the left flank and {int(f2.sum())} the right "
            "(eq. 5-6 with the current estimate); the data do not excite both sides of the dead band"
        )


class _VorosBase:
    """Shared settings, origin handling and the fitted backlash attributes."""

    def __init__(self, max_iter: int, tol: float, refine: bool, origin: str) -> None:
        self.max_iter = max_iter
        self.tol = tol
        self.refine = refine
        self.origin = origin

    def _validate_params(self) -> None:
        check_int("max_iter", self.max_iter, 1)
        check_real("tol", self.tol, 0.0)
        if not isinstance(self.refine, bool):
            raise InvalidParameterError(f"refine must be a bool, got {self.refine!r}")
        check_option("origin", self.origin, _ORIGINS)

    def _center(self, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.origin == "first":
            self.u_ref_, self.y_ref_ = float(u[0]), float(y[0])
        else:
            self.u_ref_, self.y_ref_ = 0.0, 0.0
        return u - self.u_ref_, y - self.y_ref_

    def _set_backlash(self, params: BacklashParams) -> None:
        self.params_ = params
        self.m_left_ = params.m_left
        self.c_left_ = params.c_left
        self.m_right_ = params.m_right
        self.c_right_ = params.c_right

    @property
    def backlash_(self) -> float:
        """Total play ``c_left_ + c_right_``, input units (degrees for the CLI)."""
        check_is_fitted(self, "params_")
        return self.c_left_ + self.c_right_

    def _iterate(self, step, start):
        """Run the paper's iteration: ``theta_{s+1} = step(theta_s)`` until the relative change < tol."""
        current = start
        history = []
        converged = False
        for _ in range(self.max_iter):
            new = step(current)
            history.append(new)
            if _relative_change(new, current) < self.tol:
                converged = True
                current = new
                break
            current = new
        if not converged:
            warnings.warn(
                f"{type(self).__name__}: no convergence within max_iter={self.max_iter} "
                f"(tol={self.tol}); the last estimate is kept",
                ConvergenceWarning,
                stacklevel=3,
            )
        self.n_iter_ = len(history)
        self.converged_ = converged
        return current, history


class VorosBacklash(_VorosBase):
    """Backlash alone by the paper's iterative least squares, eq. (8)-(14).

    Parameters
    ----------
    max_iter : int
        Most iterations of the equation-error stage.
    tol : float
        Stop when the largest relative change of ``theta`` (eq. 8) between iterations is below this.
    refine : bool
        Finish with a simulation-error refinement from the paper's estimate.
    origin : {"first", "zero"}
        How constant offsets of ``u`` and ``x`` are absorbed (see the module docstring).

    Attributes
    ----------
    m_left_, c_left_, m_right_, c_right_ : float
        Slopes (dimensionless) and dead-band widths (input units) of eq. (1).
    backlash_ : float
        ``c_left_ + c_right_``, the play, input units.
    equation_error_params_ : BacklashParams
        The estimate of the paper's iteration alone.
    history_ : list of BacklashParams
        The estimate after every iteration of the paper's algorithm (its Figs. 4, 6).
    n_iter_ : int
        Iterations of the paper's algorithm.
    residual_rms_ : float
        RMS of the simulation residual ``x - simulate(u)`` on the fitted data, input units.
    u_ref_, y_ref_ : float
        The origin subtracted from the inputs and outputs.

    Examples
    --------
    >>> import numpy as np
    >>> from online_backlash import VorosBacklash
    >>> from online_backlash.model import BacklashParams, simulate_backlash
    >>> u = np.random.default_rng(1).uniform(-1, 1, 800)
    >>> x = simulate_backlash(u, BacklashParams(1.3, 0.5, 2.5, 0.7))
    >>> est = VorosBacklash(origin="zero").fit(u, x)
    >>> round(est.m_left_, 6), round(est.c_left_, 6), round(est.m_right_, 6), round(est.c_right_, 6)
    (1.3, 0.5, 2.5, 0.7)
    """

    def __init__(self, max_iter: int = 50, tol: float = 1e-4, refine: bool = True, origin: str = "first") -> None:
        super().__init__(max_iter, tol, refine, origin)

    def fit(self, u: np.ndarray, x: np.ndarray) -> "VorosBacklash":
        """Fit eq. (1) to input ``u`` and output ``x`` (same units, e.g. degrees).

        Raises
        ------
        NotExcitedError
            When ``u`` never reverses or one flank is never engaged.
        """
        self._validate_params()
        u, x = check_pair(u, x)
        check_reverses(u)
        uc, xc = self._center(u, x)
        u_t, x_t, x_prev = uc[1:], xc[1:], xc[:-1]

        def step(theta: np.ndarray) -> np.ndarray:
            # eq. (12)-(13): switching functions from the s-th estimate and the measured x(t-1)
            f1, f2 = switching_functions(u_t, x_prev, BacklashParams.from_theta(theta))
            _check_sides(f1, f2)
            active = (f1 + f2) > 0
            phi = np.column_stack((u_t * f1, f1, u_t * f2, -f2))  # eq. (8)
            target = x_t - x_prev * (1 - f1) * (1 - f2)  # left side of eq. (11)
            return _solve(phi[active], target[active])  # eq. (14), least squares

        theta, history = self._iterate(step, _start_params(uc, xc).theta)
        self.history_ = [BacklashParams.from_theta(t) for t in history]
        self.equation_error_params_ = BacklashParams.from_theta(theta)
        params = self.equation_error_params_
        if self.refine:
            params = self._refine(uc, xc, params)
        self._set_backlash(params)
        self.residual_rms_ = float(np.sqrt(np.mean((xc - self._simulate(uc, params, xc[0])) ** 2)))
        return self

    @staticmethod
    def _simulate(uc: np.ndarray, params: BacklashParams, x_start: float) -> np.ndarray:
        x = np.empty_like(uc)
        x[0] = x_start
        x[1:] = simulate_backlash(uc[1:], params, x_start)
        return x

    def _refine(self, uc: np.ndarray, xc: np.ndarray, start: BacklashParams) -> BacklashParams:
        """Minimise the simulation error over ``[mL, cL, mR, cR]`` from the paper's estimate."""

        def residual(p: np.ndarray) -> np.ndarray:
            if p[0] * p[2] <= 0 or p[1] + p[3] < 0:
                return np.full(uc.size, 1e6)
            return xc - self._simulate(uc, BacklashParams(*p), xc[0])

        p0 = np.array([start.m_left, start.c_left, start.m_right, start.c_right])
        result = least_squares(residual, p0, x_scale="jac", diff_step=1e-6)
        self.refine_nfev_ = int(result.nfev)
        better = np.sum(result.fun**2) < np.sum(residual(p0) ** 2)
        return BacklashParams(*result.x) if better else start

    def predict(self, u: np.ndarray, x0: float | None = None) -> np.ndarray:
        """Simulate the fitted backlash on ``u`` (input units), eq. (1)-(3).

        ``x0`` is the output before the first sample, in the caller's frame; by default the
        model starts at rest at the origin (``x = y_ref_``).
        """
        check_is_fitted(self, "params_")
        u = np.asarray(u, dtype=float)
        x_start = 0.0 if x0 is None else float(x0) - self.y_ref_
        return simulate_backlash(u - self.u_ref_, self.params_, x_start) + self.y_ref_


class VorosCascade(_VorosBase):
    """Input backlash followed by a linear system, eq. (15)-(24), with the internal variable by eq. (23).

    The linear block is ``B(q^-1) y = A(q^-1) x`` with ``A = q^-1 + a2 q^-2 + ... + am q^-m``
    (``a1 = 1``, the key-term separation of eq. 18) and ``B = 1 + b1 q^-1 + ... + bn q^-n``.

    Parameters
    ----------
    n_a : int
        ``m``, the number of ``A`` coefficients including ``a1 = 1`` (so ``n_a - 1`` are estimated).
    n_b : int
        ``n``, the number of ``B`` coefficients ``b1..bn``.
    max_iter, tol, refine, origin
        As in :class:`VorosBacklash`. With ``origin="first"`` the system is taken to start at rest.

    Attributes
    ----------
    m_left_, c_left_, m_right_, c_right_, backlash_, equation_error_params_, n_iter_, u_ref_, y_ref_
        As in :class:`VorosBacklash`.
    a_ : array, shape (n_a,)
        ``[1, a2, ..., am]``.
    b_ : array, shape (n_b,)
        ``[b1, ..., bn]``.
    history_ : list of CascadeParams
        The estimate after every iteration (the paper's Figs. 8, 10, 12).
    residual_rms_ : float
        RMS of the simulation residual ``y - simulate(u)``, output units.
    """

    def __init__(
        self,
        n_a: int = 2,
        n_b: int = 2,
        max_iter: int = 50,
        tol: float = 1e-4,
        refine: bool = True,
        origin: str = "first",
    ) -> None:
        super().__init__(max_iter, tol, refine, origin)
        self.n_a = n_a
        self.n_b = n_b

    def _split(self, theta: np.ndarray) -> CascadeParams:
        k = self.n_a - 1
        return CascadeParams(BacklashParams.from_theta(theta[:4]), tuple(theta[4 : 4 + k]), tuple(theta[4 + k :]))

    def fit(self, u: np.ndarray, y: np.ndarray) -> "VorosCascade":
        """Fit the cascade to input ``u`` and output ``y``."""
        self._validate_params()
        check_int("n_a", self.n_a, 1)
        check_int("n_b", self.n_b, 0)
        u, y = check_pair(u, y)
        check_reverses(u)
        uc, yc = self._center(u, y)
        m, n = self.n_a, self.n_b
        start_t = max(m, n, 2)
        t = np.arange(start_t, uc.size)

        def step(theta: np.ndarray) -> np.ndarray:
            params = BacklashParams.from_theta(theta[:4])
            # eq. (23): internal variable and switching functions with the s-th estimate
            x_hat, f1, f2 = simulate_switching(uc, params, 0.0)
            f1p, f2p, up = f1[t - 1], f2[t - 1], uc[t - 1]
            _check_sides(f1p, f2p)
            cols = [up * f1p, f1p, up * f2p, -f2p]  # eq. (19), backlash part
            cols += [x_hat[t - i] for i in range(2, m + 1)]
            cols += [-yc[t - j] for j in range(1, n + 1)]
            target = yc[t] - x_hat[t - 2] * (1 - f1p) * (1 - f2p)  # eq. (24)
            return _solve(np.column_stack(cols), target)

        theta0 = np.concatenate((_start_params(uc, yc).theta, np.zeros(m - 1 + n)))
        theta, history = self._iterate(step, theta0)
        self.history_ = [self._split(h) for h in history]
        start = self._split(theta)
        self.equation_error_params_ = start.backlash
        final = self._refine(uc, yc, start) if self.refine else start
        self._set_backlash(final.backlash)
        self.a_ = np.concatenate(([1.0], final.a))
        self.b_ = np.asarray(final.b, dtype=float)
        self.equation_error_a_ = np.concatenate(([1.0], start.a))
        self.equation_error_b_ = np.asarray(start.b, dtype=float)
        self.residual_rms_ = float(np.sqrt(np.mean((yc - self._simulate(uc, final)) ** 2)))
        return self

    @staticmethod
    def _simulate(uc: np.ndarray, p: CascadeParams) -> np.ndarray:
        return linear_filter(simulate_backlash(uc, p.backlash, 0.0), np.asarray(p.a), np.asarray(p.b))

    def _refine(self, uc: np.ndarray, yc: np.ndarray, start: CascadeParams) -> CascadeParams:
        """Minimise the simulation (output) error over all parameters from the paper's estimate."""
        k = self.n_a - 1

        def unpack(v: np.ndarray) -> CascadeParams:
            return CascadeParams(BacklashParams(*v[:4]), tuple(v[4 : 4 + k]), tuple(v[4 + k :]))

        def residual(v: np.ndarray) -> np.ndarray:
            if v[0] * v[2] <= 0 or v[1] + v[3] < 0 or not _stable(v[4 + k :]):
                return np.full(uc.size, 1e6)
            return yc - self._simulate(uc, unpack(v))

        b = start.backlash
        v0 = np.array([b.m_left, b.c_left, b.m_right, b.c_right, *start.a, *start.b])
        if not np.all(np.isfinite(residual(v0))) or np.all(residual(v0) == 1e6):
            return start
        result = least_squares(residual, v0, x_scale="jac", diff_step=1e-6)
        self.refine_nfev_ = int(result.nfev)
        better = np.sum(result.fun**2) < np.sum(residual(v0) ** 2)
        return unpack(result.x) if better else start

    def predict(self, u: np.ndarray) -> np.ndarray:
        """Simulate the fitted cascade on ``u`` from rest, output units, eq. (15)-(18)."""
        check_is_fitted(self, "params_")
        p = CascadeParams(self.params_, tuple(self.a_[1:]), tuple(self.b_))
        return self._simulate(np.asarray(u, dtype=float) - self.u_ref_, p) + self.y_ref_


def _stable(b: np.ndarray) -> bool:
    """True when ``B(q^-1) = 1 + b1 q^-1 + ...`` has all roots inside the unit circle."""
    if len(b) == 0:
        return True
    return bool(np.all(np.abs(np.roots(np.concatenate(([1.0], b)))) < 1.0))
