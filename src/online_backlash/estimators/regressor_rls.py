"""A recursive estimator written in Python by its regressor alone: the recursive least squares of the paper.

:class:`RegressorRLS` writes the five hooks of :class:`~.base.RecursiveEstimator` once for an estimator that
is a recursive least squares on a regressor of its own: the state (a fixed bookkeeping part, then
``theta`` and its unscaled covariance ``P``), the step of one sample and the gap. A new estimator of that
kind writes only :meth:`RegressorRLS._regressor` (and ``n_params`` where it has more than eq. 8's four), as
``docs/estimators.md`` shows for the paper's own model in a few lines; it runs interpreted (``learn_many``
is a loop of the step), which is what the readable reference of a model needs, not a rig's data rate.

The step of one sample (J. Vörös, "Modeling and identification of systems with backlash", Automatica 46
(2010) 369-374, eq. (8)-(14); recursively with forgetting as in J. Vörös, "Recursive identification of
nonlinear cascade systems with time-varying general input backlash", ASME J. Dyn. Sys. Meas. Control
135(1) 014504, 2013):

* ``u``, ``y`` referred to the origin (the first sample with ``origin="first"``); a sample that follows a gap
  or does not move the input carries no information and only becomes the previous sample;
* the regressor ``phi`` of the sample from the previous output ``x(t-1)`` (eq. 8 with the switching
  functions of eq. 12-13: :meth:`RegressorRLS._regressor`), None in the dead band;
* the a-priori error ``e = x - phi' theta`` (eq. 14), the covariance discounted by ``lam`` per update and
  ``lam_rev`` more where the active flank changed (a reversal), the gain ``k = P phi / (1 + phi' P phi)``,
  ``P <- P - k phi' P`` and ``theta <- theta + k e`` (held while the warm start replays its buffer);
* the noise variance: the mean of ``e**2`` over the last ``noise_window`` updates.
"""

from __future__ import annotations

from abc import abstractmethod
from typing import Any, ClassVar, NamedTuple

import numpy as np

from .base import SHARED_CONSTS, RecursiveEstimator
from .layout import offsets

__all__ = ["RegressorRLS"]


class RegressorFields(NamedTuple):
    """The bookkeeping part of a :class:`RegressorRLS`'s state vector (field sizes, in order); ``theta`` and
    ``P`` follow it."""

    N_SEEN: int = 1  # samples learned
    U0: int = 1  # the reference origin of u and y
    Y0: int = 1
    NOISE_VAR: int = 1  # mean square a-priori error of eq. (14) over the last noise_window updates
    N_REV: int = 1  # changes of the active flank
    N_UPD: int = 1  # updates
    SIDE: int = 1  # the flank updated last: 1 left, 2 right (0: none yet)
    HAVE_PREV: int = 1  # 0 at the start and after a gap: no motion is read from the last sample
    U_PREV: int = 1  # u(t-1), referred
    X_PREV: int = 1  # x(t-1), the measured output, referred


REGRESSOR_STATE, N_REGRESSOR_STATE = offsets(RegressorFields())


class RegressorRLS(RecursiveEstimator):
    """The recursive least squares of eq. (14) on the regressor a subclass writes (:meth:`_regressor`).

    Parameters: the shared ones of :class:`~.base.RecursiveEstimator` (``memory_s``, ``memory_reversals``,
    ``warm_start_samples``, ``origin``, ``noise_window``, ...). ``theta_`` starts at :meth:`_start_theta` of
    the warm start's batch fit (eq. 8's ``[mL, mL cL, mR, mR cR]``) with ``P_`` the identity.
    """

    #: Parameters in ``theta_``: eq. (8)'s four first, then any of the subclass's own
    n_params: ClassVar[int] = 4
    _layout = REGRESSOR_STATE

    @abstractmethod
    def _regressor(self, u: float, x_prev: float, theta: np.ndarray) -> tuple[np.ndarray, int] | None:
        """The regressor ``phi`` (``n_params`` values) of a sample that moved the input, and the flank it
        reads (1 left, 2 right: a change is a reversal), or None where it carries no information (the dead
        band). ``u``: the input, ``x_prev``: the previous output (both referred to the origin), ``theta``: the
        parameters before this sample."""

    def _start_theta(self, start: Any) -> np.ndarray:
        """``theta`` at the start from the warm start's (or cold start's) values: eq. (8) of
        :class:`~online_backlash.model.BacklashParams`, zeros for parameters beyond its four."""
        theta = np.zeros(self.n_params)
        theta[:4] = start.theta
        return theta

    def _slices(self) -> tuple[slice, slice]:
        """Where ``theta`` and ``P`` (row by row) lie in the state vector."""
        n, at = self.n_params, N_REGRESSOR_STATE
        return slice(at, at + n), slice(at + n, at + n + n * n)

    def _initial_state(self, start: Any) -> list[float]:
        theta, cov = self._slices()
        st = [0.0] * cov.stop
        st[theta], st[cov] = self._start_theta(start).tolist(), np.eye(self.n_params).ravel().tolist()
        return st

    def _gap_now(self) -> None:
        self._st[REGRESSOR_STATE.HAVE_PREV] = 0.0

    def _learn_py(self, u: float, y: float, t: float, q: float) -> None:
        st, c, at = self._st, self._c, REGRESSOR_STATE
        if st[at.N_SEEN] == 0.0 and c[SHARED_CONSTS.ORIGIN_FIRST]:
            st[at.U0], st[at.Y0] = u, y
        st[at.N_SEEN] += 1.0
        u, x = u - st[at.U0], y - st[at.Y0]
        moved, x_prev = st[at.HAVE_PREV] and u != st[at.U_PREV], st[at.X_PREV]
        st[at.HAVE_PREV], st[at.U_PREV], st[at.X_PREV] = 1.0, u, x
        if not moved:  # after a gap, or the input still: no information
            return
        theta_at, cov_at = self._slices()
        theta = np.array(st[theta_at])
        reading = self._regressor(u, x_prev, theta)
        if reading is None:
            return
        phi, side = reading
        turned = st[at.SIDE] not in (0.0, side)
        st[at.N_REV], st[at.SIDE] = st[at.N_REV] + turned, side
        lam = c[SHARED_CONSTS.LAM] * (c[SHARED_CONSTS.LAM_REV] if turned else 1.0)
        e = x - phi @ theta  # eq. (14), a priori
        cov = np.reshape(st[cov_at], (self.n_params, self.n_params)) / lam
        gain = cov @ phi / (1.0 + phi @ cov @ phi)
        st[cov_at] = (cov - np.outer(gain, phi @ cov)).ravel().tolist()
        if not c[SHARED_CONSTS.FREEZE]:  # the warm start's replay holds theta at the batch fit
            st[theta_at] = (theta + gain * e).tolist()
        st[at.N_UPD] += 1.0
        st[at.NOISE_VAR] += (e * e - st[at.NOISE_VAR]) / min(st[at.N_UPD], c[SHARED_CONSTS.NOISE_WINDOW])

    @property
    def theta_(self) -> np.ndarray:
        """The parameters, eq. (8)'s ``[mL, mL cL, mR, mR cR]`` first (reference-origin coordinates)."""
        self._check_started()
        return np.array(self._st[self._slices()[0]])

    @property
    def P_(self) -> np.ndarray:
        """Unscaled covariance of ``theta_``."""
        self._check_started()
        return np.reshape(self._st[self._slices()[1]], (self.n_params, self.n_params))
