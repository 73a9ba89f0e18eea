"""Simulated snapshot logs of a gearbox wearing against its hour meter (the demo's series, tests, benches).

A machine runs ``hours_per_day`` a day; once a day (or on the days of a plan) a short snapshot of
its encoders is logged, with the controller's hour meter as a column (``hours``, hours). The play
grows linearly with the machine's hours, from ``play_start_deg`` at the first snapshot's start
to ``play_end_deg`` at the last one's (load side). Between two snapshots the meter advances by
``hours_per_day`` per calendar day; during a snapshot it runs with the log's own time (the machine
runs while it is logged).

:func:`write_snapshot_logs` writes the logs (CSV with UNIX times, encoder counts and the meter)
and returns the truth: the wear rate per machine hour and, for a limit, the machine hours and
the calendar time at which the play reaches it.

The recordings come from :func:`online_backlash.simulation.rig.simulate_rig` (eq. (1) with quantised, noisy
encoders) or from :func:`online_backlash.simulation.two_mass_rig.simulate_two_mass` (a two-mass drive with a
compliant shaft and contact dynamics: a simulator other than the model the estimator assumes).
"""

from __future__ import annotations

import datetime as dt
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InvalidParameterError

#: Seconds per calendar day.
DAY_S = 86400.0
#: The simulators a series can be recorded with.
SIMULATORS = ("rig", "two-mass")


@dataclass(frozen=True)
class SnapshotPlan:
    """When the snapshots are taken and how the gearbox wears.

    Attributes
    ----------
    days : sequence of float
        Calendar days after ``start`` on which a snapshot begins (fractions: the time of day).
    durations_s : sequence of float
        Each snapshot's length, seconds (one value: all alike).
    start : datetime
        The first day's midnight-based origin (UTC).
    hours_per_day : float
        The machine's running hours per calendar day.
    meter_start_h : float
        The hour meter at ``start``.
    play_start_deg, play_end_deg : float
        The play at the first snapshot's start and the last one's end, degrees (load side).
    rate_hz : float
        Sampling rate of the logs.
    speed_deg_s : float
        Load-side speed of the motion (:func:`~online_backlash.simulation.rig.simulate_rig`).
    simulator : str
        ``rig`` or ``two-mass`` (module docstring).
    seed : int
        Seed of the first snapshot (the next ones count on).
    meter_resolution_h : float
        The hour meter's resolution, hours (its column is rounded to it, as a controller's counter is).
    """

    days: Sequence[float]
    durations_s: Sequence[float] = (60.0,)
    start: dt.datetime = dt.datetime(2026, 1, 5, tzinfo=dt.timezone.utc)
    hours_per_day: float = 16.0
    meter_start_h: float = 5000.0
    play_start_deg: float = 0.2
    play_end_deg: float = 0.3
    rate_hz: float = 100.0
    speed_deg_s: float = 3.0
    simulator: str = "rig"
    seed: int = 2026
    ratio: float = 30.0
    meter_resolution_h: float = 0.001
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.simulator not in SIMULATORS:
            raise InvalidParameterError(f"simulator must be one of {SIMULATORS}, got {self.simulator!r}")
        if len(self.days) < 2 or np.any(np.diff(np.asarray(self.days, dtype=float)) <= 0):
            raise InvalidParameterError("a plan needs at least two snapshot days, in increasing order")
        if len(self.durations_s) not in (1, len(self.days)):
            raise InvalidParameterError(
                f"give one duration or one per snapshot ({len(self.days)}), got {len(self.durations_s)}"
            )

    def duration_s(self, k: int) -> float:
        return float(self.durations_s[0] if len(self.durations_s) == 1 else self.durations_s[k])

    def start_unix_s(self, k: int) -> float:
        """Calendar time of snapshot ``k``'s first sample, UNIX seconds."""
        return self.start.timestamp() + float(self.days[k]) * DAY_S

    def meter_h(self, unix_s: float) -> float:
        """The hour meter at calendar time ``unix_s`` outside the snapshots (``hours_per_day`` a day)."""
        return self.meter_start_h + self.hours_per_day * (unix_s - self.start.timestamp()) / DAY_S

    @property
    def rate_deg_per_h(self) -> float:
        """The true wear rate, degrees per machine hour."""
        last = len(self.days) - 1
        span_h = (
            self.meter_h(self.start_unix_s(last)) + self.duration_s(last) / 3600.0 - self.meter_h(self.start_unix_s(0))
        )
        return (self.play_end_deg - self.play_start_deg) / span_h

    def play_deg(self, meter_h: float | np.ndarray) -> float | np.ndarray:
        """The true play at hour-meter reading ``meter_h``."""
        return self.play_start_deg + self.rate_deg_per_h * (
            np.asarray(meter_h, dtype=float) - self.meter_h(self.start_unix_s(0))
        )

    def limit_h(self, limit_deg: float) -> float:
        """The hour meter at which the play reaches ``limit_deg``."""
        return self.meter_h(self.start_unix_s(0)) + (limit_deg - self.play_start_deg) / self.rate_deg_per_h

    def limit_unix_s(self, limit_deg: float) -> float:
        """The calendar time at which the play reaches ``limit_deg`` (the machine running ``hours_per_day`` a day)."""
        return self.start.timestamp() + (self.limit_h(limit_deg) - self.meter_start_h) / self.hours_per_day * DAY_S


def daily(n_days: int, hour_of_day: float = 8.0, **options: object) -> SnapshotPlan:
    """A snapshot every day at ``hour_of_day`` (UTC) for ``n_days`` days."""
    return SnapshotPlan(days=[d + hour_of_day / 24.0 for d in range(n_days)], **options)  # type: ignore[arg-type]


def _record(plan: SnapshotPlan, k: int, meter_at_start_h: float) -> object:
    """Snapshot ``k``'s recording, its play following the meter."""
    duration = plan.duration_s(k)
    seed = plan.seed + k
    if plan.simulator == "two-mass":
        from .two_mass_rig import simulate_two_mass

        middle = meter_at_start_h + duration / 7200.0
        return simulate_two_mass(
            duration_s=duration,
            rate_hz=plan.rate_hz,
            ratio=plan.ratio,
            play_deg=float(plan.play_deg(middle)),
            seed=seed,
            **plan.extra,
        )
    from .rig import simulate_rig

    def play(t: np.ndarray) -> np.ndarray:
        return np.asarray(plan.play_deg(meter_at_start_h + t / 3600.0))

    return simulate_rig(
        duration_s=duration,
        rate_hz=plan.rate_hz,
        ratio=plan.ratio,
        play_deg=play,
        speed_deg_s=plan.speed_deg_s,
        seed=seed,
        **plan.extra,
    )


def write_snapshot_logs(folder: str | os.PathLike[str], plan: SnapshotPlan, name: str = "snapshot") -> list[dict]:
    """Write the plan's snapshots as ``NAME_YYYY-MM-DD_HHMMSS.csv.gz`` in ``folder`` (UNIX times, encoder counts,
    ``hours`` the hour meter); returns one dict per log: ``file``, ``start`` (ISO, UTC), ``meter_start_h``,
    ``play_deg_first``, ``play_deg_last``."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    logs = []
    for k in range(len(plan.days)):
        start = plan.start_unix_s(k)
        meter = plan.meter_h(start)
        rec = _record(plan, k, meter)
        time_s = np.asarray(rec.time_s)  # type: ignore[attr-defined]
        when = dt.datetime.fromtimestamp(start, dt.timezone.utc)
        path = out / f"{name}_{when.strftime('%Y-%m-%d_%H%M%S')}.csv.gz"
        hours = meter + (time_s - time_s[0]) / 3600.0
        meter_column = np.floor(hours / plan.meter_resolution_h) * plan.meter_resolution_h
        rec.time_s = time_s - time_s[0] + start  # type: ignore[attr-defined]
        rec.write_csv(path, units="counts", extra={"hours": meter_column})  # type: ignore[attr-defined]
        logs.append(
            {
                "file": path.name,
                "start": when.isoformat(),
                "meter_start_h": meter,
                "play_deg_first": float(plan.play_deg(hours[0])),
                "play_deg_last": float(plan.play_deg(hours[-1])),
            }
        )
    return logs


def truth(plan: SnapshotPlan, limit_deg: float, last_estimate_unix_s: float) -> dict[str, float]:
    """What a forecast made at the last estimate should say: the wear rate (deg per machine hour), the
    machine hours from the estimate to the limit and the calendar days to it."""
    meter_last = (
        plan.meter_h(plan.start_unix_s(len(plan.days) - 1))
        + (last_estimate_unix_s - plan.start_unix_s(len(plan.days) - 1)) / 3600.0
    )
    hours_left = plan.limit_h(limit_deg) - meter_last
    if not math.isfinite(hours_left):
        raise InvalidParameterError("the play does not reach the limit")
    limit_unix_s = plan.limit_unix_s(limit_deg)
    return {
        "rate_deg_per_h": plan.rate_deg_per_h,
        "hours_to_limit": hours_left,
        "days_to_limit": (limit_unix_s - last_estimate_unix_s) / DAY_S,
        "limit_unix_s": limit_unix_s,
    }
