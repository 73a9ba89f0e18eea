"""Residuals of a fitted backlash model, their profiles and spectra, and the noise floor.

Two residuals (degrees, load side):

* the *simulation* residual ``y - x_hat``, with ``x_hat`` the fitted model of eq. (1)-(3)
  run freely on the referred motor angle ``u``. Everything the model lacks shows in it.
* the *one-step* residual of eq. (14), ``e(t) = y(t) - y(t-1)[1 - f1][1 - f2] - phi(t)^T theta``,
  with the switching functions of eq. (5)-(6) evaluated on the measured ``y(t-1)``: what the
  paper's equation-error stage (and the recursive estimator) minimises. It is white where the
  model is right and shows where along the record the one-step prediction fails.

The noise floor is the residual a perfect model would leave: the load encoder's quantisation
``q / sqrt(12)``, or the measurement noise seen in the data, whichever is larger. The noise is
read from the second difference of the load angle: for white noise of standard deviation ``s``
it has standard deviation ``sqrt(6) s``, while smooth motion adds almost nothing at 1 kHz; the
few large values where a flank engages are dropped (beyond six robust standard deviations).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import BacklashParams, switching_functions
from ._initial_state import simulate_with_coast

#: 1.4826 * MAD is the standard deviation of a Gaussian
_MAD_TO_STD = 1.4826


@dataclass(frozen=True)
class NoiseFloor:
    """The load encoder's step and noise, degrees.

    Attributes
    ----------
    step_deg : float
        Smallest change the load encoder reports (its quantisation step), deg.
    noise_deg : float
        Standard deviation of the sample-to-sample noise of the load angle, deg.
    floor_deg : float
        ``max(step_deg / sqrt(12), noise_deg)``: the RMS residual of a perfect model, deg.
    """

    step_deg: float
    noise_deg: float
    floor_deg: float


def noise_floor(load_deg: np.ndarray) -> NoiseFloor:
    """Estimate the noise floor of a load-angle record (degrees)."""
    y = np.asarray(load_deg, dtype=float)
    steps = np.abs(np.diff(y))
    steps = steps[steps > 1e-9 * max(1.0, float(np.max(np.abs(y))))]
    step = float(steps.min()) if steps.size else 0.0
    d2 = np.diff(y, 2)
    noise = 0.0
    if d2.size:
        d2 = d2 - np.median(d2)
        spread = _MAD_TO_STD * float(np.median(np.abs(d2)))
        # the MAD is coarse on quantised data: use it only to drop the kinks at flank changes
        kept = d2[np.abs(d2) <= max(6.0 * spread, 1.5 * step)]
        noise = float(np.sqrt(np.mean(kept**2)) / np.sqrt(6.0)) if kept.size else 0.0
    return NoiseFloor(step, noise, max(step / np.sqrt(12.0), noise))


def simulation_residual(
    params: BacklashParams, u_deg: np.ndarray, y_deg: np.ndarray, start_path_deg: np.ndarray | None = None
) -> np.ndarray:
    """``y - x_hat``: the measured load angle minus the model of eq. (1)-(3) run freely on ``u``, deg.

    The model starts from the first measured output at rest (``x(-1) = y[0]``), or, with
    ``start_path_deg`` (the load's estimated path while it coasts in the dead band at the
    record's start, :attr:`._initial_state.InitialState.path_deg`), follows that path until a
    flank first catches the load and eq. (1)-(3) from there. ``u_deg`` and ``y_deg`` are in the
    frame the parameters were fitted in (for ``VorosBacklash(origin="first")``, subtract
    ``u_ref_`` and ``y_ref_`` first).
    """
    y = np.asarray(y_deg, dtype=float)
    return y - simulate_with_coast(
        np.asarray(u_deg, dtype=float), params, np.empty(0) if start_path_deg is None else start_path_deg, float(y[0])
    )


def one_step_residual(params: BacklashParams, u_deg: np.ndarray, y_deg: np.ndarray) -> np.ndarray:
    """The equation error of eq. (14) with the fitted parameters, deg; 0 at the first sample.

    ``u_deg`` and ``y_deg`` are in the frame the parameters were fitted in (for
    ``VorosBacklash(origin="first")``, subtract ``u_ref_`` and ``y_ref_`` first).
    """
    u = np.asarray(u_deg, dtype=float)
    y = np.asarray(y_deg, dtype=float)
    e = np.zeros_like(y)
    f1, f2 = switching_functions(u[1:], y[:-1], params)  # eq. (5)-(6) on the measured y(t-1)
    phi = np.column_stack((u[1:] * f1, f1, u[1:] * f2, -f2))  # eq. (8)
    e[1:] = y[1:] - y[:-1] * (1 - f1) * (1 - f2) - phi @ params.theta  # eq. (14)
    return e


@dataclass(frozen=True)
class Profile:
    """A residual binned against one variable: bin centres, mean and standard deviation per bin."""

    variable: str
    unit: str
    centers: np.ndarray
    mean_deg: np.ndarray
    std_deg: np.ndarray
    count: np.ndarray


def profile(residual: np.ndarray, variable: np.ndarray, name: str, unit: str, bins: int = 40) -> Profile:
    """Mean and spread of ``residual`` in ``bins`` equal-width bins of ``variable``."""
    v = np.asarray(variable, dtype=float)
    edges = np.linspace(v.min(), v.max(), bins + 1) if v.max() > v.min() else np.array([v.min() - 0.5, v.min() + 0.5])
    idx = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, edges.size - 2)
    count = np.bincount(idx, minlength=edges.size - 1)
    s1 = np.bincount(idx, residual, minlength=edges.size - 1)
    s2 = np.bincount(idx, residual**2, minlength=edges.size - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, s1 / np.maximum(count, 1), np.nan)
        std = np.where(count > 1, np.sqrt(np.maximum(s2 / np.maximum(count, 1) - mean**2, 0.0)), np.nan)
    return Profile(name, unit, 0.5 * (edges[1:] + edges[:-1]), mean, std, count)


def time_spectrum(residual: np.ndarray, sample_period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Welch amplitude spectrum of the residual against time: ``(frequency_Hz, amplitude_deg)``.

    The amplitude is ``sqrt(PSD * bin width)``, so a sine of amplitude ``A`` shows as a peak
    of about ``A / sqrt(2)``.
    """
    from scipy.signal import welch  # imported here: scipy.signal takes seconds to import, and only plots need it

    nper = int(min(residual.size, 2**14))
    f, psd = welch(residual - residual.mean(), fs=1.0 / sample_period_s, nperseg=nper)
    return f, np.sqrt(psd * (f[1] - f[0]))


def order_spectrum(residual: np.ndarray, angle_deg: np.ndarray, bins: int = 720) -> tuple[np.ndarray, np.ndarray]:
    """Residual against shaft angle: ``(order, amplitude_deg)``, order in cycles per revolution.

    The residual is averaged in ``bins`` bins of the angle modulo 360 deg (empty bins count as 0)
    and the Fourier amplitudes of that one-revolution profile are returned for orders
    ``1 .. bins // 2``.
    """
    idx = (np.mod(angle_deg, 360.0) / 360.0 * bins).astype(int) % bins
    count = np.bincount(idx, minlength=bins)
    mean = np.bincount(idx, residual - residual.mean(), minlength=bins) / np.maximum(count, 1)
    amp = np.abs(np.fft.rfft(mean)) * 2.0 / bins
    return np.arange(1, amp.size), amp[1:]
