"""What may be reported as a play, a lost motion or a stiffness: one rule for every output (issue 27).

A monitoring system stores the number it is given, so a figure that is not physical must never
leave the library as one. :func:`play_verdict` decides, for the batch and the recursive estimate
(``estimate``), every row ``track`` stores and the rows a history store migrates; :func:`figure_verdict`
applies the same rule to lost motion and stiffness. The rule, for an estimate ``x`` with standard
error ``s`` (both degrees):

1. **Resolved**: ``x > 2 u`` with ``u = sqrt(s^2 + q^2)``, ``q`` the standard uncertainty the encoders'
   quantisation leaves in any average (:attr:`~online_backlash.load_aware.DwellTracker.quantisation_deg`;
   noise averages away over a log, quantisation without dither does not): ``x`` is reported with the
   standard error ``u``. So a play whose standard error exceeds half its value is never reported as
   measured, nor is one within two quantisation uncertainties of zero.
2. **Not resolved** (``x <= 2 u``: within two uncertainties of zero, or below zero):

   a. **measured zero**, where ``s`` is no larger than the resolution of one pair of samples ``r``
      (quantisation and noise of both encoders,
      :attr:`~online_backlash.load_aware.DwellTracker.sample_resolution_deg`): the log measured the
      play as finely as its encoders allow and found none. Reported as ``0`` with ``u`` and an upper
      bound ``max(x, 0) + 2 u``: a gearbox without measurable play (a harmonic drive, a preloaded
      planetary) is a measurement, not an error and not "unobservable".
   b. **not observable**, where ``s > r``: the data do not place the play (its scatter or the
      model's misfit is larger than what the encoders resolve): null, with the reason (a negative
      estimate is named as not physical) and the bounds the data do support: a lower bound from the
      motion (a dwell) where there is one, the upper bound ``max(x, 0) + 2 s``.

Without a resolution (``q = r = 0``: lost motion, stiffness), rule 2a never applies: a figure
below zero or whose standard error exceeds half its value is null.

Imports nothing of this package, so the history store can apply it too. Units: degrees (or the
figure's own unit for :func:`figure_verdict`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Verdict", "figure_verdict", "not_observable", "play_verdict"]


@dataclass(frozen=True)
class Verdict:
    """What is reported of one estimate.

    Attributes
    ----------
    value : float or None
        The reported figure (None: not observable); ``0.0`` for a measured zero.
    std : float or None
        Its standard error, finite (None where the value is None).
    observable : bool
        The data show the figure (a measured zero included).
    reason : str or None
        Why the figure is null, or that it is a measured zero; None for a resolved figure.
    lower_bound, upper_bound : float or None
        What the data support where the figure is not resolved (None: no bound).
    """

    value: float | None
    std: float | None
    observable: bool
    reason: str | None = None
    lower_bound: float | None = None
    upper_bound: float | None = None


def _finite(value: float | None) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def not_observable(reason: str, lower_bound: float | None = None, upper_bound: float | None = None) -> Verdict:
    """The verdict of an estimate the data do not show (a torque that never reversed, a load that never rested)."""
    return Verdict(None, None, False, reason, _finite(lower_bound), _finite(upper_bound))


def play_verdict(
    play_deg: float,
    std_deg: float,
    quantisation_deg: float = 0.0,
    sample_resolution_deg: float = 0.0,
    lower_bound_deg: float | None = None,
    unit: str = "deg",
    what: str = "play",
) -> Verdict:
    """The module docstring's rule for a play ``play_deg`` with standard error ``std_deg`` (degrees).

    ``quantisation_deg`` (``q``) and ``sample_resolution_deg`` (``r``): the encoders' resolution
    (NaN or 0: unknown, rule 2a then never applies); ``lower_bound_deg``: what the motion shows the
    play to be at least (a dwell), kept with a figure that is not observable.
    """
    x, s = float(play_deg), float(std_deg)
    q = quantisation_deg if math.isfinite(quantisation_deg) else 0.0
    r = sample_resolution_deg if math.isfinite(sample_resolution_deg) else 0.0
    if not math.isfinite(x):
        return not_observable(f"no {what} was estimated", lower_bound_deg)
    if not (math.isfinite(s) and s >= 0):
        return not_observable(f"the {what} ({x:.4g} {unit}) has no finite standard error", lower_bound_deg)
    u = math.hypot(s, q)
    if x > 2.0 * u:
        return Verdict(x, u, True)
    upper = max(x, 0.0) + 2.0 * u
    if r > 0 and s <= r:
        estimate = f"estimate {x:.3g} +- {u:.2g} {unit}, encoder resolution {r:.2g} {unit}"
        why = f"zero within its uncertainty: at most {upper:.3g} {unit} ({estimate})"
        return Verdict(0.0, u, True, why, 0.0, upper)
    if x < 0:
        why = f"a negative {what} ({x:.4g} +- {s:.3g} {unit}) is not physical"
    else:
        why = f"not resolved: {x:.4g} +- {s:.3g} {unit}, a standard error more than half the value"
    return not_observable(why, lower_bound_deg, max(x, 0.0) + 2.0 * s)


def figure_verdict(value: float | None, std: float | None, unit: str, what: str) -> Verdict:
    """:func:`play_verdict` without a resolution, for a lost motion or a stiffness (``unit`` and ``what``
    name it in the reason); a figure without a standard error (None or NaN) is judged by its sign alone."""
    if value is None or not math.isfinite(value):
        return not_observable(f"no {what} was estimated")
    if std is None or not math.isfinite(std):
        return (
            Verdict(float(value), None, True)
            if value > 0
            else not_observable(f"a {what} of {value:.4g} {unit} is not physical")
        )
    return play_verdict(value, std, unit=unit, what=what)
