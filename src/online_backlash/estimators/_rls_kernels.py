"""Per-sample update steps of the recursive estimators, written once in plain Python.

Every step works on a flat state vector: a Python list on the interpreted path
(``learn_one``, the readable reference) and a float64 array on the compiled path
(``learn_many``: the *same source* compiled by numba). So both paths do the same
arithmetic in the same order and give the same estimates. The vectors' fields are declared
once, by name and size (:mod:`.layout`): :data:`BACKLASH_STATE` (BacklashRLS state), :data:`FLANK` (one flank's
block in it), :data:`BACKLASH_CONSTS` (BacklashRLS constants), :data:`CASCADE_STATE` (CascadeRLS scalars, followed by
the regions of :func:`cascade_offsets`) and :data:`CASCADE_CONSTS` (CascadeRLS constants).

Equation numbers refer to J. Vörös, Automatica 46 (2010) 369-374 (``PAPER.md``).

BacklashRLS: each flank keeps its line *in local coordinates*, ``y = b + m (u - u_ref)`` with
``u_ref`` the input of the flank's latest update, and its information matrix ``R`` (the inverse
of the unscaled covariance) for ``[m, b]``. Moving the reference is an exact
reparametrisation (``b += m d``, ``R <- T^-T R T^-1``), so the regressor of eq. (8) on an
engaged flank becomes ``[0, 1]`` and the intercept is never an extrapolation to a far-away
origin.

The switching functions eq. (12)-(13) are evaluated on the model's own output ``X_HAT``
(``switching="model"``, the default without effects)
(eq. 1-3 run with the current estimates: on the engaged flank's line, held in the dead band),
not on the measured ``x(t-1)``: the *output-error* classification of the batch estimator's
final refinement. With the measured output, noise and a compliance ramp after each reversal
(the load creeping up to the flank) put samples that the model sees on a flank into the
dead band, so the flank's line is fitted without them.

The step is split so that the effects path (:class:`~.backlash_rls.BacklashRLS` with effect
columns, numpy) runs the same pieces -- :func:`begin_sample`, :func:`select_flank`,
:func:`forget_counts`, :func:`recenter`, :func:`track_noise`, :func:`close_update` -- and only
replaces the 2x2 information update of :func:`update_side` by the joint one.

Compiled with ``inline="always"`` (numba inlines the pieces into the loop: on input that
reverses every few samples a call per piece cost a third of the time) and
``error_model="numpy"`` (no ZeroDivisionError check per division; the arithmetic is the same).
The loops are compiled with ``nogil=True``: they touch only their arrays, so they release the
GIL while they run and a reader thread (:func:`~online_backlash.pipeline.read_ahead`) decodes
the next block on the other core meanwhile.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .full_engagement import FOLLOWING, NO_FLANK
from .layout import offsets


# ---- BacklashRLS state layout: field sizes, in order ----------------------------------------
class FlankFields(NamedTuple):
    """One flank's block of the BacklashRLS state."""

    M: int = 1  # slope
    B: int = 1  # intercept at UREF (local coordinates)
    UREF: int = 1  # input of the flank's latest update
    R11: int = 1  # information matrix of [m, b]
    R12: int = 1
    R22: int = 1
    W_COUNT: int = 1  # forgotten count of updates (for the mean age of the information)
    W_TIME: int = 1  # forgotten sum of their motion times
    N_UPD: int = 1  # updates of this flank


FLANK, FLANK_SIZE = offsets(FlankFields())


class BacklashFields(NamedTuple):
    """The BacklashRLS state vector."""

    N_SEEN: int = 1  # samples learned
    HAVE_PREV: int = 1  # 0 at the start and after a gap: no motion is read from the previous sample
    U0: int = 1  # reference origin of the input
    Y0: int = 1  # ... and of the output
    U_PREV: int = 1  # previous input and output (reference-origin coordinates)
    Y_PREV: int = 1
    T_MOTION: int = 1  # the motion clock: seconds during which the motor moved
    LEFT: int = FLANK_SIZE  # the left flank's block (its offset is also its code in LAST_SIDE)
    RIGHT: int = FLANK_SIZE  # the right flank's block
    LAST_SIDE: int = 1  # the flank driven last (LEFT, RIGHT or 0)
    N_REV: int = 1  # changes of the driving flank
    NOISE_VAR: int = 1  # running variance of the a-priori residuals
    N_RESID: int = 1  # residuals counted
    W_EWMA: int = 1  # EWMA of the play at reversals (wear tracker)
    W_EWMA_SET: int = 1
    T_LAST_REV: int = 1  # motion time of the last reversal
    W_RATE: int = 1  # estimated rate of change of the play
    X_HAT: int = 1  # the model's output, eq. (1)-(3) with the current estimates
    HOLD_SIDE: int = 1  # the flank X_HAT rests on (0: unknown, after a start or gap)


BACKLASH_STATE, STATE_SIZE = offsets(BacklashFields())


class BacklashConsts(NamedTuple):
    """The BacklashRLS constants vector (settings, and FREEZE during the warm-start replay)."""

    DT: int = 1  # sample period, s
    LAM: int = 1  # forgetting per update
    LAM_REV: int = 1  # forgetting per reversal
    FLOOR_M: int = 1  # information floor of the slope
    FLOOR_B: int = 1  # ... and of the intercept
    MIN_STEP: int = 1  # input steps no larger than this carry no information
    NOISE_WINDOW: int = 1  # updates averaged by the noise variance
    WEAR_HORIZON: int = 1  # time constant of the wear tracker, s of motion
    ORIGIN_FIRST: int = 1  # 1: the first sample is the reference origin
    FREEZE: int = 1  # 1: lines held (the information is gathered only)
    SWITCH_MODEL: int = 1  # 1: eq. (12)-(13) on the model's output X_HAT, 0: on the measured one
    HOLD_BAND: int = 1  # a load seen following that far from the model's held output is not held by a flank
    ENGAGED_LEVEL: int = 1  # 1: the play is read where the flanks' information lies, 0: at the current output level


BACKLASH_CONSTS, N_CONSTS = offsets(BacklashConsts())


def _make_to_reference(jit):
    @jit
    def to_reference(st, origin_first, n_seen, u0, y0, u, y):
        """Count a sample (field ``n_seen``), take the first one as the reference origin (fields
        ``u0``, ``y0``) if ``origin_first``, and return ``u``, ``y`` referred to the origin."""
        if st[n_seen] == 0.0 and origin_first:
            st[u0] = u
            st[y0] = y
        st[n_seen] += 1.0
        return u - st[u0], y - st[y0]

    return to_reference


def _make_backlash_steps(jit):
    """Build the BacklashRLS step functions, compiled by ``jit`` (numba's ``njit`` or the identity)."""
    to_reference = _make_to_reference(jit)

    @jit
    def begin_sample(st, c, u, y):
        """Reference origin, counters and previous sample. Returns ``(uc, yc, du, y_prev)``.

        ``du = 0`` means no update can follow (first sample, after a gap, motor still, or a
        step no larger than ``min_step_deg``).
        """
        uc, yc = to_reference(
            st,
            c[BACKLASH_CONSTS.ORIGIN_FIRST] != 0.0,
            BACKLASH_STATE.N_SEEN,
            BACKLASH_STATE.U0,
            BACKLASH_STATE.Y0,
            u,
            y,
        )
        du = uc - st[BACKLASH_STATE.U_PREV]
        y_prev = st[BACKLASH_STATE.Y_PREV]
        if st[BACKLASH_STATE.HAVE_PREV] == 0.0:
            du = 0.0
            st[BACKLASH_STATE.X_HAT] = yc  # (re)start the model's output at the measured one
            st[BACKLASH_STATE.HOLD_SIDE] = 0.0
        st[BACKLASH_STATE.HAVE_PREV] = 1.0
        st[BACKLASH_STATE.U_PREV] = uc
        st[BACKLASH_STATE.Y_PREV] = yc
        if du != 0.0:
            st[BACKLASH_STATE.T_MOTION] += c[
                BACKLASH_CONSTS.DT
            ]  # the motion clock: seconds during which the motor moved
        if abs(du) <= c[BACKLASH_CONSTS.MIN_STEP]:
            du = 0.0
        return uc, yc, du, y_prev

    @jit
    def engaged_side(st, uc, x_prev, du):
        """The flank that drives the load now, eq. (12)-(13), or 0.

        ``f1 = h((mL u + mL cL - x(t-1)) / mL)`` is evaluated as the sign of
        ``(yL(u) - x(t-1)) mL`` (same sign, no division), with ``yL`` the local left line
        and ``x(t-1) = x_prev`` (the model's output ``X_HAT``, or the measured one).
        A flank carries information only while the motor drives into it: the left one
        when ``u`` decreases, the right one when ``u`` increases.
        """
        # both sides evaluated, then one picked: no branch on the direction, which reverses
        # every few samples on some inputs (a mispredicted branch each time)
        m_left = st[BACKLASH_STATE.LEFT + FLANK.M]
        m_right = st[BACKLASH_STATE.RIGHT + FLANK.M]
        left = (
            st[BACKLASH_STATE.LEFT + FLANK.B] + m_left * (uc - st[BACKLASH_STATE.LEFT + FLANK.UREF]) - x_prev
        ) * m_left <= 0.0  # eq. (12)
        right = (
            x_prev - st[BACKLASH_STATE.RIGHT + FLANK.B] - m_right * (uc - st[BACKLASH_STATE.RIGHT + FLANK.UREF])
        ) * m_right <= 0.0  # eq. (13)
        return BACKLASH_STATE.LEFT * (du < 0.0 and left) + BACKLASH_STATE.RIGHT * (du > 0.0 and right)

    @jit
    def flank_width(st, level):
        """Horizontal distance between the flanks at output ``level``: the play, input units."""
        u_left = (
            st[BACKLASH_STATE.LEFT + FLANK.UREF]
            + (level - st[BACKLASH_STATE.LEFT + FLANK.B]) / st[BACKLASH_STATE.LEFT + FLANK.M]
        )
        u_right = (
            st[BACKLASH_STATE.RIGHT + FLANK.UREF]
            + (level - st[BACKLASH_STATE.RIGHT + FLANK.B]) / st[BACKLASH_STATE.RIGHT + FLANK.M]
        )
        return u_right - u_left

    @jit
    def play_level(st, c, level):
        """The output level the play is read at: ``level`` (the current output), or with ``ENGAGED_LEVEL``
        midway between the two flanks' information centroids (each line is best placed where its data lie,
        ``b + m R12 / R22`` at ``u_ref + R12 / R22``: where the flanks were fully engaged, whatever the output
        is doing now)."""
        if c[BACKLASH_CONSTS.ENGAGED_LEVEL] == 0.0:
            return level
        left = (
            st[BACKLASH_STATE.LEFT + FLANK.B]
            + st[BACKLASH_STATE.LEFT + FLANK.M]
            * st[BACKLASH_STATE.LEFT + FLANK.R12]
            / st[BACKLASH_STATE.LEFT + FLANK.R22]
        )
        right = (
            st[BACKLASH_STATE.RIGHT + FLANK.B]
            + st[BACKLASH_STATE.RIGHT + FLANK.M]
            * st[BACKLASH_STATE.RIGHT + FLANK.R12]
            / st[BACKLASH_STATE.RIGHT + FLANK.R22]
        )
        return 0.5 * (left + right)

    @jit
    def reversal(st, c, side, level):
        """Count a change of the driving flank; track the wear rate; return the per-reversal forgetting."""
        last = st[BACKLASH_STATE.LAST_SIDE]
        st[BACKLASH_STATE.LAST_SIDE] = side
        if last == 0.0 or last == side:
            return 1.0
        st[BACKLASH_STATE.N_REV] += 1.0
        # rate of change of the play: an EWMA of the play with time constant H (seconds of
        # motion) lags a ramp of slope r by r H, so r = (width - ewma) / H
        w = flank_width(st, play_level(st, c, level))
        t = st[BACKLASH_STATE.T_MOTION]
        horizon = c[BACKLASH_CONSTS.WEAR_HORIZON]
        if st[BACKLASH_STATE.W_EWMA_SET] == 0.0:
            st[BACKLASH_STATE.W_EWMA] = w
            st[BACKLASH_STATE.W_EWMA_SET] = 1.0
        else:
            a = (t - st[BACKLASH_STATE.T_LAST_REV]) / horizon
            if a > 1.0:
                a = 1.0
            st[BACKLASH_STATE.W_EWMA] += a * (w - st[BACKLASH_STATE.W_EWMA])
            st[BACKLASH_STATE.W_RATE] = (w - st[BACKLASH_STATE.W_EWMA]) / horizon
        st[BACKLASH_STATE.T_LAST_REV] = t
        return c[BACKLASH_CONSTS.LAM_REV]

    @jit
    def select_flank(st, c, uc, du, x_measured, level):
        """The flank this sample updates: ``(side, lam_rev, engaged)``; ``side = 0``: none.

        An engaged flank (eq. 12-13 on ``X_HAT`` or on ``x_measured``, the measured
        ``x(t-1)``) counts a reversal (:func:`reversal`, at output ``level``), whose forgetting
        ``lam_rev`` the caller applies before moving the flank's reference to ``uc``. With
        ``switching="model"``, motion inside the dead band updates the flank last driven at its
        reference (``engaged`` False).
        """
        model = c[BACKLASH_CONSTS.SWITCH_MODEL] != 0.0
        side = engaged_side(st, uc, st[BACKLASH_STATE.X_HAT] if model else x_measured, du)
        if side == 0:
            if model and st[BACKLASH_STATE.HOLD_SIDE] != 0.0:  # moving in the dead band
                return int(st[BACKLASH_STATE.HOLD_SIDE]), 1.0, False
            return 0, 1.0, False
        return side, reversal(st, c, side, level), True

    @jit
    def left_the_hold(st, c, seen, engaged, x):
        """The model holds the load in the dead band (``engaged`` False) where the motion shows it following
        the motor (``seen`` ``FOLLOWING``) at ``x``, farther than ``HOLD_BAND`` from the held output: no flank
        holds it there, and the sample updates no line."""
        return seen == FOLLOWING and not engaged and abs(x - st[BACKLASH_STATE.X_HAT]) > c[BACKLASH_CONSTS.HOLD_BAND]

    @jit
    def pass_by(st, yc):
        """A sample on no flank (a partial crossing of the gap): no flank holds the load where the model's
        output last was; it restarts at the measured output, on no flank (as after a gap)."""
        st[BACKLASH_STATE.X_HAT] = yc
        st[BACKLASH_STATE.HOLD_SIDE] = 0.0

    @jit
    def forget_counts(st, o, lam):
        """Forget the age bookkeeping of flank ``o`` like its information."""
        st[o + FLANK.W_COUNT] = lam * st[o + FLANK.W_COUNT]
        st[o + FLANK.W_TIME] = lam * st[o + FLANK.W_TIME]

    @jit
    def forget_side(st, o, lam, floor_m, floor_b):
        """Regularised exponential forgetting of one flank: ``R <- lam R + (1 - lam) R_floor``."""
        st[o + FLANK.R11] = lam * st[o + FLANK.R11] + (1.0 - lam) * floor_m
        st[o + FLANK.R12] = lam * st[o + FLANK.R12]
        st[o + FLANK.R22] = lam * st[o + FLANK.R22] + (1.0 - lam) * floor_b
        forget_counts(st, o, lam)

    @jit
    def recenter(st, o, uc):
        """Move the flank's reference to ``uc``: ``b += m d``, ``R <- T^-T R T^-1``; returns ``d``."""
        d = uc - st[o + FLANK.UREF]
        st[o + FLANK.B] += st[o + FLANK.M] * d
        r12 = st[o + FLANK.R12]
        r22 = st[o + FLANK.R22]
        st[o + FLANK.R11] = st[o + FLANK.R11] - 2.0 * d * r12 + d * d * r22
        st[o + FLANK.R12] = r12 - d * r22
        st[o + FLANK.UREF] = uc
        return d

    @jit
    def track_noise(st, c, e):
        """Running variance of the a-priori residuals (window ``noise_window`` updates)."""
        n = st[BACKLASH_STATE.N_RESID] + 1.0
        st[BACKLASH_STATE.N_RESID] = n
        st[BACKLASH_STATE.NOISE_VAR] += (e * e - st[BACKLASH_STATE.NOISE_VAR]) / min(n, c[BACKLASH_CONSTS.NOISE_WINDOW])

    @jit
    def close_update(st, o):
        """Bookkeeping after an update of flank ``o``: age, count, and the model's output on its line."""
        st[o + FLANK.W_COUNT] += 1.0
        st[o + FLANK.W_TIME] += st[BACKLASH_STATE.T_MOTION]
        st[o + FLANK.N_UPD] += 1.0
        st[BACKLASH_STATE.X_HAT] = st[o + FLANK.B]  # the model's output: on the updated line, at its reference
        st[BACKLASH_STATE.HOLD_SIDE] = o

    @jit
    def update_side(st, c, o, yc):
        """One RLS update of flank ``o``'s line at its reference with target ``y(t)``.

        On an engaged flank (reference moved to ``u(t)`` first) this is eq. (11); in the
        dead band (reference left where the flank was last driven) it is the output-error
        gradient of eq. (1)'s third case: the load rests where the flank left it.
        """
        if c[BACKLASH_CONSTS.LAM] != 1.0:  # lam = 1 would leave R unchanged, bit for bit
            forget_side(st, o, c[BACKLASH_CONSTS.LAM], c[BACKLASH_CONSTS.FLOOR_M], c[BACKLASH_CONSTS.FLOOR_B])
        e = yc - st[o + FLANK.B]  # a-priori error, eq. (14); the local regressor is [0, 1]
        track_noise(st, c, e)
        r11 = st[o + FLANK.R11]
        r12 = st[o + FLANK.R12]
        r22 = st[o + FLANK.R22] + 1.0  # R <- R + phi phi^T
        st[o + FLANK.R22] = r22
        if c[BACKLASH_CONSTS.FREEZE] == 0.0:  # frozen lines: only the information is gathered (warm start)
            g = e / (r11 * r22 - r12 * r12)
            st[o + FLANK.M] -= r12 * g  # theta += R^-1 phi e, R^-1 phi = [-r12, r11] / det
            st[o + FLANK.B] += r11 * g
        close_update(st, o)

    @jit
    def step(st, c, u, y, seen):
        """Learn one sample ``(u, y)`` (input and output in the caller's frame). ``seen``: what the motion
        shows of it (:class:`~.full_engagement.FullEngagement`): ``NO_FLANK`` (a partial crossing of the gap)
        updates no line and leaves the model's output where the load is (:func:`pass_by`); ``FOLLOWING``
        (the load moves with the motor) updates no line where the model holds
        the load in the dead band and the load has left the held output by more than ``HOLD_BAND`` (no flank
        holds it there); ``RESTING`` leaves the model to judge."""
        uc, yc, du, y_prev = begin_sample(st, c, u, y)
        if seen == NO_FLANK:
            pass_by(st, yc)
            return
        if du == 0.0:
            return
        side, lam, engaged = select_flank(st, c, uc, du, y_prev, yc)
        if side == 0 or left_the_hold(st, c, seen, engaged, yc):
            return
        if lam != 1.0:
            forget_side(st, BACKLASH_STATE.LEFT, lam, c[BACKLASH_CONSTS.FLOOR_M], c[BACKLASH_CONSTS.FLOOR_B])
            forget_side(st, BACKLASH_STATE.RIGHT, lam, c[BACKLASH_CONSTS.FLOOR_M], c[BACKLASH_CONSTS.FLOOR_B])
        if engaged:
            recenter(st, side, uc)
        update_side(st, c, side, yc)

    return (
        begin_sample, select_flank, left_the_hold, pass_by, flank_width, play_level, forget_counts, recenter,
        track_noise, close_update, step,
    )  # fmt: skip


def _identity(f):
    return f


_JIT = njit(cache=True, nogil=True, inline="always", error_model="numpy")
#: The loops over the samples: without numba's reference counting (``_nrt=False``). They allocate nothing and
#: return nothing, but each step inlined into them binds the arrays it is given (``st``, ``c``, scratch) anew per
#: sample, and numba counts those references with atomic increments and decrements that its pruning pass leaves
#: in place when the step branches (numba issues 2345 and 2350, where its developers give this flag as the cure):
#: eight per sample cost the cascade and BacklashRLS half their time. The arithmetic is the same, bit for bit.
#: (``_nrt`` is a keyword of numba's jit options that numba's own type hints do not list)
_LOOP = njit(cache=True, nogil=True, error_model="numpy", _nrt=False)  # type: ignore[call-overload]

(
    begin_sample,
    select_flank,
    left_the_hold,
    pass_by,
    flank_width,
    play_level,
    forget_counts,
    recenter,
    track_noise,
    close_update,
    backlash_step,
) = _make_backlash_steps(_identity)
_compiled_steps = _make_backlash_steps(_JIT)
_backlash_step_nb = _compiled_steps[-1]
_flank_width_nb = _compiled_steps[4]
_play_level_nb = _compiled_steps[5]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _run_span(st, c, u, y, after_gap, seen, lo, hi):  # pragma: no cover - compiled
    """:func:`backlash_step` over samples ``lo:hi`` of the arrays, honouring gaps and what the motion shows
    (``seen``)."""
    for i in range(lo, hi):
        if after_gap[i]:
            st[BACKLASH_STATE.HAVE_PREV] = 0.0
        _backlash_step_nb(st, c, u[i], y[i], seen[i])


@_LOOP
def backlash_run(st, c, u, y, after_gap, seen, marks, out):  # pragma: no cover - compiled
    """``learn_many``'s loop: :func:`backlash_step` over arrays, honouring gaps and ``seen``, recording the estimate
    after the first ``marks[k]`` samples (ascending, 1..n; none: :data:`NO_MARKS`) in ``out[k]``: the
    play at the level it is read at (:func:`flank_width` at :func:`play_level`, input units) and the
    slopes ``mL``, ``mR`` of eq. (1), and with ``ENGAGED_LEVEL`` that level in the caller's frame (0 without)
    -- what the estimator's ``estimate_now()`` would read there, without cutting the loop. One compiled loop
    for both uses: one load from numba's cache."""
    lo = 0
    for k in range(marks.shape[0]):
        hi = marks[k]
        _run_span(st, c, u, y, after_gap, seen, lo, hi)
        level = _play_level_nb(st, c, st[BACKLASH_STATE.Y_PREV])
        out[k, 0] = _flank_width_nb(st, level)
        out[k, 1] = st[BACKLASH_STATE.LEFT + FLANK.M]
        out[k, 2] = st[BACKLASH_STATE.RIGHT + FLANK.M]
        out[k, 3] = level + st[BACKLASH_STATE.Y0] if c[BACKLASH_CONSTS.ENGAGED_LEVEL] != 0.0 else 0.0
        lo = hi
    _run_span(st, c, u, y, after_gap, seen, lo, u.shape[0])


#: ``marks`` and ``out`` of :func:`backlash_run` without marks
NO_MARKS = (np.empty(0, dtype=np.int64), np.empty((0, 4)))


# ---- CascadeRLS state layout -----------------------------------------------------------------
class CascadeFields(NamedTuple):
    """The CascadeRLS scalars, followed by the regions of :func:`cascade_offsets`."""

    N_SEEN: int = 1  # samples learned
    U0: int = 1  # reference origin of the input
    Y0: int = 1  # ... and of the output
    K: int = 1  # samples since the start or the last gap (capped at 1e9)
    U_PREV: int = 1  # previous input (reference-origin coordinates)
    F1: int = 1  # switching functions of t-1, eq. (12)-(13)
    F2: int = 1
    NOISE_VAR: int = 1  # running variance of the a-priori residuals
    N_RES: int = 1  # residuals counted
    IDLE: int = 1  # samples with the input still
    LAST: int = 1  # the side engaged last (1 left, 2 right)
    N_REV: int = 1  # changes of the engaged side
    PSI_HEAD: int = 1  # slot of psi(t-1) in the ring of filtered gradients


CASCADE_STATE, CASCADE_SCALARS = offsets(CascadeFields())


class CascadeConsts(NamedTuple):
    """The CascadeRLS constants vector."""

    LAM: int = 1  # forgetting per update
    LAM_REV: int = 1  # extra forgetting per reversal
    TRACE_MAX: int = 1  # bound on trace(P)
    NOISE_WINDOW: int = 1  # updates averaged by the noise variance
    ORIGIN_FIRST: int = 1  # 1: the first sample is the reference origin
    NA: int = 1  # n_a
    NB: int = 1  # n_b
    OUTPUT_ERROR: int = 1  # 1: the model's simulated output in the regressor
    FREEZE: int = 1  # 1: theta held (the information is gathered only)
    PRED_ERROR: int = 1  # 1: recursive prediction-error gradient


CASCADE_CONSTS, N_CASCADE_CONSTS = offsets(CascadeConsts())


def _make_cascade_offsets(jit):
    @jit
    def cascade_offsets(na, nb):
        """Regions of a CascadeRLS state vector after the scalars :data:`CASCADE_STATE`.

        Returns ``(p, op, ox, nx, oy, oyh, osx, opsi, size)``: the number of parameters
        ``p = 4 + n_a - 1 + n_b`` and the offsets of theta (``CASCADE_SCALARS``, p), P
        (``op``, p*p row-major), the x_hat history (``ox``, ``nx = max(n_a, 2)``), the y
        history (``oy``, n_b), the simulated-output history (``oyh``, n_b, the output-error
        regressor), d x_hat / d [m1, c1, m2, c2] per x_hat entry (``osx``, 4 nx) and the ring
        of filtered gradients psi (``opsi``, n_b + 1 slots of p), then the total size.
        """
        p = 4 + na - 1 + nb
        op = CASCADE_SCALARS + p
        ox = op + p * p
        nx = max(na, 2)
        oy = ox + nx
        oyh = oy + nb
        osx = oyh + nb
        opsi = osx + 4 * nx
        return p, op, ox, nx, oy, oyh, osx, opsi, opsi + p * (nb + 1)

    return cascade_offsets


cascade_offsets = _make_cascade_offsets(_identity)
C_THETA = CASCADE_SCALARS  # theta follows the scalars


def _make_cascade_step(jit, orders=(-1, -1)):
    """The cascade's step compiled by ``jit``; ``orders = (n_a, n_b)`` fixes them at compile time (the loops then
    have constant trip counts and the state's regions constant offsets: the same arithmetic, in the same order,
    unrolled), ``(-1, -1)`` reads them from the constants ``c`` at every sample."""
    offsets_of = _make_cascade_offsets(jit)
    to_reference = _make_to_reference(jit)
    na_fixed, nb_fixed = orders

    @jit
    def step(st, c, u, y, phi, pphi):
        """Learn one sample of the cascade, eq. (18)-(24); ``phi``, ``pphi`` are scratch vectors of length p."""
        na = int(c[CASCADE_CONSTS.NA]) if na_fixed < 0 else na_fixed
        nb = int(c[CASCADE_CONSTS.NB]) if nb_fixed < 0 else nb_fixed
        # osx + 4 i: d x_hat(t-1-i) / d [m1, c1, m2, c2]; opsi: the ring of psi vectors
        p, op, ox, nx, oy, oyh, osx, opsi, _ = offsets_of(na, nb)
        oe = c[CASCADE_CONSTS.OUTPUT_ERROR] != 0.0
        pe = c[CASCADE_CONSTS.PRED_ERROR] != 0.0
        uc, yc = to_reference(
            st, c[CASCADE_CONSTS.ORIGIN_FIRST] != 0.0, CASCADE_STATE.N_SEEN, CASCADE_STATE.U0, CASCADE_STATE.Y0, u, y
        )
        y_hat = yc  # the model output where no regression runs
        if st[CASCADE_STATE.K] == 0.0:
            # start, or restart after a gap: the system at rest, x = y B(1) / A(1)
            a_sum = 1.0
            for i in range(1, na):
                a_sum += st[C_THETA + 3 + i]
            b_sum = 1.0
            for j in range(nb):
                b_sum += st[C_THETA + 3 + na + j]
            x0 = yc * b_sum / a_sum if a_sum != 0.0 else yc
            for i in range(nx):
                st[ox + i] = x0
            for j in range(nb):
                st[oy + j] = yc
                st[oyh + j] = yc
            for i in range(4 * nx + p * (nb + 1)):
                st[osx + i] = 0.0
            st[CASCADE_STATE.U_PREV] = uc
            st[CASCADE_STATE.IDLE] = 0.0
        elif st[CASCADE_STATE.K] >= max(na, nb, 2) and st[CASCADE_STATE.IDLE] <= na + nb + 1:
            # ---- regression on eq. (18)-(19) with the switching functions of t-1 (eq. 23)
            f1p = st[CASCADE_STATE.F1]
            f2p = st[CASCADE_STATE.F2]
            u1 = st[CASCADE_STATE.U_PREV]
            phi[0] = u1 * f1p
            phi[1] = f1p
            phi[2] = u1 * f2p
            phi[3] = -f2p
            for i in range(1, na):
                phi[3 + i] = st[ox + i]  # x_hat(t-1-i)
            for j in range(nb):
                # -y(t-1-j); output-error form: the model's own simulated output instead
                phi[3 + na + j] = -st[oyh + j] if oe else -st[oy + j]
            target = yc - st[ox + 1] * (1.0 - f1p) * (1.0 - f2p)  # eq. (24)
            lam = c[CASCADE_CONSTS.LAM]
            side = 1.0 if f1p > 0.0 else (2.0 if f2p > 0.0 else 0.0)
            if side != 0.0:
                if st[CASCADE_STATE.LAST] != 0.0 and st[CASCADE_STATE.LAST] != side:
                    st[CASCADE_STATE.N_REV] += 1.0
                    lam = lam * c[CASCADE_CONSTS.LAM_REV]
                st[CASCADE_STATE.LAST] = side
            # forgetting P <- P / lam, limited so that trace(P) stays <= trace_max (anti-windup)
            tr = 0.0
            for i in range(p):
                tr += st[op + i * p + i]
            if tr > lam * c[CASCADE_CONSTS.TRACE_MAX]:
                lam = tr / c[CASCADE_CONSTS.TRACE_MAX]
                if lam > 1.0:
                    lam = 1.0
            if lam != 1.0:
                inv_lam = 1.0 / lam
                for i in range(p * p):
                    st[op + i] = st[op + i] * inv_lam
            e = target
            for i in range(p):
                e -= st[C_THETA + i] * phi[i]
            n = st[CASCADE_STATE.N_RES] + 1.0
            st[CASCADE_STATE.N_RES] = n
            st[CASCADE_STATE.NOISE_VAR] += (e * e - st[CASCADE_STATE.NOISE_VAR]) / min(
                n, c[CASCADE_CONSTS.NOISE_WINDOW]
            )
            if pe:
                # recursive prediction-error method: the gain follows the gradient of the model
                # output, d y_hat / d theta = (A / B) d x_hat / d[m1..c2], (q^-i / B) x_hat,
                # -(q^-j / B) y_hat (eq. 15-18 differentiated), i.e. phi with the sensitivity of
                # x_hat (held through the dead band) and filtered by 1 / B
                y_hat = yc - e  # a-priori model output
                for k in range(4):
                    g = st[osx + k]
                    for i in range(1, na):
                        g += st[C_THETA + 3 + i] * st[osx + 4 * i + k]
                    phi[k] = g
                n_slots = nb + 1
                head = int(st[CASCADE_STATE.PSI_HEAD])
                for j in range(1, nb + 1):  # psi(t) = raw(t) - sum_j b_j psi(t-j)
                    b_j = st[C_THETA + 3 + na + j - 1]
                    slot = head + j - 1  # (head + j - 1) mod n_slots, without an integer division
                    if slot >= n_slots:
                        slot -= n_slots
                    o = opsi + slot * p
                    for i in range(p):
                        phi[i] -= b_j * st[o + i]
                head += nb  # the free slot (psi(t-nb-1)) takes psi(t)
                if head >= n_slots:
                    head -= n_slots
                st[CASCADE_STATE.PSI_HEAD] = head
                o = opsi + head * p
                for i in range(p):
                    st[o + i] = phi[i]
            # P phi, one dot product per row, and s = 1 + phi' P phi (a zero of phi adds an exact
            # zero: the sums are those of the nonzero terms, in the same order)
            s = 1.0
            for i in range(p):
                row = op + i * p
                acc = 0.0
                for j in range(p):
                    acc += st[row + j] * phi[j]
                pphi[i] = acc
                s += phi[i] * acc
            inv_s = 1.0 / s
            if c[CASCADE_CONSTS.FREEZE] == 0.0:  # (warm-start replay: theta held, P gathers the information)
                for i in range(p):
                    st[C_THETA + i] += pphi[i] * inv_s * e  # gain K = P phi / (1 + phi' P phi)
            # P <- P - P phi phi' P / s; P stays exactly symmetric (pi pj = pj pi), so with the sizes fixed the
            # upper triangle is computed and mirrored (the same values; with sizes read at run time that is slower)
            for i in range(p):
                row = op + i * p
                pi = pphi[i]
                if na_fixed < 0:
                    for j in range(p):
                        st[row + j] -= (pi * pphi[j]) * inv_s
                else:
                    for j in range(i, p):
                        v = st[row + j] - (pi * pphi[j]) * inv_s
                        st[row + j] = v
                        st[op + j * p + i] = v
            if not pe:
                # a-posteriori model output (eq. 18 with the updated theta), for the output-error regressor
                y_hat = yc - target
                for i in range(p):
                    y_hat += st[C_THETA + i] * phi[i]
        if uc != st[CASCADE_STATE.U_PREV]:
            st[CASCADE_STATE.IDLE] = 0.0
        else:
            st[CASCADE_STATE.IDLE] += 1.0
        # ---- internal variable, eq. (23), with the current estimates
        m1 = st[C_THETA]
        c1 = st[C_THETA + 1]
        m2 = st[C_THETA + 2]
        c2 = st[C_THETA + 3]
        xp = st[ox]
        f1 = 1.0 if (m1 * uc + c1 - xp) * m1 <= 0.0 else 0.0  # eq. (12)
        f2 = 1.0 if (xp - m2 * uc + c2) * m2 <= 0.0 else 0.0  # eq. (13)
        if f1 > 0.0 and f2 > 0.0:  # crossed lines (cL + cR < 0 while learning): hold
            f1 = 0.0
            f2 = 0.0
        x = m1 * uc * f1 + c1 * f1 + m2 * uc * f2 - c2 * f2 + xp * (1.0 - f1) * (1.0 - f2)
        for i in range(nx - 1, 0, -1):
            st[ox + i] = st[ox + i - 1]
        st[ox] = x
        if pe:  # d x_hat / d [m1, c1, m2, c2]: the engaged line's regressor, else held
            for i in range(4 * nx - 1, 3, -1):
                st[osx + i] = st[osx + i - 4]
            if f1 > 0.0 or f2 > 0.0:
                st[osx] = uc * f1
                st[osx + 1] = f1
                st[osx + 2] = uc * f2
                st[osx + 3] = -f2
        for j in range(nb - 1, 0, -1):
            st[oy + j] = st[oy + j - 1]
            st[oyh + j] = st[oyh + j - 1]
        if nb > 0:
            st[oy] = yc
            st[oyh] = y_hat
        st[CASCADE_STATE.U_PREV] = uc
        st[CASCADE_STATE.F1] = f1
        st[CASCADE_STATE.F2] = f2
        if st[CASCADE_STATE.K] < 1e9:
            st[CASCADE_STATE.K] += 1.0

    return step


cascade_step = _make_cascade_step(_identity)
_cascade_step_nb = _make_cascade_step(_JIT)
_cascade_step_22 = _make_cascade_step(_JIT, (2, 2))


@_LOOP
def cascade_run(st, c, u, y, after_gap, phi, pphi):  # pragma: no cover - compiled
    """``learn_many``'s loop for the cascade."""
    if c[CASCADE_CONSTS.NA] == 2.0 and c[CASCADE_CONSTS.NB] == 2.0:
        for i in range(u.shape[0]):
            if after_gap[i]:
                st[CASCADE_STATE.K] = 0.0
            _cascade_step_22(st, c, u[i], y[i], phi, pphi)
        return
    for i in range(u.shape[0]):
        if after_gap[i]:
            st[CASCADE_STATE.K] = 0.0
        _cascade_step_nb(st, c, u[i], y[i], phi, pphi)
