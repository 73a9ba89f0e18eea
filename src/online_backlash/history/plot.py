"""The wear plot: estimates with their standard deviation, the trend and its band, the limit."""

from __future__ import annotations

import math
import os

import numpy as np
from matplotlib.figure import Figure

from .report import ARCMIN_PER_DEG, WearReport


def plot_wear(report: WearReport, path: str | os.PathLike[str], dpi: int = 120) -> None:
    """Draw backlash against operating hours and save it (the format follows the suffix: .png, .svg, .pdf).

    Estimates are points with bars of one standard deviation; the Theil-Sen trend is a line
    with its band shaded; the limit (if known) is a horizontal line and the forecast crossing
    a vertical one with its interval shaded. The right axis reads the same values in arcmin.
    """
    hours = report.column("operating_hours")
    backlash = report.column("backlash_deg")
    std = np.nan_to_num(report.column("backlash_std_deg"), nan=0.0)
    trend, fc = report.summary.per_hour, report.summary.forecast

    fig = Figure(figsize=(8.0, 4.8), layout="constrained")
    ax = fig.add_subplot()
    ax.errorbar(hours, backlash, yerr=std, fmt="o", ms=3, lw=0.8, color="tab:blue", ecolor="0.6", label="estimates (± 1 std)")
    x_end = float(np.nanmax(hours)) if hours.size else 1.0
    crossing = None
    if trend is not None and fc is not None:
        crossing = report.summary.last_hours + fc.hours_to_limit
        if math.isfinite(crossing):
            x_end = max(x_end, crossing)
    x = np.linspace(0.0, 1.1 * x_end, 200)
    if trend is not None:
        low, high = trend.band(x)
        ax.fill_between(x, low, high, color="tab:orange", alpha=0.25, lw=0, label=f"band ({trend.confidence:.0%})")
        ax.plot(x, trend.line(x), color="tab:orange", label=f"trend {trend.slope:+.4g} deg/h (Theil-Sen)")
    if fc is not None:
        ax.axhline(fc.limit_deg, color="tab:red", ls="--", lw=1, label=f"limit {fc.limit_deg * ARCMIN_PER_DEG:g} arcmin")
        if crossing is not None and math.isfinite(crossing):
            last = report.summary.last_hours
            early = last + fc.hours_to_limit_low
            late = last + fc.hours_to_limit_high if math.isfinite(fc.hours_to_limit_high) else x[-1]
            ax.axvspan(early, min(late, x[-1]), color="tab:red", alpha=0.08, lw=0)
            ax.axvline(crossing, color="tab:red", lw=1, label=f"forecast: limit at {crossing:.3g} h")
    ax.set_xlim(0.0, x[-1])
    ax.set_xlabel("operating hours since new")
    ax.set_ylabel("backlash, deg (load side)")
    right = ax.secondary_yaxis("right", functions=(lambda d: d * ARCMIN_PER_DEG, lambda a: a / ARCMIN_PER_DEG))
    right.set_ylabel("arcmin")
    ax.set_title(f"gearbox {report.gearbox.id}: wear history ({len(report.estimates)} estimates)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.savefig(path, dpi=dpi)
