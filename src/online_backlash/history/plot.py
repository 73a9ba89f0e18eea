"""The wear plot: estimates with their standard deviation, the trend and its band, the limit."""

from __future__ import annotations

import math
import os

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

from .report import ARCMIN_PER_DEG, WearReport


def plot_wear(report: WearReport, path: str | os.PathLike[str], dpi: int = 120) -> None:
    """Draw backlash against operating hours and save it (the format follows the suffix: .png, .svg, .pdf).

    Estimates are points with bars of one standard deviation; estimates whose data did not show
    the play (``play_observable`` false) are grey open circles, outside the trend. The trend (Theil-Sen, or the
    Kalman level with ``--trend kalman``) is a line with two labelled bands: the *confidence*
    band of the line (dark: where the trend is) and the *prediction* band (light: where a new
    estimate falls, which holds the scatter). The limit (if known) is a horizontal line; the
    forecast crossing a vertical one with its interval shaded, or, for a gearbox already over
    its limit, a vertical line at the first estimate of its trailing run above the limit
    ("limit exceeded since"). The right axis reads the same values in arcmin.
    """
    hours = report.column("operating_hours")
    backlash = report.column("backlash_deg")
    std = np.nan_to_num(report.column("backlash_std_deg"), nan=0.0)
    trend, fc = report.summary.per_hour, report.summary.forecast
    exceeded = report.status.limit_exceeded_since_unix_s

    fig = Figure(figsize=(8.0, 4.8), layout="constrained")
    ax = fig.add_subplot()
    seen = report.observable
    ax.errorbar(
        hours[seen], backlash[seen], yerr=std[seen], fmt="o", ms=3, lw=0.8, color="tab:blue", ecolor="0.6", label="estimates (± 1 std)"
    )
    hidden = ~seen & np.isfinite(backlash)
    if hidden.any():  # greyed: the data did not show the play (preloaded); left out of the trend
        ax.plot(hours[hidden], backlash[hidden], "o", ms=3, mfc="none", color="0.65", label="play not observable (not in the trend)")
    x_end = float(np.nanmax(hours)) if hours.size else 1.0
    last = report.summary.last_hours
    crossing = None
    if trend is not None and fc is not None and exceeded is None and last is not None:
        crossing = last + fc.hours_to_limit
        if math.isfinite(crossing):
            x_end = max(x_end, crossing)
    x = np.linspace(0.0, 1.1 * x_end, 200)
    if trend is not None:
        conf = f"{trend.confidence:.0%}"
        low, high = trend.prediction_band(x)
        ax.fill_between(x, low, high, color="tab:orange", alpha=0.12, lw=0, label=f"prediction band ({conf}): new estimates")
        low, high = trend.band(x)
        ax.fill_between(x, low, high, color="tab:orange", alpha=0.35, lw=0, label=f"confidence band ({conf}): the trend")
        name = "Kalman level, lag-corrected" if trend.method == "kalman" else "Theil-Sen"
        ax.plot(x, trend.line(x), color="tab:orange", label=f"trend {trend.slope:+.4g} deg/h ({name})")
    if fc is not None:
        ax.axhline(fc.limit_deg, color="tab:red", ls="--", lw=1, label=f"limit {fc.limit_deg * ARCMIN_PER_DEG:g} arcmin")
    if exceeded is not None:
        since = float(np.interp(exceeded, report.column("time_unix_s"), hours))
        ax.axvline(since, color="tab:red", lw=1.5, label=f"limit exceeded since {report.status_dict()['limit_exceeded_since']}")
    elif fc is not None and last is not None and crossing is not None and math.isfinite(crossing):
        early = last + fc.hours_to_limit_low
        late = last + fc.hours_to_limit_high if math.isfinite(fc.hours_to_limit_high) else x[-1]
        ax.axvspan(early, min(late, x[-1]), color="tab:red", alpha=0.08, lw=0)
        ax.axvline(crossing, color="tab:red", lw=1, label=f"forecast: limit at {crossing:.3g} h")
    ax.set_xlim(0.0, x[-1])
    ax.set_xlabel("operating hours since new")
    ax.set_ylabel("backlash, deg (load side)")
    right = ax.secondary_yaxis("right", functions=(_deg_to_arcmin, _arcmin_to_deg))
    right.set_ylabel("arcmin")
    ax.set_title(f"gearbox {report.gearbox.id}: wear history ({_counted(report)}), state {report.status.state}")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.savefig(path, dpi=dpi)


def _counted(report: WearReport) -> str:
    n, seen = len(report.estimates), int(report.observable.sum())
    return f"{n} estimates" if seen == n else f"{n} estimates, {n - seen} not observable"


def _deg_to_arcmin(deg: ArrayLike) -> np.ndarray:
    return np.asarray(deg, dtype=float) * ARCMIN_PER_DEG


def _arcmin_to_deg(arcmin: ArrayLike) -> np.ndarray:
    return np.asarray(arcmin, dtype=float) / ARCMIN_PER_DEG
