"""Which flank carries the load, from the sign of the transmitted torque.

Torque flows through the gear only while a flank touches: on the right flank the transmitted
torque is positive, on the left flank negative, and inside the dead band it is zero (up to the
sensor's noise). This replaces the paper's unmeasurable switching functions ``f1`` (left) and
``f2`` (right), eq. (5)-(6) of Vörös (2010), by measured ones::

    f2(t) = 1  if tau(t) >  deadband      (right flank engaged, +1)
    f1(t) = 1  if tau(t) < -deadband      (left flank engaged,  -1)
    neither    otherwise                  (in the gap, or too close to zero to tell: 0)

The torque that means "no flank touches" need not be zero (issue 27): a sensor reads a zero offset,
and a friction torque between it and the flanks is read while the motor crosses the gap. Given the
torques at which the left and the right flank engage (``T_L``, ``T_R``, from the dwells of the
motion, :func:`~.observability.engagement_torques`), the rule reads ``tau > max(T_L, T_R) + deadband``
(right) and ``tau < min(T_L, T_R) - deadband`` (left): between the two engagement torques the
torque cannot tell the flanks apart.

The dead band comes from the torque noise, estimated robustly from the torque's high-passed
part (its second difference, whose median absolute value is insensitive to the steps at flank
contacts): ``sigma = median(|d2 tau|) / (0.6745 * sqrt(6))`` for white noise, and
``deadband = n_sigma * sigma``.

Units: torque in N m.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidParameterError
from ..estimators.resolution import robust_noise_std

__all__ = [
    "DEADBAND_SIGMAS",
    "count_torque_reversals",
    "engaged_flank",
    "torque_deadband",
    "torque_noise_std",
    "torque_orientation",
]

#: Dead band in noise standard deviations (a Gaussian sample exceeds 4 sigma once in 16 000).
DEADBAND_SIGMAS = 4.0


def _torque_array(torque_Nm: np.ndarray) -> np.ndarray:
    q = np.asarray(torque_Nm, dtype=float)
    if q.ndim != 1:
        raise InvalidParameterError(f"torque must be a 1-D array, got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise InvalidParameterError(
            f"torque has non-finite values, first at index {int(np.flatnonzero(~np.isfinite(q))[0])}"
        )
    return q


def torque_noise_std(torque_Nm: np.ndarray) -> float:
    """Robust standard deviation of the torque sensor's noise, N m
    (:func:`~online_backlash.estimators.resolution.robust_noise_std`).

    The median absolute second difference, scaled for white Gaussian noise. A quantised, noise-free
    torque (median 0) gives half its smallest non-zero step (the quantisation); a constant torque 0.
    """
    q = _torque_array(torque_Nm)
    if q.size < 3:
        raise InvalidParameterError(f"need at least 3 torque samples to estimate its noise, got {q.size}")
    return robust_noise_std(q)


def torque_deadband(torque_Nm: np.ndarray, n_sigma: float = DEADBAND_SIGMAS) -> float:
    """The dead band around zero torque inside which no flank is said to be engaged, N m:
    ``n_sigma`` robust noise standard deviations (:func:`torque_noise_std`)."""
    if not n_sigma > 0:
        raise InvalidParameterError(f"n_sigma must be > 0, got {n_sigma!r}")
    return n_sigma * torque_noise_std(torque_Nm)


def _torque_and_deadband(torque_Nm: np.ndarray, deadband_Nm: float) -> np.ndarray:
    """The torque as a checked array, after checking the dead band too."""
    q = _torque_array(torque_Nm)
    if not (math.isfinite(deadband_Nm) and deadband_Nm >= 0):
        raise InvalidParameterError(f"deadband_Nm must be finite and >= 0, got {deadband_Nm!r}")
    return q


def engaged_flank(
    torque_Nm: np.ndarray, deadband_Nm: float, engagement_Nm: tuple[float, float] = (0.0, 0.0)
) -> np.ndarray:
    """The engaged flank at each sample: +1 right (torque > deadband), -1 left (torque < -deadband),
    0 neither (int8 array). The measured switching functions: ``f2 = (out == 1)``, ``f1 = (out == -1)``
    (eq. 5-6). ``engagement_Nm``: the torques ``(T_L, T_R)`` at which the left and right flank engage
    (module docstring); the dead band is then taken about them."""
    q = _torque_and_deadband(torque_Nm, deadband_Nm)
    out = np.zeros(q.size, dtype=np.int8)
    out[q > max(engagement_Nm) + deadband_Nm] = 1
    out[q < min(engagement_Nm) - deadband_Nm] = -1
    return out


def either_flank_engaged(torque_Nm: np.ndarray, deadband_Nm: float) -> np.ndarray:
    """True where a flank is engaged (``|torque| > deadband``): ``engaged_flank(...) != 0`` as one boolean
    array (``f1 + f2`` of eq. 5-6 measured), without the flank's sign."""
    return np.abs(_torque_and_deadband(torque_Nm, deadband_Nm)) > deadband_Nm


def count_torque_reversals(flank: np.ndarray) -> int:
    """How many times the engaged flank changes (right to left or back) through the dead band;
    samples in the dead band (0) are skipped, so noise around zero is not counted."""
    f = np.asarray(flank)
    f = f[f != 0]
    return int(np.count_nonzero(f[1:] != f[:-1])) if f.size > 1 else 0


def torque_orientation(u_deg: np.ndarray, y_deg: np.ndarray, torque_Nm: np.ndarray) -> float:
    """The sign (+1.0 or -1.0) that makes the torque column follow this package's convention.

    On either flank the torsion angle ``u - y`` grows with the transmitted torque (the right
    flank, ``u - y = cR + tau / k``, lies above the left, ``u - y = -cL + tau / k``), so a torque
    measured with this package's sign correlates positively with ``u - y``. A sensor mounted the
    other way round (e.g. on the motor side) correlates negatively and is flipped. ``u - y`` is
    taken about a straight-line fit of ``y`` on ``u``, so an imperfect ratio does not enter.
    """
    u = np.asarray(u_deg, dtype=float)
    y = np.asarray(y_deg, dtype=float)
    q = _torque_array(torque_Nm)
    if u.size < 3 or u.shape != q.shape or y.shape != q.shape:
        raise InvalidParameterError(
            f"need equal-length u, y and torque of at least 3 samples, got {u.size}, {y.size}, {q.size}"
        )
    design = np.column_stack((np.ones_like(u), u - u.mean()))
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    torsion = design @ coef - y  # u - y about the fitted line
    return -1.0 if float(np.dot(torsion - torsion.mean(), q - q.mean())) < 0.0 else 1.0
