"""The two flank lines of a loaded gear, and the play between them.

On an engaged flank the load angle is the flank offset plus the torsional wind-up. Written in
the paper's form (eq. 1, ``x = mR (u - cR)`` right, ``x = mL (u + cL)`` left) with the wind-up
added, each flank is a line linear in its parameters::

    y = m u - a - s tau        right: a = mR cR,   left: a = -mL cL,   s = 1 / k  (deg per N m)

i.e. the regressor of eq. (8) restricted to one flank, ``phi = [u, -1, -tau]``, with the
switching functions eq. (5)-(6) measured from the torque (:mod:`.engagement`) and the wind-up
column ``-tau`` appended. The play is the horizontal distance between the lines at zero torque
(eq. 9: ``cL + cR`` when the slopes are equal); where the sensor reads an offset or a friction
torque while no flank touches, at the torques ``(T_L, T_R)`` at which each flank engages
(``engagement_Nm``, issue 27: :func:`~.observability.engagement_torques`), where the flank itself
carries none.

Units: degrees (load side), N m; stiffness at the API in N m/arcmin (the data-sheet unit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..estimators.uncertainty import CyclePlays, PlayUncertainty, forgetting_weights, play_uncertainty
from ..output_columns import ARCMIN_PER_DEG

__all__ = [
    "MAX_LEVER",
    "FlankLine",
    "FlankPairFigures",
    "at_operating_torque",
    "flank_offsets",
    "noisy_torque_corrected",
    "play_between",
    "play_gradient",
    "sample_offsets",
    "windup_separable",
]

#: The wind-up is told apart from the flank offset only when the torque on a flank varies: the
#: offset at zero torque is an extrapolation over ``|mean torque| / (2 std torque)`` times the
#: torque's spread; beyond this lever the split between offset and wind-up is not determined.
MAX_LEVER = 3.0


@dataclass(frozen=True)
class FlankLine:
    """``y = m u - a - s tau`` on one engaged flank (reference-origin coordinates).

    Attributes
    ----------
    m : float
        Slope (eq. 1: ``mL`` or ``mR``).
    a : float
        Offset, degrees: ``mR cR`` on the right flank, ``-mL cL`` on the left.
    s : float
        Torsional compliance, degrees per N m (``1 / k``).
    """

    m: float
    a: float
    s: float

    def u_at(self, y_deg: float, torque_Nm: float = 0.0) -> float:
        """The input (deg) at which this flank holds the output ``y_deg`` under ``torque_Nm``."""
        return (y_deg + self.a + self.s * torque_Nm) / self.m

    def torsion_deg(self, y_deg: float, torque_Nm: float) -> float:
        """Torsion angle ``u - y`` (deg) on this flank at output level ``y_deg`` and ``torque_Nm``."""
        return self.u_at(y_deg, torque_Nm) - y_deg

    @property
    def stiffness_nm_per_arcmin(self) -> float:
        """Torsional stiffness ``1 / s`` in N m per arc minute (inf for no measurable wind-up)."""
        return math.inf if self.s <= 0 else 1.0 / (self.s * ARCMIN_PER_DEG)


#: Torques at which the (left, right) flank engage where the sensor reads zero with no flank touching, N m.
NO_ENGAGEMENT_OFFSET = (0.0, 0.0)


def play_between(
    left: FlankLine,
    right: FlankLine,
    y_level_deg: float = 0.0,
    engagement_Nm: tuple[float, float] = NO_ENGAGEMENT_OFFSET,
) -> float:
    """The play, degrees: the horizontal distance between the flanks at output level ``y_level_deg``, each
    where it carries no torque (the measured torque at its engagement, ``engagement_Nm = (T_L, T_R)``;
    ``cL + cR``, eq. 9, when the slopes are equal)."""
    return right.u_at(y_level_deg, engagement_Nm[1]) - left.u_at(y_level_deg, engagement_Nm[0])


def play_gradient(
    left: FlankLine,
    right: FlankLine,
    y_level_deg: float = 0.0,
    engagement_Nm: tuple[float, float] = NO_ENGAGEMENT_OFFSET,
) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of :func:`play_between` with respect to ``[m, a, s]`` of the left and of the right
    flank (for the delta-method variance of the play)."""
    t_left, t_right = engagement_Nm
    gl = np.array([left.u_at(y_level_deg, t_left) / left.m, -1.0 / left.m, -t_left / left.m])
    gr = np.array([-right.u_at(y_level_deg, t_right) / right.m, 1.0 / right.m, t_right / right.m])
    return gl, gr


def flank_offsets(
    left: FlankLine,
    right: FlankLine,
    y_level_deg: float = 0.0,
    engagement_Nm: tuple[float, float] = NO_ENGAGEMENT_OFFSET,
) -> tuple[float, float]:
    """``(c_left, c_right)``, degrees: the distances from the reference point, carried to the output
    level ``y_level_deg`` at the mean slope, to the left and right flanks where they carry no torque. They
    sum to :func:`play_between`; at ``y_level_deg = 0`` (or with equal slopes) they are eq. (9)'s ``cL``, ``cR``."""
    mid = y_level_deg / (0.5 * (left.m + right.m))
    return mid - left.u_at(y_level_deg, engagement_Nm[0]), right.u_at(y_level_deg, engagement_Nm[1]) - mid


def sample_offsets(
    u: np.ndarray,
    y: np.ndarray,
    torque_Nm: np.ndarray,
    side: np.ndarray,
    left: FlankLine | None,
    right: FlankLine | None,
    y_level_deg: float = 0.0,
    engagement_Nm: tuple[float, float] = NO_ENGAGEMENT_OFFSET,
) -> np.ndarray:
    """The flank offset each engaged sample implies, degrees (for
    :class:`~online_backlash.estimators.uncertainty.CyclePlays`).

    On a flank ``y = m u - a - s tau``, a sample places the flank, where it carries no torque (at its
    engagement torque ``T``), at ``u* = (y_level + a + s T) / m`` with ``a = m u - y - s tau``; its offset
    is ``-u* = (y + s (tau - T) - y_level) / m - u``, so that the left flank's offsets sit the play
    (:func:`play_between` at ``y_level_deg``) above the right's.
    ``side``: -1 left, +1 right, 0 none (offset 0; also for a flank whose line is None).
    ``u``, ``y`` in the lines' (reference) coordinates, degrees; torque N m.
    """
    out = np.zeros(np.shape(side))
    for flank, line, engaged_at in ((-1, left, engagement_Nm[0]), (1, right, engagement_Nm[1])):
        if line is None:
            continue
        on = np.flatnonzero(side == flank)
        out[on] = (y[on] + line.s * (torque_Nm[on] - engaged_at) - y_level_deg) / line.m - u[on]
    return out


def windup_separable(torque_mean_Nm: float, torque_std_Nm: float) -> bool:
    """Whether a flank's torque varies enough to tell its wind-up from its offset (:data:`MAX_LEVER`)."""
    return abs(torque_mean_Nm) <= MAX_LEVER * 2.0 * torque_std_Nm


def at_operating_torque(line: FlankLine, torque_mean_Nm: float) -> FlankLine:
    """The flank as it stands at its mean operating torque, with the wind-up folded into the offset
    (``a + s tau_mean``, ``s = 0``): what the data determine when the wind-up is not separable."""
    return FlankLine(line.m, line.a + line.s * torque_mean_Nm, 0.0)


def noisy_torque_corrected(
    info: np.ndarray, theta: np.ndarray, weight: float, torque_var: float, column: int
) -> np.ndarray:
    """Least-squares coefficients corrected for the noise of the torque regressor (errors in variables).

    The torque column carries the sensor's noise (variance ``torque_var``, N^2 m^2), which biases its
    coefficient, the compliance ``s``, towards zero (attenuation: the stiffness comes out too high
    by about ``torque_var / var(torque)`` on a flank whose torque varies little). The corrected
    least-squares estimate subtracts the noise's share from the information matrix:
    ``theta_c = (A - w torque_var e e^T)^-1 A theta``, ``A = X^T X`` (``info``, possibly weighted by
    forgetting), ``w`` the (weighted) number of samples, ``e`` the unit vector of ``column``
    (W. A. Fuller, *Measurement Error Models*, Wiley 1987, sec. 2.2). Where the correction would
    leave no information (noise as large as the torque's variation), ``theta`` is returned as is.
    """
    corrected = np.array(info, dtype=float)
    corrected[column, column] -= weight * torque_var
    try:
        np.linalg.cholesky(corrected)
    except np.linalg.LinAlgError:
        return np.asarray(theta, dtype=float)
    return np.linalg.solve(corrected, info @ theta)


class FlankPairFigures:
    """The fitted figures of an estimator made of two flank lines (batch or recursive), stated once.

    The estimator supplies :meth:`_flank_pair` (the lines the play is measured between, left and
    right, None for a flank never engaged; its "not fitted" check goes there), :meth:`_pair_covs`
    (their unscaled covariances of ``[m, a, s]``), ``_y_level()`` (the output level of the play,
    deg), ``noise_var_`` (residual variance, deg^2), ``play_observable_`` (the play is observable)
    and ``windup_separable_`` (the wind-up of every engaged flank is separable); for the standard error
    that covers repeat runs, ``cycle_plays_`` (per-reversal plays, :class:`CyclePlays` fed with
    :func:`sample_offsets`), ``memory_reversals`` (None: equal weights), :meth:`_raw_pair` and
    :meth:`_misfit_deg`.
    """

    memory_reversals: float | None = None
    cycle_plays_: CyclePlays
    #: The torques at which the (left, right) flank engage, N m, as the lines' torque reads (issue 27)
    engagement_torques_Nm_: tuple[float, float] = NO_ENGAGEMENT_OFFSET

    def _flank_pair(self) -> tuple[FlankLine | None, FlankLine | None]:
        raise NotImplementedError

    def _pair_covs(self) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _y_level(self) -> float:
        raise NotImplementedError

    if TYPE_CHECKING:  # the estimator's own: a fitted attribute (batch) or a property of its state (recursive)

        @property
        def noise_var_(self) -> float: ...

        @property
        def play_observable_(self) -> bool: ...

        @property
        def windup_separable_(self) -> bool: ...

    @property
    def backlash_(self) -> float:
        """The play, degrees (NaN while not observable)."""
        left, right = self._flank_pair()
        if not self.play_observable_ or left is None or right is None:
            return math.nan
        return play_between(left, right, self._y_level(), self.engagement_torques_Nm_)

    def _misfit_deg(self) -> float:
        return 0.0

    def _raw_pair(self) -> tuple[FlankLine | None, FlankLine | None]:
        """The lines as fitted, wind-up not folded in (where it is not separable, :meth:`_flank_pair` folds it)."""
        raise NotImplementedError

    @property
    def windup_ambiguity_deg_(self) -> float:
        """Where the wind-up is not separable (:func:`windup_separable`), how far the reported play
        (at the operating torques, wind-up folded in) lies from the play the fitted lines extrapolate
        to zero torque, degrees: the data cannot tell the two apart, so repeat runs that fall on either
        side of the separability test differ by about this much. 0 where the wind-up is separable."""
        left, right = self._raw_pair()
        if self.windup_separable_ or left is None or right is None or not self.play_observable_:
            return 0.0
        folded = self.backlash_
        raw = play_between(left, right, self._y_level(), self.engagement_torques_Nm_)
        return abs(folded - raw) if math.isfinite(folded - raw) else 0.0

    @property
    def uncertainty_(self) -> PlayUncertainty | None:
        """The parts of :attr:`backlash_std_` (None while the play is not observable)."""
        if not self.play_observable_:
            return None
        cycles = self.cycle_plays_
        plays = cycles.plays_deg
        return play_uncertainty(
            plays, forgetting_weights(plays.size, self.memory_reversals), noise_var_deg2=cycles.noise_var_deg2,
            floor_deg=self.backlash_white_std_, misfit_deg=math.hypot(self._misfit_deg(), self.windup_ambiguity_deg_),
        )  # fmt: skip

    @property
    def backlash_std_(self) -> float:
        """Standard error of the play that covers repeat runs, degrees (NaN while not observable).

        The scatter of the play from torque reversal to torque reversal (one play per reversal:
        the mean flank offset, :func:`sample_offsets`, of a stretch on one flank against the next
        stretch on the other), as the moving-block bootstrap standard error of their (forgetting-
        weighted) mean (Künsch 1989, :func:`~online_backlash.estimators.uncertainty.play_uncertainty`),
        floored at the white-noise standard error :attr:`backlash_white_std_`, with the scatter
        between reversals beyond white noise or the model misfit (the residual beyond the output's
        noise, and :attr:`windup_ambiguity_deg_` where the wind-up is not separable, in quadrature)
        added in quadrature (issue 12 item 4; the method in :mod:`online_backlash.estimators.uncertainty`).
        """
        unc = self.uncertainty_
        return math.nan if unc is None else unc.std_deg

    @property
    def backlash_white_std_(self) -> float:
        """Standard error of the play from the lines' covariance and the residual variance (delta method), degrees."""
        left, right = self._flank_pair()
        if not self.play_observable_ or left is None or right is None:
            return math.nan
        gl, gr = play_gradient(left, right, self._y_level(), self.engagement_torques_Nm_)
        cov_left, cov_right = self._pair_covs()
        return math.sqrt(max(self.noise_var_ * float(gl @ cov_left @ gl + gr @ cov_right @ gr), 0.0))

    def _offsets(self) -> tuple[float, float]:
        left, right = self._flank_pair()
        t_left, t_right = self.engagement_torques_Nm_
        if left is not None and right is not None:
            return flank_offsets(left, right, self._y_level(), (t_left, t_right))
        return (
            math.nan if left is None else -left.u_at(0.0, t_left),
            math.nan if right is None else right.u_at(0.0, t_right),
        )

    @property
    def c_left_(self) -> float:
        """Distance to the left flank at zero torque, degrees (:func:`flank_offsets`)."""
        return self._offsets()[0]

    @property
    def c_right_(self) -> float:
        """Distance to the right flank at zero torque, degrees (:func:`flank_offsets`)."""
        return self._offsets()[1]

    @property
    def m_left_(self) -> float:
        """Slope of the left flank (eq. 1), NaN if never engaged."""
        left = self._flank_pair()[0]
        return math.nan if left is None else left.m

    @property
    def m_right_(self) -> float:
        """Slope of the right flank (eq. 1), NaN if never engaged."""
        right = self._flank_pair()[1]
        return math.nan if right is None else right.m

    def _stiffness(self, line: FlankLine | None) -> float:
        return math.nan if line is None or not self.windup_separable_ else line.stiffness_nm_per_arcmin

    @property
    def stiffness_left_nm_per_arcmin_(self) -> float:
        """Torsional stiffness of the left flank, N m/arcmin (NaN: never engaged, or wind-up not separable)."""
        return self._stiffness(self._flank_pair()[0])

    @property
    def stiffness_right_nm_per_arcmin_(self) -> float:
        """Torsional stiffness of the right flank, N m/arcmin (NaN: never engaged, or wind-up not separable)."""
        return self._stiffness(self._flank_pair()[1])
