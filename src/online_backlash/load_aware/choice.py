"""The data decide the model: the torque path or the kinematic play, and why (issue 27).

A torque column is evidence, not an order. The torque path (:class:`~.flank_fit.TorqueBacklash`,
:class:`~.torque_rls.TorqueBacklashRLS`) reads the engaged flank from the torque; the kinematic
path (:class:`~online_backlash.estimators.VorosBacklash`, :class:`~online_backlash.estimators.BacklashRLS`)
from the motion alone. Both are fitted; :func:`choose_play_method` picks one and says why, and
:func:`online_backlash.physical.play_verdict` then decides what of its play may be reported.

**The test** (:func:`dwell_test`). Where the load rests while the motor crosses the gap (a *dwell*,
:class:`~.observability.DwellTracker`) no flank touches. A torque model of the flanks (two lines
``y = m u - a - s tau``) then predicts the motor travel of every dwell from the torques at its two
ends: from the old flank's line at the torque of the turning point to the new flank's line at the
torque where the load moved on, each flank's torque (the measured one less its engagement torque)
taken as it can be, pushing or zero: at the turning point the motor stops, and a friction torque
read with the motor's direction of motion flips before the old flank lets go. Where the prediction
misses the travel the motion shows by more than the dwell can be placed to (the two noise bands of
the ends, and the torque's noise through the compliances) and more than the scatter of the misses
allows -- the travel may fall short of it by the wind-up of the torque read where the load moves on,
which holds the contact's damping and inertia, not only the spring's -- the torque does not measure
what the flanks carry -- a torque path around the flanks (friction, a cable drive), a reading that drifts
while the flanks are open -- and the kinematic play is used. The torques at which the flanks engage
are estimated from the same dwells (:func:`~.observability.engagement_torques`) instead of assuming
zero: a sensor's zero offset and a friction torque between it and the flanks move them.

**The choice** (``auto``), in order:

1. no torque column (or it is not mapped): ``kinematic``;
2. the dwells contradict the torque model: ``kinematic``;
3. the torque never reversed (or one flank was never placed) although the load rested while the
   motor crossed the gap: the flanks opened without the torque seeing it: ``kinematic``;
4. the torque path's play is not physical (:func:`~online_backlash.physical.play_verdict`: below
   zero or unresolved) while the kinematic one is: ``kinematic``;
5. otherwise ``torque`` (with the number of dwells it was tested on, or that none could test it).

``--play-method torque`` or ``kinematic`` takes that path whatever the evidence (the reason says so).
Units: degrees (load side), N m.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..physical import Verdict, not_observable, play_verdict
from .flank_lines import FlankLine
from .observability import Dwell, DwellTracker

__all__ = [
    "NO_TORQUE", "PLAY_METHODS", "DwellTest", "PathEstimate", "PlayDecision", "choose_play_method", "dwell_test",
    "kinematic_path",
    "torque_dwell_test", "torque_path",
]  # fmt: skip

#: The choices of ``--play-method``.
PLAY_METHODS = ("auto", "torque", "kinematic")
#: Why there is no torque path, by default.
NO_TORQUE = "no torque column"
#: Why the kinematic play is not observable where the load never rested although the lines lie apart.
NEVER_RESTED = (
    "not observable: the load never held still while the motor crossed the gap (held against one flank, e.g. by a load "
    "torque); log the transmitted torque or run without the load"
)


@dataclass(frozen=True)
class PathEstimate:
    """One path's play (degrees) with its standard error, and whether its own evidence shows the play.

    ``observable`` False with ``why_not`` (one line): the torque never reversed, the load never rested
    although the lines lie apart. ``quantisation_deg``, ``sample_resolution_deg``: the encoders'
    resolution (:class:`~.observability.DwellTracker`); ``lower_bound_deg``: what the dwells show the play
    to be at least.
    """

    method: str
    play_deg: float
    std_deg: float
    observable: bool
    why_not: str | None = None
    quantisation_deg: float = 0.0
    sample_resolution_deg: float = 0.0
    lower_bound_deg: float | None = None

    def verdict(self) -> Verdict:
        """What of this path's play may be reported (:func:`~online_backlash.physical.play_verdict`)."""
        if not self.observable:
            return not_observable(self.why_not or "not observable", self.lower_bound_deg)
        return play_verdict(
            self.play_deg, self.std_deg, self.quantisation_deg, self.sample_resolution_deg, self.lower_bound_deg
        )


@dataclass(frozen=True)
class DwellTest:
    """The torque model against the dwells (module docstring): medians over ``n`` dwells, degrees.

    ``travel_deg``: the motor travel the motion shows; ``predicted_deg``: what the flank lines predict
    from the torques at the dwells' ends; ``miss_deg``: the median of their differences;
    ``tolerance_deg``: how far it may lie from zero.
    """

    n: int
    travel_deg: float
    predicted_deg: float
    miss_deg: float
    tolerance_deg: float
    contact_deg: float = 0.0

    @property
    def fits(self) -> bool:
        """The torque model predicts the dwells within their tolerance: the travel lies between the
        prediction less the wind-up of the contact torque (``contact_deg``) and the prediction."""
        return -self.tolerance_deg <= self.miss_deg <= self.tolerance_deg + self.contact_deg


def dwell_test(
    left: FlankLine | None,
    right: FlankLine | None,
    dwells: Sequence[Dwell],
    y_ref_deg: float,
    torque_sign: float,
    band_u_deg: float,
    band_y_deg: float,
    torque_noise_Nm: float,
    engagement_Nm: tuple[float, float] = (0.0, 0.0),
) -> DwellTest | None:
    """Test the flank lines (reference coordinates, torque times ``torque_sign``; the flanks engage at
    ``engagement_Nm``, left and right) on the ``dwells`` (module docstring); None where it cannot be
    tested (a flank without a line, no dwell with torque).

    Each dwell's travel is placed to within ``band_u_deg + band_y_deg`` (the ends are found by the noise
    bands of input and output) and each torque reading to ``2 torque_noise_Nm`` through the flank's
    compliance; the median miss may lie that far from zero plus two robust standard errors of the
    misses (their scatter, ``1.4826 MAD / sqrt(n)``).
    """
    usable = [d for d in dwells if math.isfinite(d.torque_turn_Nm) and math.isfinite(d.torque_end_Nm)]
    if left is None or right is None or not usable:
        return None
    travel, predicted, contact = [], [], []
    for d in usable:
        new, old = (right, left) if d.direction > 0 else (left, right)
        t_new, t_old = (engagement_Nm[1], engagement_Nm[0]) if d.direction > 0 else engagement_Nm
        # a flank only pushes: right flank torque >= 0, left <= 0, about its engagement torque
        carried_old = max(0.0, d.direction * (t_old - torque_sign * d.torque_turn_Nm))
        carried_new = max(0.0, d.direction * (torque_sign * d.torque_end_Nm - t_new))
        u_old = old.u_at(d.y_turn_deg - y_ref_deg, t_old - d.direction * carried_old)
        u_new = new.u_at(d.y_end_deg - y_ref_deg, t_new + d.direction * carried_new)
        travel.append(d.travel_deg)
        predicted.append((u_new - u_old) * d.direction)
        contact.append(abs(new.s) * carried_new)
    miss = np.asarray(predicted) - np.asarray(travel)
    median = float(np.median(miss))
    se = 1.4826 * float(np.median(np.abs(miss - median))) / math.sqrt(miss.size)
    reading = band_u_deg + band_y_deg + 2.0 * torque_noise_Nm * (abs(left.s) + abs(right.s))
    return DwellTest(
        miss.size,
        float(np.median(travel)),
        float(np.median(predicted)),
        median,
        reading + 2.0 * se,
        float(np.median(contact)),
    )


@dataclass(frozen=True)
class PlayDecision:
    """The path taken (``"torque"`` or ``"kinematic"``), why (one line), and what of its play is reported."""

    method: str
    reason: str
    verdict: Verdict

    def keys(self) -> dict[str, Any]:
        """The keys of ``estimate --json`` (and the columns of a row) for the path and its play's verdict."""
        v = self.verdict
        return {
            "backlash_deg": v.value,
            "backlash_std_deg": v.std,
            "play_observable": v.observable,
            "reason": v.reason,
            "backlash_lower_bound_deg": v.lower_bound,
            "backlash_upper_bound_deg": v.upper_bound,
            "play_method": self.method,
            "play_method_reason": self.reason,
        }


def choose_play_method(
    requested: str,
    torque: PathEstimate | None,
    kinematic: PathEstimate | None,
    test: DwellTest | None,
    no_torque_why: str = "no torque column",
) -> PlayDecision:
    """The path whose play is reported (module docstring), from the two paths' estimates (None: not
    fitted) and the dwell test of the torque path (None: nothing to test it on). ``no_torque_why``
    says why there is no torque path (e.g. a torque-like column that was not mapped)."""
    check_play_method(requested)
    if torque is None or requested == "kinematic":
        if kinematic is None:
            raise InvalidParameterError("the kinematic play was not estimated")
        why = "asked for (--play-method kinematic)" if requested == "kinematic" else no_torque_why
        return PlayDecision("kinematic", why, kinematic.verdict())
    if requested == "torque" or kinematic is None:
        return PlayDecision(
            "torque",
            "asked for (--play-method torque)" if requested == "torque" else "no kinematic play",
            torque.verdict(),
        )
    travel = ""
    if test is not None:
        travel = f"the torque model predicts {test.predicted_deg:.3g} deg of motor travel, "
        travel += f"the motion shows {test.travel_deg:.3g}"
    if test is not None and not test.fits:
        return PlayDecision(
            "kinematic",
            f"the torque does not fit the motion: where the load rested while the motor crossed the gap, {travel} deg "
            f"(median of {test.n} dwells, tolerance {test.tolerance_deg:.2g} deg): the torque is not what the flanks "
            "carry",
            kinematic.verdict(),
        )
    if not torque.observable and kinematic.observable and kinematic.lower_bound_deg is not None:
        return PlayDecision(
            "kinematic",
            f"{torque.why_not or 'the torque path shows no play'}; yet the load rested while the motor crossed the gap "
            f"(at least {kinematic.lower_bound_deg:.3g} deg): the flanks opened without the torque seeing it",
            kinematic.verdict(),
        )
    torque_verdict, kinematic_verdict = torque.verdict(), kinematic.verdict()
    if torque_verdict.value is None and kinematic_verdict.value is not None:
        return PlayDecision(
            "kinematic", f"the torque path's play is not physical ({torque_verdict.reason})", kinematic_verdict
        )
    if test is None:
        return PlayDecision(
            "torque",
            "no dwell to test the torque on (the load never rested while the motor crossed the gap): the torque "
            "decides",
            torque_verdict,
        )
    return PlayDecision("torque", f"the torque fits the motion ({test.n} dwells: {travel})", torque_verdict)


def check_play_method(requested: object) -> str:
    """``requested`` if it is one of :data:`PLAY_METHODS`, else InvalidParameterError."""
    if requested not in PLAY_METHODS:
        raise InvalidParameterError(f"play_method must be one of {', '.join(PLAY_METHODS)}, got {requested!r}")
    return str(requested)


def kinematic_path(
    play_deg: float, std_deg: float, tracker: DwellTracker, not_started: str | None = None
) -> PathEstimate:
    """The kinematic path's play with its evidence: observable where the load rested while the motor
    crossed the gap (:attr:`~.observability.DwellTracker.observable_`), or where the play is smaller than
    the least dwell the encoders can show (``|play| + 2 std`` below the dwell threshold: a play that
    small needs no dwell to be believed, a gearbox without play shows none). ``not_started``: why the
    estimator has no play yet."""
    finite = math.isfinite(play_deg) and math.isfinite(std_deg)
    small = finite and abs(play_deg) + 2.0 * std_deg < tracker.threshold_deg
    observable = finite and (tracker.observable_ or small)
    why = not_started if not_started is not None and not math.isfinite(play_deg) else NEVER_RESTED
    return PathEstimate(
        "kinematic", play_deg, std_deg, observable, None if observable else why, tracker.quantisation_deg,
        tracker.sample_resolution_deg, tracker.lower_bound_deg,
    )  # fmt: skip


def torque_path(est: Any, tracker: DwellTracker) -> PathEstimate:
    """The torque path's play with its evidence (a fitted :class:`~.flank_fit.TorqueBacklash` or a started
    :class:`~.torque_rls.TorqueBacklashRLS`): observable where the torque reversed and both flanks were placed."""
    observable = bool(est.play_observable_)
    reversals = int(est.n_reversals_ if hasattr(est, "n_reversals_") else est.torque_reversals_)
    if reversals == 0:
        why = "not observable: the transmitted torque never reversed (a preloaded drive: the output stays on one flank)"
    else:
        why = "not observable: one flank carried torque too briefly to place it"
    resolution = (tracker.quantisation_deg, tracker.sample_resolution_deg, tracker.lower_bound_deg)
    play, std = float(est.backlash_), float(est.backlash_std_)
    return PathEstimate("torque", play, std, observable, None if observable else why, *resolution)


def torque_dwell_test(est: Any, tracker: DwellTracker) -> DwellTest | None:
    """:func:`dwell_test` of a torque estimator's lines as fitted (wind-up not folded) on the tracker's dwells."""
    band_u, band_y = tracker.bands_deg
    if band_u is None or band_y is None:
        return None
    left, right = est._raw_pair()
    noise, engagement = est.torque_noise_std_Nm_, est.engagement_torques_Nm_
    return dwell_test(left, right, tracker.dwells_, est.y_ref_, est.torque_sign_, band_u, band_y, noise, engagement)
