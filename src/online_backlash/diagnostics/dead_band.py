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
* **while the model's output rests** (optional, ``rest_time_constants_s``): where eq. (7) holds
  the output, ``x(t) = x(t-1)`` (the motor at rest on a flank, or the dead band), the load goes
  on creeping in the direction ``d`` the output last moved, released by what the drive train
  stored while it pushed (the reaction torque, the shaft's twist): ``[d > 0] (1 - exp(-r /
  tau_j))`` and ``[d < 0] (1 - exp(-r / tau_j))``, ``r`` the time since ``x`` last moved, one
  column per direction and time constant (a stroke's top and bottom are loaded differently). The
  coast above scales with the speed the output last moved at, which a motor that ramps down
  before it rests makes small; this creep does not need the speed. Coefficients in deg (the
  creep's share reached with each time constant).

Engaged or not is decided by the model's own switching functions, eq. (5)-(6), run on ``u``
with the backlash parameters the effect is given (the loop's current fit, in its frame: ``u``
minus its first sample, the output starting at 0). Coefficients are in seconds (deg of load
angle per deg/s of motor speed) and deg per N m. The columns are causal and give the same rows
for a record passed whole or in pieces.

Units: degrees (load side), seconds, newton metres.
"""

from __future__ import annotations

import math
from dataclasses import replace
from itertools import pairwise
from typing import Any

import numpy as np
from numba import njit

from ..errors import InvalidParameterError
from ..model import BacklashParams, simulate_switching
from ._causal import CausalWindow, velocity_deg_s
from ._effect_base import EffectBase
from ._scoring import BIC_THRESHOLD, Detection, DetectionData, best_detection

#: time constants of the coast after the flank leaves the load, in sample periods (a factor of 8
#: apart: closer ones are nearly collinear over a dead band of a few hundred samples)
EXIT_TIME_CONSTANTS = (4, 32, 256)
#: time constants of the creep while the model's output rests, in sample periods
REST_TIME_CONSTANTS = (8, 32, 128)
#: the parts :meth:`DeadBandMotion.detect` tries, alone and together
VARIANTS = (
    ("coast", "entry"), ("coast",), ("entry",),
    ("coast", "entry", "creep at rest"), ("coast", "creep at rest"), ("entry", "creep at rest"), ("creep at rest",),
)
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
        Time constants of the creep while the output rests, s (empty: no creep columns).
    window_samples : int
        Span of the causal velocity of ``u``, samples.
    smooth_samples : int
        Causal moving average of the torque, samples.
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
    ) -> None:
        self.m_left, self.c_left_deg, self.m_right, self.c_right_deg = float(m_left), float(c_left_deg), float(m_right), float(c_right_deg)
        self._params = BacklashParams(self.m_left, self.c_left_deg, self.m_right, self.c_right_deg)
        self.exit_time_constants_s = tuple(float(v) for v in exit_time_constants_s)
        self.entry_knots_s = tuple(float(v) for v in entry_knots_s)
        self.rest_time_constants_s = tuple(float(v) for v in rest_time_constants_s)
        if any(not v > 0 for v in self.exit_time_constants_s + self.rest_time_constants_s):
            raise InvalidParameterError(
                f"exit_time_constants_s and rest_time_constants_s must be > 0, got {exit_time_constants_s!r}, {rest_time_constants_s!r}"
            )
        if self.entry_knots_s and (self.entry_knots_s[0] != 0.0 or np.any(np.diff(self.entry_knots_s) <= 0)):
            raise InvalidParameterError(f"entry_knots_s must start at 0 and increase, got {entry_knots_s!r}")
        self.torque = bool(torque)
        if int(window_samples) < 1 or int(smooth_samples) < 1:
            raise InvalidParameterError(f"window_samples and smooth_samples must be >= 1, got {window_samples!r}, {smooth_samples!r}")
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
    def n_rest(self) -> int:
        """Columns of the creep while the output rests."""
        return 2 * len(self.rest_time_constants_s)

    @property
    def n_terms(self) -> int:
        return len(self.exit_time_constants_s) + 2 * self.torque + self.n_entry + self.n_rest

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

    def columns_at(self, u_deg: np.ndarray, time_s: np.ndarray, torque_Nm: np.ndarray, rows: np.ndarray | None) -> np.ndarray:
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

    def _stream(self, u_deg: np.ndarray, time_s: np.ndarray, torque_Nm: np.ndarray, rows: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
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
            e, dx, np.ascontiguousarray(t, dtype=float), np.ascontiguousarray(v, dtype=float), np.ascontiguousarray(qs, dtype=float), state,
            np.asarray(self.exit_time_constants_s, dtype=float), self.torque, np.asarray(self.entry_knots_s, dtype=float), self.n_entry,
            np.asarray(self.rest_time_constants_s, dtype=float), rows, cols, nonzero,
        )
        self._entry = (float(state[1]), float(state[2]))
        self._moved = (float(state[3]), float(state[4]), float(state[5]), float(state[6]))
        return cols, np.flatnonzero(nonzero)

    def describe(self, coef: np.ndarray) -> dict[str, Any]:
        c = [float(v) for v in coef]
        n_exit = len(self.exit_time_constants_s)
        coast = c[:n_exit]
        out: dict[str, Any] = {
            "model": "where the model's output rests: the load coasts on from where the flank stopped pushing it (turned back "
            "or stopped); after a flank engages: a transient scaled by the speed of the impact",
            "active_on": "the coast wherever eq. (7) holds the model's output (the dead band, a flank while the motor stands still); "
            "the first entry_knots_s[-1] s after a flank engages, by the model's switching functions (eq. 5-6)",
            "dead_band_deg": self.c_left_deg + self.c_right_deg,
            "coast": [{"time_constant_s": tau, "deg_per_deg_s": b} for tau, b in zip(self.exit_time_constants_s, coast)],
            "coast_per_exit_speed_s": float(sum(coast)),
        }
        k = n_exit
        if self.torque:
            out["torque_at_exit_deg_per_Nm"] = c[k]
            out["torque_change_in_dead_band_deg_per_Nm"] = c[k + 1]
            k += 2
        entry, rest = c[k : k + self.n_entry], c[k + self.n_entry :]
        if self.rest_time_constants_s:
            out["model"] += "; while the model's output rests: the load creeps on in the direction it last moved"
            out["active_on"] += "; the creep wherever eq. (7) holds the model's output"
            out["creep_at_rest"] = [
                {"time_constant_s": tau, "moving_up_deg": up, "moving_down_deg": down}
                for tau, up, down in zip(self.rest_time_constants_s, rest[0::2], rest[1::2])
            ]
            out["creep_at_rest_total_deg"] = {"moving_up": float(sum(rest[0::2])), "moving_down": float(sum(rest[1::2]))}
        out["entry_transient"] = {"knots_s": list(self.entry_knots_s), "deg_per_deg_s": [*entry, 0.0] if entry else []}
        out["entry_peak_deg_per_deg_s"] = max(entry, key=abs) if entry else 0.0
        return out

    @classmethod
    def detect(cls, data: DetectionData) -> Detection | None:
        """The coast in the dead band, the entry transient and the creep while the output rests, in
        every combination, whichever scores best; a combination with the creep only if it beats the
        best one without it by :data:`BIC_THRESHOLD` (the creep must hold on its own).

        Needs the current backlash fit (``data.backlash_params``); without it nothing is tried.
        """
        p = data.backlash_params
        if p is None:
            return None
        dt = data.sample_period_s
        torque = bool(np.mean(np.isfinite(data.torque_Nm)) > 0.5)
        taus, knots, rests = _at_period(EXIT_TIME_CONSTANTS, dt), _at_period(ENTRY_KNOTS, dt), _at_period(REST_TIME_CONSTANTS, dt)
        found = []
        every_one = cls(p.m_left, p.c_left, p.m_right, p.c_right, taus, knots, torque, rests)
        # the coast (and torque) columns come first, then the entry's, the creep's last: each a slice
        every, nonzero = every_one.columns_and_support_at(data.u_deg, data.time_s, data.torque_Nm, data.scored_rows)  # the rows the scores use
        split = every_one.n_terms - every_one.n_entry - every_one.n_rest
        ends = np.cumsum([0, split, every_one.n_entry, every_one.n_rest])
        parts = dict(zip(("coast", "entry", "creep at rest"), (range(int(a), int(b)) for a, b in pairwise(ends))))
        # one set of cross-products, over the rows where the load coasts, enters or creeps only
        scores = data.score_subsets(every, [[j for n in names for j in parts[n]] for names in VARIANTS], support=nonzero)
        for names, s in zip(VARIANTS, scores):
            exit_taus = taus if "coast" in names else ()
            effect = cls(
                p.m_left, p.c_left, p.m_right, p.c_right, exit_taus, knots if "entry" in names else (), torque and bool(exit_taus),
                rests if "creep at rest" in names else (),
            )
            what = " and ".join(names)
            found.append(Detection(effect, s, f"residual at the reversals follows the load's {what} (dead band {p.play:.4g} deg)"))
        plain = best_detection([d for d, n in zip(found, VARIANTS) if "creep at rest" not in n and d.score.significant()])
        creep = best_detection([d for d, n in zip(found, VARIANTS) if "creep at rest" in n and d.score.significant()])
        # the creep is claimed only where it beats the parts without it by the criterion's own margin
        best: Detection | None
        if creep is not None and (plain is None or creep.score.delta_bic - plain.score.delta_bic < BIC_THRESHOLD):
            best = creep
        else:
            best = plain or best_detection(found)
        if best is None or data.scored_rows is not None:
            return best
        # every sample's columns were formed: the chosen parts' are a slice of them (the same numbers as its terms)
        chosen = [j for n in VARIANTS[found.index(best)] for j in parts[n]]
        if len(chosen) == every.shape[1]:
            return replace(best, columns=every, nonzero_rows=nonzero)
        mine = np.ascontiguousarray(every[:, chosen])
        return replace(best, columns=mine, nonzero_rows=nonzero[np.any(mine[nonzero] != 0.0, axis=1)])


@njit(cache=True, nogil=True)
def _columns_pass(e, dx, t, v, qs, state, exit_taus, torque, knots, n_entry, rest_taus, rows, out, nonzero):  # pragma: no cover - compiled
    """:meth:`DeadBandMotion.terms`' columns in one pass over the samples, continuing ``state``
    (updated in place, see there), written for the samples ``rows`` (increasing) only, ``out[r]`` for
    ``rows[r]`` (``out`` zero on entry), and ``nonzero[r]`` set where ``out[r]`` holds a value other
    than zero. Where the output rests (``dx == 0``: the dead band, or a flank while the motor stands
    still) since it last moved at ``t_m`` with the velocity ``v_m`` and torque ``q_m``, in the direction
    ``d``: ``v_m`` times ``1 - exp(-(t - t_m) / tau)`` per ``exit_taus``, then (``torque``) ``q_m`` and
    the torque's change since; ``1 - exp(-(t - t_m) / tau)`` per ``rest_taus`` in the column of the
    direction ``d``. After the last entry (a flank engaged, ``e``) at ``t_e``, ``v_e`` times the hat
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
            for j in range(rest_taus.size):
                shape = -math.expm1(-(t[s] - t_m) / rest_taus[j])
                if d_m > 0:
                    out[r, k + 2 * j] = shape
                elif d_m < 0:
                    out[r, k + 2 * j + 1] = shape
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
