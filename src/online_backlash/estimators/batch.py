"""The batch iterative estimators of Vörös (2010), scikit-learn style.

* :class:`VorosBacklash` identifies backlash alone, eq. (8)-(14).
* :class:`VorosCascade` identifies input backlash followed by a linear system, eq. (19)-(24),
  with the unmeasured internal variable estimated by eq. (23).

Each runs the paper's iteration (the *equation-error* stage: least squares on eq. 14 or 24 with
the switching functions re-evaluated from the previous estimate), then, with ``refine=True``,
a final refinement that minimises the *simulation* (output) error, the model run freely on
the input, with the paper's estimate as the start. The equation error of eq. (14) puts the
noisy ``x(t-1)`` into the regressor and into the switching functions (errors in variables); the
output error is the least-squares (maximum-likelihood, for white Gaussian output noise)
criterion of the model itself, and on the paper's examples it scatters less, most visibly for
the narrow dead bands of examples 2 and 4 (``docs/paper-examples.md``). It is minimised by
Gauss-Newton with the analytic Jacobian of the simulation, the switching pattern held fixed
(:func:`~online_backlash.model.backlash_sensitivity`). Both stages are kept:
``equation_error_params_`` and the final ``m_left_`` ...

The paper leaves the stopping rule open; the one used here (``tol`` standard errors from the
previous estimate, or from an earlier one when the iteration cycles) is described in
:meth:`_VorosBase._iterate`.

Full engagement (issue 27). ``VorosBacklash(full_engagement=True)`` fits the flank lines only where the
data show the flanks fully engaged: a drive whose gap is crossed in two steps (a train of two stages, a
load torque holding the load across part of the gap) has samples of a partial crossing, on neither flank
line (:class:`~.full_engagement.FullEngagement`); they are left out of eq. (14) and of the refinement's
criterion (the model still runs through them), and the play is read where the flanks were fully engaged.
The paper's examples and :mod:`online_backlash.diagnostics` keep every sample (the default).

Offsets. With ``origin="zero"`` (the default) the data are fitted as given: ``c_left_`` and
``c_right_`` are eq. (1)'s, in the input's own coordinates (simulations, the paper's examples,
where ``x = 0`` at ``u = 0`` is known). Encoders have arbitrary zeros: with ``origin="first"``
(what the CLI uses) both signals are referred to their first sample, ``u - u[0]`` and
``y - y[0]``, so a constant offset on either changes no estimate; ``c_left_`` and ``c_right_``
are then the distances, in input units, from the starting position to the left and right
flanks, and their sum, the play, keeps its meaning.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..errors import ConvergenceWarning, InvalidParameterError, NotExcitedError
from ..model import (
    BacklashParams,
    backlash_sensitivity,
    linear_filter,
    simulate_backlash,
    simulate_switching,
    switching_at,
)
from .full_engagement import NO_FLANK, FullEngagement
from .uncertainty import KinematicPlayScatter, PlayUncertainty
from .validation import check_int, check_is_fitted, check_option, check_pair, check_real, check_reverses

_ORIGINS = ("first", "zero")


@dataclass(frozen=True)
class CascadeParams:
    """Backlash parameters plus the linear block: ``a = [a2..am]`` (``a1 = 1``), ``b = [b1..bn]``."""

    backlash: BacklashParams
    a: tuple[float, ...]
    b: tuple[float, ...]


@dataclass(frozen=True)
class _Step:
    """One iteration of the paper's algorithm: the new estimate and its standard errors."""

    theta: np.ndarray
    se: np.ndarray


def _solve(phi: np.ndarray, target: np.ndarray) -> _Step:
    """Least squares of eq. (14) or (24) and the standard error of every parameter.

    The standard errors are the usual ``sqrt(diag(sigma^2 (Phi^T Phi)^-1))`` with
    ``sigma^2 = RSS / (rows - columns)``; they set the scale of the stopping rule.
    """
    theta, inv_diag = _normal_equations(phi, target)
    resid = target - phi @ theta
    return _with_errors(theta, inv_diag, _inner(resid, resid), phi.shape[0], phi.shape[1])


def _with_errors(theta: np.ndarray, inv_diag: np.ndarray, rss: float, rows: int, columns: int) -> _Step:
    """The :class:`_Step` of ``theta`` with ``sigma^2 = rss / (rows - columns)`` times ``inv_diag``, the
    diagonal of ``(Phi^T Phi)^+``."""
    sigma2 = rss / max(rows - columns, 1)
    return _Step(theta, np.sqrt(np.maximum(sigma2 * inv_diag, 0.0)))


def _inner(a: np.ndarray, b: np.ndarray) -> float:
    """``sum(a * b)`` of two 1-D arrays without BLAS: OpenBLAS's threaded ``ddot`` took 16 ms for
    20 000 samples here (0.01 ms this way) while other processes held the cores."""
    return float(np.einsum("i,i->", a, b))


def _normal_equations(phi: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares ``min |phi theta - target|`` by column-scaled normal equations (:func:`_gram_solution`)."""
    return _gram_solution(phi.T @ phi, phi.T @ target)


def _gram_solution(gram: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``theta`` of the normal equations ``gram theta = rhs`` (``gram = phi^T phi``, ``rhs = phi^T
    target``) and the diagonal of ``gram^+``.

    With 4-8 columns the Gram matrix is tiny, and scaling every column to unit norm keeps it well
    conditioned even when ``u`` spans thousands of degrees. (LAPACK's tall least squares was up to
    100 times slower here on a loaded machine, where OpenBLAS threads compete for the cores.) A
    rank-deficient ``phi`` gets the least-norm answer, as ``numpy.linalg.lstsq`` would give.
    """
    scale = np.sqrt(np.diag(gram).copy())
    scale[scale == 0] = 1.0
    gram_inv = np.linalg.pinv(gram / np.outer(scale, scale))
    theta = gram_inv @ (rhs / scale) / scale
    return theta, np.diag(gram_inv) / scale**2


def _equation_error_step(
    u_t: np.ndarray, x_prev: np.ndarray, x_t: np.ndarray, params: BacklashParams, kept: np.ndarray | None = None
) -> _Step:
    """One step of the paper's iteration for backlash, eq. (12)-(14): the switching functions from
    ``params`` and the measured ``x(t-1)``, then the least squares of eq. (14) over the ``kept`` samples
    (all by default) with a flank engaged, with the standard errors of :func:`_solve`; two compiled passes
    over the samples (:func:`_eq14_normal_equations`, :func:`_eq14_rss`), no ``n x 4`` regressor formed."""
    kept = np.ones(u_t.size, dtype=np.bool_) if kept is None else kept
    gram, rhs = np.zeros((4, 4)), np.zeros(4)
    p = (params.m_left, params.c_left, params.m_right, params.c_right)
    left, right, rows = _eq14_normal_equations(u_t, x_prev, x_t, kept, *p, gram, rhs)
    _check_sides(left, right)
    theta, inv_diag = _gram_solution(gram, rhs)
    return _with_errors(theta, inv_diag, _eq14_rss(u_t, x_prev, x_t, kept, *p, theta), rows, 4)


@njit(cache=True)
def _eq14_normal_equations(u, x_prev, x, kept, mL, cL, mR, cR, gram, rhs):  # pragma: no cover - compiled
    """``gram += phi^T phi`` and ``rhs += phi^T target`` over the ``kept`` samples with ``f1 + f2 > 0``, with
    ``phi = [u f1, f1, u f2, -f2]`` (eq. 8) and ``target = x - x_prev (1 - f1)(1 - f2)`` (left side of
    eq. 11), ``f1``, ``f2`` of eq. (5)-(6) from ``x_prev`` as :func:`~online_backlash.model.switching_functions`
    evaluates them (:func:`~online_backlash.model.switching_at`); returns the samples with ``f1`` set,
    with ``f2`` set, and with either (the rows)."""
    left = 0
    right = 0
    rows = 0
    row = np.empty(4)
    for t in range(u.size):
        f1, f2 = switching_at(u[t], x_prev[t], mL, cL, mR, cR)
        if f1 + f2 == 0 or not kept[t]:
            continue
        left += f1 > 0
        right += f2 > 0
        rows += 1
        row[0], row[1], row[2], row[3] = u[t] * f1, f1, u[t] * f2, -f2
        target = x[t] - x_prev[t] * (1 - f1) * (1 - f2)
        for i in range(4):
            rhs[i] += row[i] * target
            for j in range(4):
                gram[i, j] += row[i] * row[j]
    return left, right, rows


@njit(cache=True)
def _eq14_rss(u, x_prev, x, kept, mL, cL, mR, cR, theta):  # pragma: no cover - compiled
    """The residual sum of squares of eq. (14) at ``theta`` over the samples of :func:`_eq14_normal_equations`."""
    rss = 0.0
    for t in range(u.size):
        f1, f2 = switching_at(u[t], x_prev[t], mL, cL, mR, cR)
        if f1 + f2 == 0 or not kept[t]:
            continue
        e = (
            x[t]
            - x_prev[t] * (1 - f1) * (1 - f2)
            - (theta[0] * u[t] * f1 + theta[1] * f1 + theta[2] * u[t] * f2 - theta[3] * f2)
        )
        rss += e * e
    return rss


def _start_params(u: np.ndarray, y: np.ndarray) -> BacklashParams:
    """The paper's start: ``mL = mR = +-1`` (sign of the input-output correlation), ``cL = cR = 0.001``."""
    sign = 1.0 if _inner(np.diff(u), np.diff(y)) >= 0 else -1.0
    return BacklashParams(sign, 1e-3, sign, 1e-3)


def _direction_guess(u: np.ndarray, y: np.ndarray, kept: np.ndarray | None = None) -> BacklashParams:
    """Start lines from the direction of motion alone (no switching functions).

    A sample is taken as engaged when input and output move together (``du dy`` of the sign of
    the overall correlation): on the right flank when ``u`` rises, on the left when it falls.
    One least-squares fit ``y = m u + b_side`` gives a common slope and the two intercepts, so
    the lines pass through the data of each flank whatever the slope. ``kept``: the samples that
    may count (not a partial crossing of the gap; all by default).
    """
    du, dy = np.diff(u), np.diff(y)
    sign = 1.0 if _inner(du, dy) >= 0 else -1.0
    moving = du * dy * sign > 0
    if kept is not None:
        moving &= kept[1:]
    right = moving & (du > 0)
    left = moving & (du < 0)
    if right.sum() < 2 or left.sum() < 2:
        raise NotExcitedError(
            f"input and output move together on {int(right.sum())} samples with the input rising "
            f"and {int(left.sum())} with it falling; both flanks need at least 2"
        )
    sel = right | left
    X = np.column_stack((u[1:][sel], right[sel], left[sel])).astype(float)
    (m, b_right, b_left), _ = _normal_equations(X, y[1:][sel])
    if m == 0:
        raise NotExcitedError("the output does not follow the input (zero slope) while both move")
    return BacklashParams(m, b_left / m, m, -b_right / m)


def _engaged_level(u: np.ndarray, y: np.ndarray, kept: np.ndarray) -> float:
    """The output level midway between the centroids of the samples on each flank (input and output moving
    together, the ``kept`` ones): where the two lines are best placed, the play read there."""
    du, dy = np.diff(u), np.diff(y)
    moving = (du * dy * (1.0 if _inner(du, dy) >= 0 else -1.0) > 0) & kept[1:]
    levels = [y[1:][moving & side] for side in (du > 0, du < 0)]
    return 0.5 * sum(float(np.mean(v)) for v in levels) if all(v.size for v in levels) else 0.0


def _check_sides(left: int, right: int) -> None:
    """Both flanks engaged by at least two samples (``left``, ``right``: the samples with ``f1``, ``f2`` set)."""
    if left < 2 or right < 2:
        raise NotExcitedError(
            f"only {left} samples engage the left flank and {right} the right "
            "(eq. 5-6 with the current estimate); the data do not excite both sides of the dead band"
        )


_RESOLUTION = float(np.sqrt(np.finfo(float).eps))  # relative change below which theta has converged


class _VorosBase:
    """Shared settings, origin handling and the fitted backlash attributes.

    ``warn_unconverged`` (True) may be set False on an instance: an iteration stopped at ``max_iter``
    is then told by ``converged_`` alone, without a ConvergenceWarning. The recursive estimators'
    warm start does so; catching the warning instead (``warnings.catch_warnings``) would change the
    process's warnings settings, which every thread shares, and swallow another thread's warnings.
    """

    #: Issue a ConvergenceWarning when the iteration stops at ``max_iter``.
    warn_unconverged = True

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

    def estimates(self, stage: str = "final") -> dict[str, float]:
        """The fitted parameters by name: ``m_left, c_left, m_right, c_right`` and, for a cascade,
        ``a2..am, b1..bn``.

        ``stage="equation_error"`` gives the paper's iteration alone, ``"final"`` the fitted
        attributes (after the refinement when ``refine=True``). The keys match
        :meth:`online_backlash.model.PaperExample.parameters`.
        """
        check_is_fitted(self, "params_")
        check_option("stage", stage, ("final", "equation_error"))
        p = getattr(self, "params_" if stage == "final" else "equation_error_params_")
        out = {name: float(getattr(p, name)) for name in ("m_left", "c_left", "m_right", "c_right")}
        if hasattr(self, "a_"):
            a, b = (
                getattr(self, f"{prefix}{k}_")
                for k in ("a", "b")
                for prefix in ["" if stage == "final" else "equation_error_"]
            )
            out.update({f"a{i}": float(v) for i, v in enumerate(a[1:], start=2)})
            out.update({f"b{j}": float(v) for j, v in enumerate(b, start=1)})
        return out

    @property
    def backlash_(self) -> float:
        """Total play ``c_left_ + c_right_``, input units (degrees for the CLI)."""
        check_is_fitted(self, "params_")
        return self.c_left_ + self.c_right_

    def _iterate(self, step: Callable[[np.ndarray], _Step], start: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """Run the paper's iteration ``theta_{s+1} = step(theta_s)``, steps (a)-(c) after eq. (14).

        Stopping rule (the paper leaves it open): stop after the first iteration whose estimate
        is within ``tol`` standard errors of the one before, ``|theta_{s+1} - theta_s| <= tol *
        se(theta_{s+1})`` element-wise (``stop_reason_ = "tol"``), or of any earlier one
        (``"cycle"``). Further iterations then change the estimate by far less than the noise
        already does (``docs/paper-examples.md`` compares with running on). The second case
        exists because the switching functions are discrete: the iteration can settle into a
        cycle of two or three switching patterns that it never leaves; for backlash alone a
        repeated pattern repeats ``theta`` exactly. The last estimate is kept. On noise-free
        data the standard errors shrink with the steps (the cascade iteration converges
        geometrically), so a floor of ``sqrt(machine epsilon) * |theta|`` ends it there.
        """
        current = start
        history: list[np.ndarray] = []
        self.stop_reason_ = "max_iter"
        for _ in range(self.max_iter):
            result = step(current)
            # tol standard errors, and never below what double precision can resolve
            limit = self.tol * result.se + _RESOLUTION * np.abs(result.theta)
            if np.all(np.abs(result.theta - current) <= limit):
                self.stop_reason_ = "tol"
            elif any(np.all(np.abs(result.theta - old) <= limit) for old in history[:-1]):
                self.stop_reason_ = "cycle"
            history.append(result.theta)
            current = result.theta
            if self.stop_reason_ != "max_iter":
                break
        self.n_iter_ = len(history)
        self.converged_ = self.stop_reason_ != "max_iter"
        if not self.converged_ and self.warn_unconverged:
            warnings.warn(
                f"{type(self).__name__}: no convergence within max_iter={self.max_iter} "
                f"(tol={self.tol} standard errors); the last estimate is kept",
                ConvergenceWarning,
                stacklevel=3,
            )
        return current, history


class VorosBacklash(_VorosBase):
    """Backlash alone by the paper's iterative least squares, eq. (8)-(14).

    Parameters
    ----------
    max_iter : int
        Most iterations of the equation-error stage.
    tol : float
        Stopping rule of the paper's iteration: stop once no parameter of ``theta`` (eq. 8)
        moved by more than ``tol`` of its standard error in the last iteration (or the
        estimate came back that close to an earlier one; see :meth:`_VorosBase._iterate`). ``0.1`` is a tenth of a
        standard error: later iterations can't change the estimate by more than its noise.
    refine : bool
        Finish with a simulation-error refinement from the paper's estimate.
    origin : {"first", "zero"}
        How constant offsets of ``u`` and ``x`` are absorbed (see the module docstring).
    full_engagement : bool
        Fit the flank lines only where the data show the flanks fully engaged: the samples of a partial
        crossing of the gap (:class:`~.full_engagement.FullEngagement`, issue 27) are left out of eq. (14),
        of the refinement's criterion and of the per-reversal plays. False: every sample, as the paper.

    Attributes
    ----------
    m_left_, c_left_, m_right_, c_right_ : float
        Slopes (dimensionless) and dead-band widths (input units) of eq. (1).
    backlash_ : float
        The play, input units: ``c_left_ + c_right_``, or with ``full_engagement`` the flanks' distance at
        ``play_level_``.
    partial_ : array of bool
        The samples left out as partial crossings (all False without ``full_engagement``).
    play_level_ : float
        The output level (from the origin) the play is read at: 0 (the origin's), or with ``full_engagement``
        midway between the centroids of the samples fitted on each flank.
    equation_error_params_ : BacklashParams
        The estimate of the paper's iteration alone.
    history_ : list of BacklashParams
        The estimate after every iteration of the paper's algorithm (its Figs. 4, 6).
    n_iter_ : int
        Iterations of the paper's algorithm.
    converged_ : bool
        False when the iteration stopped at ``max_iter`` (a ConvergenceWarning was issued, unless
        ``warn_unconverged`` was set False on the instance).
    stop_reason_ : {"tol", "cycle", "max_iter"}
        Why the iteration stopped.
    start_ : {"paper", "direction"}
        Where the iteration started (see Notes).
    refine_nfev_ : int
        Simulations run by the refinement (when ``refine=True``).
    residual_rms_ : float
        RMS of the simulation residual ``x - simulate(u)`` on the fitted data (the samples not left out),
        input units.
    backlash_std_ : float
        Standard error of ``backlash_``, input units: the scatter of the play over the reversal
        cycles and the model misfit, never below the white-noise standard error
        (:mod:`~online_backlash.estimators.uncertainty`; the parts in ``uncertainty_``); with
        ``full_engagement`` the misfit includes what the samples left out would take off the play
        (``uncertainty_.engagement_deg``).
    backlash_white_std_ : float
        The least-squares standard error of ``backlash_`` for white output noise:
        ``sqrt(g^T (J^T J)^-1 g RSS / (n - 4))`` with ``J`` the Jacobian of the simulation and
        ``g = [0, 1, 0, 1]`` (at ``play_level_ = L``: ``[L / mL^2, 1, -L / mR^2, 1]``).
    cycle_plays_ : array
        The play of every reversal (:class:`~online_backlash.estimators.uncertainty.CyclePlays`).
    uncertainty_ : PlayUncertainty
        The parts of ``backlash_std_``.
    u_ref_, y_ref_ : float
        The origin subtracted from the inputs and outputs.

    Notes
    -----
    Start. The iteration starts from the paper's values, ``mL = mR = +-1``, ``cL = cR = 0.001``
    (``start_ = "paper"``). On a rig whose slope is not 1 (a gear ratio off its nominal value)
    the data drift away from those lines over a long stroke: with ``u`` running 280 deg one way
    at slope 0.97 they end 8 deg below the start line, every sample falls on one flank, and
    eq. (12)-(13) leave the other empty. When the paper's start engages fewer than 2 samples
    on a side, or leads to a zero slope or slopes of opposite sign (eq. 9), the iteration is
    run again from lines fitted to the direction of motion (``start_ = "direction"``): samples
    where input and output move together, rising ``u`` on the right flank and falling ``u``
    on the left, give one least-squares slope and an intercept per flank, so each line passes
    through its flank's data. Where the paper's start works it is kept, and so are the
    paper's iteration counts. When neither start engages both flanks (a stretch that barely
    moves one way), :class:`~online_backlash.errors.NotExcitedError` says so with the counts.

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

    def __init__(
        self,
        max_iter: int = 50,
        tol: float = 0.1,
        refine: bool = True,
        origin: str = "zero",
        full_engagement: bool = False,
    ) -> None:
        super().__init__(max_iter, tol, refine, origin)
        self.full_engagement = full_engagement

    def fit(self, u: np.ndarray, x: np.ndarray) -> VorosBacklash:
        """Fit eq. (1) to input ``u`` and output ``x`` (same units, e.g. degrees).

        Raises
        ------
        NotExcitedError
            When ``u`` never reverses or one flank is never engaged (from either start, see Notes).
        """
        self._validate_params()
        if not isinstance(self.full_engagement, bool):
            raise InvalidParameterError(f"full_engagement must be a bool, got {self.full_engagement!r}")
        u, x = check_pair(u, x)
        check_reverses(u)
        uc, xc = self._center(u, x)
        u_t, x_t, x_prev = uc[1:], xc[1:], xc[:-1]
        judge = FullEngagement()
        self.partial_ = judge.fit(uc, xc) == NO_FLANK if self.full_engagement else np.zeros(uc.size, dtype=bool)
        self._engagement_std = judge.engagement_std_deg_ if self.full_engagement else 0.0
        kept = ~self.partial_

        def step(theta: np.ndarray) -> _Step:
            # eq. (12)-(14): switching functions from the s-th estimate (a negative dead band taken at
            # zero: BacklashParams.feasible) and the measured x(t-1), least squares
            return _equation_error_step(u_t, x_prev, x_t, BacklashParams.from_theta(theta).feasible(), kept[1:])

        def run(start: BacklashParams) -> list[BacklashParams]:
            # eq. (9) on every estimate: a zero slope or slopes of opposite sign raise here
            return [BacklashParams.from_theta(t).feasible() for t in self._iterate(step, start.theta)[1]]

        try:
            if self.full_engagement:  # a partial crossing's samples left out: the paper's start may lie off them
                raise NotExcitedError("start from the lines of the samples fitted")
            self.history_ = run(_start_params(uc, xc))
            self.start_ = "paper"
        except (NotExcitedError, InvalidParameterError):
            # the paper's start lines lie off the data (slope not +-1 over a long stroke):
            # start again from lines fitted to the direction of motion
            try:
                guess = _direction_guess(uc, xc, kept)
            except NotExcitedError as exc:
                raise NotExcitedError(
                    "the paper's iteration found no estimate that engages both flanks, from the "
                    f"paper's start or from the direction of motion ({exc}); the data do not "
                    "excite both sides of the dead band well enough (more reversals needed)"
                ) from exc
            try:
                self.history_ = run(guess)
                self.start_ = "direction"
            except (NotExcitedError, InvalidParameterError):
                # input and output move together both ways, yet eq. (5)-(6) engage one flank only: a dead band
                # below what the encoders resolve (issue 27); the lines of the two directions of motion are the estimate
                self.history_, self.n_iter_, self.converged_ = [guess.feasible()], 0, True
                self.start_ = self.stop_reason_ = "direction lines"
        self.equation_error_params_ = self.history_[-1]
        params = self.equation_error_params_
        if self.refine:
            params = self._refine(uc, xc, params, kept)
        self._set_backlash(params)
        self.play_level_ = _engaged_level(uc, xc, kept) if self.full_engagement else 0.0
        x_sim, jac = self._simulate_with_jacobian(uc, params, xc[0])
        resid = (xc - x_sim)[kept]
        self.residual_rms_ = float(np.sqrt(np.mean(resid**2)))
        self._set_uncertainty(uc, xc, resid, jac[kept])
        return self

    @property
    def backlash_(self) -> float:
        """The play, input units: ``c_left_ + c_right_`` (the flanks' distance at the origin's level); with
        ``full_engagement`` their distance at ``play_level_``, where the flanks were fully engaged (equal where
        the slopes are)."""
        check_is_fitted(self, "params_")
        level = self.play_level_
        return (level / self.m_right_ + self.c_right_) - (level / self.m_left_ - self.c_left_)

    def _set_uncertainty(self, uc: np.ndarray, xc: np.ndarray, resid: np.ndarray, jac: np.ndarray) -> None:
        """``backlash_std_`` and its parts: white noise through the Jacobian (the rows of the samples fitted),
        then the per-cycle plays (without the partial crossings, ``partial_``)."""
        level = self.play_level_  # d(play) / d[mL, cL, mR, cR], the play read at that level (eq. 1)
        grad = np.array([level / self.m_left_**2, 1.0, -level / self.m_right_**2, 1.0])
        cov = np.linalg.pinv(jac.T @ jac)
        sigma2 = _inner(resid, resid) / max(resid.size - 4, 1)
        self.backlash_white_std_ = float(np.sqrt(max(sigma2 * float(grad @ cov @ grad), 0.0)))
        scatter = KinematicPlayScatter()
        scatter.update(uc, xc, None, self.backlash_, self.m_left_, self.m_right_, self.partial_, self.play_level_)
        self.cycle_plays_ = scatter.plays_deg
        self.uncertainty_: PlayUncertainty = scatter.uncertainty(
            self.backlash_white_std_, None, self.residual_rms_, self._engagement_std
        )
        self.backlash_std_ = self.uncertainty_.std_deg

    @staticmethod
    def _simulate(uc: np.ndarray, params: BacklashParams, x_start: float) -> np.ndarray:
        return VorosBacklash._simulate_with_jacobian(uc, params, x_start)[0]

    @staticmethod
    def _simulate_with_jacobian(
        uc: np.ndarray, params: BacklashParams, x_start: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The model run freely from the measured first sample, and ``d x / d [mL, cL, mR, cR]``."""
        x = np.empty_like(uc)
        dx = np.empty((uc.size, 4))
        x[0], dx[0] = x_start, 0.0
        backlash_sensitivity(uc[1:], params, x_start, out=(x[1:], dx[1:]))
        return x, dx

    def _refine(self, uc: np.ndarray, xc: np.ndarray, start: BacklashParams, kept: np.ndarray) -> BacklashParams:
        """Minimise the simulation error of the ``kept`` samples over ``[mL, cL, mR, cR]`` from the paper's
        estimate (the model runs through all of them: a partial crossing's samples are only not counted).

        Levenberg-Marquardt (damped Gauss-Newton) with the analytic Jacobian of
        :func:`~online_backlash.model.backlash_sensitivity` (switching pattern held fixed).
        """
        weight = kept.astype(float)

        def evaluate(p: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
            if not (p[0] * p[2] > 0 and p[1] + p[3] >= 0):  # eq. (1) needs it
                return None
            x, dx = self._simulate_with_jacobian(uc, BacklashParams(*p), xc[0])
            return (xc - x) * weight, -dx * weight[:, None]

        p0 = np.array([start.m_left, start.c_left, start.m_right, start.c_right])
        best = _levenberg_marquardt(evaluate, p0)
        self.refine_nfev_ = best.nfev
        return BacklashParams(*best.x) if best.improved else start

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
        As in :class:`VorosBacklash`; so are ``converged_``, ``stop_reason_``, ``refine_nfev_``.
    a_ : array, shape (n_a,)
        ``[1, a2, ..., am]``.
    b_ : array, shape (n_b,)
        ``[b1, ..., bn]``.
    equation_error_a_, equation_error_b_ : arrays
        ``a_`` and ``b_`` of the paper's iteration alone.
    history_ : list of CascadeParams
        The estimate after every iteration (the paper's Figs. 8, 10, 12).
    residual_rms_ : float
        RMS of the simulation residual ``y - simulate(u)``, output units.

    Examples
    --------
    The paper's example 3 (1500 samples, SNR 25):

    >>> from online_backlash import VorosCascade
    >>> from online_backlash.model import PAPER_EXAMPLES
    >>> u, y = PAPER_EXAMPLES[3].generate(seed=0)
    >>> est = VorosCascade(origin="zero").fit(u, y)
    >>> {k: round(v, 2) for k, v in est.estimates().items()}
    {'m_left': 1.3, 'c_left': 0.6, 'm_right': 2.0, 'c_right': 0.7, 'a2': 0.5, 'b1': -0.2, 'b2': 0.35}
    >>> est.n_iter_ <= PAPER_EXAMPLES[3].paper_iterations + 3
    True
    """

    def __init__(
        self,
        n_a: int = 2,
        n_b: int = 2,
        max_iter: int = 50,
        tol: float = 0.1,
        refine: bool = True,
        origin: str = "zero",
    ) -> None:
        super().__init__(max_iter, tol, refine, origin)
        self.n_a = n_a
        self.n_b = n_b

    def _split(self, theta: np.ndarray) -> CascadeParams:
        k = self.n_a - 1
        return CascadeParams(BacklashParams.from_theta(theta[:4]), tuple(theta[4 : 4 + k]), tuple(theta[4 + k :]))

    def fit(self, u: np.ndarray, y: np.ndarray) -> VorosCascade:
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

        def step(theta: np.ndarray) -> _Step:
            params = BacklashParams.from_theta(theta[:4])
            # eq. (23): internal variable and switching functions with the s-th estimate
            x_hat, f1, f2 = simulate_switching(uc, params, 0.0)
            f1p, f2p, up = f1[t - 1], f2[t - 1], uc[t - 1]
            _check_sides(int(f1p.sum()), int(f2p.sum()))
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
    def _filter_coefficients(p: CascadeParams) -> tuple[np.ndarray, np.ndarray]:
        """Numerator ``[0, 1, a2, ...]`` and denominator ``[1, b1, ...]`` of eq. (15)-(17)."""
        return np.concatenate(([0.0, 1.0], np.asarray(p.a, dtype=float))), np.concatenate(
            ([1.0], np.asarray(p.b, dtype=float))
        )

    @staticmethod
    def _simulate(uc: np.ndarray, p: CascadeParams) -> np.ndarray:
        return linear_filter(simulate_backlash(uc, p.backlash, 0.0), np.asarray(p.a), np.asarray(p.b))

    def _simulate_with_jacobian(self, uc: np.ndarray, p: CascadeParams) -> tuple[np.ndarray, np.ndarray]:
        """Output ``y`` of the cascade from rest and ``d y / d [mL, cL, mR, cR, a2.., b1..]``.

        With ``B y = A x`` (eq. 15): ``dy/d(backlash) = (A/B) dx/d(backlash)``,
        ``dy/da_i = (q^-i / B) x`` and ``dy/db_j = -(q^-j / B) y``.
        """
        from scipy.signal import lfilter  # imported here: scipy.signal costs ~1 s at package import

        num, den = self._filter_coefficients(p)
        x, dx = backlash_sensitivity(uc, p.backlash, 0.0)
        y = lfilter(num, den, x)
        cols = [lfilter(num, den, dx, axis=0)]
        for i in range(2, len(p.a) + 2):
            cols.append(lfilter(np.eye(1, i + 1, i)[0], den, x)[:, None])
        for j in range(1, len(p.b) + 1):
            cols.append(lfilter(np.eye(1, j + 1, j)[0], den, -y)[:, None])
        return y, np.hstack(cols)

    def _refine(self, uc: np.ndarray, yc: np.ndarray, start: CascadeParams) -> CascadeParams:
        """Minimise the simulation (output) error over all parameters from the paper's estimate.

        Levenberg-Marquardt (damped Gauss-Newton) with the analytic Jacobian of
        :meth:`_simulate_with_jacobian`; the search stays in the region of valid backlash and
        a stable ``B``.
        """
        k = self.n_a - 1

        def unpack(v: np.ndarray) -> CascadeParams:
            return CascadeParams(BacklashParams(*v[:4]), tuple(v[4 : 4 + k]), tuple(v[4 + k :]))

        def evaluate(v: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
            if not (v[0] * v[2] > 0 and v[1] + v[3] >= 0 and _stable(v[4 + k :])):
                return None
            y, dy = self._simulate_with_jacobian(uc, unpack(v))
            return yc - y, -dy

        b = start.backlash
        v0 = np.array([b.m_left, b.c_left, b.m_right, b.c_right, *start.a, *start.b])
        best = _levenberg_marquardt(evaluate, v0)
        self.refine_nfev_ = best.nfev
        return unpack(best.x) if best.improved else start

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


@dataclass(frozen=True)
class _Refined:
    x: np.ndarray
    nfev: int
    improved: bool


def _levenberg_marquardt(
    evaluate: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray] | None], v0: np.ndarray, max_iter: int = 100
) -> _Refined:
    """Minimise ``|r(v)|^2`` by Gauss-Newton with Marquardt's damping, from ``v0``.

    ``evaluate(v)`` returns the residual ``r`` and its Jacobian ``dr/dv``, or None outside the
    valid region (a trial step there is refused like one that raises the cost). Each step
    solves ``(J^T J + lam diag(J^T J)) dv = -J^T r``; ``lam`` starts at 0 (pure Gauss-Newton),
    grows tenfold on a refused step and shrinks after an accepted one. Stops when the next step
    would change every parameter by less than 1e-10 of its size, or an accepted step lowered
    the cost by less than 1e-12 of it. Returns ``v0`` unchanged (``improved=False``) unless the cost went down.
    """
    first = evaluate(v0)
    if first is None:
        return _Refined(v0, 1, False)
    r, jac = first
    v, cost, lam, nfev = v0, _inner(r, r), 0.0, 1
    cost0 = cost
    for _ in range(max_iter):
        hess, grad = jac.T @ jac, jac.T @ r
        diag = np.diag(hess).copy()
        diag[diag == 0] = 1.0
        scale = np.sqrt(diag)
        while True:
            system = hess / np.outer(scale, scale) + lam * np.eye(v.size)
            step = -(np.linalg.lstsq(system, grad / scale, rcond=None)[0]) / scale
            if np.all(np.abs(step) <= 1e-10 * np.abs(v)):  # converged: nothing left but rounding
                return _Refined(v, nfev, cost < cost0)
            trial = v + step
            out = evaluate(trial)
            nfev += 1
            if out is not None and _inner(out[0], out[0]) < cost:
                break
            lam = max(10.0 * lam, 1e-4)
            if lam > 1e10:
                return _Refined(v, nfev, cost < cost0)
        r, jac = out
        new_cost = _inner(r, r)
        small = cost - new_cost <= 1e-12 * cost
        v, cost, lam = trial, new_cost, (lam / 10.0 if lam > 1e-3 else 0.0)
        if small:
            break
    return _Refined(v, nfev, cost < cost0)
