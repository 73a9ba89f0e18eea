"""Recursive least squares for backlash alone, eq. (8)-(14), that tracks wear (:class:`BacklashRLS`).

``learn_one`` runs the per-sample step of :mod:`._rls_kernels` in plain Python (the readable
reference); ``learn_many`` runs the same source compiled by numba, so both give the same
estimates. With effects, the same step runs with the effect columns appended to the regressor
(:meth:`BacklashRLS._step_effects`, numpy). Memory is flat: no per-sample history is kept.

Units: ``u`` and ``y`` share one unit (degrees, load side, in this package); slopes are
dimensionless; ``c_left_``, ``c_right_``, ``backlash_`` are in input units; times in seconds.
"""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..effect_terms import EffectTerms
from ..errors import InvalidParameterError, NotFittedError
from ..model import BacklashParams
from . import _rls_kernels as kernels
from ._judge_ahead import learn_judged
from ._rls_kernels import BACKLASH_CONSTS, BACKLASH_STATE, FLANK
from .base import EstimateAt, RecursiveEstimator, StateField, WarmStartParams, finite, memory_factors
from .batch import VorosBacklash, _levenberg_marquardt
from .full_engagement import NO_FLANK, RESTING, FullEngagement
from .layout import pack
from .validation import check_option, check_real

if TYPE_CHECKING:
    from typing_extensions import Unpack

_SWITCHING = ("model", "measured")


def _refine_with_effects(
    uc: np.ndarray, yc: np.ndarray, terms: np.ndarray, start: BacklashParams, kept: np.ndarray
) -> BacklashParams:
    """The batch refinement with effect columns: minimise ``|y - x_sim(u) - terms beta|^2`` over the
    ``kept`` samples (not a partial crossing) and ``[mL, cL, mR, cR, beta]`` jointly, from the batch
    estimate and ``beta = 0``.

    ``x_sim`` is eq. (1)-(3) run freely on ``u`` (the simulation error of
    :meth:`VorosBacklash._refine`); the effects enter linearly, so the Jacobian is
    ``[dx_sim/dp, terms]`` and Levenberg-Marquardt runs as for backlash alone. Returns the
    lines (``beta`` is learned again by the replay of the buffer).
    """

    weight = kept.astype(float)

    def evaluate(v: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        if not (v[0] * v[2] > 0 and v[1] + v[3] >= 0):  # eq. (1) needs it
            return None
        x, dx = VorosBacklash._simulate_with_jacobian(uc, BacklashParams(*v[:4]), yc[0])
        return (yc - x - terms @ v[4:]) * weight, -np.hstack((dx, terms)) * weight[:, None]

    v0 = np.concatenate(([start.m_left, start.c_left, start.m_right, start.c_right], np.zeros(terms.shape[1])))
    best = _levenberg_marquardt(evaluate, v0)
    return BacklashParams(*best.x[:4]) if best.improved else start


class BacklashRLS(RecursiveEstimator):
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
    gap_policy : GapPolicy or None
        Which flagged gaps (``after_gap``) are bridged, the state kept across them, and which
        restart the reading of the motion (:class:`~online_backlash.gap_policy.GapPolicy`; None:
        its defaults, gaps up to 0.1 s without a jump over 5 deg are bridged). Tallied in ``gaps_``
        (:class:`~online_backlash.gap_policy.GapTally`: gaps since made, reset or restored).
    full_engagement : bool
        Update a flank line only where the data show the flanks fully engaged: a sample of a partial
        crossing of the gap (:class:`~.full_engagement.FullEngagement`, issue 27) updates neither line.
        The warm start's batch fit and the replay of its buffer judge the buffer as a whole record (each
        stroke against the full width its own end shows); the samples after it are judged as they come,
        against the strokes completed before them. False: every sample, as the paper.

    Attributes
    ----------
    m_left_, m_right_ : float
        Slopes of eq. (1).
    c_left_, c_right_ : float
        Distances, input units, from the reference point to the left and right flanks at the
        level the play is read at; they sum to ``backlash_``. The reference point is the reference
        origin (the first sample with ``origin="first"``) carried along the band at the mean
        slope; with equal slopes, or at the origin's level, they are eq. (9)'s ``c1 / m1`` and
        ``c2 / m2``. Over a long run their split is only as good as the slopes (the origin lies
        far away), their sum is not.
    backlash_ : float
        The play: horizontal distance between the flanks at the current output level (equal
        to ``c_left_ + c_right_`` when the slopes are equal), input units. With ``full_engagement``
        (and no effects) at the level where the flanks were fully engaged: midway between the two
        flanks' information centroids, where each line is best placed (a partial crossing at one end of
        the stroke leaves a flank's line fitted over part of it only, and read far from its data a small
        slope error would move the play).
    backlash_std_ : float
        Its standard error: the covariance of the local lines times the residual variance,
        plus the lag of each flank behind the wear (estimated wear rate times the mean age of
        the flank's information, which grows while the flank sits disengaged), and with
        ``full_engagement`` what the samples left out would take off the play
        (:attr:`FullEngagement.engagement_std_deg_ <.full_engagement.FullEngagement.engagement_std_deg_>`).
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
    >>> from online_backlash.simulation.rig import simulate_rig
    >>> rec = simulate_rig(duration_s=60.0, play_deg=0.5)
    >>> est = BacklashRLS(memory_reversals=20)
    >>> est.learn_many(rec.motor_deg / rec.ratio, rec.load_deg)
    >>> round(est.backlash_, 3)
    0.5
    """

    _layout = BACKLASH_STATE
    _consts = BACKLASH_CONSTS

    wear_rate_ = StateField("W_RATE", float, "Estimated rate of change of the play, input units per second of motion.")

    def __init__(
        self,
        min_step_deg: float = 0.0,
        wear_horizon_s: float = 120.0,
        info_floor: float = 1e-6,
        effects: Sequence[EffectTerms] | None = None,
        switching: str | None = None,
        full_engagement: bool = False,
        **shared: Unpack[WarmStartParams],
    ) -> None:
        self.min_step_deg = min_step_deg
        self.wear_horizon_s = wear_horizon_s
        self.info_floor = info_floor
        self.effects = effects
        self.switching = switching
        self.full_engagement = full_engagement
        super().__init__(**shared)

    def _reset_own(self) -> None:
        # the joint information matrix of [mL, bL, mR, bR, beta] (effects only), beta, and the
        # effects' output at the previous sample
        self._R = np.zeros((0, 0))
        self._beta = np.zeros(0)
        self._prev_shift = 0.0
        # the partial crossings (full_engagement), and the marks of the warm-start buffer while it is replayed
        self._fe = FullEngagement() if self.full_engagement else None
        self._replayed: np.ndarray | None = None

    def _validate(self) -> None:
        if not isinstance(self.full_engagement, bool):
            raise InvalidParameterError(f"full_engagement must be a bool, got {self.full_engagement!r}")
        check_real("min_step_deg", self.min_step_deg, 0.0, low_open=False)
        check_real("wear_horizon_s", self.wear_horizon_s, 0.0)
        check_real("info_floor", self.info_floor, 0.0)
        if self.switching is not None:
            check_option("switching", self.switching, _SWITCHING)

    def _switching(self) -> str:
        """``switching``, with None resolved: ``"model"`` without effects, ``"measured"`` with them."""
        if self.switching is not None:
            return self.switching
        return "measured" if self._fx.effects else "model"

    def _warm_fit(self, uc: np.ndarray, yc: np.ndarray, terms: np.ndarray) -> tuple[BacklashParams, int, bool]:
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
        batch = VorosBacklash(origin="zero", full_engagement=self.full_engagement)
        batch.warn_unconverged = False  # told by converged_ (warm_start_), as no warning the user could act on
        batch.fit(uc, yc)
        start = (
            batch.params_
            if terms.shape[1] == 0
            else _refine_with_effects(uc, yc, terms, batch.params_, ~batch.partial_)
        )
        return start, int(batch.n_iter_), bool(batch.converged_)

    def _constants(self) -> list[float]:
        lam, lam_rev = memory_factors(self.memory_s, self.memory_reversals, self.sample_period_s)
        return pack(
            BACKLASH_CONSTS, kernels.N_CONSTS, DT=self.sample_period_s, LAM=lam, LAM_REV=lam_rev,
            FLOOR_M=self.info_floor, FLOOR_B=self.info_floor, MIN_STEP=self.min_step_deg,
            NOISE_WINDOW=self.noise_window, WEAR_HORIZON=self.wear_horizon_s, ORIGIN_FIRST=self.origin == "first",
            SWITCH_MODEL=self._switching() == "model", HOLD_BAND=self._hold_band(),
            ENGAGED_LEVEL=self.full_engagement and not self._fx.effects,
        )  # fmt: skip

    def _hold_band(self) -> float:
        """How far a load seen following may be from the model's held output and still be held by a flank
        there, degrees: what tells a partial crossing from the encoders' noise
        (:attr:`FullEngagement.tolerance_deg_ <.full_engagement.FullEngagement.tolerance_deg_>`); unbounded
        before the motion was judged (or without ``full_engagement``)."""
        fe = self._fe
        return math.inf if fe is None or not hasattr(fe, "tolerance_deg_") else float(fe.tolerance_deg_)

    def _judged(self) -> None:
        """The motion has been judged anew (the warm start, a restored state): its band into the constants."""
        if self._started:
            self._c[BACKLASH_CONSTS.HOLD_BAND] = self._hold_band()
            self._c_arr = np.asarray(self._c)

    def _initial_state(self, start: BacklashParams) -> list[float]:
        """Eq. (1)'s lines through the reference origin (``u_ref = 0``): ``y = mL (u + cL)``, ``y = mR (u - cR)``."""
        st = [0.0] * kernels.STATE_SIZE
        st[BACKLASH_STATE.LEFT + FLANK.M] = start.m_left
        st[BACKLASH_STATE.LEFT + FLANK.B] = start.m_left * start.c_left
        st[BACKLASH_STATE.RIGHT + FLANK.M] = start.m_right
        st[BACKLASH_STATE.RIGHT + FLANK.B] = -start.m_right * start.c_right
        for o in (BACKLASH_STATE.LEFT, BACKLASH_STATE.RIGHT):
            st[o + FLANK.R11] = self.info_floor
            st[o + FLANK.R22] = self.info_floor
        return st

    def _begin(self, start: BacklashParams) -> None:
        super()._begin(start)
        n_fx = self._fx.n_terms
        self._R = np.diag(np.full(4 + n_fx, self.info_floor)) if self._fx.effects else np.zeros((0, 0))
        self._beta = np.zeros(n_fx)
        self._prev_shift = 0.0

    def _gap_now(self) -> None:
        self._st[BACKLASH_STATE.HAVE_PREV] = 0.0
        self._fx.reset()
        if self._fe is not None and self._replayed is None:  # (the replay's marks were read with its gaps)
            self._fe.mark_gap()

    def _replay(self, buf: dict[str, list], compiled: bool) -> None:
        """The warm start's replay, with the buffer judged as a whole record (:meth:`FullEngagement.fit
        <.full_engagement.FullEngagement.fit>`), where ``full_engagement``."""
        if self._fe is not None:
            u, y, gap = np.asarray(buf["u"]), np.asarray(buf["y"]), np.asarray(buf["gap"], dtype=bool)
            self._replayed = self._fe.fit(u, y, gap)
            self._judged()
        try:
            super()._replay(buf, compiled)
        finally:
            self._replayed = None

    def _seen(self, u: np.ndarray, y: np.ndarray, gap: np.ndarray | None) -> np.ndarray:
        """What the motion shows of the samples (:class:`~.full_engagement.FullEngagement`'s judgement; all
        ``RESTING``, left to the model, without ``full_engagement``): the replayed buffer's, taken in turn, or
        the next samples' judged now."""
        if self._replayed is not None:
            seen, self._replayed = self._replayed[: u.size], self._replayed[u.size :]
            return seen
        if self._fe is None:
            return np.full(u.size, RESTING, dtype=np.int8)
        return self._fe.update(u, y, gap)

    # -- the two paths -------------------------------------------------------------------------
    def _learn_py(self, u: float, y: float, t: float, q: float) -> None:
        seen = int(self._seen(np.array([u]), np.array([y]), None)[0])
        if self._fx.effects:
            row = self._fx.feed(np.array([u]), np.array([t]), np.array([q]))[0]
            self._step_effects(u, y, row, seen)
        else:
            kernels.backlash_step(self._st, self._c, u, y, seen)

    def _learn_arrays(
        self, u: np.ndarray, y: np.ndarray, gap: np.ndarray, t: np.ndarray | None, q: np.ndarray | None
    ) -> None:
        if t is None or q is None:  # no effects: compiled
            self._run(u, y, gap, *kernels.NO_MARKS)
            return
        seen = self._seen(u, y, gap)
        # segment by gap: effects keep a history that a gap must reset
        starts = [0, *np.flatnonzero(gap[1:]) + 1, u.size]
        for lo, hi in itertools.pairwise(starts):
            if gap[lo]:
                self._gap_now()
            rows = self._fx.feed(u[lo:hi], t[lo:hi], q[lo:hi])
            for i in range(lo, hi):
                self._step_effects(float(u[i]), float(y[i]), rows[i - lo], int(seen[i]))

    def _learn_arrays_marked(
        self,
        u: np.ndarray,
        y: np.ndarray,
        gap: np.ndarray,
        t: np.ndarray | None,
        q: np.ndarray | None,
        marks: np.ndarray,
    ) -> list[EstimateAt]:
        if t is not None or q is not None:  # effects: the interpreted path, cut at the marks
            return super()._learn_arrays_marked(u, y, gap, t, q, marks)
        out = np.empty((marks.size, 4))
        self._run(u, y, gap, marks, out)  # (play, mL, mR, level) at each
        return [EstimateAt(True, *row) for row in out.tolist()]

    def _run(self, u: np.ndarray, y: np.ndarray, gap: np.ndarray, marks: np.ndarray, out: np.ndarray) -> None:
        """The compiled loop over a block (:func:`~._rls_kernels.backlash_run`, the estimate after the first
        ``marks[k]`` samples into ``out[k]``). With ``full_engagement`` judging a stream
        (:attr:`FullEngagement.settled_ <.full_engagement.FullEngagement.settled_>`), the block is learned in
        pieces, the next piece judged in a worker thread meanwhile (:func:`~._judge_ahead.learn_judged`: the
        same judgement and the same loop, bit for bit)."""
        st = np.asarray(self._st, dtype=float)
        fe = self._fe
        if fe is None or self._replayed is not None or not fe.settled_:
            kernels.backlash_run(st, self._c_arr, u, y, gap, self._seen(u, y, gap), marks, out)
        else:

            def learn(lo: int, hi: int, seen: np.ndarray) -> None:
                first, last = np.searchsorted(marks, (lo, hi), side="right")  # the marks in (lo, hi]
                part = slice(lo, hi)
                kernels.backlash_run(
                    st, self._c_arr, u[part], y[part], gap[part], seen, marks[first:last] - lo, out[first:last]
                )

            learn_judged(lambda lo, hi: fe.update(u[lo:hi], y[lo:hi], gap[lo:hi]), learn, u.size)
        self._st = st.tolist()

    def _step_effects(self, u: float, y: float, terms: np.ndarray, seen: int) -> None:
        """:func:`_rls_kernels.backlash_step` with the effect columns in the regressor (numpy).

        The same pieces (sample, flank selection and reversal, recentring, noise, bookkeeping)
        on ``x = y - beta . terms``, the backlash output without the effects; the 2x2 update of
        the flank's ``[m, b]`` becomes the joint one of ``[mL, bL, mR, bR, beta]``, which share
        one information matrix. Forgetting on a flank's update scales that flank's and the
        effects' rows and columns by ``sqrt(lam)`` (with no effects this is exactly the
        per-flank step).
        """
        st, c, R = self._st, self._c, self._R
        uc, yc, du, y_prev = kernels.begin_sample(st, c, u, y)
        if seen == NO_FLANK:
            kernels.pass_by(st, yc - float(self._beta @ terms))
            return
        if du == 0.0:
            return
        shift = float(self._beta @ terms)
        prev_shift, self._prev_shift = self._prev_shift, shift
        side, lam_rev, engaged = kernels.select_flank(st, c, uc, du, y_prev - prev_shift, yc - shift)
        if side == 0 or kernels.left_the_hold(st, c, seen, engaged, yc - shift):
            return
        floor = np.full(R.shape[0], self.info_floor)
        if lam_rev != 1.0:
            R *= lam_rev
            R += np.diag((1.0 - lam_rev) * floor)
            for o in (BACKLASH_STATE.LEFT, BACKLASH_STATE.RIGHT):
                kernels.forget_counts(st, o, lam_rev)
        j = 0 if side == BACKLASH_STATE.LEFT else 2
        if engaged:
            d = kernels.recenter(st, side, uc)
            # information matrix under b' = b + m d: column/row j <- j - d (j+1)
            R[:, j] -= d * R[:, j + 1]
            R[j, :] -= d * R[j + 1, :]
        lam = c[BACKLASH_CONSTS.LAM]
        idx = np.r_[j, j + 1, 4 : R.shape[0]]
        scale = np.ones(R.shape[0])
        scale[idx] = math.sqrt(lam)
        R *= np.outer(scale, scale)
        R[idx, idx] += (1.0 - lam) * floor[idx]
        kernels.forget_counts(st, side, lam)
        phi = np.zeros(R.shape[0])
        phi[j + 1] = 1.0  # the local regressor of eq. (8), [0, 1], then the effect columns
        phi[4:] = terms
        e = yc - st[side + FLANK.B] - shift  # a-priori error, eq. (14)
        kernels.track_noise(st, c, e)
        R += np.outer(phi, phi)
        if c[BACKLASH_CONSTS.FREEZE] != 0.0:
            # warm-start replay: the lines stay at the batch estimate; the effects learn given them
            if self._beta.size:
                self._beta += np.linalg.solve(R[4:, 4:], phi[4:]) * e
        else:
            delta = np.linalg.solve(R, phi) * e
            for k, o in enumerate(
                (
                    BACKLASH_STATE.LEFT + FLANK.M,
                    BACKLASH_STATE.LEFT + FLANK.B,
                    BACKLASH_STATE.RIGHT + FLANK.M,
                    BACKLASH_STATE.RIGHT + FLANK.B,
                )
            ):
                st[o] += delta[k]
            self._beta += delta[4:]
        kernels.close_update(st, side)

    def _extra_state(self) -> dict[str, Any]:
        extra: dict[str, Any] = {} if self._fe is None else {"full_engagement": self._fe.state_dict()}
        if self._fx.effects:
            extra.update(effects_R=self._R.tolist(), beta=self._beta.tolist(), prev_shift=self._prev_shift)
        return extra

    def _restore_extra(self, d: dict[str, Any]) -> None:
        if self._fe is not None:
            self._fe = FullEngagement.from_state(d["full_engagement"])
            self._judged()
        if self._fx.effects:
            self._R = np.asarray(d["effects_R"], dtype=float)
            self._beta = np.asarray(d["beta"], dtype=float)
            self._prev_shift = float(d["prev_shift"])

    # -- prediction ------------------------------------------------------------------------------
    def predict_one(self, u: float, *, time_s: float | None = None, torque_Nm: float | None = None) -> float:
        """One-step-ahead load angle for input ``u``, eq. (1)-(3), from the last measured output.

        Effects (if any) are evaluated on copies, so the stream history is not advanced.
        """
        self._check_started()
        st = self._st
        if st[BACKLASH_STATE.N_SEEN] == 0.0:
            raise NotFittedError("predict_one needs at least one learned sample (the previous output x(t-1))")
        uc = finite("u", u) - st[BACKLASH_STATE.U0]
        shift = 0.0
        if self._fx.effects:
            t = self._time(time_s)
            q = math.nan if torque_Nm is None else float(torque_Nm)
            rows = self._fx.terms(
                np.array([u]), np.array([t]), np.array([q]), [copy.deepcopy(e) for e in self._fx.effects]
            )
            shift = float(self._beta @ rows[0])
        x_prev = st[BACKLASH_STATE.Y_PREV] - self._prev_shift
        y_left = st[BACKLASH_STATE.LEFT + FLANK.B] + st[BACKLASH_STATE.LEFT + FLANK.M] * (
            uc - st[BACKLASH_STATE.LEFT + FLANK.UREF]
        )
        y_right = st[BACKLASH_STATE.RIGHT + FLANK.B] + st[BACKLASH_STATE.RIGHT + FLANK.M] * (
            uc - st[BACKLASH_STATE.RIGHT + FLANK.UREF]
        )
        if (y_left - x_prev) * st[BACKLASH_STATE.LEFT + FLANK.M] <= 0.0:  # eq. (5)
            x = y_left
        elif (x_prev - y_right) * st[BACKLASH_STATE.RIGHT + FLANK.M] <= 0.0:  # eq. (6)
            x = y_right
        else:
            x = x_prev
        return float(x + shift + st[BACKLASH_STATE.Y0])

    # -- fitted attributes -----------------------------------------------------------------------
    def _lines(self) -> tuple[float, float, float, float, float, float]:
        st, left, right = self._st, BACKLASH_STATE.LEFT, BACKLASH_STATE.RIGHT
        return (
            st[left + FLANK.M], st[left + FLANK.B], st[left + FLANK.UREF],
            st[right + FLANK.M], st[right + FLANK.B], st[right + FLANK.UREF],
        )  # fmt: skip

    @property
    def theta_(self) -> np.ndarray:
        """``[mL, mL cL, mR, mR cR]``, eq. (8), in reference-origin coordinates."""
        self._check_started()
        mL, bL, uL, mR, bR, uR = self._lines()
        return np.array([mL, bL - mL * uL, mR, -(bR - mR * uR)])

    def _local_cov(self) -> np.ndarray:
        """Unscaled covariance of ``[mL, bL, mR, bR]`` (local coordinates)."""
        if self._fx.effects:
            return np.linalg.inv(self._R)[:4, :4]
        st = self._st
        R = np.zeros((4, 4))
        for j, o in ((0, BACKLASH_STATE.LEFT), (2, BACKLASH_STATE.RIGHT)):
            R[j : j + 2, j : j + 2] = [[st[o + FLANK.R11], st[o + FLANK.R12]], [st[o + FLANK.R12], st[o + FLANK.R22]]]
        return np.linalg.inv(R)

    @property
    def P_local_(self) -> np.ndarray:
        """Unscaled covariance of the local lines ``[mL, bL, mR, bR]`` (``b`` at each flank's latest operating
        point)."""
        self._check_started()
        return self._local_cov()

    @property
    def P_(self) -> np.ndarray:
        """Unscaled covariance of ``theta_`` (reference-origin coordinates)."""
        self._check_started()
        _, _, uL, _, _, uR = self._lines()
        T = np.array([[1, 0, 0, 0], [-uL, 1, 0, 0], [0, 0, 1, 0], [0, 0, uR, -1]], dtype=float)
        return T @ self._local_cov() @ T.T

    def _play_level_deg(self) -> float:
        """The output level the play is read at, in the caller's frame, where it is the flanks' (``full_engagement``
        without effects); 0 otherwise."""
        return self._level() + self.y_ref_ if self._c[BACKLASH_CONSTS.ENGAGED_LEVEL] else 0.0

    def _level(self) -> float:
        """The output level the play is read at (reference-origin coordinates): the current one, or with
        ``full_engagement`` (and no effects) where the flanks were fully engaged (:func:`~._rls_kernels.play_level`)."""
        return float(kernels.play_level(self._st, self._c, self._st[BACKLASH_STATE.Y_PREV]))

    def _flank_split(self) -> tuple[float, float]:
        """Distances from the reference point to the left and right flanks at the level the play is read at.

        The reference point is the reference origin carried along the band at the mean slope,
        ``u* = level / ((mL + mR) / 2)`` (reference-origin coordinates).
        """
        self._check_started()
        mL, bL, uL, mR, bR, uR = self._lines()
        level = self._level()
        u_star = level / (0.5 * (mL + mR))
        return u_star - (uL + (level - bL) / mL), (uR + (level - bR) / mR) - u_star

    @property
    def c_left_(self) -> float:
        """Distance from the reference point to the left flank (eq. 9's ``c1 / m1`` at the origin's level)."""
        return float(self._flank_split()[0])

    @property
    def c_right_(self) -> float:
        """Distance from the reference point to the right flank (eq. 9's ``c2 / m2`` at the origin's level)."""
        return float(self._flank_split()[1])

    @property
    def backlash_(self) -> float:
        """Play at the current output level (local lines), input units; with ``full_engagement`` (and no
        effects) at the level where the flanks were fully engaged (midway between the two flanks'
        information centroids: where each line is best placed)."""
        self._check_started()
        return float(kernels.flank_width(self._st, self._level()))

    @property
    def beta_(self) -> np.ndarray:
        """Coefficients of the effect terms (empty without effects)."""
        self._check_started()
        return self._beta.copy()

    def _flank_ages(self) -> tuple[float, float]:
        """Mean age, seconds of motion, of each flank's information (grows while it is disengaged)."""
        st = self._st
        ages = []
        for o in (BACKLASH_STATE.LEFT, BACKLASH_STATE.RIGHT):
            count = st[o + FLANK.W_COUNT]
            ages.append(st[BACKLASH_STATE.T_MOTION] - st[o + FLANK.W_TIME] / count if count > 0 else 0.0)
        return ages[0], ages[1]

    @property
    def backlash_std_(self) -> float:
        """Standard error of ``backlash_``: noise through the local covariance, plus the lag behind the wear
        and (``full_engagement``) what the samples left out would take off the play."""
        self._check_started()
        mL, bL, _, mR, bR, _ = self._lines()
        level = self._level()
        # d width / d [mL, bL, mR, bR] with width = uR(level) - uL(level), uX = uref + (level - bX) / mX
        g = np.array([(level - bL) / mL**2, 1.0 / mL, -(level - bR) / mR**2, -1.0 / mR])
        var = self.noise_var_ * float(g @ self._local_cov() @ g)
        age_left, age_right = self._flank_ages()
        lag = abs(self.wear_rate_) * 0.5 * (age_left + age_right)
        engagement = 0.0 if self._fe is None else self._fe.engagement_std_deg_
        return math.sqrt(max(var, 0.0) + lag * lag + engagement * engagement)
