"""The wear plot: the estimates with their standard deviations against the trend's clock, the trend, the limit."""

from __future__ import annotations

import datetime as dt
import math
import os

import numpy as np
from matplotlib import dates as mdates
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

from .clock import CALENDAR_DAYS, DAY_S, clock_values
from .report import ARCMIN_PER_DEG, WearReport
from .text import amount, rate, wear_figures

#: matplotlib's date number of the UNIX epoch (days).
_EPOCH_DAYS = float(mdates.date2num(dt.datetime(1970, 1, 1, tzinfo=dt.timezone.utc)))


def plot_wear(report: WearReport, path: str | os.PathLike[str], dpi: int = 120) -> None:
    """Draw backlash against the trend's clock and save it (the format follows the suffix: .png, .svg, .pdf).

    The x-axis is the trend's clock (machine hours, calendar days, load revolutions or logged
    operating hours: :mod:`.clock`), the top axis the calendar dates it maps to (the estimates'
    own times, and ahead of them the recent rate of use). Estimates are points with bars of one
    standard deviation; estimates whose data did not show the play (``play_observable`` false)
    are grey open circles, outside the trend. The trend (Theil-Sen, or the Kalman level with
    ``--trend kalman``) is a line with two labelled bands: the *confidence* band of the line (dark:
    where the trend is) and the *prediction* band (light: where a new estimate falls). The limit
    (if known) is a horizontal line; the forecast crossing a vertical one with its interval
    shaded, or, for a gearbox already over its limit, a vertical line at the first estimate of its
    trailing run above the limit. A trend without measured wear draws no crossing; the y-axis
    stays on the estimates and the limit (the bands are cut there). The right axis reads arcmin.
    """
    s = report.summary
    clock = s.clock
    x_all = _clock_column(report)
    backlash = report.column("backlash_deg")
    std = np.nan_to_num(report.column("backlash_std_deg"), nan=0.0)
    trend, fc = s.trend, s.forecast
    exceeded = report.status.limit_exceeded_since_unix_s
    figures = wear_figures(report)

    fig = Figure(figsize=(8.0, 5.0), layout="constrained")
    ax = fig.add_subplot()
    seen = report.observable & np.isfinite(x_all)
    ax.errorbar(
        x_all[seen],
        backlash[seen],
        yerr=std[seen],
        fmt="o",
        ms=3,
        lw=0.8,
        color="tab:blue",
        ecolor="0.6",
        label="estimates (± 1 std)",
    )
    hidden = ~report.observable & np.isfinite(backlash) & np.isfinite(x_all)
    if hidden.any():  # greyed: the data did not show the play (preloaded); left out of the trend
        ax.plot(
            x_all[hidden],
            backlash[hidden],
            "o",
            ms=3,
            mfc="none",
            color="0.65",
            label="play not observable (not in the trend)",
        )
    finite = x_all[np.isfinite(x_all)]
    x_first = float(finite.min()) if finite.size else 0.0
    x_end = float(finite.max()) if finite.size else 1.0
    crossing = None
    if trend is not None and fc is not None and exceeded is None and s.last_x is not None and s.wear_measured:
        crossing = s.last_x + fc.to_limit
        if math.isfinite(crossing):
            x_end = max(x_end, crossing)
    # logged operating hours count from new; the other clocks from the first estimate (an hour meter at 5,000 h)
    x_start = min(0.0, x_first) if clock.key == "operating_hours" else x_first - 0.05 * (x_end - x_first)
    x = np.linspace(x_start, x_end + 0.1 * (x_end - x_start or 1.0), 200)
    if trend is not None:
        conf = f"{trend.confidence:.0%}"
        low, high = trend.prediction_band(x)
        ax.fill_between(
            x, low, high, color="tab:orange", alpha=0.12, lw=0, label=f"prediction band ({conf}): new estimates"
        )
        low, high = trend.band(x)
        ax.fill_between(
            x, low, high, color="tab:orange", alpha=0.35, lw=0, label=f"confidence band ({conf}): the trend"
        )
        name = "Kalman level, lag-corrected" if trend.method == "kalman" else "Theil-Sen"
        label = f"trend {rate(trend.slope, clock)} ({name})" if s.wear_measured else f"no wear measured ({name})"
        ax.plot(x, trend.line(x), color="tab:orange", label=label)
    if fc is not None:
        ax.axhline(
            fc.limit_deg, color="tab:red", ls="--", lw=1, label=f"limit {fc.limit_deg * ARCMIN_PER_DEG:g} arcmin"
        )
    if exceeded is not None:
        since = float(np.interp(exceeded, report.column("time_unix_s"), np.nan_to_num(x_all, nan=0.0)))
        ax.axvline(
            since, color="tab:red", lw=1.5, label=f"limit exceeded since {report.status_dict()['limit_exceeded_since']}"
        )
    elif fc is not None and s.last_x is not None and crossing is not None and math.isfinite(crossing):
        early = s.last_x + fc.to_limit_low
        late = s.last_x + fc.to_limit_high if math.isfinite(fc.to_limit_high) else x[-1]
        ax.axvspan(early, min(late, x[-1]), color="tab:red", alpha=0.08, lw=0)
        ax.axvline(crossing, color="tab:red", lw=1, label=f"forecast: {figures.forecast_short}")
    ax.set_xlim(x[0], x[-1])
    ax.set_ylim(*_y_range(backlash[seen], std[seen], None if fc is None else fc.limit_deg))
    ax.set_xlabel(_axis_label(report))
    ax.set_ylabel("backlash, deg (load side)")
    right = ax.secondary_yaxis("right", functions=(_deg_to_arcmin, _arcmin_to_deg))
    right.set_ylabel("arcmin")
    _date_axis(ax, report, x_all)
    ax.set_title(
        f"gearbox {report.gearbox.id}: wear against {clock.label} ({_counted(report)}), state {report.status.state}",
        fontsize=10,
    )
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.savefig(path, dpi=dpi)


def _clock_column(report: WearReport) -> np.ndarray:
    """Each estimate's reading of the trend's clock."""
    names = ("time_unix_s", "operating_hours", "load_revolutions", "machine_hours")
    return clock_values(report.summary.clock, *(report.column(n) for n in names))


def _axis_label(report: WearReport) -> str:
    clock = report.summary.clock
    if clock.key == CALENDAR_DAYS.key:
        first = report.column("time_unix_s")
        start = (
            dt.datetime.fromtimestamp(float(np.nanmin(first)), dt.timezone.utc).date().isoformat() if first.size else ""
        )
        return f"calendar days since {start} (UTC)"
    since = "" if clock.key == "machine_hours" else " since new"
    return f"{clock.label}{since}, {clock.unit}"


def _y_range(play: np.ndarray, std: np.ndarray, limit: float | None) -> tuple[float, float]:
    """The estimates (with their bars) and the limit, with a margin: bands beyond them are cut."""
    values = np.concatenate([play - std, play + std, [] if limit is None else [limit]])
    values = values[np.isfinite(values)]
    if values.size == 0:
        return 0.0, 1.0
    low, high = float(values.min()), float(values.max())
    margin = 0.15 * (high - low) or 0.05 * abs(high) or 0.01
    return low - margin, high + margin


def _date_axis(ax: object, report: WearReport, x_all: np.ndarray) -> None:
    """A top axis of calendar dates: the estimates' own times along the clock, the recent rate of use ahead."""
    s = report.summary
    t = report.column("time_unix_s")
    ok = np.isfinite(x_all) & np.isfinite(t)
    per_day = s.forecast.usage_per_day if s.forecast is not None else None
    if ok.sum() < 2 or not per_day or per_day <= 0:
        return
    xs, first = np.unique(x_all[ok], return_index=True)
    ts = np.maximum.accumulate(t[ok][first])
    if xs.size < 2 or np.ptp(ts) <= 0:
        return

    def to_date(x: ArrayLike) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        unix = np.interp(x, xs, ts) + (np.maximum(x - xs[-1], 0.0) - np.maximum(xs[0] - x, 0.0)) / per_day * DAY_S
        return unix / DAY_S + _EPOCH_DAYS

    def to_clock(days: ArrayLike) -> np.ndarray:
        unix = (np.asarray(days, dtype=float) - _EPOCH_DAYS) * DAY_S
        return (
            np.interp(unix, ts, xs) + (np.maximum(unix - ts[-1], 0.0) - np.maximum(ts[0] - unix, 0.0)) * per_day / DAY_S
        )

    top = ax.secondary_xaxis("top", functions=(to_date, to_clock))  # type: ignore[attr-defined]
    top.xaxis.set_major_locator(mdates.AutoDateLocator(maxticks=6))
    top.xaxis.set_major_formatter(mdates.DateFormatter("%Y-%m-%d"))
    top.set_xlabel(
        "date (UTC)" + ("" if s.clock.key == CALENDAR_DAYS.key else f", ahead at {amount(per_day, s.clock)} per day"),
        fontsize=8,
    )
    top.tick_params(labelsize=7)


def _counted(report: WearReport) -> str:
    n, seen = len(report.estimates), int(report.observable.sum())
    return f"{n} estimates" if seen == n else f"{n} estimates, {n - seen} not observable"


def _deg_to_arcmin(deg: ArrayLike) -> np.ndarray:
    return np.asarray(deg, dtype=float) * ARCMIN_PER_DEG


def _arcmin_to_deg(arcmin: ArrayLike) -> np.ndarray:
    return np.asarray(arcmin, dtype=float) / ARCMIN_PER_DEG
