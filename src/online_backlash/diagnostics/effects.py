"""The effect library: what a real gearbox adds to the play-and-two-slopes model of eq. (1).

Each effect adds to the predicted load angle a sum ``sum_k beta_k * term_k`` of known,
causal functions of the data with coefficients ``beta`` that enter linearly. Appended to
the regressor ``phi`` of eq. (8) (and so to the least-squares problem of eq. 14, or of eq. 19
and 24 for the cascade), the problem stays *quasi-linear*: for fixed switching functions
eq. (5)-(6), the output is linear in ``[theta, beta]``, so the paper's iteration, its
output-error refinement and recursive least squares fit the backlash and the effects jointly.
Every class implements :class:`~online_backlash.effect_terms.EffectTerms` (``name``,
``n_terms``, ``terms``, ``reset``), so ``BacklashRLS(effects=[...])`` can track with it.

Each class also

* ``detect(data)`` -- tests a residual for its signature and returns a configured instance
  with its score (the information criterion of :mod:`._scoring`, threshold
  :data:`~._scoring.BIC_THRESHOLD`, plus a minimum share of the residual explained), and
* ``describe(coef)`` -- its parameters with units, from the fitted ``beta``.

Units: angles in degrees (load side), time in seconds, torque in N m.

Examples
--------
>>> import numpy as np
>>> from online_backlash.diagnostics.effects import TransmissionError
>>> te = TransmissionError(load_orders=(2,), ratio=30.0)
>>> u = np.array([0.0, 45.0, 90.0])
>>> te.terms(u, np.zeros(3), np.full(3, np.nan)).round(6)  # sin(2u), cos(2u)
array([[ 0.,  1.],
       [ 1.,  0.],
       [ 0., -1.]])
>>> te.describe(np.array([0.0, 0.02]))["harmonics"][0]["amplitude_deg"]
0.02
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..load_aware.engagement import either_flank_engaged, torque_deadband
from ._causal import SAVGOL_ORDER, lagged_difference, savgol_derivative
from ._effect_base import EffectBase
from ._harmonics import harmonic_columns, held_harmonic
from ._scoring import Detection, DetectionData, Score, best_detection
from ._speed import MAX_INNER_KNOTS, held_spline_columns, record_speed_knots
from .dead_band import DeadBandMotion
from .flank_profile import FlankProfile

_RAD = np.pi / 180.0
#: share of the residual one harmonic order must explain on its own to be kept
MIN_ORDER_GAIN = 0.01
#: a transmission error claims a repeating pattern: its order must repeat at least this often in the record
PERIODIC_MIN_PERIODS = 2.0


def amplitudes_phases(coef: np.ndarray) -> list[tuple[float, float]]:
    """``a sin + b cos = A sin(. + phase)``: ``(A, phase_deg)`` per ``(a, b)`` pair."""
    c = np.asarray(coef, dtype=float).reshape(-1, 2)
    return [(float(np.hypot(a, b)), float(np.degrees(np.arctan2(b, a)))) for a, b in c]


#: most memory :func:`select_orders` keeps for its candidates' columns (bytes); beyond it they are rebuilt
SELECT_CACHE_BYTES = 256 * 2**20


def select_orders(
    data: DetectionData,
    columns: Callable[[int], np.ndarray],
    max_order: int,
    span_deg: float,
    max_orders: int,
    min_periods: float = 1.0,
    held: bool = False,
) -> list[int]:
    """Harmonic orders chosen by forward selection (at most ``max_orders``), strongest first.

    Only orders of which the data cover at least ``min_periods`` periods
    (``n * span_deg >= 360 * min_periods``) are tried, and once an order is chosen its
    neighbours closer than the resolution ``360 / span_deg`` are dropped: over a short span
    they are nearly collinear and would fit huge amplitudes that cancel. Orders are screened
    in sample; the one kept must also hold on the held-out cycles. Only the
    ``2 max_orders`` orders strongest on their own take part. At each step every remaining order is scored given
    the orders already chosen; the best is kept if it passes the information criterion and explains at
    least :data:`MIN_ORDER_GAIN` of what is left (so the leakage of a strong order into its
    neighbours is not kept). ``columns(n)`` gives the columns of order ``n``; with ``held`` they
    are already held through the dead band (else they are held here).
    """
    if span_deg <= 0:
        return []
    resolution = 360.0 / span_deg
    remaining = [n for n in range(1, max_order + 1) if n >= min_periods * resolution]

    def build(n: int) -> np.ndarray:
        return columns(n) if held else data.hold(columns(n))

    # forward selection among the strongest orders on their own (a cheap first pass, whose scores
    # are the selection's first step: no columns are kept from it, fresh memory costs more than
    # building them again)
    first = []
    alone: dict[int, Score] = {}  # the scores on their own: the first step of the selection below
    for n in remaining:
        alone[n] = data.score(False, build(n), heldout=False)
        first.append((alone[n].delta_bic, n))
    first.sort()
    remaining = [n for _, n in first[: 2 * max_orders]]
    kept: dict[int, np.ndarray] = {}  # the candidates' columns held through the dead band, built once

    def candidate(n: int) -> np.ndarray:
        if n in kept:
            return kept[n]
        x = build(n)
        if x.nbytes * len(remaining) <= SELECT_CACHE_BYTES:  # a long record rebuilds them instead
            kept[n] = x
        return x

    chosen: list[int] = []
    current = data
    while remaining and len(chosen) < max_orders:
        scored = [(current.score(False, candidate(n), heldout=False) if chosen else alone[n], n) for n in remaining]
        _, best = min(scored, key=lambda item: item[0].delta_bic)
        if not current.score(False, candidate(best)).significant(min_gain=MIN_ORDER_GAIN):  # held out too
            break
        chosen.append(best)
        remaining = [n for n in remaining if abs(n - best) >= resolution]
        current = current.with_nuisance(candidate(best))
    return chosen


class TransmissionError(EffectBase):
    """Transmission error: harmonics of the load angle and of the motor angle, eq. (8) + columns.

    ``sum_n a_n sin(n theta) + b_n cos(n theta)`` with ``theta`` the load angle (``load_orders``,
    cycles per load revolution) or the motor angle ``ratio * u`` (``motor_orders``, cycles per
    motor revolution). The load angle is approximated by ``u``, the motor angle referred to the
    load side; the two differ by less than the play, a phase error of ``n * play`` degrees.

    Parameters
    ----------
    load_orders, motor_orders : tuple of int
        Harmonic orders on each shaft.
    ratio : float
        Gear ratio motor:load (to rebuild the motor angle from ``u``).
    """

    name = "transmission_error"

    def __init__(
        self, load_orders: tuple[int, ...] = (), motor_orders: tuple[int, ...] = (), ratio: float = 1.0
    ) -> None:
        self.load_orders = tuple(load_orders)
        self.motor_orders = tuple(motor_orders)
        self.ratio = ratio
        super().__init__()

    @property
    def n_terms(self) -> int:
        return 2 * (len(self.load_orders) + len(self.motor_orders))

    def _columns(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        return np.column_stack(
            (harmonic_columns(u, self.load_orders), harmonic_columns(u * self.ratio, self.motor_orders))
        )

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        shafts = ["load"] * len(self.load_orders) + ["motor"] * len(self.motor_orders)
        orders = self.load_orders + self.motor_orders
        return {
            "harmonics": [
                {"shaft": s, "order_per_rev": int(n), "amplitude_deg": a, "phase_deg": p}
                for s, n, (a, p) in zip(shafts, orders, amplitudes_phases(coef))
            ],
            "model": "sum A sin(order * shaft_angle + phase), added to the load angle",
        }

    @classmethod
    def detect(
        cls, data: DetectionData, max_load_order: int = 24, max_motor_order: int = 3, max_orders: int = 6
    ) -> Detection | None:
        """Significant harmonics of the residual against the load and motor angles."""
        u = data.u_deg

        def orders_of(scored_on: DetectionData, shaft: str, angle_deg: np.ndarray, top: int) -> list[int]:
            """The orders of the shaft's angle ``angle_deg`` chosen on ``scored_on`` (held through the dead band)."""
            return select_orders(
                scored_on,
                lambda n: held_harmonic(data, shaft, angle_deg, n, top),
                top,
                float(np.ptp(angle_deg)),
                max_orders,
                PERIODIC_MIN_PERIODS,
                held=True,
            )

        load = orders_of(data, "load", u, max_load_order)
        motor: list[int] = []
        if abs(data.ratio) > 1:
            motor_deg = u * data.ratio
            # given the load orders chosen: their structure would leak into a motor order fitted on
            # a few held-out cycles
            given = data.with_nuisance(data.hold(harmonic_columns(u, load))) if load else data
            motor = orders_of(given, "motor", motor_deg, max_motor_order)
        if not load and not motor:
            return None
        effect = cls(tuple(sorted(int(n) for n in load)), tuple(sorted(int(n) for n in motor)), float(data.ratio))
        s = data.score(effect.input_side, effect.clone().terms(u, data.time_s, data.torque_Nm))
        shafts = [
            f"{shaft} orders {list(orders)}"
            for shaft, orders in (("load", effect.load_orders), ("motor", effect.motor_orders))
            if orders
        ]
        return Detection(effect, s, f"residual repeats with the shaft angle: {' and '.join(shafts)} per revolution")


class Delay(EffectBase):
    """A lag between the load and motor samples (the two encoders' clocks).

    ``y(t) = x(t - d)``. The lag is not linear in its parameter; it is linearised on a grid:
    with a grid lag of ``k`` samples, the column is ``u(t - k) - u(t)`` (deg, causal) and on a
    flank of unit slope ``x(t - d) - x(t) = (d / k) [u(t - k) - u(t)]`` at constant speed, so the
    coefficient ``beta`` gives ``d = beta k`` samples. ``detect`` picks ``k`` from a grid by the
    information criterion. A negative ``d`` (the load sample leads) is a negative ``beta``.
    Exact for ``d = k`` on a flank; inside the dead band, where the load does not move, the
    column is a small error (the dead band is crossed in ``play / speed`` seconds).

    Parameters
    ----------
    lag_step_samples : int
        ``k``, the grid lag of the column, samples.
    sample_period_s : float
        The sampling period, to report the lag in seconds.
    """

    name = "delay"

    def __init__(self, lag_step_samples: int = 1, sample_period_s: float = 1e-3) -> None:
        if int(lag_step_samples) < 1:
            raise InvalidParameterError(f"lag_step_samples must be >= 1, got {lag_step_samples!r}")
        self.lag_step_samples = int(lag_step_samples)
        self.sample_period_s = sample_period_s
        self.history = self.lag_step_samples
        super().__init__()

    @property
    def n_terms(self) -> int:
        return 1

    def _columns(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        return -lagged_difference(u, self.lag_step_samples)

    def output_columns(self, x_deg: np.ndarray) -> np.ndarray:
        """The column on the backlash model's own output ``x`` (deg): ``x(t - k) - x(t)``.

        Exact for a whole-sample lag everywhere, in the dead band too (where ``x`` stands still
        and a lag of the load reading vanishes after ``k`` samples); the diagnostics loop uses it
        in place of :meth:`terms` (``u`` based, for the recursive estimator) when it knows ``x``.
        """
        return -lagged_difference(np.asarray(x_deg, dtype=float), self.lag_step_samples)[:, None]

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        lag = float(coef[0]) * self.lag_step_samples
        return {
            "lag_samples": lag,
            "lag_s": lag * self.sample_period_s,
            "grid_lag_samples": self.lag_step_samples,
            "model": "load sample taken lag_s after the motor sample (negative: before)",
        }

    def _prepared(self, data: DetectionData) -> tuple[bool, np.ndarray]:
        """``(held, column)``: on the model's output when the data carry it, else on ``u`` held through the
        dead band."""
        if data.model_output_deg is not None:
            return False, self.output_columns(data.model_output_deg)
        return True, self.clone().terms(data.u_deg, data.time_s, data.torque_Nm)

    @classmethod
    def detect(cls, data: DetectionData, grid: Sequence[int] = (1, 2, 3, 5, 8, 13, 21, 34, 55)) -> Detection | None:
        """The lag from the grid column that explains the residual best, then the column at that lag.

        The final column's step is the estimated lag rounded to whole samples (at least 1), so
        the column is exact for a whole-sample lag.
        """
        found = []
        for k in grid:
            s = data.score(*cls(k)._prepared(data), heldout=False)
            found.append((s.delta_bic, k, float(s.coef[0]) * k))
        _, k_grid, lag = min(found)
        effect = cls(max(1, round(abs(lag))), data.sample_period_s)
        s = data.score(*effect._prepared(data))
        p = effect.describe(s.coef)
        return Detection(
            effect,
            s,
            f"residual follows the motor-angle change over {k_grid} samples "
            f"(lag {p['lag_samples']:.2f} samples, {p['lag_s'] * 1e3:.3f} ms)",
        )


class Compliance(EffectBase):
    """Twist of the output shaft under the torque it transmits, only while a flank is engaged.

    Torque reaches the output only through an engaged flank: inside the dead band the shaft
    carries no torque and does not twist. On the right flank the load angle is
    ``y = u - c_right - tau / k`` (eq. 1 plus the wind-up), so the column is a torque and its
    coefficient a compliance.

    * ``proxy="torque"``: the measured transmitted torque (N m), averaged over the last
      ``smooth_samples`` samples against the sensor's noise, where a flank is engaged by the
      torque's sign (:func:`online_backlash.load_aware.engagement.engaged_flank` with
      ``deadband_Nm``), 0 elsewhere; coefficient in deg/N m (``-1 / k``). The causal mean
      delays the column by ``(smooth_samples - 1) / 2`` samples, and the twist does lag the
      measured torque: the contact's damping carries part of it while the flank winds up
      (``tau = k theta + d theta'``, a lag of ``d / k``). How long a mean trades the sensor's
      noise against that lag is the rig's, so the loop fits it in the joint refit
      (:meth:`neighbours`, from :data:`SMOOTHING_GRID`), as it fits the delay's lag.
    * ``proxy="acceleration"`` (no torque measured): the torque the output needs to follow an
      engaged flank, from its motion: the inertial torque ``J y''``, so the twist is
      ``-(J / k) y''`` and the coefficient, in deg per deg/s^2, is ``-J / k`` (s^2). On an engaged
      flank the load follows ``u`` (eq. 1, slope about 1; the twist's own acceleration is a share
      ``(J / k) omega^2`` of it), so ``y''`` is read from ``u``, the motor angle referred to the load
      side: the finer encoder through the ratio, and not the load reading that holds the twist being
      explained. Quantised angles differenced twice are steps of ``q / T^2``; a causal Savitzky-Golay
      filter over ``window_samples`` (:func:`._causal.savgol_derivative`) fits a quartic through the
      window, which averages the steps out and, evaluated at the newest sample, follows the motion
      without lag (the model's own prediction ``x`` is no smoother: on a flank it is ``u`` shifted, and
      it stands still in the dead band, so its second derivative has a step at every engagement). How
      long a window trades the encoder's steps against the motion's curvature is the record's, so the
      loop fits it in the joint refit (:meth:`neighbours`, from :data:`WINDOW_GRID`). Over a record's
      first ``window_samples - 1`` samples the window holds what there is.
    * ``proxy="motion"``: the acceleration and the velocity (deg/s, the viscous share ``-b / k``,
      coefficient in deg per deg/s), by the same filter, for a caller who knows the load is viscous.
      :meth:`detect` does not offer it: on an engaged flank a viscous twist is a lag, which the
      ``delay`` describes exactly, and on strokes at constant speed a speed-proportional column is
      nearly a play (held through the dead band it took the delay's place on the rig's delay logs
      and moved the play 8 % on the creep strokes of ``tests/test_creep_at_rest.py``).

    The motion proxies act on the input side of the backlash (``input_side``): the loop holds them
    through the dead band (eq. 7), so on an engaged flank the column is the acceleration and while no
    flank is engaged it keeps its value from the last engaged sample: a load at rest stays where the
    flank left it, twist and all (it does not jump back when the torque is gone). They add to the load
    angle ``-(J / k) u''`` as ``y = B(u - (J / k) u'')`` does to first order, ``B`` eq. (1)-(3).
    Missing torque samples (NaN) contribute 0.

    Parameters
    ----------
    proxy : {"torque", "acceleration", "motion"}
    window_samples : int
        Window of the Savitzky-Golay differentiator of the motion proxies, samples (at least
        ``SAVGOL_ORDER + 2``, 6).
    deadband_Nm : float
        Torque within this of zero engages no flank (``proxy="torque"``), N m.
    smooth_samples : int
        Causal moving average of the torque, samples (1: none).
    """

    name = "compliance"
    #: the torque's averaging windows the joint refit may choose from, samples
    SMOOTHING_GRID: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 8, 11, 16)
    #: the motion proxies' differentiator windows the joint refit may choose from, samples
    WINDOW_GRID: tuple[int, ...] = (11, 15, 21, 31, 41, 61, 81, 121, 161)

    def __init__(
        self, proxy: str = "torque", window_samples: int = 61, deadband_Nm: float = 0.0, smooth_samples: int = 5
    ) -> None:
        if proxy not in ("torque", "motion", "acceleration"):
            raise InvalidParameterError(f"proxy must be 'torque', 'motion' or 'acceleration', got {proxy!r}")
        if not deadband_Nm >= 0:
            raise InvalidParameterError(f"deadband_Nm must be >= 0, got {deadband_Nm!r}")
        if int(window_samples) < SAVGOL_ORDER + 2:
            raise InvalidParameterError(f"window_samples must be >= {SAVGOL_ORDER + 2}, got {window_samples!r}")
        self.proxy = proxy
        # the measured torque is read on the load side (zero in the dead band by its sign); the motion
        # proxies act on the input side: held through the dead band, where the load rests as the flank left it
        self.input_side = proxy != "torque"
        self.window_samples = int(window_samples)
        self.deadband_Nm = float(deadband_Nm)
        if int(smooth_samples) < 1:
            raise InvalidParameterError(f"smooth_samples must be >= 1, got {smooth_samples!r}")
        self.smooth_samples = int(smooth_samples)
        self.history = max(self.window_samples - 1, self.smooth_samples)
        super().__init__()

    @property
    def n_terms(self) -> int:
        return 2 if self.proxy == "motion" else 1

    def _columns(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        if self.proxy == "torque":
            q = np.nan_to_num(q, nan=0.0)
            w = self.smooth_samples
            mean = (
                np.convolve(q, np.ones(w) / w)[: q.size] if w > 1 else q
            )  # the first w-1 rows are in the window's past
            return mean * either_flank_engaged(q, self.deadband_Nm)
        start = self._window.record_start  # the rows before it are the rest before the record: no motion there
        acc = savgol_derivative(u, t, self.window_samples, 2, start)
        if self.proxy == "acceleration":
            return acc
        return np.column_stack((acc, savgol_derivative(u, t, self.window_samples, 1, start)))

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        c = [float(v) for v in coef]
        if self.proxy == "torque":
            stiffness = 1.0 / abs(c[0]) if c[0] else float("inf")
            return {
                "proxy": "measured torque",
                "active_on": "engaged samples, by the torque's sign",
                "compliance_deg_per_Nm": c[0],
                "stiffness_Nm_per_deg": stiffness,
                "stiffness_Nm_per_arcmin": stiffness / 60.0,
                "torque_deadband_Nm": self.deadband_Nm,
                "torque_smoothing_samples": self.smooth_samples,
                "torque_column_lag_samples": (self.smooth_samples - 1) / 2.0,
            }
        out: dict[str, Any] = {
            "proxy": "load-side acceleration"
            + (" and velocity (inertial and viscous torque)" if self.proxy == "motion" else " (inertial torque)"),
            "active_on": "engaged samples, by the model's switching functions (eq. 5-6); "
            "held through the dead band (eq. 7)",
            "deflection_per_acceleration_s2": c[0],
            "differentiator_window_samples": self.window_samples,
        }
        if (
            c[0] < 0
        ):  # the twist opposes the acceleration, as an inertia's does: J / k and the shaft's natural frequency
            out["inertia_over_stiffness_s2"] = -c[0]
            out["natural_frequency_hz"] = float(1.0 / (2.0 * np.pi * np.sqrt(-c[0])))
        if self.proxy == "motion":
            out["deflection_per_velocity_s"] = c[1]
        return out

    @classmethod
    def detect(cls, data: DetectionData) -> Detection | None:
        """The measured torque when the log has one, else the load side's acceleration (the inertial torque)."""
        q = np.nan_to_num(data.torque_Nm, nan=0.0)
        if np.mean(np.isfinite(data.torque_Nm)) > 0.5 and q.size >= 3:
            return cls("torque", deadband_Nm=torque_deadband(q)).detection(data)
        return cls("acceleration").detection(data)

    def detection(self, data: DetectionData) -> Detection:
        """This effect's columns scored on the residual (the motion proxies held through the model's dead band)."""
        if self.proxy == "torque":
            what = "the measured torque on engaged samples"
        elif self.proxy == "acceleration":
            what = "the load side's acceleration on engaged samples"
        else:
            what = "the load side's acceleration and velocity on engaged samples"
        s = data.score(self.input_side, data.record_columns(self))
        return Detection(self, s, f"residual is proportional to {what} (correlation {np.sqrt(max(s.gain, 0.0)):.2f})")

    def neighbours(self) -> list[Compliance]:
        """The same term with the next shorter and the next longer setting that the joint refit tries: the
        torque's average (:data:`SMOOTHING_GRID`) or the motion proxies' differentiator window
        (:data:`WINDOW_GRID`)."""
        torque = self.proxy == "torque"
        setting, grid = (
            (self.smooth_samples, self.SMOOTHING_GRID) if torque else (self.window_samples, self.WINDOW_GRID)
        )
        options = sorted({*grid, setting})
        i = options.index(setting)
        near = options[max(i - 1, 0) : i] + options[i + 1 : i + 2]
        if torque:
            return [type(self)(self.proxy, self.window_samples, self.deadband_Nm, w) for w in near]
        return [type(self)(self.proxy, w, self.deadband_Nm, self.smooth_samples) for w in near]


class Drift(EffectBase):
    """A slow offset in time (an encoder zero that moves as the rig warms up).

    Columns ``((t - t0) / time_scale_s) ** j`` for ``j = 1 .. degree``, with ``t0`` the first
    time seen; the coefficients are degrees (the offset at ``t0 + time_scale_s``). The constant
    is left to the backlash offsets.

    Parameters
    ----------
    degree : int
        Polynomial degree, 1 to 3.
    time_scale_s : float
        Time that scales the powers (the record length for a batch fit), s.
    """

    name = "drift"
    input_side = False  # the encoder zero moves whether or not the load does

    def __init__(self, degree: int = 1, time_scale_s: float = 60.0) -> None:
        if int(degree) < 1:
            raise InvalidParameterError(f"degree must be >= 1, got {degree!r}")
        if not time_scale_s > 0:
            raise InvalidParameterError(f"time_scale_s must be > 0, got {time_scale_s!r}")
        self.degree = int(degree)
        self.time_scale_s = float(time_scale_s)
        super().__init__()

    def reset(self) -> None:
        super().reset()
        self._t0: float | None = None

    @property
    def n_terms(self) -> int:
        return self.degree

    def _columns(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        if self._t0 is None:
            self._t0 = float(t[0])
        return self.powers(t, self._t0)

    def powers(self, time_s: np.ndarray, t0: float) -> np.ndarray:
        """The columns at the times ``time_s`` of a stream that started at ``t0`` (s):
        ``((t - t0) / time_scale_s) ** j``."""
        s = (np.asarray(time_s, dtype=float) - t0) / self.time_scale_s
        return np.column_stack([s**j for j in range(1, self.degree + 1)])

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        c = [float(v) for v in coef]
        return {
            "degree": self.degree,
            "time_scale_s": self.time_scale_s,
            "coefficients_deg": c,
            "offset_at_time_scale_deg": float(sum(c)),
        }

    @classmethod
    def detect(cls, data: DetectionData, max_degree: int = 3) -> Detection | None:
        """The polynomial degree in time that explains the residual best, beyond the same
        polynomial in the net rotation.

        A rig that turns steadily while it reverses makes time nearly collinear with the angle:
        a drift in time and anything that grows with the angle (a slope error, a long-period
        error of the shaft) then explain the same part of the residual. And a polynomial in time
        picks up what a function of the speed leaves from one stretch of constant speed to the
        next (the rig's speed changes at every reversal). The drift is therefore scored with two
        rivals among the nuisance columns: the polynomial of degree ``max_degree`` of the net
        rotation ``u - u[0]``, and the most flexible smooth function of the speed
        (:func:`._speed.held_spline_columns` with the most inner knots). It is claimed only if time
        explains a share of the residual that neither does (in sample and on the held-out cycles).

        If it was significant in time alone, the rivals that take it away are named:
        ``"net_rotation"`` (the loop reports the two as not separable) and ``"velocity_function"``
        when a function of the speed is a finding of its own on this residual. When only the
        speed takes it away and the speed's columns are not significant themselves (a velocity
        term already in the model leaves this: they keep less than ``MIN_OWN_SHARE`` of their
        variance beyond it, or explain too little), what the polynomial fits is that term's
        leftover, and nothing is claimed: the non-significant score is returned.
        """
        span = float(data.time_s[-1] - data.time_s[0]) or 1.0
        scale = float(np.max(np.abs(data.u_deg - data.u_deg[0]))) or 1.0
        # every column at the rows the scores read only (all of them unless screened)
        rotation = data.scored(data.u_deg)[:, 0] - data.u_deg[0]
        t0, times = float(data.time_s[0]), data.scored(data.time_s)[:, 0]
        rivals = {
            "net_rotation": np.column_stack([(rotation / scale) ** j for j in range(1, max_degree + 1)]),
            "velocity_function": held_spline_columns(data, record_speed_knots(data, MAX_INNER_KNOTS)),
        }
        beyond = data.with_nuisance(*rivals.values())
        found, alone = [], []
        for degree in range(1, max_degree + 1):
            effect = cls(degree, span)
            cols = effect.powers(times, t0)  # effect.terms on the record, at those rows
            in_time = data.score(effect.input_side, cols)
            # what time explains beyond its rivals decides; the collinearity test is against the terms only
            s = replace(beyond.score(effect.input_side, cols), own_share=in_time.own_share)
            found.append(
                Detection(
                    effect,
                    s,
                    f"residual drifts in time (degree {degree} over {span:.0f} s), "
                    "beyond the net rotation and the speed",
                )
            )
            alone.append(Detection(effect, in_time, "in time alone"))
        best = best_detection(found)
        confounded = best_detection([d for d in alone if d.score.significant()])
        if best is None or best.score.significant() or confounded is None:
            return best
        cols = confounded.effect.powers(times, t0)  # type: ignore[attr-defined]
        named = tuple(
            k for k, x in rivals.items() if x.shape[1] and not data.with_nuisance(x).score(False, cols).significant()
        )
        if "velocity_function" in named and not data.score(False, rivals["velocity_function"]).significant():
            named = tuple(k for k in named if k != "velocity_function")  # the leftover of a velocity term already in
            if not named:
                return best
        return Detection(
            confounded.effect,
            confounded.score,
            f"residual drifts in time (degree {getattr(confounded.effect, 'degree', 0)}), "
            f"but time is collinear with {' and '.join(named or tuple(rivals))}",
            rivals=named or tuple(rivals),
        )


#: The library's effects, in the order the closing-the-loop search tries them: the one list of them. A saved
#: estimator names its effects, and :func:`online_backlash.effect_terms.effect_class` finds them here by their
#: ``name`` (:data:`online_backlash.effect_terms.EFFECTS` is built from this list on its first look-up).
LIBRARY = (TransmissionError, Delay, Compliance, Drift, DeadBandMotion, FlankProfile)

#: the names an effect of the library may carry (the ``name`` of the JSON contract)
VOCABULARY = tuple(effect.name for effect in LIBRARY)
