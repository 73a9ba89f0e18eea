"""Batch torque-aware backlash fit: one linear least-squares line per engaged flank (:class:`TorqueBacklash`).

With the engaged flank measured from the torque sign (:mod:`.engagement`), the switching
functions of eq. (5)-(6) are known, so the iteration of eq. (12)-(14) is not needed: eq. (11)
restricted to the samples where a flank carries torque is linear in ``theta = [m, a, s]`` per
flank (:mod:`.flank_lines`), and one least-squares solve per flank is the fit. Samples inside
the torque dead band (the gap, or too close to zero torque to tell) carry no information about
either line and are left out (the paper's held output, eq. 7's third term, is not fitted).

The play is observable only when the torque reverses: with the output held against one flank
the whole time (a preloaded drive), the other flank's line is never seen and ``backlash_`` is
NaN with ``play_observable_`` False.

The torque at which a flank engages need not be zero (issue 27): given the torques at which the
left and the right flank engage (``engagement_Nm`` of :meth:`TorqueBacklash.fit`, from the dwells of
the motion, :func:`~.observability.engagement_torques`), the flanks are told apart about them
(:func:`~.engagement.engaged_flank`) and the play is measured where each flank carries no torque
(:func:`~.flank_lines.play_between`).

Units: degrees (load side), N m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidParameterError, NotFittedError
from ..estimators.uncertainty import CyclePlays, OutputNoise, model_misfit
from .engagement import DEADBAND_SIGMAS, count_torque_reversals, engaged_flank, torque_noise_std, torque_orientation
from .flank_lines import (
    FlankLine,
    FlankPairFigures,
    at_operating_torque,
    noisy_torque_corrected,
    sample_offsets,
    windup_separable,
)
from .segments import SegmentFit, check_knots, fit_segments

__all__ = ["FlankFit", "TorqueBacklash", "fit_flank"]

#: Fewest engaged samples a flank needs for its line.
MIN_FLANK_SAMPLES = 20
#: Largest condition number of the column-scaled design before the slope is taken as fixed.
_MAX_COND = 1e6


@dataclass(eq=False, repr=False)
class FlankFit:
    """The least-squares line of one flank: ``line``, its unscaled covariance ``cov`` (3x3, of
    ``[m, a, s]``; multiply by the residual variance), residual sum of squares, sample count, and
    the mean and standard deviation of the torque the flank carries (N m: the measured torque less
    ``engaged_at``, the torque at which the flank engages)."""

    line: FlankLine
    cov: np.ndarray
    rss: float
    n: int
    slope_fixed: bool
    torque_mean: float = 0.0
    torque_std: float = 0.0
    engaged_at: float = 0.0

    @property
    def separable(self) -> bool:
        """The torque varied enough on this flank to tell its wind-up from its offset
        (:func:`~.flank_lines.windup_separable`)."""
        return windup_separable(self.torque_mean, self.torque_std)

    def at_operating_torque(self) -> FlankFit:
        """This fit with the wind-up at the mean torque folded into the offset (``s = 0``), covariance mapped."""
        measured = self.torque_mean + self.engaged_at  # the operating torque as the sensor reads it
        T = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, measured], [0.0, 0.0, 0.0]])
        line = at_operating_torque(self.line, measured)
        torque = (self.torque_mean, self.torque_std, self.engaged_at)
        return FlankFit(line, T @ self.cov @ T.T, self.rss, self.n, self.slope_fixed, *torque)


def _solve(
    columns: list[np.ndarray], target: np.ndarray, torque_var: float
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Least squares of ``target`` on ``columns`` (scaled for conditioning; the last column is the
    torque, corrected for its noise variance ``torque_var``, :func:`~.flank_lines.noisy_torque_corrected`):
    ``(coef, unscaled cov, rss)``, or None when the design is singular or ill-conditioned."""
    X = np.column_stack(columns)
    scale = np.sqrt(np.sum(X * X, axis=0))
    if np.any(scale == 0):
        return None
    Xs = X / scale
    if np.linalg.cond(Xs) > _MAX_COND:
        return None
    coef_s, *_ = np.linalg.lstsq(Xs, target, rcond=None)
    info = Xs.T @ Xs
    last = X.shape[1] - 1
    coef_s = noisy_torque_corrected(info, coef_s, X.shape[0], torque_var / scale[last] ** 2, last)
    cov_s = np.linalg.inv(info)
    coef = coef_s / scale
    cov = cov_s / np.outer(scale, scale)
    resid = target - X @ coef
    return coef, cov, float(resid @ resid)


def fit_flank(
    u: np.ndarray,
    y: np.ndarray,
    torque_Nm: np.ndarray,
    *,
    fit_slope: bool = True,
    slope: float = 1.0,
    torque_var: float = 0.0,
    engaged_at: float = 0.0,
) -> FlankFit | None:
    """Fit ``y = m u - a - s tau`` to the samples of one engaged flank (eq. 11 with measured ``f``).

    ``u`` is centred for the solve (a long run's intercept at ``u = 0`` is a long extrapolation)
    and the result mapped back exactly. Without ``fit_slope``, or when the slope cannot be told
    apart from the wind-up (an ill-conditioned design, e.g. a flank touched only briefly),
    ``m = slope`` is held fixed. None when even that is singular. ``torque_var`` (N^2 m^2): the
    torque sensor's noise variance, corrected for (errors in variables). ``engaged_at`` (N m): the
    torque at which the flank engages (the flank's own torque is the measured one less it).
    """
    if u.size < MIN_FLANK_SAMPLES:
        return None
    stats = float(np.mean(torque_Nm)) - engaged_at, float(np.std(torque_Nm)), engaged_at
    uc = float(np.mean(u))
    du = u - uc
    ones = np.ones_like(u)
    if fit_slope:
        sol = _solve([du, -ones, -torque_Nm], y, torque_var)
        if sol is not None:
            (m, b, s), cov_local, rss = sol
            # a = m uc + b (y = m (u - uc) - b - s tau): J maps [m, b, s] to [m, a, s]
            J = np.array([[1.0, 0.0, 0.0], [uc, 1.0, 0.0], [0.0, 0.0, 1.0]])
            return FlankFit(
                FlankLine(float(m), float(m * uc + b), float(s)), J @ cov_local @ J.T, rss, int(u.size), False, *stats
            )
    sol = _solve([-ones, -torque_Nm], y - slope * u, torque_var)
    if sol is None:
        return None
    (a, s), cov2, rss = sol
    cov = np.zeros((3, 3))
    cov[1:, 1:] = cov2
    return FlankFit(FlankLine(float(slope), float(a), float(s)), cov, rss, int(u.size), True, *stats)


class TorqueBacklash(FlankPairFigures):
    """Batch backlash with a torque column: flank lines with wind-up, play only where torque reverses.

    Parameters
    ----------
    deadband_Nm : float or None
        Torque dead band, N m (:func:`~.engagement.engaged_flank`); None: ``n_sigma`` robust noise
        standard deviations of the torque (:func:`~.engagement.torque_deadband`).
    n_sigma : float
        Dead band in noise standard deviations when ``deadband_Nm`` is None.
    fit_slope : bool
        Fit each flank's slope ``m`` (eq. 1); False holds ``m = 1`` (motor angle exactly referred).
    origin : {"first", "zero"}
        ``"first"`` refers ``u`` and ``y`` to their first sample (encoders have arbitrary zeros).
    torque_sign : {"auto", 1.0, -1.0}
        Multiplies the torque column so that the right flank carries positive torque; ``"auto"``:
        :func:`~.engagement.torque_orientation` (a sensor mounted the other way round is flipped).
    stiffness_torques_Nm : (T1, T2) or None
        The data sheet's segment torques, N m: each flank's wind-up is then the three-segment spring
        of :mod:`.segments` (``K1`` to ``T1``, ``K2`` to ``T2``, ``K3`` above; the segments the torque
        covers are fitted) instead of one straight line, and its offset where it carries no torque
        places the play.

    Attributes
    ----------
    left_, right_ : FlankLine or None
        The lines of the flanks that carried torque (None: never engaged); where the wind-up is
        not separable (``windup_separable_`` False), the lines at their mean operating torque,
        wind-up folded into the offset, so the play includes the wind-up at those torques.
    windup_separable_ : bool
        Every engaged flank's torque varied enough to tell its wind-up from its offset
        (:data:`~.flank_lines.MAX_LEVER`); else the stiffness is not determined (NaN).
    torque_sign_ : float
        The sign the torque column was multiplied by.
    engagement_torques_Nm_ : (float, float)
        The torques at which the left and the right flank engage (times ``torque_sign_``), N m.
    deadband_Nm_ : float
    flank_ : int8 array
        Engaged flank per sample (+1 right, -1 left, 0 neither).
    torque_reversals_ : int
        Changes of the engaged flank through the dead band.
    play_observable_ : bool
        Both flanks carried torque (the torque reversed).
    backlash_ : float
        The play, degrees (NaN when not observable).
    backlash_std_ : float
        Its standard error, degrees: the scatter of the play over the torque reversals (moving-block
        bootstrap, Künsch 1989) and the model misfit (the residual RMS beyond the output's white
        noise), floored at ``backlash_white_std_`` (:attr:`FlankPairFigures.backlash_std_`).
    backlash_white_std_ : float
        The white-noise standard error from the lines' covariance and residual variance (delta method), degrees.
    cycle_plays_ : CyclePlays
        One play per torque reversal (:func:`~.flank_lines.sample_offsets`).
    segments_ : (SegmentFit or None, SegmentFit or None)
        With ``stiffness_torques_Nm``: the left and right flanks' three-segment fits (:mod:`.segments`).
    c_left_, c_right_ : float
        Left and right flank offsets at the reference origin's level, degrees (NaN for a flank not seen).
    m_left_, m_right_ : float
    stiffness_left_nm_per_arcmin_, stiffness_right_nm_per_arcmin_ : float
        Torsional stiffness per direction (NaN for a flank not seen).
    residual_rms_ : float
        RMS residual of the engaged samples, degrees.
    n_iter_ : int
        1 (linear: no iteration).

    References
    ----------
    J. Vörös, Automatica 46 (2010) 369-374 (eq. 1, 5-9, 11).
    """

    noise_var_: float
    play_observable_: bool
    windup_separable_: bool

    def __init__(
        self,
        deadband_Nm: float | None = None,
        n_sigma: float = DEADBAND_SIGMAS,
        fit_slope: bool = True,
        origin: str = "first",
        torque_sign: float | str = "auto",
        stiffness_torques_Nm: tuple[float, float] | None = None,
    ) -> None:
        self.deadband_Nm = deadband_Nm
        self.n_sigma = n_sigma
        self.fit_slope = fit_slope
        self.origin = origin
        self.torque_sign = torque_sign
        self.stiffness_torques_Nm = stiffness_torques_Nm

    def fit(
        self,
        u: np.ndarray,
        y: np.ndarray,
        torque_Nm: np.ndarray,
        engagement_Nm: tuple[float | None, float | None] = (None, None),
    ) -> TorqueBacklash:
        """Fit to input ``u`` (deg, motor referred to the load side), output ``y`` (deg) and the
        transmitted torque (N m). ``engagement_Nm``: the torques (as measured, N m) at which the left
        and the right flank engage (None: zero). InvalidParameterError for unequal lengths or
        non-finite values."""
        from ..estimators.validation import check_pair  # the estimators' one statement of the input checks

        u, y = check_pair(u, y)
        q = np.ascontiguousarray(torque_Nm, dtype=float)
        if q.shape != u.shape:
            raise InvalidParameterError(f"torque must be as long as u, got {q.size} and {u.size}")
        if self.origin not in ("first", "zero"):
            raise InvalidParameterError(f"origin must be 'first' or 'zero', got {self.origin!r}")
        if not (isinstance(self.n_sigma, (int, float)) and self.n_sigma > 0):
            raise InvalidParameterError(f"n_sigma must be > 0, got {self.n_sigma!r}")
        if self.torque_sign not in ("auto", 1.0, -1.0):
            raise InvalidParameterError(f"torque_sign must be 'auto', 1 or -1, got {self.torque_sign!r}")
        self.torque_sign_ = torque_orientation(u, y, q) if self.torque_sign == "auto" else float(self.torque_sign)
        q = self.torque_sign_ * q
        eng = tuple(0.0 if t is None else self.torque_sign_ * float(t) for t in engagement_Nm)
        self.engagement_torques_Nm_: tuple[float, float] = (eng[0], eng[1])
        u0, y0 = (u[0], y[0]) if self.origin == "first" else (0.0, 0.0)
        uc, yc = u - u0, y - y0
        sigma = torque_noise_std(q)
        self.torque_noise_std_Nm_ = sigma
        db = self.n_sigma * sigma if self.deadband_Nm is None else float(self.deadband_Nm)
        flank = engaged_flank(q, db, self.engagement_torques_Nm_)
        self.u_ref_, self.y_ref_ = float(u0), float(y0)
        self.deadband_Nm_ = db
        self.flank_ = flank
        self.torque_reversals_ = count_torque_reversals(flank)
        fits: dict[int, FlankFit | None] = {}
        engaged_at = {-1: eng[0], 1: eng[1]}
        for side in (-1, 1):
            sel = flank == side
            fits[side] = fit_flank(
                uc[sel], yc[sel], q[sel], fit_slope=self.fit_slope, torque_var=sigma**2, engaged_at=engaged_at[side]
            )
        if fits[-1] is not None and fits[1] is not None and fits[-1].slope_fixed != fits[1].slope_fixed:
            # one flank too short to tell its slope: hold it at the other flank's
            short = -1 if fits[-1].slope_fixed else 1
            sel = flank == short
            other = fits[-short]
            assert other is not None
            held = {"slope": other.line.m, "torque_var": sigma**2, "engaged_at": engaged_at[short]}
            held_fit = fit_flank(uc[sel], yc[sel], q[sel], fit_slope=False, **held)
            fits[short] = held_fit or fits[short]
        knots = None if self.stiffness_torques_Nm is None else check_knots(self.stiffness_torques_Nm)
        self.segments_: tuple[SegmentFit | None, SegmentFit | None] = (None, None)
        if knots is not None:  # the data sheet's spring: the segments the torque covers, the slope held
            segs: list[SegmentFit | None] = []
            for side in (-1, 1):
                sel, fit = flank == side, fits[side]
                carried = side * (q[sel] - engaged_at[side])
                seg_args = (carried, side, knots, fit.line.m, engaged_at[side], MIN_FLANK_SAMPLES) if fit else None
                segs.append(None if seg_args is None else fit_segments(uc[sel], yc[sel], *seg_args))
            self.segments_ = (segs[0], segs[1])
            for side, seg in zip((-1, 1), segs):
                fit = fits[side]
                if seg is not None and fit is not None:
                    torque = (fit.torque_mean, fit.torque_std, fit.engaged_at)
                    fits[side] = FlankFit(seg.line, seg.cov, seg.rss, seg.n, True, *torque)
        self.raw_fits_ = dict(fits)
        self.windup_separable_ = knots is not None or all(f.separable for f in fits.values() if f is not None)
        if not self.windup_separable_:
            fits = {side: None if f is None else f.at_operating_torque() for side, f in fits.items()}
        self.fits_ = fits
        self.left_ = None if fits[-1] is None else fits[-1].line
        self.right_ = None if fits[1] is None else fits[1].line
        n = sum(f.n for f in fits.values() if f is not None)
        rss = sum(f.rss for f in fits.values() if f is not None)
        self.noise_var_ = rss / max(n - 6, 1) if n else math.nan
        self.residual_rms_ = math.sqrt(self.noise_var_) if n else math.nan
        engaged = flank != 0
        self.y_level_ = float(np.mean(yc[engaged])) if np.any(engaged) else 0.0
        self.play_observable_ = bool(self.left_ is not None and self.right_ is not None and self.torque_reversals_ >= 1)
        self.cycle_plays_ = CyclePlays()
        offsets = sample_offsets(uc, yc, q, flank, self.left_, self.right_, self.y_level_, self.engagement_torques_Nm_)
        self.cycle_plays_.update(flank, offsets)
        noise = OutputNoise()
        noise.update(yc)
        self.output_noise_var_ = noise.var_deg2
        self.n_samples_ = int(u.size)
        self.n_iter_ = 1
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "flank_"):
            raise NotFittedError("this TorqueBacklash is not fitted yet; call fit(u, y, torque_Nm)")

    def _flank_pair(self) -> tuple[FlankLine | None, FlankLine | None]:
        self._check_fitted()
        return self.left_, self.right_

    def _pair_covs(self) -> tuple[np.ndarray, np.ndarray]:
        empty = np.full((3, 3), np.nan)
        return tuple(empty if f is None else f.cov for f in (self.fits_[-1], self.fits_[1]))  # type: ignore[return-value]

    def _y_level(self) -> float:
        return self.y_level_

    def _raw_pair(self) -> tuple[FlankLine | None, FlankLine | None]:
        return tuple(None if f is None else f.line for f in (self.raw_fits_[-1], self.raw_fits_[1]))  # type: ignore[return-value]

    def _misfit_deg(self) -> float:
        return model_misfit(self.residual_rms_, self.output_noise_var_)

    @property
    def operating_torque_Nm_(self) -> float | None:
        """Where the wind-up is not separable: the mean torque magnitude of the engaged flanks, N m; else None."""
        self._check_fitted()
        if self.windup_separable_:
            return None
        means = [abs(f.torque_mean) for f in self.fits_.values() if f is not None]
        return float(np.mean(means)) if means else None

    def get_params(self) -> dict[str, Any]:
        """The constructor arguments."""
        return {
            "deadband_Nm": self.deadband_Nm, "n_sigma": self.n_sigma, "fit_slope": self.fit_slope,
            "origin": self.origin, "torque_sign": self.torque_sign, "stiffness_torques_Nm": self.stiffness_torques_Nm,
        }  # fmt: skip
