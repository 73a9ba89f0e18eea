"""Causal, streaming-consistent bookkeeping shared by the effect terms.

An effect whose columns at sample ``t`` need the ``w`` samples before it keeps those samples
between calls of ``terms``. Before the first sample the record is taken to be at rest at its
first value (the first sample repeated), so one call on a whole record and many calls on its
pieces give the same rows (the :class:`~online_backlash.effect_terms.EffectTerms` contract); the
window says where the record starts among those rows (:attr:`CausalWindow.record_start`), for a
derivative that must not read the rest before it (:func:`savgol_derivative`).
Units: degrees, seconds, newton metres.
"""

from __future__ import annotations

from functools import lru_cache

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
        self._seen = 0  # samples seen since the reset, up to ``history + 1``
        #: where the record's first sample is in the arrays :meth:`extend` last returned (the rows before
        #: it are the rest before the record: its first sample repeated); None: before their first row
        self.record_start: int | None = self.history

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
        self.record_start = self.history - self._seen if self._seen <= self.history else None
        if past is None:  # at rest at the first sample before the record starts
            past = (np.full(self.history, u[0]), np.full(self.history, t[0]), np.full(self.history, q[0]))
        return (np.concatenate((past[0], u)), np.concatenate((past[1], t)), np.concatenate((past[2], q)), self.history)

    def keep(self, u: np.ndarray, t: np.ndarray, q: np.ndarray) -> None:
        """Store the last ``history`` samples of the extended arrays for the next call."""
        if u.size:
            h = self.history
            self._past = (u[u.size - h :].copy(), t[t.size - h :].copy(), q[q.size - h :].copy())
            self._seen = min(self._seen + u.size - h, h + 1)


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


#: polynomial order of :func:`savgol_derivative`: a quadratic's second derivative is one number over the
#: window, that of its middle (a lag of half the window); a quartic's varies along it, so its value at the
#: newest sample has no lag wherever the motion is a quartic over the window
SAVGOL_ORDER = 4
#: at a record's start, before a full window: a quadratic through at least this many samples
START_SAMPLES = 6


@lru_cache(maxsize=1024)
def _savgol_weights(window: int, order: int, deriv: int) -> np.ndarray:
    """The Savitzky-Golay weights of the ``deriv``-th derivative at the newest of ``window`` samples, per
    sample period^deriv."""
    from scipy.signal import (
        savgol_coeffs,
    )  # 0.3 s to import scipy.signal: paid by a record without a torque column only

    return savgol_coeffs(window, order, deriv=deriv, pos=window - 1, use="dot")


def savgol_derivative(u: np.ndarray, t: np.ndarray, window: int, deriv: int, start: int | None = 0) -> np.ndarray:
    """Causal Savitzky-Golay derivative of ``u`` (deg): deg/s (``deriv=1``) or deg/s^2 (``deriv=2``).

    At every sample, the ``deriv``-th derivative, at that sample, of the least-squares polynomial of
    order :data:`SAVGOL_ORDER` through it and the ``window - 1`` samples before it (A. Savitzky,
    M. J. E. Golay, *Anal. Chem.* 36 (1964) 1627-1639; the weights are
    ``scipy.signal.savgol_coeffs(..., pos=window - 1)``, the fit evaluated at the window's newest
    sample, not its middle: causal). The sample period is the window's mean, ``(t[i] - t[i-w+1]) / (w - 1)``.

    ``start`` is where the record's first sample is in ``u`` (None: before ``u[0]``). Before it there is
    nothing (0): a record is not at rest before its first sample as far as its acceleration goes. Over
    the record's first ``window - 1`` samples the window holds what there is: a quadratic through the
    samples since the start (at least :data:`START_SAMPLES`; a quartic's value at the end of a short
    window is mostly the encoder's steps). Rows whose window reaches before ``u[0]`` when the record
    started earlier (the past a streaming caller keeps) and rows over which no time passes are 0.
    """
    out = np.zeros_like(u)
    if u.size >= window:
        k = _savgol_weights(window, SAVGOL_ORDER, deriv)
        # the weights sum to zero up to rounding: the difference from the newest sample makes the result
        # independent of the angle's zero (a shaft that has turned 1e5 deg)
        d = np.correlate(u, k, mode="valid") - u[window - 1 :] * k.sum()
        step = (t[window - 1 :] - t[: t.size - window + 1]) / (window - 1)
        np.divide(d, step**deriv, out=out[window - 1 :], where=step > 0)
    first = 0 if start is None else start
    out[: first + window - 1] = 0.0
    if start is not None:
        for i in range(start + START_SAMPLES - 1, min(start + window - 1, u.size)):
            n = i - start + 1
            step = (t[i] - t[start]) / (n - 1)
            if step > 0:
                w = u[start : i + 1]
                out[i] = (w - w[-1]) @ _savgol_weights(n, 2, deriv) / step**deriv
    return out


def motion_direction(u: np.ndarray, window: int, deadzone_deg: float, start: float) -> np.ndarray:
    """+1 / -1: the sign of ``u(t) - u(t - window)``, held while the change is within ``deadzone_deg``.

    ``start`` is the direction before the first sample (0 when unknown).
    """
    du = lagged_difference(u, window)
    raw = np.where(du > deadzone_deg, 1.0, np.where(du < -deadzone_deg, -1.0, 0.0))
    idx = np.where(raw != 0, np.arange(raw.size), -1)
    idx = np.maximum.accumulate(idx)
    return np.where(idx >= 0, raw[np.maximum(idx, 0)], start)
