"""The per-sample step of :class:`~.torque_rls.TorqueBacklashRLS`, written once in plain Python.

The step works on a flat state vector: a Python list on the interpreted path (``learn_one``)
and a float64 array on the compiled path (``learn_many``, the same source compiled by numba),
so both do the same scalar arithmetic in the same order. Fields are declared once by name and
size (:mod:`online_backlash.estimators.layout`).

Each flank keeps its line ``y = m (u - UC) + b - s tau`` in coordinates local to its latest
update ``UC`` (moving the centre is an exact reparametrisation, ``b += m d``, ``P <- J P J^T``)
and the unscaled covariance ``P`` of ``[m, b, s]``; the regressor of eq. (8) on the engaged
flank, with the wind-up column, is ``phi = [u - UC, 1, -tau]`` (:mod:`.flank_lines`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from numba import njit

from ..estimators.layout import offsets
from ..estimators.resolution import MEDIAN_ABS_D2


class FlankFields(NamedTuple):
    """One flank's block of the state."""

    M: int = 1  # slope
    B: int = 1  # level at UC, zero torque
    S: int = 1  # compliance, deg per N m
    UC: int = 1  # input of the flank's latest update (local centre)
    P: int = 9  # unscaled covariance of [m, b, s], row major
    N: int = 1  # updates of this flank
    QMAX: int = 1  # largest torque magnitude learned on it, N m
    QMEAN: int = 1  # mean torque magnitude and sum of squared deviations (Welford), N m, N^2 m^2
    QM2: int = 1
    W: int = 1  # weighted number of updates (forgetting applied): the weight of the torque-noise correction


TORQUE_FLANK, FLANK_SIZE = offsets(FlankFields())


class TorqueState(NamedTuple):
    N_SEEN: int = 1
    U0: int = 1  # reference origin
    Y0: int = 1
    NOISE_VAR: int = 1  # residual variance, deg^2
    N_REV: int = 1  # torque reversals (changes of the engaged flank through the dead band)
    LAST_FLANK: int = 1  # last engaged flank, -1 / +1 (0: none yet)
    HAVE_PREV: int = 1  # 0 right after a gap (or at the start)
    Q_PREV: int = 1  # the two previous torques (second difference)
    Q_PREV2: int = 1
    N_Q: int = 1  # torques in that history since the last gap, at most 2
    Q_MED: int = 1  # running median of |second difference of the torque|, N m
    N_QMED: int = 1  # updates of Q_MED
    U_LAST: int = 1  # input and torque of the latest flank update
    Q_LAST: int = 1
    N_UPD: int = 1  # flank updates
    Y_LEVEL: int = 1  # output of the latest flank update (reference coordinates)
    LEFT: int = FLANK_SIZE
    RIGHT: int = FLANK_SIZE
    ENG_LEFT: int = 1  # torque at which the left flank engages, N m (signed as learned; issue 27)
    ENG_RIGHT: int = 1  # and the right flank


TORQUE_STATE, STATE_SIZE = offsets(TorqueState())


class TorqueConsts(NamedTuple):
    FREEZE: int = 1  # 1: lines held (information only)
    LAM: int = 1  # forgetting per flank update
    LAM_REV: int = 1  # forgetting per torque reversal (applied to the flank engaged anew)
    DEADBAND: int = 1  # fixed torque dead band, N m; < 0: from the running noise median
    N_SIGMA: int = 1
    MED_UP: int = 1  # running-median factors exp(+eta), exp(-eta)
    MED_DOWN: int = 1
    NOISE_WARMUP: int = 1  # median updates before the running dead band is trusted
    MIN_STEP: int = 1  # input steps no larger than this carry no information, deg
    NOISE_WINDOW: int = 1
    ORIGIN_FIRST: int = 1
    P0: int = 1  # prior (and largest) variance of each parameter, unscaled


TORQUE_CONSTS, N_CONSTS = offsets(TorqueConsts())


def torque_step(st, c, u, y, q):
    """One sample: reference origin, torque noise, engaged flank, and the flank's RLS update.

    ``u``, ``y`` degrees (load side), ``q`` torque N m. Nothing is learned right after a gap,
    inside the dead band (taken about the torques at which the flanks engage, ``ENG_LEFT`` and
    ``ENG_RIGHT``: :func:`~.engagement.engaged_flank`), while the running dead band is still settling,
    or when neither the input (more than ``MIN_STEP``) nor the torque (more than the dead band) moved
    since the last update: a still drive carries no information, and the flank not engaged keeps its line.
    """
    if st[TORQUE_STATE.N_SEEN] == 0.0 and c[TORQUE_CONSTS.ORIGIN_FIRST] != 0.0:
        st[TORQUE_STATE.U0] = u
        st[TORQUE_STATE.Y0] = y
    st[TORQUE_STATE.N_SEEN] += 1.0
    uc = u - st[TORQUE_STATE.U0]
    yc = y - st[TORQUE_STATE.Y0]
    # torque noise: running median of |second difference| (a held value carries no noise information)
    if st[TORQUE_STATE.N_Q] >= 2.0:
        d2 = abs(q - 2.0 * st[TORQUE_STATE.Q_PREV] + st[TORQUE_STATE.Q_PREV2])
        if d2 > 0.0:
            if st[TORQUE_STATE.N_QMED] == 0.0:
                st[TORQUE_STATE.Q_MED] = d2
            elif d2 > st[TORQUE_STATE.Q_MED]:
                st[TORQUE_STATE.Q_MED] *= c[TORQUE_CONSTS.MED_UP]
            elif d2 < st[TORQUE_STATE.Q_MED]:
                st[TORQUE_STATE.Q_MED] *= c[TORQUE_CONSTS.MED_DOWN]
            st[TORQUE_STATE.N_QMED] += 1.0
    st[TORQUE_STATE.Q_PREV2] = st[TORQUE_STATE.Q_PREV]
    st[TORQUE_STATE.Q_PREV] = q
    st[TORQUE_STATE.N_Q] = min(st[TORQUE_STATE.N_Q] + 1.0, 2.0)
    if c[TORQUE_CONSTS.DEADBAND] >= 0.0:
        db = c[TORQUE_CONSTS.DEADBAND]
    elif st[TORQUE_STATE.N_QMED] >= c[TORQUE_CONSTS.NOISE_WARMUP]:
        db = c[TORQUE_CONSTS.N_SIGMA] * st[TORQUE_STATE.Q_MED] / MEDIAN_ABS_D2
    else:
        return  # the dead band is not known yet: no flank can be told
    eng_hi = max(st[TORQUE_STATE.ENG_LEFT], st[TORQUE_STATE.ENG_RIGHT])
    eng_lo = min(st[TORQUE_STATE.ENG_LEFT], st[TORQUE_STATE.ENG_RIGHT])
    flank = 1.0 if q > eng_hi + db else (-1.0 if q < eng_lo - db else 0.0)
    if flank == 0.0:
        return
    reversal = st[TORQUE_STATE.LAST_FLANK] != 0.0 and flank != st[TORQUE_STATE.LAST_FLANK]
    if reversal:
        st[TORQUE_STATE.N_REV] += 1.0
    st[TORQUE_STATE.LAST_FLANK] = flank
    have_prev = st[TORQUE_STATE.HAVE_PREV]
    st[TORQUE_STATE.HAVE_PREV] = 1.0
    if have_prev == 0.0:
        return  # the first sample after a gap: a reference, not motion
    o = TORQUE_STATE.LEFT if flank < 0.0 else TORQUE_STATE.RIGHT
    p = o + TORQUE_FLANK.P
    if st[o + TORQUE_FLANK.N] == 0.0:  # the flank's first update: its prior, centred here
        st[o + TORQUE_FLANK.M] = 1.0
        st[o + TORQUE_FLANK.B] = yc
        st[o + TORQUE_FLANK.S] = 0.0
        st[o + TORQUE_FLANK.UC] = uc
        for i in range(9):
            st[p + i] = 0.0
        st[p + 0] = c[TORQUE_CONSTS.P0]
        st[p + 4] = c[TORQUE_CONSTS.P0]
        st[p + 8] = c[TORQUE_CONSTS.P0]
        st[o + TORQUE_FLANK.QMAX] = 0.0
        st[o + TORQUE_FLANK.QMEAN] = 0.0
        st[o + TORQUE_FLANK.QM2] = 0.0
        st[o + TORQUE_FLANK.W] = 0.0
    elif not (
        reversal
        or abs(uc - st[TORQUE_STATE.U_LAST]) > c[TORQUE_CONSTS.MIN_STEP]
        or abs(q - st[TORQUE_STATE.Q_LAST]) > db
    ):
        return  # nothing moved: no information
    lam = c[TORQUE_CONSTS.LAM] * (c[TORQUE_CONSTS.LAM_REV] if reversal else 1.0)
    f0 = uc - st[o + TORQUE_FLANK.UC]
    f2 = -q
    e = yc - (st[o + TORQUE_FLANK.M] * f0 + st[o + TORQUE_FLANK.B] + st[o + TORQUE_FLANK.S] * f2)
    v0 = st[p + 0] * f0 + st[p + 1] + st[p + 2] * f2
    v1 = st[p + 3] * f0 + st[p + 4] + st[p + 5] * f2
    v2 = st[p + 6] * f0 + st[p + 7] + st[p + 8] * f2
    den = lam + f0 * v0 + v1 + f2 * v2
    if not den > lam * 0.5:  # phi' P phi < 0: the covariance lost its definiteness (rounding): no update
        return
    k0 = v0 / den
    k1 = v1 / den
    k2 = v2 / den
    if c[TORQUE_CONSTS.FREEZE] == 0.0:
        st[o + TORQUE_FLANK.M] += k0 * e
        st[o + TORQUE_FLANK.B] += k1 * e
        st[o + TORQUE_FLANK.S] += k2 * e
    # P <- [(I - k phi^T) P (I - k phi^T)^T + lam k k^T] / lam (Joseph form: stays symmetric and
    # positive definite under rounding, where P - k v^T drifts indefinite over long runs with
    # forgetting), bounded by the prior (no windup however long the forgetting runs)
    a00 = 1.0 - k0 * f0
    a01 = -k0
    a02 = -k0 * f2
    a10 = -k1 * f0
    a11 = 1.0 - k1
    a12 = -k1 * f2
    a20 = -k2 * f0
    a21 = -k2
    a22 = 1.0 - k2 * f2
    t00 = a00 * st[p + 0] + a01 * st[p + 3] + a02 * st[p + 6]
    t01 = a00 * st[p + 1] + a01 * st[p + 4] + a02 * st[p + 7]
    t02 = a00 * st[p + 2] + a01 * st[p + 5] + a02 * st[p + 8]
    t10 = a10 * st[p + 0] + a11 * st[p + 3] + a12 * st[p + 6]
    t11 = a10 * st[p + 1] + a11 * st[p + 4] + a12 * st[p + 7]
    t12 = a10 * st[p + 2] + a11 * st[p + 5] + a12 * st[p + 8]
    t20 = a20 * st[p + 0] + a21 * st[p + 3] + a22 * st[p + 6]
    t21 = a20 * st[p + 1] + a21 * st[p + 4] + a22 * st[p + 7]
    t22 = a20 * st[p + 2] + a21 * st[p + 5] + a22 * st[p + 8]
    n00 = (t00 * a00 + t01 * a01 + t02 * a02 + lam * k0 * k0) / lam
    n01 = (t00 * a10 + t01 * a11 + t02 * a12 + lam * k0 * k1) / lam
    n02 = (t00 * a20 + t01 * a21 + t02 * a22 + lam * k0 * k2) / lam
    n11 = (t10 * a10 + t11 * a11 + t12 * a12 + lam * k1 * k1) / lam
    n12 = (t10 * a20 + t11 * a21 + t12 * a22 + lam * k1 * k2) / lam
    n22 = (t20 * a20 + t21 * a21 + t22 * a22 + lam * k2 * k2) / lam
    st[p + 0] = n00
    st[p + 1] = n01
    st[p + 2] = n02
    st[p + 3] = n01
    st[p + 4] = n11
    st[p + 5] = n12
    st[p + 6] = n02
    st[p + 7] = n12
    st[p + 8] = n22
    top = max(n00, max(n11, n22))
    if top > c[TORQUE_CONSTS.P0]:
        shrink = c[TORQUE_CONSTS.P0] / top
        for i in range(9):
            st[p + i] *= shrink
    # residual variance from the a-priori and a-posteriori errors
    n = st[TORQUE_STATE.N_UPD] + 1.0
    w = 1.0 / min(n, c[TORQUE_CONSTS.NOISE_WINDOW])
    st[TORQUE_STATE.NOISE_VAR] += w * (e * e * lam / den - st[TORQUE_STATE.NOISE_VAR])
    # recentre at this input: b += m d, P <- J P J^T with J = [[1,0,0],[d,1,0],[0,0,1]]
    d = uc - st[o + TORQUE_FLANK.UC]
    st[o + TORQUE_FLANK.B] += st[o + TORQUE_FLANK.M] * d
    p00, p01, p02 = st[p + 0], st[p + 1], st[p + 2]
    p11, p12 = st[p + 4], st[p + 5]
    st[p + 4] = p11 + 2.0 * d * p01 + d * d * p00
    st[p + 1] = p01 + d * p00
    st[p + 3] = st[p + 1]
    st[p + 5] = p12 + d * p02
    st[p + 7] = st[p + 5]
    st[o + TORQUE_FLANK.UC] = uc
    st[o + TORQUE_FLANK.N] += 1.0
    st[o + TORQUE_FLANK.W] = lam * st[o + TORQUE_FLANK.W] + 1.0
    aq = abs(
        q - (st[TORQUE_STATE.ENG_LEFT] if flank < 0.0 else st[TORQUE_STATE.ENG_RIGHT])
    )  # the torque the flank carries
    dq = aq - st[o + TORQUE_FLANK.QMEAN]
    st[o + TORQUE_FLANK.QMEAN] += dq / st[o + TORQUE_FLANK.N]
    st[o + TORQUE_FLANK.QM2] += dq * (aq - st[o + TORQUE_FLANK.QMEAN])
    st[o + TORQUE_FLANK.QMAX] = max(st[o + TORQUE_FLANK.QMAX], aq)
    st[TORQUE_STATE.N_UPD] = n
    st[TORQUE_STATE.U_LAST] = uc
    st[TORQUE_STATE.Q_LAST] = q
    st[TORQUE_STATE.Y_LEVEL] = yc
    if math.isnan(st[TORQUE_STATE.NOISE_VAR]):  # pragma: no cover - guarded by the finite inputs
        st[TORQUE_STATE.NOISE_VAR] = 0.0


_step_nb = njit(cache=True, nogil=True, error_model="numpy")(torque_step)


@njit(cache=True, nogil=True, error_model="numpy")
def torque_run(st, c, u, y, q, after_gap):  # pragma: no cover - compiled
    """``learn_many``'s loop: :func:`torque_step` over arrays, honouring gaps."""
    for i in range(u.shape[0]):
        if after_gap[i]:
            st[TORQUE_STATE.HAVE_PREV] = 0.0
            st[TORQUE_STATE.N_Q] = 0.0
        _step_nb(st, c, u[i], y[i], q[i])
