"""Per-sample update steps of the recursive estimators, written once in plain Python.

Every step works on a flat state vector: a Python list on the interpreted path
(``learn_one``, the readable reference) and a float64 array on the compiled path
(``learn_many``: the *same source* compiled by numba). So both paths do the same
arithmetic in the same order and give the same estimates.

Equation numbers refer to J. Vörös, Automatica 46 (2010) 369-374 (``PAPER.md``).

BacklashRLS state (indices below). Each flank keeps its line *in local coordinates*,
``y = b + m (u - u_ref)`` with ``u_ref`` the input of the flank's latest update, and its
information matrix ``R`` (the inverse of the unscaled covariance) for ``[m, b]``. Moving the
reference is an exact reparametrisation (``b += m d``, ``R <- T^-T R T^-1``), so the regressor
of eq. (8) on an engaged flank becomes ``[0, 1]`` and the intercept is never an extrapolation
to a far-away origin.

The switching functions eq. (12)-(13) are evaluated on the model's own output ``X_HAT``
(``switching="model"``, the default without effects)
(eq. 1-3 run with the current estimates: on the engaged flank's line, held in the dead band),
not on the measured ``x(t-1)``: the *output-error* classification of the batch estimator's
final refinement. With the measured output, noise and a compliance ramp after each reversal
(the load creeping up to the flank) put samples that the model sees on a flank into the
dead band, so the flank's line is fitted without them.
"""

from __future__ import annotations

from numba import njit

# ---- BacklashRLS state layout --------------------------------------------------------------
N_SEEN, HAVE_PREV, U0, Y0, U_PREV, Y_PREV, T_MOTION = range(7)
LEFT, RIGHT = 7, 16  # offset of each flank's block; also the flank's code in LAST_SIDE
M, B, UREF, R11, R12, R22, W_COUNT, W_TIME, N_UPD = range(9)  # fields of a flank block
LAST_SIDE, N_REV, NOISE_VAR, N_RESID, W_EWMA, W_EWMA_SET, T_LAST_REV, W_RATE, X_HAT, HOLD_SIDE = range(25, 35)
STATE_SIZE = 35  # HOLD_SIDE: the flank the model's output X_HAT rests on (0: unknown, after a start or gap)

# ---- BacklashRLS constants ---------------------------------------------------------------------
K_DT, K_LAM, K_LAM_REV, K_FLOOR_M, K_FLOOR_B, K_MIN_STEP, K_NOISE_WINDOW, K_WEAR_HORIZON, K_ORIGIN_FIRST, K_FREEZE, K_SWITCH_MODEL = range(11)
N_CONSTS = 11


def _make_backlash_steps(jit):
    """Build the BacklashRLS step functions, compiled by ``jit`` (numba's ``njit`` or the identity)."""

    @jit
    def begin_sample(st, c, u, y):
        """Reference origin, counters and previous sample. Returns ``(uc, yc, du, y_prev)``.

        ``du = 0`` means no update can follow (first sample, after a gap, motor still, or a
        step no larger than ``min_step_deg``).
        """
        if st[N_SEEN] == 0.0 and c[K_ORIGIN_FIRST] != 0.0:
            st[U0] = u
            st[Y0] = y
        st[N_SEEN] += 1.0
        uc = u - st[U0]
        yc = y - st[Y0]
        du = uc - st[U_PREV]
        y_prev = st[Y_PREV]
        if st[HAVE_PREV] == 0.0:
            du = 0.0
            st[X_HAT] = yc  # (re)start the model's output at the measured one
            st[HOLD_SIDE] = 0.0
        st[HAVE_PREV] = 1.0
        st[U_PREV] = uc
        st[Y_PREV] = yc
        if du != 0.0:
            st[T_MOTION] += c[K_DT]  # the motion clock: seconds during which the motor moved
        if abs(du) <= c[K_MIN_STEP]:
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
        if du < 0.0:
            m = st[LEFT + M]
            if (st[LEFT + B] + m * (uc - st[LEFT + UREF]) - x_prev) * m <= 0.0:  # eq. (12)
                return LEFT
        elif du > 0.0:
            m = st[RIGHT + M]
            if (x_prev - st[RIGHT + B] - m * (uc - st[RIGHT + UREF])) * m <= 0.0:  # eq. (13)
                return RIGHT
        return 0

    @jit
    def flank_width(st, level):
        """Horizontal distance between the flanks at output ``level``: the play, input units."""
        u_left = st[LEFT + UREF] + (level - st[LEFT + B]) / st[LEFT + M]
        u_right = st[RIGHT + UREF] + (level - st[RIGHT + B]) / st[RIGHT + M]
        return u_right - u_left

    @jit
    def reversal(st, c, side, level):
        """Count a change of the driving flank; track the wear rate; return the per-reversal forgetting."""
        last = st[LAST_SIDE]
        st[LAST_SIDE] = side
        if last == 0.0 or last == side:
            return 1.0
        st[N_REV] += 1.0
        # rate of change of the play: an EWMA of the play with time constant H (seconds of
        # motion) lags a ramp of slope r by r H, so r = (width - ewma) / H
        w = flank_width(st, level)
        t = st[T_MOTION]
        horizon = c[K_WEAR_HORIZON]
        if st[W_EWMA_SET] == 0.0:
            st[W_EWMA] = w
            st[W_EWMA_SET] = 1.0
        else:
            a = (t - st[T_LAST_REV]) / horizon
            if a > 1.0:
                a = 1.0
            st[W_EWMA] += a * (w - st[W_EWMA])
            st[W_RATE] = (w - st[W_EWMA]) / horizon
        st[T_LAST_REV] = t
        return c[K_LAM_REV]

    @jit
    def forget_side(st, o, lam, floor_m, floor_b):
        """Regularised exponential forgetting of one flank: ``R <- lam R + (1 - lam) R_floor``."""
        st[o + R11] = lam * st[o + R11] + (1.0 - lam) * floor_m
        st[o + R12] = lam * st[o + R12]
        st[o + R22] = lam * st[o + R22] + (1.0 - lam) * floor_b
        st[o + W_COUNT] = lam * st[o + W_COUNT]
        st[o + W_TIME] = lam * st[o + W_TIME]

    @jit
    def recenter(st, o, uc):
        """Move the flank's reference to ``uc``: ``b += m d``, ``R <- T^-T R T^-1``; returns ``d``."""
        d = uc - st[o + UREF]
        st[o + B] += st[o + M] * d
        r12 = st[o + R12]
        r22 = st[o + R22]
        st[o + R11] = st[o + R11] - 2.0 * d * r12 + d * d * r22
        st[o + R12] = r12 - d * r22
        st[o + UREF] = uc
        return d

    @jit
    def track_noise(st, c, e):
        """Running variance of the a-priori residuals (window ``noise_window`` updates)."""
        n = st[N_RESID] + 1.0
        st[N_RESID] = n
        st[NOISE_VAR] += (e * e - st[NOISE_VAR]) / min(n, c[K_NOISE_WINDOW])

    @jit
    def update_side(st, c, o, yc):
        """One RLS update of flank ``o``'s line at its reference with target ``y(t)``.

        On an engaged flank (reference moved to ``u(t)`` first) this is eq. (11); in the
        dead band (reference left where the flank was last driven) it is the output-error
        gradient of eq. (1)'s third case: the load rests where the flank left it.
        """
        forget_side(st, o, c[K_LAM], c[K_FLOOR_M], c[K_FLOOR_B])
        e = yc - st[o + B]  # a-priori error, eq. (14); the local regressor is [0, 1]
        track_noise(st, c, e)
        r11 = st[o + R11]
        r12 = st[o + R12]
        r22 = st[o + R22] + 1.0  # R <- R + phi phi^T
        st[o + R22] = r22
        if c[K_FREEZE] == 0.0:  # frozen lines: only the information is gathered (warm start)
            g = e / (r11 * r22 - r12 * r12)
            st[o + M] -= r12 * g  # theta += R^-1 phi e, R^-1 phi = [-r12, r11] / det
            st[o + B] += r11 * g
        st[o + W_COUNT] += 1.0
        st[o + W_TIME] += st[T_MOTION]
        st[o + N_UPD] += 1.0
        st[X_HAT] = st[o + B]  # the model's output: on the updated line, at its reference
        st[HOLD_SIDE] = o

    @jit
    def step(st, c, u, y):
        """Learn one sample ``(u, y)`` (input and output in the caller's frame)."""
        uc, yc, du, y_prev = begin_sample(st, c, u, y)
        if du == 0.0:
            return
        model = c[K_SWITCH_MODEL] != 0.0
        side = engaged_side(st, uc, st[X_HAT] if model else y_prev, du)
        if side == 0:
            if model and st[HOLD_SIDE] != 0.0:  # moving in the dead band
                update_side(st, c, int(st[HOLD_SIDE]), yc)
            return
        lam = reversal(st, c, side, yc)
        if lam != 1.0:
            forget_side(st, LEFT, lam, c[K_FLOOR_M], c[K_FLOOR_B])
            forget_side(st, RIGHT, lam, c[K_FLOOR_M], c[K_FLOOR_B])
        recenter(st, side, uc)
        update_side(st, c, side, yc)

    return begin_sample, engaged_side, flank_width, reversal, recenter, track_noise, step


def _identity(f):
    return f


(
    begin_sample,
    engaged_side,
    flank_width,
    reversal,
    recenter,
    track_noise,
    backlash_step,
) = _make_backlash_steps(_identity)
_backlash_step_nb = _make_backlash_steps(njit(cache=True))[-1]


@njit(cache=True)
def backlash_run(st, c, u, y, after_gap):  # pragma: no cover - compiled
    """``learn_many``'s loop: :func:`backlash_step` over arrays, honouring gaps."""
    for i in range(u.shape[0]):
        if after_gap[i]:
            st[HAVE_PREV] = 0.0
        _backlash_step_nb(st, c, u[i], y[i])


# ---- CascadeRLS state layout -----------------------------------------------------------------
# scalars, then theta (p), P (p*p, row-major), x_hat history (max(n_a, 2)), y history (n_b),
# simulated-output history (n_b, the output-error regressor), then for the prediction-error
# regressor: d x_hat / d [m1, c1, m2, c2] history (4 per x_hat entry) and the filtered
# gradient psi, a ring of n_b + 1 slots of p (C_PSI_HEAD: the slot of psi(t-1))
CN_SEEN, CU0, CY0, C_K, C_UPREV, C_F1, C_F2, C_NOISE, C_NRES, C_IDLE, C_LAST, C_NREV, C_PSI_HEAD = range(13)
C_THETA = 13
# constants
Q_LAM, Q_LAM_REV, Q_TRACE_MAX, Q_NOISE_WINDOW, Q_ORIGIN_FIRST, Q_NA, Q_NB, Q_OUTPUT_ERROR, Q_FREEZE, Q_PRED_ERROR = range(10)


def cascade_sizes(n_a: int, n_b: int) -> tuple[int, int, int, int, int]:
    """``(p, P offset, x_hat offset, y offset, state size)`` of a CascadeRLS state vector."""
    p = 4 + n_a - 1 + n_b
    off_p = C_THETA + p
    off_x = off_p + p * p
    off_y = off_x + max(n_a, 2)
    return p, off_p, off_x, off_y, off_y + 2 * n_b + 4 * max(n_a, 2) + p * (n_b + 1)


def _make_cascade_step(jit):
    @jit
    def step(st, c, u, y, phi, pphi):
        """Learn one sample of the cascade, eq. (18)-(24); ``phi``, ``pphi`` are scratch vectors of length p."""
        na = int(c[Q_NA])
        nb = int(c[Q_NB])
        p = 4 + na - 1 + nb
        op = C_THETA + p
        ox = op + p * p
        nx = max(na, 2)
        oy = ox + nx
        oyh = oy + nb
        osx = oyh + nb  # d x_hat(t-1-i) / d [m1, c1, m2, c2] at osx + 4 i
        opsi = osx + 4 * nx  # ring of psi vectors
        oe = c[Q_OUTPUT_ERROR] != 0.0
        pe = c[Q_PRED_ERROR] != 0.0
        if st[CN_SEEN] == 0.0 and c[Q_ORIGIN_FIRST] != 0.0:
            st[CU0] = u
            st[CY0] = y
        st[CN_SEEN] += 1.0
        uc = u - st[CU0]
        yc = y - st[CY0]
        y_hat = yc  # the model output where no regression runs
        if st[C_K] == 0.0:
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
            st[C_UPREV] = uc
            st[C_IDLE] = 0.0
        elif st[C_K] >= max(na, nb, 2) and st[C_IDLE] <= na + nb + 1:
            # ---- regression on eq. (18)-(19) with the switching functions of t-1 (eq. 23)
            f1p = st[C_F1]
            f2p = st[C_F2]
            u1 = st[C_UPREV]
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
            lam = c[Q_LAM]
            side = 1.0 if f1p > 0.0 else (2.0 if f2p > 0.0 else 0.0)
            if side != 0.0:
                if st[C_LAST] != 0.0 and st[C_LAST] != side:
                    st[C_NREV] += 1.0
                    lam = lam * c[Q_LAM_REV]
                st[C_LAST] = side
            # forgetting P <- P / lam, limited so that trace(P) stays <= trace_max (anti-windup)
            tr = 0.0
            for i in range(p):
                tr += st[op + i * p + i]
            if tr > lam * c[Q_TRACE_MAX]:
                lam = tr / c[Q_TRACE_MAX]
                if lam > 1.0:
                    lam = 1.0
            if lam != 1.0:
                inv_lam = 1.0 / lam
                for i in range(p * p):
                    st[op + i] = st[op + i] * inv_lam
            e = target
            for i in range(p):
                e -= st[C_THETA + i] * phi[i]
            n = st[C_NRES] + 1.0
            st[C_NRES] = n
            st[C_NOISE] += (e * e - st[C_NOISE]) / min(n, c[Q_NOISE_WINDOW])
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
                head = int(st[C_PSI_HEAD])
                for j in range(1, nb + 1):  # psi(t) = raw(t) - sum_j b_j psi(t-j)
                    b_j = st[C_THETA + 3 + na + j - 1]
                    o = opsi + ((head + j - 1) % n_slots) * p
                    for i in range(p):
                        phi[i] -= b_j * st[o + i]
                head = (head + nb) % n_slots  # the free slot (psi(t-nb-1)) takes psi(t)
                st[C_PSI_HEAD] = head
                o = opsi + head * p
                for i in range(p):
                    st[o + i] = phi[i]
            # P phi as a sum of P's rows (P is symmetric), skipping the zeros of phi: half of
            # the backlash part of eq. (19) is zero at any time
            for i in range(p):
                pphi[i] = 0.0
            for j in range(p):
                pj = phi[j]
                if pj != 0.0:
                    row = op + j * p
                    for i in range(p):
                        pphi[i] += st[row + i] * pj
            s = 1.0
            for i in range(p):
                s += phi[i] * pphi[i]
            inv_s = 1.0 / s
            if c[Q_FREEZE] == 0.0:  # (warm-start replay: theta held, P gathers the information)
                for i in range(p):
                    st[C_THETA + i] += pphi[i] * inv_s * e  # gain K = P phi / (1 + phi' P phi)
            for i in range(p):  # P <- P - P phi phi' P / s, exactly symmetric
                row = op + i * p
                pi = pphi[i]
                for j in range(p):
                    st[row + j] -= (pi * pphi[j]) * inv_s
            if not pe:
                # a-posteriori model output (eq. 18 with the updated theta), for the output-error regressor
                y_hat = yc - target
                for i in range(p):
                    y_hat += st[C_THETA + i] * phi[i]
        if uc != st[C_UPREV]:
            st[C_IDLE] = 0.0
        else:
            st[C_IDLE] += 1.0
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
        st[C_UPREV] = uc
        st[C_F1] = f1
        st[C_F2] = f2
        if st[C_K] < 1e9:
            st[C_K] += 1.0

    return step


cascade_step = _make_cascade_step(_identity)
_cascade_step_nb = _make_cascade_step(njit(cache=True))


@njit(cache=True)
def cascade_run(st, c, u, y, after_gap, phi, pphi):  # pragma: no cover - compiled
    """``learn_many``'s loop for the cascade."""
    for i in range(u.shape[0]):
        if after_gap[i]:
            st[C_K] = 0.0
        _cascade_step_nb(st, c, u[i], y[i], phi, pphi)
