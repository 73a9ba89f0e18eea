"""Recursive torque-aware backlash: one RLS per flank on ``[u, 1, -tau]`` (:class:`TorqueBacklashRLS`).

The recursive form of :class:`~.flank_fit.TorqueBacklash` (Vörös 2013 gives the recursive
identification of the backlash model of Vörös 2010; here its switching functions are measured
from the torque sign, so the per-flank regression of eq. (11) is linear and one RLS per flank
solves it exactly, with no iteration and no warm start).

Units: ``u`` and ``y`` degrees (load side), torque N m, times seconds.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InvalidParameterError
from ..estimators.base import TORQUE_DEFAULTS, RecursiveEstimator, SharedParams, StateField, memory_factors
from ..estimators.layout import pack
from ..estimators.uncertainty import CyclePlays, OutputNoise, model_misfit
from ..estimators.validation import check_real, finite_array
from . import _torque_kernel as torque_kernel
from ._torque_kernel import TORQUE_CONSTS, TORQUE_FLANK, TORQUE_STATE
from .engagement import DEADBAND_SIGMAS, engaged_flank
from .flank_lines import (
    FlankLine,
    FlankPairFigures,
    at_operating_torque,
    noisy_torque_corrected,
    sample_offsets,
    windup_separable,
)

if TYPE_CHECKING:
    from typing_extensions import Unpack

__all__ = ["TorqueBacklashRLS"]

#: Updates each flank needs before the play is reported.
MIN_FLANK_UPDATES = 10
#: Running-median step of the torque noise (log scale per sample) and the median updates before it is trusted.
_MEDIAN_ETA = 0.02
_NOISE_WARMUP = 200
#: Samples between the instants at which the lines and dead band that place the per-reversal plays
#: are refreshed (a data clock: the same instants however the stream is cut into blocks).
SCATTER_TICK_SAMPLES = 1000
#: Per-reversal segments kept: ``MEMORY_SPANS`` memories in reversals (older plays weigh less than
#: ``exp(-MEMORY_SPANS)``), at most ``MAX_SEGMENTS`` (bounded memory and saved state on a long stream).
MEMORY_SPANS = 20
MAX_SEGMENTS = 20_000


def _empty_held() -> dict[str, Any]:
    return {"u": [], "y": [], "q": [], "gap": [], "gap_next": False}


class TorqueBacklashRLS(FlankPairFigures, RecursiveEstimator):
    """Recursive least squares per flank with the torque: flank offsets, wind-up and the play.

    On every sample the engaged flank is read from the torque sign through a dead band
    (:mod:`.engagement`: a fixed ``deadband_Nm``, or ``n_sigma`` times the torque noise estimated
    online from a running median of its second difference), and only that flank's line
    ``y = m u - a - s tau`` (:mod:`.flank_lines`) is updated, by RLS with forgetting, on the
    regressor ``[u, -1, -tau]`` (eq. 8 restricted to the engaged flank, wind-up column appended).

    **No information, no update.** Samples inside the dead band, right after a gap, or on which
    neither the input nor the torque moved are not learned; the flank not engaged keeps its
    line (its prior until it is first engaged). The play is reported (``play_observable_``) only
    once the torque has reversed and both flanks have at least ``MIN_FLANK_UPDATES`` updates;
    until then ``backlash_`` is NaN. A preloaded drive, held against one flank, never reports a
    play, however long it runs. Forgetting per update and per reversal is bounded by the prior
    covariance, so a still or one-sided drive cannot wind the covariance up.

    Parameters
    ----------
    memory_s, memory_reversals : float or None
        Memory in seconds of a flank's own updates, and in torque reversals (as
        :class:`~online_backlash.estimators.BacklashRLS`); None: no such forgetting.
    sample_period_s : float
        Sampling period, seconds.
    deadband_Nm : float or None
        Fixed torque dead band, N m; None: from the torque noise, online.
    n_sigma : float
        The online dead band in noise standard deviations.
    origin : {"first", "zero"}
        Reference origin of ``u`` and ``y``.
    min_step_deg : float
        Input steps no larger than this carry no information (deg).
    noise_window : int
        Updates over which the residual variance is averaged.
    prior_var : float
        Prior variance (unscaled) of each flank parameter; also the bound of the covariance.
    torque_sign : {1.0, -1.0}
        Multiplies the torque so that the right flank carries positive torque (-1 for a sensor
        mounted the other way round; :func:`~.engagement.torque_orientation` tells from data).
    gap_policy : GapPolicy or None
        Which flagged gaps are bridged (as :class:`~online_backlash.estimators.BacklashRLS`).

    Attributes
    ----------
    theta_ : array, shape (6,)
        ``[mL, aL, sL, mR, aR, sR]`` in reference-origin coordinates (NaN for a flank never engaged).
    P_ : array, shape (6, 6)
        Unscaled covariance of ``theta_`` (block diagonal; the block of a flank never engaged is NaN).
    backlash_, backlash_std_ : float
        The play (horizontal distance between the flanks at zero torque, current output level)
        and its standard error, degrees; NaN while not observable. The standard error covers the
        scatter of the play from torque reversal to torque reversal (moving-block bootstrap of the
        per-reversal plays weighted ``exp(-age / memory_reversals)``, Künsch 1989), floored at the
        white-noise ``backlash_white_std_`` (delta method); see :attr:`FlankPairFigures.backlash_std_`.
        The per-reversal plays are placed with the lines of the latest data-clock tick
        (every :data:`SCATTER_TICK_SAMPLES` samples).
    play_observable_ : bool
    c_left_, c_right_, m_left_, m_right_ : float
    stiffness_left_nm_per_arcmin_, stiffness_right_nm_per_arcmin_ : float
    deadband_Nm_ : float
        The dead band in use (NaN while the online one settles).
    n_reversals_ : int
        Torque reversals (changes of the engaged flank through the dead band).
    cycle_plays_ : CyclePlays
        One play per torque reversal (what ``backlash_std_`` is made from).
    backlash_white_std_ : float
        The white-noise standard error (delta method), degrees.

    References
    ----------
    J. Vörös, Automatica 46 (2010) 369-374 (eq. 1, 5-9, 11); J. Vörös, "Recursive identification
    of nonlinear cascade systems with time-varying general input backlash", ASME J. Dyn. Sys. Meas.
    Control 135(1) 014504 (2013) (the recursive form).

    Examples
    --------
    >>> from online_backlash.simulation.two_mass_rig import simulate_two_mass
    >>> rec = simulate_two_mass(duration_s=10.0, play_deg=0.4)
    >>> est = TorqueBacklashRLS()
    >>> est.learn_many(rec.motor_deg / rec.ratio, rec.load_deg, torque_Nm=rec.torque_Nm)
    >>> round(est.backlash_, 2), est.play_observable_
    (0.4, True)
    """

    _layout = TORQUE_STATE
    _consts = TORQUE_CONSTS
    takes_torque = True
    shared_defaults = TORQUE_DEFAULTS  # memory_reversals None; no warm start (declared there, with the reasons)
    fixed_params = ("start", "warm_start_samples")

    def __init__(
        self,
        deadband_Nm: float | None = None,
        n_sigma: float = DEADBAND_SIGMAS,
        min_step_deg: float = 0.0,
        prior_var: float = 1e6,
        torque_sign: float = 1.0,
        **shared: Unpack[SharedParams],
    ) -> None:
        self.torque_sign = torque_sign
        self.deadband_Nm = deadband_Nm
        self.n_sigma = n_sigma
        self.min_step_deg = min_step_deg
        self.prior_var = prior_var
        super().__init__(**shared)

    # -- hooks -------------------------------------------------------------------------------------
    def _reset_own(self) -> None:
        self._cycles = CyclePlays()
        self._frozen: dict[str, Any] | None = None  # lines and dead band placing the plays, set at each tick
        self._held: dict[str, Any] = _empty_held()  # samples since the last tick
        self._y_noise = [
            0.0,
            0,
        ]  # sum of squared second differences of the output and their count (OutputNoise), per tick block

    def _validate(self) -> None:
        if self.deadband_Nm is not None:
            check_real("deadband_Nm", self.deadband_Nm, 0.0, low_open=False)
        check_real("n_sigma", self.n_sigma, 0.0)
        check_real("min_step_deg", self.min_step_deg, 0.0, low_open=False)
        check_real("prior_var", self.prior_var, 0.0)
        if self.torque_sign not in (1.0, -1.0):
            raise InvalidParameterError(f"torque_sign must be 1 or -1, got {self.torque_sign!r}")

    def _cold_params(self, u: np.ndarray | None, y: np.ndarray | None) -> None:
        return None  # each flank starts from its prior when first engaged

    def _constants(self) -> list[float]:
        lam, lam_rev = memory_factors(self.memory_s, self.memory_reversals, self.sample_period_s)
        return pack(
            TORQUE_CONSTS, torque_kernel.N_CONSTS, LAM=lam, LAM_REV=lam_rev,
            DEADBAND=-1.0 if self.deadband_Nm is None else self.deadband_Nm, N_SIGMA=self.n_sigma,
            MED_UP=math.exp(_MEDIAN_ETA), MED_DOWN=math.exp(-_MEDIAN_ETA), NOISE_WARMUP=_NOISE_WARMUP,
            MIN_STEP=self.min_step_deg, NOISE_WINDOW=self.noise_window, ORIGIN_FIRST=self.origin == "first",
            P0=self.prior_var,
        )  # fmt: skip

    def _initial_state(self, start: Any) -> list[float]:
        return [0.0] * torque_kernel.STATE_SIZE

    def _gap_now(self) -> None:
        self._st[TORQUE_STATE.HAVE_PREV] = 0.0
        self._st[TORQUE_STATE.N_Q] = 0.0
        self._held["gap_next"] = True

    def _hold(self, u: np.ndarray, y: np.ndarray, q: np.ndarray, gap: np.ndarray | None) -> None:
        """Hold a block (torque already signed) until the next tick, where it is measured as one
        block: the plays then do not depend on how the stream was cut."""
        held = self._held
        g = np.zeros(u.size, dtype=bool) if gap is None else np.array(gap, dtype=bool)
        if u.size and held["gap_next"]:
            g[0], held["gap_next"] = True, False
        for key, v in (("u", u), ("y", y), ("q", q), ("gap", g)):
            held[key].extend(v.tolist())

    def _tick(self) -> None:
        """At every :data:`SCATTER_TICK_SAMPLES` samples seen: the per-reversal plays of the samples
        held, with the flank from the torque through the dead band and the offsets
        (:func:`~.flank_lines.sample_offsets`) of the lines of the tick before (none before the
        first tick: nothing measured); then take the current lines for the next."""
        if int(self._st[TORQUE_STATE.N_SEEN]) % SCATTER_TICK_SAMPLES:
            return
        held, fz = self._held, self._frozen
        u, y, q = (np.asarray(held[k], dtype=float) for k in ("u", "y", "q"))
        gap = np.asarray(held["gap"], dtype=bool)
        db = None if fz is None else fz["deadband"]  # None: the online dead band had not settled at the tick
        saved = (0.0, 0.0) if fz is None else fz.get("engagement", (0.0, 0.0))  # lines frozen before issue 27: zero
        engagement = (float(saved[0]), float(saved[1]))
        side = np.zeros(q.size, np.int8) if db is None else engaged_flank(q, db, engagement)
        left, right = (
            (None, None) if fz is None else (None if v is None else FlankLine(*v) for v in (fz["left"], fz["right"]))
        )
        uc, yc = u - self._st[TORQUE_STATE.U0], y - self._st[TORQUE_STATE.Y0]
        # offsets at one output level (0) for the whole run: a level that moved from tick to tick would
        # shift a stretch against the next by the motion between the ticks
        self._cycles.update(side, sample_offsets(uc, yc, q, side, left, right, 0.0, engagement), gap)
        noise = OutputNoise()
        noise.update(y, gap)
        self._y_noise = [
            self._y_noise[0] + noise.total,
            self._y_noise[1] + noise.count,
        ]  # across blocks: 2 differences per tick lost
        memory = self.memory_reversals
        self._cycles.trim(MAX_SEGMENTS if memory is None else min(MAX_SEGMENTS, math.ceil(MEMORY_SPANS * memory) + 2))
        self._held = {**_empty_held(), "gap_next": held["gap_next"]}
        if not self.play_observable_:
            return  # lines not placed yet: no plays measured until they are
        left, right = self.flank_lines_()
        self._frozen = {
            "left": None if left is None else [left.m, left.a, left.s],
            "right": None if right is None else [right.m, right.a, right.s],
            "deadband": self.deadband_Nm_ if math.isfinite(self.deadband_Nm_) else None,
            "engagement": list(self.engagement_torques_Nm_),
        }  # fmt: skip

    @property
    def cycle_plays_(self) -> CyclePlays:  # type: ignore[override]
        """One play per torque reversal so far (the latest ``MEMORY_SPANS * memory_reversals`` kept),
        measured up to the latest data-clock tick."""
        return self._cycles

    def _raw_pair(self) -> tuple[FlankLine | None, FlankLine | None]:
        return self._line(TORQUE_STATE.LEFT), self._line(TORQUE_STATE.RIGHT)

    def _misfit_deg(self) -> float:
        noise = OutputNoise()  # the blocks' sums, summed
        noise.total, noise.count = float(self._y_noise[0]), int(self._y_noise[1])
        return model_misfit(self.residual_rms_, noise.var_deg2)

    def _learn_py(self, u: float, y: float, t: float, q: float) -> None:
        if not math.isfinite(q):
            raise InvalidParameterError(
                f"torque must be finite, got {q!r} (TorqueBacklashRLS needs the torque of every sample)"
            )
        q = self.torque_sign * q
        self._hold(np.array([u]), np.array([y]), np.array([q]), None)
        torque_kernel.torque_step(self._st, self._c, u, y, q)
        self._tick()

    def _learn_arrays(
        self, u: np.ndarray, y: np.ndarray, gap: np.ndarray, t: np.ndarray | None, q: np.ndarray | None
    ) -> None:
        if q is None:
            raise InvalidParameterError("TorqueBacklashRLS needs torque_Nm with every sample")
        q = self.torque_sign * finite_array("torque_Nm", q)
        lo = 0
        while lo < u.size:  # cut at the ticks, where the plays' lines are refreshed
            hi = min(u.size, lo + SCATTER_TICK_SAMPLES - int(self._st[TORQUE_STATE.N_SEEN]) % SCATTER_TICK_SAMPLES)
            self._hold(u[lo:hi], y[lo:hi], q[lo:hi], gap[lo:hi])
            st = np.asarray(self._st, dtype=float)
            torque_kernel.torque_run(st, self._c_arr, u[lo:hi], y[lo:hi], q[lo:hi], gap[lo:hi])
            self._st = st.tolist()
            self._tick()
            lo = hi

    def _extra_state(self) -> dict[str, Any]:
        held = {k: list(v) if isinstance(v, list) else v for k, v in self._held.items()}
        return {
            "cycle_plays": self._cycles.state_dict(),
            "cycle_lines": self._frozen,
            "cycle_held": held,
            "output_noise": list(self._y_noise),
        }

    def _restore_extra(self, d: dict[str, Any]) -> None:
        self._st += [0.0] * (torque_kernel.STATE_SIZE - len(self._st))  # saved before the engagement torques: zero
        self._cycles = CyclePlays.from_state(d["cycle_plays"])
        self._frozen = d["cycle_lines"]
        self._held = d["cycle_held"]
        self._y_noise = list(d["output_noise"])

    # -- fitted attributes ---------------------------------------------------------------------------
    n_reversals_ = StateField("N_REV", int, "Torque reversals: changes of the engaged flank through the dead band.")

    def _line(self, o: int) -> FlankLine | None:
        """The flank's line in reference coordinates (``a = m UC - b``), None if never engaged;
        corrected for the torque noise (:func:`~.flank_lines.noisy_torque_corrected`, the weight
        of the flank's updates and the online noise variance)."""
        self._check_started()
        st = self._st
        if st[o + TORQUE_FLANK.N] == 0.0:
            return None
        theta = np.array([st[o + TORQUE_FLANK.M], st[o + TORQUE_FLANK.B], st[o + TORQUE_FLANK.S]])
        sigma = (
            st[TORQUE_STATE.Q_MED] / torque_kernel.MEDIAN_ABS_D2 if st[TORQUE_STATE.N_QMED] >= _NOISE_WARMUP else 0.0
        )
        if sigma > 0.0 and st[o + TORQUE_FLANK.N] > 3.0:
            P = np.asarray(st[o + TORQUE_FLANK.P : o + TORQUE_FLANK.P + 9]).reshape(3, 3)
            try:
                theta = noisy_torque_corrected(np.linalg.inv(P), theta, st[o + TORQUE_FLANK.W], sigma * sigma, 2)
            except np.linalg.LinAlgError:
                pass  # a singular covariance: no information to correct with
        m, b, s = (float(v) for v in theta)
        return FlankLine(m, m * st[o + TORQUE_FLANK.UC] - b, s)

    def _mean_torque(self, o: int) -> float:
        """The flank's mean torque as measured, signed (N m): the mean torque it carries plus its engagement torque."""
        carried = self._st[o + TORQUE_FLANK.QMEAN] * (-1.0 if o == TORQUE_STATE.LEFT else 1.0)
        return carried + self._st[TORQUE_STATE.ENG_LEFT if o == TORQUE_STATE.LEFT else TORQUE_STATE.ENG_RIGHT]

    @property
    def engagement_torques_Nm_(self) -> tuple[float, float]:  # type: ignore[override]
        """The torques (times ``torque_sign``) at which the left and the right flank engage, N m
        (:meth:`set_engagement_torques`)."""
        self._check_started()
        return float(self._st[TORQUE_STATE.ENG_LEFT]), float(self._st[TORQUE_STATE.ENG_RIGHT])

    def set_engagement_torques(self, left_Nm: float | None, right_Nm: float | None) -> None:
        """The torques at which the left and the right flank engage, as measured (N m; None: zero), from
        the dwells of the motion (:func:`~.observability.engagement_torques`, issue 27): the flanks are
        told apart about them from the next sample on, and the play is measured where each flank carries
        no torque. Where either moves by more than the dead band, the samples learned so far were read
        with the wrong flank: the lines, the torque reversals and the per-reversal plays start afresh
        (each flank from its prior). A no-op before the estimator has started."""
        if not self._started:
            return
        new = [0.0 if t is None else self.torque_sign * float(t) for t in (left_Nm, right_Nm)]
        db = self.deadband_Nm_
        moved = (
            abs(new[0] - self._st[TORQUE_STATE.ENG_LEFT]) > db or abs(new[1] - self._st[TORQUE_STATE.ENG_RIGHT]) > db
        )
        self._st[TORQUE_STATE.ENG_LEFT], self._st[TORQUE_STATE.ENG_RIGHT] = new
        if moved and math.isfinite(db):
            for o in (TORQUE_STATE.LEFT, TORQUE_STATE.RIGHT):
                self._st[o + TORQUE_FLANK.N] = 0.0
            self._st[TORQUE_STATE.N_REV] = self._st[TORQUE_STATE.LAST_FLANK] = 0.0
            self._cycles = CyclePlays()
            self._frozen = None

    def _separable(self, o: int) -> bool:
        st = self._st
        n = st[o + TORQUE_FLANK.N]
        return n == 0.0 or windup_separable(
            st[o + TORQUE_FLANK.QMEAN], math.sqrt(max(st[o + TORQUE_FLANK.QM2], 0.0) / n)
        )

    @property
    def windup_separable_(self) -> bool:
        """Every engaged flank's torque varied enough to tell its wind-up from its offset
        (:data:`~.flank_lines.MAX_LEVER`); else the lines are taken at their operating torques."""
        self._check_started()
        return self._separable(TORQUE_STATE.LEFT) and self._separable(TORQUE_STATE.RIGHT)

    def _effective(self, o: int) -> FlankLine | None:
        """The flank's line, folded at its operating torque where the wind-up is not separable."""
        line = self._line(o)
        if line is None or self.windup_separable_:
            return line
        return at_operating_torque(line, self._mean_torque(o))

    def flank_lines_(self) -> tuple[FlankLine | None, FlankLine | None]:
        """The left and right flank lines the play is measured between (reference coordinates; None
        for a flank never engaged; at the operating torques where the wind-up is not separable)."""
        return self._effective(TORQUE_STATE.LEFT), self._effective(TORQUE_STATE.RIGHT)

    @property
    def compliance_var_(self) -> tuple[float, float]:
        """Unscaled variances of the left and right compliance (inf for a flank never engaged)."""
        self._check_started()
        return tuple(
            math.inf if self._st[o + TORQUE_FLANK.N] == 0.0 else float(self._st[o + TORQUE_FLANK.P + 8])
            for o in (TORQUE_STATE.LEFT, TORQUE_STATE.RIGHT)
        )  # type: ignore[return-value]

    @property
    def torque_peaks_Nm_(self) -> tuple[float | None, float | None]:
        """The largest torque magnitude the left and right flanks were learned at (None: never engaged), N m."""
        self._check_started()
        return tuple(
            None if self._st[o + TORQUE_FLANK.N] == 0.0 else float(self._st[o + TORQUE_FLANK.QMAX])
            for o in (TORQUE_STATE.LEFT, TORQUE_STATE.RIGHT)
        )  # type: ignore[return-value]

    @property
    def operating_torque_Nm_(self) -> float | None:
        """Where the wind-up is not separable: the mean torque magnitude of the engaged flanks, N m; else None."""
        if self.windup_separable_:
            return None
        means = [
            self._st[o + TORQUE_FLANK.QMEAN]
            for o in (TORQUE_STATE.LEFT, TORQUE_STATE.RIGHT)
            if self._st[o + TORQUE_FLANK.N] > 0.0
        ]
        return float(np.mean(means)) if means else None

    def _cov(self, o: int) -> np.ndarray:
        """Unscaled covariance of ``[m, a, s]`` (reference coordinates) of one flank (of the folded
        line's ``[m, a + s tau_mean, 0]`` where the wind-up is not separable)."""
        st = self._st
        P = np.asarray(st[o + TORQUE_FLANK.P : o + TORQUE_FLANK.P + 9]).reshape(3, 3)
        J = np.array([[1.0, 0.0, 0.0], [st[o + TORQUE_FLANK.UC], -1.0, 0.0], [0.0, 0.0, 1.0]])
        if not self.windup_separable_:
            J = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, self._mean_torque(o)], [0.0, 0.0, 0.0]]) @ J
        return J @ P @ J.T

    @property
    def play_observable_(self) -> bool:
        """The torque reversed and both flanks have been updated enough to place them."""
        self._check_started()
        st = self._st
        return bool(
            st[TORQUE_STATE.N_REV] >= 1
            and min(st[TORQUE_STATE.LEFT + TORQUE_FLANK.N], st[TORQUE_STATE.RIGHT + TORQUE_FLANK.N])
            >= MIN_FLANK_UPDATES
        )

    @property
    def theta_(self) -> np.ndarray:
        out = np.full(6, np.nan)
        for i, o in enumerate((TORQUE_STATE.LEFT, TORQUE_STATE.RIGHT)):
            line = self._line(o)
            if line is not None:
                out[3 * i : 3 * i + 3] = (line.m, line.a, line.s)
        return out

    @property
    def P_(self) -> np.ndarray:
        self._check_started()
        out = np.zeros((6, 6))  # the flanks' lines are independent: block diagonal
        for i, o in enumerate((TORQUE_STATE.LEFT, TORQUE_STATE.RIGHT)):
            block = self._cov(o) if self._st[o + TORQUE_FLANK.N] > 0.0 else np.full((3, 3), np.nan)
            out[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = block
        return out

    def _flank_pair(self) -> tuple[FlankLine | None, FlankLine | None]:
        return self.flank_lines_()

    def _pair_covs(self) -> tuple[np.ndarray, np.ndarray]:
        return self._cov(TORQUE_STATE.LEFT), self._cov(TORQUE_STATE.RIGHT)

    def _y_level(self) -> float:
        return self._st[TORQUE_STATE.Y_LEVEL]

    @property
    def torque_sign_(self) -> float:
        """The sign the torque is multiplied by (``torque_sign``, as ``TorqueBacklash.torque_sign_``)."""
        return float(self.torque_sign)

    @property
    def torque_noise_std_Nm_(self) -> float:
        """The torque sensor's noise standard deviation the dead band is made of, N m (NaN before it has settled)."""
        return self.deadband_Nm_ / self.n_sigma

    @property
    def deadband_Nm_(self) -> float:
        self._check_started()
        if self.deadband_Nm is not None:
            return float(self.deadband_Nm)
        st = self._st
        return (
            self.n_sigma * st[TORQUE_STATE.Q_MED] / torque_kernel.MEDIAN_ABS_D2
            if st[TORQUE_STATE.N_QMED] >= _NOISE_WARMUP
            else math.nan
        )

    def predict_one(self, u: float, torque_Nm: float = 0.0) -> float:
        """The output (deg) of the flank the torque engages (NaN in the dead band or for a flank not yet seen)."""
        self._check_started()
        db = self.deadband_Nm_
        side = engaged_flank(np.array([torque_Nm]), db, self.engagement_torques_Nm_)[0] if math.isfinite(db) else 0
        o = TORQUE_STATE.RIGHT if side > 0 else TORQUE_STATE.LEFT if side < 0 else None
        line = None if o is None else self._line(o)
        if line is None:
            return math.nan
        return line.m * (u - self.u_ref_) - line.a - line.s * torque_Nm + self.y_ref_
