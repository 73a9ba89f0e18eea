"""What an encoder resolves: its quantum, its noise, the band within which a signal is still, and the
least dwell that shows a gap.

One statement of these figures for the kinematic observability (:class:`~online_backlash.load_aware.DwellTracker`,
which measures the dwells), the torque's noise (:func:`~online_backlash.load_aware.torque_noise_std`) and
the full-engagement rule of the flank lines (:class:`~.full_engagement.FullEngagement`, issue 27).

The noise is estimated robustly from the signal's second difference: a smooth motion sampled fast has
almost none, white noise of standard deviation ``s`` gives ``6 s^2`` of variance, and the median of its
absolute value ignores the steps at flank contacts (``s = median(|d2 x|) / (0.6745 sqrt 6)``).

Units: those of the signal (degrees for angles, N m for a torque).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidParameterError

__all__ = ["DWELL_FACTOR", "MEDIAN_ABS_D2", "quantum_and_noise", "robust_noise_std", "still_band"]

#: A dwell (motor travel with the load still) shows the gap when it exceeds this many output still bands.
DWELL_FACTOR = 4.0
#: ``median(|N(0, 6 sigma^2)|) / sigma``: the second difference of white noise has variance ``6 sigma^2``.
MEDIAN_ABS_D2 = 0.6744897501960817 * math.sqrt(6.0)


def robust_noise_std(x: np.ndarray) -> float:
    """Robust standard deviation of a sampled signal's white noise: the median absolute second
    difference scaled for white Gaussian noise; a quantised, noise-free signal (median 0) gives half its
    smallest non-zero step, a constant one 0. ``x``: a 1-D array of at least 3 finite values."""
    d2 = np.abs(np.diff(x, 2))
    sigma = float(np.median(d2)) / MEDIAN_ABS_D2
    if sigma > 0.0:
        return sigma
    steps = np.abs(np.diff(x))
    steps = steps[steps > 0]
    return float(steps.min()) / 2.0 if steps.size else 0.0


def quantum_and_noise(x_deg: np.ndarray) -> tuple[float, float]:
    """A sampled signal's quantum (the smallest gap between the values it takes: its encoder's step) and
    the robust standard deviation of its noise (from its second differences), degrees."""
    x = np.asarray(x_deg, dtype=float)
    if x.size < 3:
        raise InvalidParameterError(f"need at least 3 samples to tell noise from motion, got {x.size}")
    steps = np.diff(np.unique(x))
    quantum = float(steps.min()) if steps.size else 0.0
    return quantum, float(np.median(np.abs(np.diff(x, 2)))) / MEDIAN_ABS_D2


def still_band(x_deg: np.ndarray) -> float:
    """The band (deg) within which a signal counts as still: 4 robust noise standard deviations of
    its second difference (:func:`robust_noise_std`), at least 1.5 quantisation steps (its smallest
    non-zero step)."""
    quantum, _ = quantum_and_noise(x_deg)
    return max(4.0 * robust_noise_std(np.asarray(x_deg, dtype=float)), 1.5 * quantum, 1e-9)
