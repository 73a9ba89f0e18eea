"""The load's motion inside the dead band, and the transient when a flank engages again.

Eq. (1)-(3) hold the load still while neither flank is engaged (``f1 = f2 = 0`` in eq. 5-6,
``x(t) = x(t-1)`` in eq. 7). A real output does not stop when the driving flank leaves it: it
coasts on from where the flank left it, slowed by its friction, and the measured torque on it
(a reaction torque, a cable stage) keeps pushing it. When the motor reaches the other flank,
the teeth meet at the motor's speed: the load is kicked, and on a compliant gear it rings
before it settles on the flank line. Neither sits in the paper's model; both show in the
simulation residual as spikes at the reversals.

:class:`DeadBandMotion` describes them with columns that are linear in their coefficients, so
the loop's joint fit (eq. 8 and 14 with appended columns) and its held-out scoring apply:

* **where the model's output rests** (eq. 7 holds it, ``x(t) = x(t-1)``: in the dead band, and on
  a flank while the motor stands still; zero elsewhere): the velocity ``v_x`` of ``u`` at the last
  sample where the output moved times ``1 - exp(-s / tau_j)``, ``s`` the time since that sample,
  for a few time constants ``tau_j`` (a load that leaves the pushing flank at ``v_x``, because the
  flank turns back or stops, and is braked by viscous friction coasts ``v_x tau (1 - exp(-s /
  tau))``); with a measured torque, also the torque then (held) and the change of the torque since.
  The flank *leaves* the load where the motor stops pushing it, not only where eq. (5)-(6) let go
  of it: a motor that stops on a flank keeps it engaged (a tie that ``h(0) = 1`` decides, see
  :func:`~online_backlash.model.simulate_switching`) while the load runs on;
* **after a flank engages** (zero elsewhere): the entry velocity ``v_e`` of ``u`` at the first
  engaged sample times hat functions of the time since engagement (the impact's response,
  scaled by the speed of the impact), up to the last knot;
* **while the model's output rests** (optional, ``rest_time_constants_s``, ``creep_step``): where
  eq. (7) holds the output, ``x(t) = x(t-1)`` (the motor at rest on a flank, or the dead band), the
  load goes on creeping in the direction ``d`` the output last moved, released by what the drive
  train stored while it pushed (the reaction torque, the shaft's twist): ``[d > 0] (1 - exp(-r /
  tau_j))`` and ``[d < 0] (1 - exp(-r / tau_j))``, ``r`` the time since ``x`` last moved, one
  column per direction and time constant (a stroke's top and bottom are loaded differently), and
  with ``creep_step`` ``[d > 0]`` and ``[d < 0]`` themselves: the lead the load already has when
  the output stops (a motor that slows down faster than the load's friction can brake it leaves the
  load before it stops; ``tests/test_creep_at_rest.py``). ``creep_directions`` keeps the columns of
  one direction only. The coast above scales with the speed the output last moved at, which a
  motor that ramps down before it rests makes small; this creep does not need the speed.
  Coefficients in deg (the creep's share reached with each time constant, at once for the step).

What :meth:`DeadBandMotion.detect` offers is what the record can tell apart and what a load at rest
can do (``docs/closing-the-loop.md``, "The creep's asymptote"): the creep's time constants the
record's rests outlast (a longer one is a ramp over every rest, whose asymptote, the reported total,
would be an extrapolation traded against the others), the coast and the creep together only where
neither is a copy of the other (after a stop at the same crawl speed every time, the coast's columns
are the creep's scaled), and the creep of a direction only where it is physical: over the rests and
at its asymptote, in the direction the load last moved and inside the dead band (within the noise
floor).

Engaged or not is decided by the model's own switching functions, eq. (5)-(6), run on ``u``
with the backlash parameters the effect is given (the loop's current fit, in its frame: ``u``
minus its first sample, the output starting at 0). Coefficients are in seconds (deg of load
angle per deg/s of motor speed) and deg per N m. The columns are causal and give the same rows
for a record passed whole or in pieces.

Units: degrees (load side), seconds, newton metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from itertools import pairwise
from typing import Any

import numpy as np
from numba import njit

from ..errors import InvalidParameterError
from ..model import BacklashParams, simulate_switching
from ._causal import CausalWindow, sample_period_s, velocity_deg_s
from ._effect_base import EffectBase
from ._normal_equations import left_sum_of_squares
from ._scoring import BIC_THRESHOLD, MIN_OWN_SHARE, Detection, DetectionData, Score, best_detection

#: time constants of the coast after the flank leaves the load, in sample periods (a factor of 8
#: apart: closer ones are nearly collinear over a dead band of a few hundred samples)
EXIT_TIME_CONSTANTS = (4, 32, 256)
#: time constants of the creep while the model's output rests, in sample periods
REST_TIME_CONSTANTS = (8, 32, 128)
#: the parts :meth:`DeadBandMotion.detect` tries, alone and together
VARIANTS = (
    ("coast", "entry"),
    ("coast",),
    ("entry",),
    ("coast", "entry", "creep at rest"),
    ("coast", "creep at rest"),
    ("entry", "creep at rest"),
    ("creep at rest",),
)
#: the JSON names of the directions the output last moved
DIRECTION_NAMES = {1: "moving_up", -1: "moving_down"}
#: knots of the entry transient's hat functions, in sample periods (the last one ends it): an
#: octave apart, from the impact of a stiff gear (a few samples) to a closed loop's settling
ENTRY_KNOTS = (0, 2, 4, 8, 16, 32, 64, 128)


def _at_period(samples: tuple[int, ...], period_s: float) -> tuple[float, ...]:
    """Sample counts as times, s."""
    return tuple(period_s * k for k in samples)


class DeadBandMotion(EffectBase):
    """The load's motion inside the dead band and its transient when a flank engages again.

    Parameters
    ----------
    m_left, c_left_deg, m_right, c_right_deg : float
        The backlash parameters (eq. 1) whose switching functions (eq. 5-6) decide where a flank
        is engaged, in the frame of ``u`` minus its first sample (deg).
    exit_time_constants_s : tuple of float
        Time constants of the coast columns in the dead band, s (empty: no coast columns).
    entry_knots_s : tuple of float
        Knots of the entry transient, s, increasing from 0; the transient ends at the last one
        (fewer than two: no entry columns).
    torque : bool
        Add the measured torque at exit (held) and its change since exit, in the dead band.
    rest_time_constants_s : tuple of float
        Time constants of the creep while the output rests, s (empty and no ``creep_step``: no creep columns).
    window_samples : int
        Span of the causal velocity of ``u``, samples.
    smooth_samples : int
        Causal moving average of the torque, samples.
    creep_step : bool
        Add to the creep a step per direction: the lead the load has when the output stops.
    creep_directions : tuple of int
        The directions the output last moved (+1 up, -1 down) whose creep has columns.
    """

    name = "dead_band_motion"
    input_side = False  # the columns are built for the dead band itself, not held through it
    #: the state reaches back to the last reversal, beyond any fixed window: not restorable from
    #: the last samples (``effect_terms.stream_history`` gives None, an estimator restarts it)
    history = None  # type: ignore[assignment]

    def __init__(
        self,
        m_left: float = 1.0,
        c_left_deg: float = 0.25,
        m_right: float = 1.0,
        c_right_deg: float = 0.25,
        exit_time_constants_s: tuple[float, ...] = _at_period(EXIT_TIME_CONSTANTS, 1e-3),
        entry_knots_s: tuple[float, ...] = _at_period(ENTRY_KNOTS, 1e-3),
        torque: bool = False,
        rest_time_constants_s: tuple[float, ...] = (),
        window_samples: int = 5,
        smooth_samples: int = 5,
        creep_step: bool = False,
        creep_directions: tuple[int, ...] = (1, -1),
    ) -> None:
        self.m_left, self.c_left_deg, self.m_right, self.c_right_deg = (
            float(m_left),
            float(c_left_deg),
            float(m_right),
            float(c_right_deg),
        )
        self._params = BacklashParams(self.m_left, self.c_left_deg, self.m_right, self.c_right_deg)
        self.exit_time_constants_s = tuple(float(v) for v in exit_time_constants_s)
        self.entry_knots_s = tuple(float(v) for v in entry_knots_s)
        self.rest_time_constants_s = tuple(float(v) for v in rest_time_constants_s)
        if any(not v > 0 for v in self.exit_time_constants_s + self.rest_time_constants_s):
            raise InvalidParameterError(
                "exit_time_constants_s and rest_time_constants_s must be > 0, "
                f"got {exit_time_constants_s!r}, {rest_time_constants_s!r}"
            )
        if self.entry_knots_s and (self.entry_knots_s[0] != 0.0 or np.any(np.diff(self.entry_knots_s) <= 0)):
            raise InvalidParameterError(f"entry_knots_s must start at 0 and increase, got {entry_knots_s!r}")
        self.torque = bool(torque)
        self.creep_step = bool(creep_step)
        self.creep_directions = tuple(int(d) for d in creep_directions)
        directions = self.creep_directions
        if not directions or len(set(directions)) != len(directions) or set(directions) - {1, -1}:
            raise InvalidParameterError(f"creep_directions must be 1, -1 or both, got {creep_directions!r}")
        if int(window_samples) < 1 or int(smooth_samples) < 1:
            raise InvalidParameterError(
                f"window_samples and smooth_samples must be >= 1, got {window_samples!r}, {smooth_samples!r}"
            )
        self.window_samples = int(window_samples)
        self.smooth_samples = int(smooth_samples)
        self._window = CausalWindow(max(self.window_samples, self.smooth_samples))
        self.reset()

    def reset(self) -> None:
        super().reset()
        self._u0: float | None = None
        self._x = 0.0
        # the last sample's input (from u0) and switching functions, eq. (5)-(6) (None before any)
        self._switched: tuple[float, float, float] | None = None
        # the last entry (time, velocity)
        self._entry = (np.nan, 0.0)
        # the output's last move: time, direction (+1 / -1, 0 before any), velocity, smoothed torque
        self._moved = (np.nan, 0.0, 0.0, 0.0)

    @property
    def n_entry(self) -> int:
        """Columns of the entry transient."""
        return max(len(self.entry_knots_s) - 1, 0)

    @property
    def creep_shapes(self) -> tuple[float, ...]:
        """The creep's time constants, s, the step's (0) first: one column per direction each."""
        return (0.0,) * self.creep_step + self.rest_time_constants_s

    @property
    def n_rest(self) -> int:
        """Columns of the creep while the output rests."""
        return len(self.creep_shapes) * len(self.creep_directions) if self.creep_shapes else 0

    @property
    def n_terms(self) -> int:
        return len(self.exit_time_constants_s) + 2 * self.torque + self.n_entry + self.n_rest

    def creep_by_direction(self, rest_coef: np.ndarray) -> dict[int, np.ndarray]:
        """The creep's coefficients (deg, the last :attr:`n_rest` of the effect's) per direction the
        output last moved (+1, -1), in the order of :attr:`creep_shapes`; zeros for a direction without
        columns."""
        nd, none = len(self.creep_directions), np.zeros(len(self.creep_shapes))
        directions = self.creep_directions
        return {d: rest_coef[directions.index(d) :: nd] if d in directions else none for d in (1, -1)}

    def engaged(self, u_deg: np.ndarray) -> np.ndarray:
        """Where a flank is engaged by the switching functions, eq. (5)-(6), continuing the stream (advances it)."""
        return self._switch(u_deg)[0]

    def _switch(self, u_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Engaged (eq. 5-6) and the output's change ``x(t) - x(t-1)`` (eq. 7), deg, continuing the stream."""
        if self._u0 is None:
            self._u0 = float(u_deg[0])
        uc = np.asarray(u_deg, dtype=float) - self._u0
        x, f1, f2 = simulate_switching(uc, self._params, self._x, self._switched)
        dx = np.diff(x, prepend=self._x)
        self._x = float(x[-1])
        self._switched = (float(uc[-1]), float(f1[-1]), float(f2[-1]))
        return (f1 + f2) > 0, dx

    def switch_clock(self, u_deg: np.ndarray, time_s: np.ndarray, limit_s: float = 0.25) -> np.ndarray:
        """Time since a flank left (negative, in the dead band) or engaged (positive), s, clipped to
        ``limit_s``: the axis this effect acts along (a fresh stream over a whole record)."""
        e = self.clone().engaged(np.asarray(u_deg, dtype=float))  # type: ignore[attr-defined]
        t = np.asarray(time_s, dtype=float)
        i = np.arange(e.size)
        since = t - t[np.maximum.accumulate(np.where(np.r_[True, e[1:] != e[:-1]], i, 0))]
        return np.clip(np.where(e, since, -since), -limit_s, limit_s)

    def terms(self, u_deg: np.ndarray, time_s: np.ndarray, torque_Nm: np.ndarray) -> np.ndarray:
        """Regressor columns ``(len(u_deg), n_terms)``: coast, torque and entry columns (causal)."""
        return self._stream(u_deg, time_s, torque_Nm, None)[0]

    def columns_at(
        self, u_deg: np.ndarray, time_s: np.ndarray, torque_Nm: np.ndarray, rows: np.ndarray | None
    ) -> np.ndarray:
        """:meth:`terms` of a fresh stream over the whole record, at the sample indices ``rows`` only
        (increasing; None: every sample): the same numbers, without the record's full block."""
        return self.columns_and_support_at(u_deg, time_s, torque_Nm, rows)[0]

    def columns_and_support_at(
        self, u_deg: np.ndarray, time_s: np.ndarray, torque_Nm: np.ndarray, rows: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`columns_at` and the positions of its rows with a value other than zero (increasing;
        what :func:`._normal_equations.nonzero_rows` finds, noted by the pass as it writes them: the
        columns are zero outside the rests and entries, most of a record)."""
        fresh: DeadBandMotion = self.clone()  # type: ignore[assignment]
        return fresh._stream(u_deg, time_s, torque_Nm, rows)

    def _stream(
        self, u_deg: np.ndarray, time_s: np.ndarray, torque_Nm: np.ndarray, rows: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The columns of the next samples (:meth:`terms`), at ``rows`` of them only unless None, and
        the positions of the rows written with a value other than zero."""
        ue, te, qe, n_past = self._window.extend(u_deg, time_s, torque_Nm)
        if ue.size == 0:
            return np.empty((0, self.n_terms)), np.empty(0, dtype=np.int64)
        v = velocity_deg_s(ue, te, self.window_samples)[n_past:]
        qz = np.nan_to_num(qe, nan=0.0)
        w = self.smooth_samples
        qs = (np.convolve(qz, np.ones(w) / w)[: qz.size] if w > 1 else qz)[n_past:]
        self._window.keep(ue, te, qe)
        u, t = ue[n_past:], te[n_past:]
        engaged_before = self._switched is not None and self._switched[1] + self._switched[2] > 0
        e, dx = self._switch(u)
        rows = np.arange(u.size) if rows is None else np.ascontiguousarray(rows, dtype=np.int64)
        cols = np.zeros((rows.size, self.n_terms))
        nonzero = np.zeros(rows.size, dtype=np.bool_)
        # the stream's state: the last sample engaged, the last entry (time, velocity), the output's
        # last move (time, direction, velocity, torque)
        state = np.array([float(engaged_before), *self._entry, *self._moved], dtype=float)
        _columns_pass(
            e,
            dx,
            np.ascontiguousarray(t, dtype=float),
            np.ascontiguousarray(v, dtype=float),
            np.ascontiguousarray(qs, dtype=float),
            state,
            np.asarray(self.exit_time_constants_s, dtype=float),
            self.torque,
            np.asarray(self.entry_knots_s, dtype=float),
            self.n_entry,
            np.asarray(self.creep_shapes, dtype=float),
            np.asarray(self.creep_directions, dtype=np.int64),
            rows,
            cols,
            nonzero,
        )
        self._entry = (float(state[1]), float(state[2]))
        self._moved = (float(state[3]), float(state[4]), float(state[5]), float(state[6]))
        return cols, np.flatnonzero(nonzero)

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        c = [float(v) for v in coef]
        n_exit = len(self.exit_time_constants_s)
        coast = c[:n_exit]
        out: dict[str, Any] = {
            "model": "where the model's output rests: the load coasts on from where the flank stopped pushing it "
            "(turned back "
            "or stopped); after a flank engages: a transient scaled by the speed of the impact",
            "active_on": "the coast wherever eq. (7) holds the model's output "
            "(the dead band, a flank while the motor stands still); "
            "the first entry_knots_s[-1] s after a flank engages, by the model's switching functions (eq. 5-6)",
            "dead_band_deg": self.c_left_deg + self.c_right_deg,
            "coast": [
                {"time_constant_s": tau, "deg_per_deg_s": b} for tau, b in zip(self.exit_time_constants_s, coast)
            ],
            "coast_per_exit_speed_s": float(sum(coast)),
        }
        k = n_exit
        if self.torque:
            out["torque_at_exit_deg_per_Nm"] = c[k]
            out["torque_change_in_dead_band_deg_per_Nm"] = c[k + 1]
            k += 2
        entry, rest = c[k : k + self.n_entry], c[k + self.n_entry :]
        if self.n_rest:
            out["model"] += "; while the model's output rests: the load creeps on in the direction it last moved"
            out["active_on"] += "; the creep wherever eq. (7) holds the model's output"
            per = self.creep_by_direction(np.asarray(rest))
            out["creep_at_rest"] = [
                {"time_constant_s": tau, "moving_up_deg": float(up), "moving_down_deg": float(down)}
                for tau, up, down in zip(self.creep_shapes, per[1], per[-1])
            ]
            out["creep_at_rest_total_deg"] = {"moving_up": float(per[1].sum()), "moving_down": float(per[-1].sum())}
            out["creep_directions"] = [DIRECTION_NAMES[d] for d in self.creep_directions]
        out["entry_transient"] = {"knots_s": list(self.entry_knots_s), "deg_per_deg_s": [*entry, 0.0] if entry else []}
        out["entry_peak_deg_per_deg_s"] = max(entry, key=abs) if entry else 0.0
        return out

    def typical_rest_s(self, u_deg: np.ndarray, time_s: np.ndarray) -> float:
        """How long the output's rests last, s: the rest the median resting sample is in, from where the
        output last moved to its last sample at rest (eq. 7 holding it: the dead band, a motor at rest on a
        flank; a fresh stream over a whole record); 0 without a rest. Weighed by their samples, the short
        pauses of a slow motor between two encoder counts count for little."""
        _, dx = self.clone()._switch(np.asarray(u_deg, dtype=float))  # type: ignore[attr-defined]
        t = np.asarray(time_s, dtype=float)
        moved = np.flatnonzero(dx != 0.0)
        if moved.size == 0:
            return 0.0
        ends = np.r_[moved[1:] - 1, t.size - 1]  # the last sample of the rest after each move
        samples = ends - moved
        lengths = (t[ends] - t[moved])[samples > 0]
        return float(np.median(np.repeat(lengths, samples[samples > 0]))) if lengths.size else 0.0

    @classmethod
    def record_rest_s(cls, data: DetectionData, params: Any) -> float:
        """:meth:`typical_rest_s` of the record ``data`` under the backlash fit ``params`` (eq. 1), s: formed once
        per record and fit (a round's detection on its screen and its confirmation on every sample share it)."""
        p = params
        key = ("typical rest", float(p.m_left), float(p.c_left), float(p.m_right), float(p.c_right))
        rest = cls(p.m_left, p.c_left, p.m_right, p.c_right)
        return float(data.memo(key, lambda: np.array([rest.typical_rest_s(data.u_deg, data.time_s)]))[0])

    def creep_is_physical(self, rest_coef: np.ndarray, horizon_s: float, period_s: float, tolerance_deg: float) -> bool:
        """True when the creep of every direction with columns, ``rest_coef`` (deg, the effect's last
        :attr:`n_rest`), stays in the direction the output last moved and inside the dead band, up to
        ``tolerance_deg``: at every sample of a rest up to ``horizon_s`` and at its asymptote (the
        reported total). A load at rest in the gap neither moves back through the flank it left nor
        beyond the other one."""
        shapes = np.asarray(self.creep_shapes)
        r = period_s * np.arange(1, max(round(horizon_s / period_s), 1) + 1)
        reached = np.where(shapes == 0.0, 1.0, -np.expm1(-r[:, None] / np.where(shapes == 0.0, 1.0, shapes)))
        gap = self.c_left_deg + self.c_right_deg
        for d, coef in self.creep_by_direction(np.asarray(rest_coef, dtype=float)).items():
            if d not in self.creep_directions:
                continue
            ahead = d * np.r_[reached @ coef, coef.sum()]
            if ahead.min() < -tolerance_deg or ahead.max() > gap + tolerance_deg:
                return False
        return True

    def is_physical(self, coef: np.ndarray, u_deg: np.ndarray, time_s: np.ndarray, tolerance_deg: float) -> bool:
        """:meth:`creep_is_physical` of the creep's part of the effect's coefficients ``coef`` on the record
        ``u_deg``, ``time_s`` (its rests, :meth:`typical_rest_s`); True without a creep."""
        if not self.n_rest:
            return True
        period = sample_period_s(time_s)
        horizon = self.typical_rest_s(u_deg, time_s)
        return self.creep_is_physical(np.asarray(coef)[self.n_terms - self.n_rest :], horizon, period, tolerance_deg)

    @classmethod
    def detect(cls, data: DetectionData) -> Detection | None:
        """The coast in the dead band, the entry transient and the creep while the output rests, in
        every combination, whichever scores best; a combination with the creep only if it beats the
        best one without it by :data:`BIC_THRESHOLD` (the creep must hold on its own), and the creep's
        step only if it beats the same creep without it by that margin.

        What is offered is what the record can tell apart and what a load at rest can do: the creep's
        time constants up to :meth:`typical_rest_s`; the coast and the creep together only where each of
        the coast's columns keeps :data:`~._scoring.MIN_OWN_SHARE` of its variance beyond the creep's and
        each of the creep's beyond the coast's, over the rows where the dead band acts (after stops at one
        crawl speed the coast's columns, that speed times shapes of the creep's clock, are the creep's
        scaled); and a creep only where it is physical (:meth:`creep_is_physical`, within the noise floor
        ``data.noise_floor_deg``): where it is not, with the creep of each direction alone.

        Needs the current backlash fit (``data.backlash_params``); without it nothing is tried.
        """
        p = data.backlash_params
        if p is None:
            return None
        dt = data.sample_period_s
        torque = bool(np.mean(np.isfinite(data.torque_Nm)) > 0.5)
        horizon = cls.record_rest_s(data, p)
        taus, knots = _at_period(EXIT_TIME_CONSTANTS, dt), _at_period(ENTRY_KNOTS, dt)
        rests = tuple(tau for tau in _at_period(REST_TIME_CONSTANTS, dt) if tau <= horizon)
        every_one = cls(p.m_left, p.c_left, p.m_right, p.c_right, taus, knots, torque, rests, creep_step=True)
        # the coast (and torque) columns come first, then the entry's, the creep's last: each a slice
        every, nonzero = every_one.columns_and_support_at(
            data.u_deg, data.time_s, data.torque_Nm, data.scored_rows
        )  # the rows the scores use
        split = every_one.n_terms - every_one.n_entry - every_one.n_rest
        ends = np.cumsum([0, split, every_one.n_entry, every_one.n_rest])
        parts = dict(zip(("coast", "entry", "creep at rest"), (list(range(int(a), int(b))) for a, b in pairwise(ends))))
        # the creep's columns without and with its step (per shape, the step's first: up, then down)
        creep_cols = {step: parts["creep at rest"][0 if step else 2 :] for step in (False, True) if step or rests}
        gram = _gram_with_constant(every[nonzero])
        menu: list[_Option] = []
        for names in VARIANTS:
            others = [j for n in names if n != "creep at rest" for j in parts[n]]
            if "creep at rest" not in names:
                menu.append(_Option(names, False, (), others))
            for step, cols in creep_cols.items() if "creep at rest" in names else ():
                if "coast" not in names or _apart(gram, parts["coast"][: len(taus)], cols):
                    menu.append(_Option(names, step, (1, -1), others, cols))

        def offered(options: list[_Option]) -> list[tuple[_Option, Detection]]:
            # one set of cross-products, over the rows where the load coasts, enters or creeps only
            scores = data.score_subsets(every, [o.columns for o in options], support=nonzero)
            return [(o, cls._detection(p, o, taus, knots, torque, rests, s)) for o, s in zip(options, scores)]

        def physical(detection: Detection) -> bool:
            effect: DeadBandMotion = detection.effect  # type: ignore[assignment]
            coef = detection.score.coef[effect.n_terms - effect.n_rest :]
            return detection.score.significant() and effect.creep_is_physical(coef, horizon, dt, data.noise_floor_deg)

        found = offered(menu)
        plain = best_detection([d for o, d in found if not o.directions and d.score.significant()])
        creeps = [(o, d) for o, d in found if o.directions and physical(d)]
        # where the creep of both directions is significant but not physical, the creep of each direction alone
        unphysical = [o for o, both in found if o.directions and both.score.significant() and not physical(both)]
        alone = [o.alone(d) for o in unphysical for d in (1, -1)]
        alone_found = [(o, d) for o, d in offered(alone) if physical(d)] if alone else []
        creeps += alone_found
        found += alone_found
        # the creep's step only where it beats the creep without it, and the creep only where it beats the parts
        # without it, by the criterion's own margin
        without_step, with_step = (best_detection([d for o, d in creeps if o.step == s]) for s in (False, True))
        creep = _beaten(without_step, with_step)
        best = _beaten(plain, creep) or best_detection([d for o, d in found if not o.directions])
        if best is None or data.scored_rows is not None:
            return best
        # every sample's columns were formed: the chosen parts' are a slice of them (the same numbers as its terms)
        chosen = next(o.columns for o, d in found if d is best)
        if len(chosen) == every.shape[1]:
            return replace(best, columns=every, nonzero_rows=nonzero)
        mine = np.ascontiguousarray(every[:, chosen])
        return replace(best, columns=mine, nonzero_rows=nonzero[np.any(mine[nonzero] != 0.0, axis=1)])

    @classmethod
    def _detection(
        cls,
        p: Any,
        option: _Option,
        taus: tuple[float, ...],
        knots: tuple[float, ...],
        torque: bool,
        rests: tuple[float, ...],
        score: Score,
    ) -> Detection:
        """The effect of ``option`` (its parts, the creep's step and directions) on the backlash fit ``p``, and
        its evidence."""
        names, creep = option.names, bool(option.directions)
        exit_taus = taus if "coast" in names else ()
        effect = cls(
            p.m_left,
            p.c_left,
            p.m_right,
            p.c_right,
            exit_taus,
            knots if "entry" in names else (),
            torque and bool(exit_taus),
            rests if creep else (),
            creep_step=option.step,
            creep_directions=option.directions or (1, -1),
        )
        notes = ["from the lead at the stop"] * option.step
        if len(option.directions) == 1:
            notes.append(DIRECTION_NAMES[option.directions[0]].replace("_", " ") + " only")
        what = " and ".join(names) + (f" ({', '.join(notes)})" if notes else "")
        evidence = f"residual at the reversals follows the load's {what} (dead band {p.play:.4g} deg)"
        return Detection(effect, score, evidence)


@dataclass(frozen=True)
class _Option:
    """A combination :meth:`DeadBandMotion.detect` scores: its parts, whether the creep has its step,
    the directions of the creep (empty: no creep), and its columns among the detector's: those of the
    other parts and the creep's (per shape, up then down, of the directions it has)."""

    names: tuple[str, ...]
    step: bool
    directions: tuple[int, ...]
    others: list[int]
    creep: list[int] = field(default_factory=list)

    @property
    def columns(self) -> list[int]:
        return self.others + self.creep

    def alone(self, direction: int) -> _Option:
        """The same combination with the creep of ``direction`` only (of a creep of both directions)."""
        return replace(self, directions=(direction,), creep=self.creep[0 if direction > 0 else 1 :: 2])


def _beaten(first: Detection | None, second: Detection | None) -> Detection | None:
    """``second`` where it beats ``first`` by :data:`BIC_THRESHOLD` in the criterion (or there is no
    ``first``), else ``first``."""
    if second is not None and (first is None or second.score.delta_bic - first.score.delta_bic < BIC_THRESHOLD):
        return second
    return first


def _gram_with_constant(rows: np.ndarray) -> np.ndarray:
    """The Gram matrix of ``[1, rows]`` (a constant column first)."""
    gram = np.empty((rows.shape[1] + 1, rows.shape[1] + 1))
    gram[0, 0], gram[0, 1:] = rows.shape[0], rows.sum(axis=0)
    gram[1:, 0], gram[1:, 1:] = gram[0, 1:], rows.T @ rows
    return gram


def _apart(gram: np.ndarray, a: list[int], b: list[int]) -> bool:
    """True when every one of the columns ``a`` keeps :data:`~._scoring.MIN_OWN_SHARE` of its variance
    beyond a constant and the columns ``b``, and every one of ``b`` beyond ``a`` (either empty: True);
    ``gram``: :func:`_gram_with_constant` of the columns (positions counted without the constant)."""
    for mine, others in ((a, b), (b, a)) if a and b else ():
        for j in mine:
            beyond = [0, *(k + 1 for k in others), j + 1]
            spread = left_sum_of_squares(gram[np.ix_([0, j + 1], [0, j + 1])])
            if left_sum_of_squares(gram[np.ix_(beyond, beyond)]) < MIN_OWN_SHARE * spread:
                return False
    return True


@njit(cache=True, nogil=True)
def _columns_pass(  # pragma: no cover - compiled
    e, dx, t, v, qs, state, exit_taus, torque, knots, n_entry, rest_taus, directions, rows, out, nonzero
):
    """:meth:`DeadBandMotion.terms`' columns in one pass over the samples, continuing ``state``
    (updated in place, see there), written for the samples ``rows`` (increasing) only, ``out[r]`` for
    ``rows[r]`` (``out`` zero on entry), and ``nonzero[r]`` set where ``out[r]`` holds a value other
    than zero. Where the output rests (``dx == 0``: the dead band, or a flank while the motor stands
    still) since it last moved at ``t_m`` with the velocity ``v_m`` and torque ``q_m``, in the direction
    ``d``: ``v_m`` times ``1 - exp(-(t - t_m) / tau)`` per ``exit_taus``, then (``torque``) ``q_m`` and
    the torque's change since; ``1 - exp(-(t - t_m) / tau)`` per ``rest_taus`` (1 for a ``tau`` of 0: the
    step) in the column of the direction ``d`` among ``directions`` (none if it is not among them).
    After the last entry (a flank engaged, ``e``) at ``t_e``, ``v_e`` times the hat
    functions of ``knots`` at ``t - t_e`` (as ``numpy.interp`` evaluates them), while ``t - t_e`` is
    below the last knot."""
    e_prev, t_e, v_e = state[0] > 0.5, state[1], state[2]
    t_m, d_m, v_m, q_m = state[3], state[4], state[5], state[6]
    n_exit = exit_taus.size
    r = 0
    for s in range(e.size):
        now = e[s]
        if now and not e_prev:  # a flank engaged at this one
            t_e, v_e = t[s], v[s]
        if dx[s] != 0.0:
            t_m, d_m, v_m, q_m = t[s], np.sign(dx[s]), v[s], qs[s]
        write = r < rows.size and rows[r] == s
        resting = write and dx[s] == 0.0 and np.isfinite(t_m)
        if resting:
            gone = t[s] - t_m
            for j in range(n_exit):
                out[r, j] = v_m * -math.expm1(-gone / exit_taus[j])
            if torque:
                out[r, n_exit] = q_m
                out[r, n_exit + 1] = qs[s] - q_m
        k = n_exit + 2 * torque
        entering = False
        if write and n_entry and now and np.isfinite(t_e):
            since = t[s] - t_e
            entering = since < knots[knots.size - 1]
            if entering:
                i = 0
                while i < knots.size - 2 and knots[i + 1] <= since:
                    i += 1
                for j in range(n_entry):  # the hat of knot j: 1 at knots[j], 0 at the others
                    lo = 1.0 if i == j else 0.0
                    hi = 1.0 if i + 1 == j else 0.0
                    out[r, k + j] = v_e * ((hi - lo) / (knots[i + 1] - knots[i]) * (since - knots[i]) + lo)
        k += n_entry
        if resting:
            nd = directions.size
            for i in range(nd):
                if d_m == directions[i]:
                    for j in range(rest_taus.size):
                        tau = rest_taus[j]
                        out[r, k + nd * j + i] = 1.0 if tau == 0.0 else -math.expm1(-(t[s] - t_m) / tau)
        if resting or entering:  # the only rows written
            for j in range(out.shape[1]):
                if out[r, j] != 0.0:
                    nonzero[r] = True
                    break
        if write:
            r += 1
        e_prev = now
    state[0], state[1], state[2] = 1.0 if e_prev else 0.0, t_e, v_e
    state[3], state[4], state[5], state[6] = t_m, d_m, v_m, q_m
