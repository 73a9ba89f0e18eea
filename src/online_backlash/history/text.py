"""The wear figures in words: one formatting of the clock, the trend and the forecast for every reader.

``history`` (its report and ``--check`` line), the ``serve`` page, the MQTT state message and the
wear plot all say the same figures the same way: :func:`wear_figures` turns a
:class:`~online_backlash.history.report.WearReport` into :class:`WearFigures`, strings with their
units. Play and rates are in arcmin (the unit of the limits), rates per 1000 hours or load
revolutions or per calendar day (:data:`RATE_PER`), amounts of the trend's clock in its own
unit, dates in UTC.

A trend whose rate interval reaches down to zero or below says "no wear measured" with the
upper bound of the rate it supports, and gives no forecast date. A forecast date already past
(the last estimate is old) is said to be reached, with the date of the last estimate.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from ..output_columns import ARCMIN_PER_DEG
from .clock import TrendClock
from .report import WearReport
from .trend import iso_date

#: Rates are given per this many units of each clock unit (arcmin per 1000 machine hours, ...).
RATE_PER = {"h": 1000.0, "d": 1.0, "rev": 1000.0}
#: A clock unit's name for one of it.
ONE = {
    "machine_hours": "machine hour",
    "calendar_days": "calendar day",
    "load_revolutions": "load revolution",
    "operating_hours": "logged operating hour",
}


def amount(value: float, clock: TrendClock) -> str:
    """``490 machine hours``, ``30.2 calendar days``, ``1.25e+05 load revolutions``.

    >>> from .clock import MACHINE_HOURS
    >>> amount(1240.4, MACHINE_HOURS), amount(2.456, MACHINE_HOURS)
    ('1,240 machine hours', '2.46 machine hours')
    """
    return f"{number(value)} {clock.label}"


def number(value: float) -> str:
    """A count of the clock's units: whole from 100 on, else three significant digits; ``never`` for infinity."""
    if not math.isfinite(value):
        return "never"
    return f"{value:,.0f}" if abs(value) >= 100 else f"{value:.3g}"


def rate(slope_deg: float, clock: TrendClock) -> str:
    """A wear rate (degrees per clock unit) in arcmin per :data:`RATE_PER` units.

    >>> from .clock import MACHINE_HOURS
    >>> rate(1.0417e-4, MACHINE_HOURS)
    '+6.25 arcmin per 1,000 machine hours'
    """
    per = RATE_PER.get(clock.unit, 1.0)
    unit = ONE.get(clock.key, clock.label) if per == 1.0 else f"{per:,.0f} {clock.label}"
    return f"{slope_deg * ARCMIN_PER_DEG * per:+.3g} arcmin per {unit}"


def _bounds(low_deg: float, high_deg: float, clock: TrendClock) -> str:
    per = RATE_PER.get(clock.unit, 1.0) * ARCMIN_PER_DEG
    return f"[{low_deg * per:+.3g}, {high_deg * per:+.3g}]"


@dataclass(frozen=True)
class WearFigures:
    """A gearbox's wear figures in words (module docstring).

    Attributes
    ----------
    clock : str
        The trend's clock and why (``machine hours: the machine's hour meter was given with every log``).
    trend : str
        The wear rate with its interval, or ``no wear measured`` with its bound.
    trend_short : str
        The same in a few words (the page's table, MQTT).
    use : str
        The recent rate of use (``16.0 machine hours per calendar day recently``), or "".
    forecast : str
        The forecast in full: on the clock with its interval, and the date with its interval.
    forecast_short : str
        The same in a few words (the page's table, the ``--check`` line, MQTT).
    """

    clock: str
    trend: str
    trend_short: str
    use: str
    forecast: str
    forecast_short: str

    def as_dict(self) -> dict[str, str]:
        return asdict(self)


def wear_figures(report: WearReport) -> WearFigures:
    """The figures of ``report`` in words."""
    s = report.summary
    clock = s.clock
    points = f"{s.n_points} snapshot logs" if s.snapshots else f"{s.n_points} estimates"
    clock_text = f"{clock.label}: {clock.reason}" if clock.reason else clock.label
    if s.trend is None:
        trend, short = "needs at least 3 estimates at different readings of the clock", "needs 3 estimates"
    else:
        method = "Kalman local linear trend, lag-corrected" if s.trend.method == "kalman" else "Theil-Sen"
        conf = f"{s.trend.confidence:.0%}"
        if s.wear_measured:
            short = rate(s.trend.slope, clock)
            trend = f"{short} {_bounds(s.trend.slope_low, s.trend.slope_high, clock)} ({conf}, {method}, {points})"
        else:
            short = f"no wear measured (at most {rate(s.trend.slope_high, clock)})"
            trend = f"no wear measured: at most {rate(s.trend.slope_high, clock)} ({conf} bound, {method}, {points})"
    f = s.forecast
    use = ""
    if f is not None and f.usage_per_day and clock.key != "calendar_days":
        use = f"{number(f.usage_per_day)} {clock.label} per calendar day recently"
    long, short_forecast = _forecast(report)
    return WearFigures(clock_text, trend, short, use, long, short_forecast)


def _forecast(report: WearReport) -> tuple[str, str]:
    """The forecast in full and in a few words."""
    s, status = report.summary, report.status
    since = report.status_dict()["limit_exceeded_since"]
    limit_arcmin = report.limit_arcmin
    if since is not None:
        return (
            f"limit {limit_arcmin:g} arcmin exceeded since {since} (UTC), play now {status.play_arcmin:.2f} arcmin",
            f"exceeded since {since}",
        )
    if limit_arcmin is None:
        return "no limit (give --limit-arcmin, or store one with track --limit-arcmin)", "no limit stored"
    f, clock, limit = s.forecast, s.clock, f"limit {limit_arcmin:g} arcmin"
    if s.trend is None or f is None:
        return f"{limit}: no forecast, the trend needs at least 3 estimates", "no forecast yet"
    if not s.wear_measured:
        early = (
            ""
            if not math.isfinite(f.to_limit_low)
            else f"; at the rate's upper bound it is at least {amount(f.to_limit_low, clock)} away"
        )
        return f"{limit} not forecast: no wear measured{early}", "no wear measured"
    date, (d_low, d_high) = iso_date(f.date_unix_s), (iso_date(f.date_low_unix_s), iso_date(f.date_high_unix_s))
    if f.to_limit < 0:
        when = f" around {date} (the estimates' clock)" if date else ""
        return (
            f"{limit} reached by the trend {amount(-f.to_limit, clock)} before the last estimate{when}",
            f"reached by the trend{when}",
        )
    interval = f"[{number(f.to_limit_low)}, {number(f.to_limit_high)}]"
    ahead = f"{limit} in {amount(f.to_limit, clock)} {interval} from the last estimate"
    if date is None:
        return f"{ahead}; no date: no recent rate of use", f"in {amount(f.to_limit, clock)}"
    rate_of_use = (
        "" if clock.key == "calendar_days" else f" at {number(f.usage_per_day or 0.0)} {clock.label} per calendar day"
    )
    dated = f"{ahead}, around {date} [{d_low}, {d_high or 'never'}] (UTC){rate_of_use}"
    today = iso_date(report.now_unix_s) or ""
    if date < today:
        last = iso_date(s.last_time_unix_s)
        note = f"reached by the trend around {date}, before today: the last estimate is from {last}"
        return f"{dated}: {note}; track newer logs", note
    return dated, f"in {amount(f.to_limit, clock)}, around {date}"
