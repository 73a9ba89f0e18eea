"""Causal, streaming-consistent bookkeeping shared by the effect terms.

An effect whose columns at sample ``t`` need the ``w`` samples before it keeps those samples
between calls of ``terms``. Before the first sample the record is taken to be at rest at its
first value (the first sample repeated), so one call on a whole record and many calls on its
pieces give the same rows (the :class:`~online_backlash.effect_terms.EffectTerms` contract).
Units: degrees, seconds, newton metres.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidParameterError


class CausalWindow:
    """Keep the last ``history`` samples of ``u`` (deg), ``time`` (s) and ``torque`` (N m)."""

    def __init__(self, history: int) -> None:
        self.history = int(history)
        self.reset()

    def reset(self) -> None:
        """Forget the past (start of a record or after a gap)."""
        self._past: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def extend(
        self, u_deg: np.ndarray, time_s: np.ndarray, torque_Nm: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Prepend the kept past to the new samples; return ``(u, time, torque, n_past)``.

        Call :meth:`keep` afterwards with the same extended arrays.
        """
        u, t, q = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (u_deg, time_s, torque_Nm))
        if u.ndim != 1 or u.shape != t.shape or u.shape != q.shape:
            raise InvalidParameterError(
                f"u_deg, time_s and torque_Nm must be 1-D and equally long, got {u.shape}, {t.shape}, {q.shape}"
            )
        if u.size == 0:
            return u, t, q, 0
        past = self._past
        if past is None:  # at rest at the first sample before the record starts
            past = (np.full(self.history, u[0]), np.full(self.history, t[0]), np.full(self.history, q[0]))
        return (np.concatenate((past[0], u)), np.concatenate((past[1], t)), np.concatenate((past[2], q)), self.history)

    def keep(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> None:
        """Store the last ``history`` samples of the extended arrays for the next call."""
        if u.size:
            h = self.history
            self._past = (u[u.size - h :].copy(), t[t.size - h :].copy(), q[q.size - h :].copy())


def _difference_from_rest(a: np.ndarray, lag: int) -> np.ndarray:
    """``a[i] - a[max(i - lag, 0)]``: :func:`lagged_difference` with the record at rest at ``a[0]`` before it starts."""
    out = lagged_difference(a, lag)
    head = min(lag, a.size)
    out[:head] = a[:head] - a[0] if a.size else out[:head]
    return out


def lagged_difference(a: np.ndarray, lag: int) -> np.ndarray:
    """``a[i] - a[i - lag]`` for ``i >= lag`` (the first ``lag`` entries are 0)."""
    out = np.zeros_like(a)
    out[lag:] = a[lag:] - a[:-lag]
    return out


def sample_period_s(time_s: np.ndarray) -> float:
    """The record's sample period, s: the median of its time steps that advance (a logger that writes
    a sample twice repeats its time stamp: a step of 0 is no period; with half the steps 0 the plain
    median was 0, and the initial state's time constants with it); 1.0 for a record without such a step.

    >>> sample_period_s(np.array([0.0, 0.0, 0.5, 0.5, 1.0, 1.0]))
    0.5
    """
    steps = np.diff(np.asarray(time_s, dtype=float))
    steps = steps[steps > 0]
    return float(np.median(steps)) if steps.size else 1.0


def velocity_deg_s(u: np.ndarray, t: np.ndarray, window: int) -> np.ndarray:
    """Causal velocity ``(u[i] - u[i-w]) / (t[i] - t[i-w])``, deg/s; 0 where no time has passed.

    Before the first sample the record is at rest at its first value (as in :class:`CausalWindow`),
    so the first ``w`` samples get ``(u[i] - u[0]) / (t[i] - t[0])``: a record that starts in
    motion has its speed from its second sample on, not 0 for ``w`` samples.
    """
    du = _difference_from_rest(u, window)
    dt = _difference_from_rest(t, window)
    return np.divide(du, dt, out=np.zeros_like(du), where=dt > 0)


def acceleration_deg_s2(u: np.ndarray, t: np.ndarray, window: int) -> np.ndarray:
    """Causal acceleration from two velocities ``window`` samples apart, deg/s^2."""
    v = velocity_deg_s(u, t, window)
    dv = lagged_difference(v, window)
    dt = lagged_difference(t, window)
    return np.divide(dv, dt, out=np.zeros_like(dv), where=dt > 0)


def motion_direction(u: np.ndarray, window: int, deadzone_deg: float, start: float) -> np.ndarray:
    """+1 / -1: the sign of ``u(t) - u(t - window)``, held while the change is within ``deadzone_deg``.

    ``start`` is the direction before the first sample (0 when unknown).
    """
    du = lagged_difference(u, window)
    raw = np.where(du > deadzone_deg, 1.0, np.where(du < -deadzone_deg, -1.0, 0.0))
    idx = np.where(raw != 0, np.arange(raw.size), -1)
    idx = np.maximum.accumulate(idx)
    return np.where(idx >= 0, raw[np.maximum(idx, 0)], start)
