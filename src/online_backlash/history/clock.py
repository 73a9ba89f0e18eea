"""The clock a wear trend runs on: the machine's hour meter where it was given, else the best the logs allow.

Wear grows with the machine's use. The logged samples count only the time they recorded
(``operating_hours``, time in motion while logging), which is the machine's use only when the
logs cover it. The trend's clock (:class:`TrendClock`) is, in this order:

``machine hours``
    every estimate of the trend carries the machine's hour meter (``machine_hours``: ``track
    --operating-hours`` or ``--hours-column``);
``calendar days``
    else, for *snapshot logs*: the logs recorded less than :data:`SNAPSHOT_FRACTION` of the
    calendar time they span (a minute a day, a few test cycles a week), so their logged hours say
    nothing of the machine's use between them; calendar time does, while the use per day is steady;
``load revolutions``
    else (the logs cover the machine's running): the load shaft's travel, which counts use
    whatever the speed;
``operating hours``
    the logged time in motion: only where nothing is known about the logs (the library's
    :func:`~online_backlash.history.trend.summarise` called without it), as before issue 28.

Snapshot logs also make one trend point per log (:func:`snapshot_points`): a recursive
estimator's estimates within one short log share most of their data, so a log ten times longer
would otherwise weigh ten times more; each log's last estimate carries what the log showed, with
its own standard deviation, and the trend weighs it by that (:mod:`.trend`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Logs that recorded less than this fraction of the calendar time they span are snapshot logs.
SNAPSHOT_FRACTION = 0.1

#: Seconds per calendar day.
DAY_S = 86400.0


@dataclass(frozen=True)
class TrendClock:
    """A clock the wear trend can run on.

    Attributes
    ----------
    key : str
        ``machine_hours``, ``calendar_days``, ``load_revolutions`` or ``operating_hours`` (``trend_clock`` in JSON).
    label : str
        Its name in a sentence (``machine hours``).
    unit : str
        Its unit (``h``, ``d``, ``rev``).
    reason : str
        Why the trend runs on it.
    """

    key: str
    label: str
    unit: str
    reason: str = ""

    @property
    def counts_hours(self) -> bool:
        """The clock counts hours of use (machine hours or logged operating hours)."""
        return self.unit == "h"


MACHINE_HOURS = TrendClock("machine_hours", "machine hours", "h")
CALENDAR_DAYS = TrendClock("calendar_days", "calendar days", "d")
LOAD_REVOLUTIONS = TrendClock("load_revolutions", "load revolutions", "rev")
OPERATING_HOURS = TrendClock("operating_hours", "logged operating hours", "h")


@dataclass(frozen=True)
class Recording:
    """How much of the calendar a gearbox's logs recorded: the sum of their durations and the span
    from the first log's start to the last one's end, seconds."""

    recorded_s: float
    span_s: float

    @property
    def snapshots(self) -> bool:
        """The logs recorded less than :data:`SNAPSHOT_FRACTION` of the span (module docstring)."""
        return self.span_s > 0 and self.recorded_s < SNAPSHOT_FRACTION * self.span_s

    @property
    def fraction(self) -> float | None:
        """Recorded time over the span (None without a span)."""
        return self.recorded_s / self.span_s if self.span_s > 0 else None


def recording(starts_unix_s: np.ndarray, ends_unix_s: np.ndarray) -> Recording:
    """The :class:`Recording` of logs that ran from ``starts_unix_s`` to ``ends_unix_s`` (UNIX seconds, one per log).

    >>> day = 86400.0
    >>> recording(np.array([0.0, day, 2 * day]), np.array([60.0, day + 60, 2 * day + 60])).snapshots
    True
    """
    starts = np.asarray(starts_unix_s, dtype=float)
    ends = np.maximum(np.asarray(ends_unix_s, dtype=float), starts)
    if starts.size == 0:
        return Recording(0.0, 0.0)
    return Recording(float(np.sum(ends - starts)), float(np.max(ends) - np.min(starts)))


def choose_clock(machine_hours: np.ndarray, rec: Recording | None) -> TrendClock:
    """The trend's clock (module docstring), given each trend estimate's machine hours (NaN: none)
    and how much of the calendar the logs recorded (None: not known)."""
    machine = np.asarray(machine_hours, dtype=float)
    with_meter = int(np.isfinite(machine).sum())
    if machine.size and with_meter == machine.size:
        return _because(MACHINE_HOURS, "the machine's hour meter was given with every log")
    missing = f"; {machine.size - with_meter} of {machine.size} estimates have no hour meter" if with_meter else ""
    hint = " (give --operating-hours or --hours-column when tracking)"
    if rec is None:
        return _because(OPERATING_HOURS, f"no hour meter{missing}: the time in motion the logs recorded{hint}")
    if rec.snapshots:
        share = f"{rec.recorded_s / 3600:.3g} h recorded in {rec.span_s / DAY_S:.3g} days"
        return _because(CALENDAR_DAYS, f"snapshot logs ({share}) and no hour meter{missing}{hint}")
    return _because(LOAD_REVOLUTIONS, f"the logs cover the machine's running and have no hour meter{missing}{hint}")


def _because(clock: TrendClock, reason: str) -> TrendClock:
    return TrendClock(clock.key, clock.label, clock.unit, reason)


def clock_values(
    clock: TrendClock,
    time_unix_s: np.ndarray,
    operating_hours: np.ndarray,
    load_revolutions: np.ndarray,
    machine_hours: np.ndarray,
) -> np.ndarray:
    """Each estimate's reading of ``clock`` (hours, days since the first estimate, or revolutions)."""
    if clock.key == CALENDAR_DAYS.key:
        t = np.asarray(time_unix_s, dtype=float)
        return (t - np.nanmin(t)) / DAY_S if t.size else t
    columns = {
        MACHINE_HOURS.key: machine_hours,
        LOAD_REVOLUTIONS.key: load_revolutions,
        OPERATING_HOURS.key: operating_hours,
    }
    return np.asarray(columns[clock.key], dtype=float)


def snapshot_points(group: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Indices of the trend points: of the estimates flagged ``keep``, the last of each ``group`` (a
    log's run id) in the order given.

    >>> snapshot_points(np.array([1, 1, 1, 2, 2, 3]), np.array([True, True, False, True, True, True]))
    array([1, 4, 5])
    """
    group = np.asarray(group)
    candidates = np.flatnonzero(np.asarray(keep, dtype=bool))
    if candidates.size == 0:
        return candidates
    ids = group[candidates]
    last = np.r_[ids[1:] != ids[:-1], True]
    return candidates[last]


def lag_on_clock(x: np.ndarray, hours: np.ndarray, lag_hours: float) -> np.ndarray:
    """A recursive estimator's lag, ``lag_hours`` of its logged operating hours, on another clock ``x``:
    per estimate, ``x`` now minus ``x`` where the logged hours were ``lag_hours`` fewer (interpolated
    between estimates, which places the lag across a gap between two logs by the share of the
    memory that lies before it).

    >>> lag_on_clock(np.array([0.0, 1.0, 17.0, 18.0]), np.array([0.0, 1.0, 1.01, 2.01]), 0.5)
    array([ 0.  ,  0.5 , 16.49,  0.5 ])
    """
    x = np.asarray(x, dtype=float)
    hours = np.asarray(hours, dtype=float)
    if lag_hours <= 0 or x.size == 0:
        return np.zeros(x.shape)
    ok = np.isfinite(x) & np.isfinite(hours)
    if ok.sum() < 2:
        return np.zeros(x.shape)
    order = np.argsort(hours[ok], kind="stable")
    h_sorted, x_sorted = hours[ok][order], x[ok][order]
    earlier = np.interp(hours - lag_hours, h_sorted, x_sorted)
    return np.where(ok, np.maximum(x - earlier, 0.0), 0.0)
