"""A gearbox's current figures, as a plant system reads them: the gauges of ``opcua`` and ``serve``'s ``/metrics``.

:func:`gearbox_gauges` takes them from the gearbox's :class:`~online_backlash.history.report.WearReport`,
the same report ``history --json`` and ``history --check`` print, so every figure is the history's to
the last digit: the play is the report's ``play_arcmin`` (the latest observable estimate, :mod:`.alarms`),
its standard error that estimate's ``backlash_std_arcmin``, the state and levels those of ``history
--check``, the hours to the limit the report's ``forecast_hours_to_limit``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..output_columns import arcmin
from .report import WearReport

#: The plugin exit code of each state (``history --check``): a number for systems that want one.
STATE_CODES = {"ok": 0, "warning": 1, "alarm": 2, "unknown": 3}


@dataclass(frozen=True)
class GearboxGauges:
    """What a control room or a scraper reads of one gearbox (None: not known).

    Attributes
    ----------
    gearbox : str
        The gearbox id.
    state : str
        ``ok``, ``warning``, ``alarm`` or ``unknown`` (:mod:`.alarms`), and ``state_reason`` why.
    play_arcmin, play_std_arcmin : float or None
        The latest observable estimate of the play and its standard error, arcmin.
    play_deg : float or None
        The same play in degrees, as stored.
    play_time_unix_s : float or None
        The time of that estimate, UNIX seconds.
    play_observable : bool or None
        Whether the latest estimate's data showed the play (None: no estimate yet).
    warn_arcmin, limit_arcmin : float or None
        The warning level and the limit the state is checked against, arcmin.
    hours_to_limit : float or None
        Operating hours from the last estimate until the trend reaches the limit (``inf``: it
        does not; negative: already crossed; None: no forecast).
    last_estimate_unix_s : float or None
        The time of the newest estimate of any kind, UNIX seconds.
    stiffness_nm_per_arcmin : float or None
        The torsional stiffness of the newest estimate that has one (with a torque column), N m/arcmin.
    checked_unix_s : float
        The wall-clock time the state was evaluated at, UNIX seconds.
    """

    gearbox: str
    state: str
    state_reason: str
    play_arcmin: float | None
    play_std_arcmin: float | None
    play_deg: float | None
    play_time_unix_s: float | None
    play_observable: bool | None
    warn_arcmin: float | None
    limit_arcmin: float | None
    hours_to_limit: float | None
    last_estimate_unix_s: float | None
    stiffness_nm_per_arcmin: float | None
    checked_unix_s: float

    @property
    def state_code(self) -> int:
        """0, 1, 2, 3 for ok, warning, alarm, unknown (the plugin exit codes of ``history --check``)."""
        return STATE_CODES[self.state]

    @property
    def last_estimate_age_s(self) -> float | None:
        """Seconds from the newest estimate to :attr:`checked_unix_s` (None: no estimate)."""
        return None if self.last_estimate_unix_s is None else self.checked_unix_s - self.last_estimate_unix_s


def gearbox_gauges(report: WearReport) -> GearboxGauges:
    """The gauges of one gearbox from its wear report (see the module docstring)."""
    status = report.status
    estimates = report.estimates
    latest = None
    if status.play_time_unix_s is not None:  # the estimate the play is read from
        seen = [e for e, ok in zip(estimates, report.observable) if ok and e.time_unix_s == status.play_time_unix_s]
        latest = seen[-1] if seen else None
    stiffness = [e.stiffness_nm_per_arcmin for e in estimates if e.stiffness_nm_per_arcmin is not None]
    hours = report.summary.as_dict()["forecast_hours_to_limit"]
    return GearboxGauges(
        gearbox=report.gearbox.id,
        state=status.state,
        state_reason=status.reason,
        play_arcmin=status.play_arcmin,
        play_std_arcmin=None if latest is None else arcmin(latest.backlash_std_deg),
        play_deg=None if latest is None else latest.backlash_deg,
        play_time_unix_s=status.play_time_unix_s,
        play_observable=bool(estimates[-1].play_observable) if estimates else None,
        warn_arcmin=status.warn_arcmin,
        limit_arcmin=status.limit_arcmin,
        hours_to_limit=None if hours is None or math.isnan(hours) else float(hours),
        last_estimate_unix_s=max(e.time_unix_s for e in estimates) if estimates else None,
        stiffness_nm_per_arcmin=stiffness[-1] if stiffness else None,
        checked_unix_s=report.now_unix_s,
    )
