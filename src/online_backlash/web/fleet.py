"""The fleet table: one row per gearbox, from its wear report."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..history.report import WearReport, wear_report
from ..history.store import HistoryStore
from ..history.text import wear_figures


@dataclass(frozen=True)
class FleetRow:
    """What the fleet table shows of one gearbox (strings ready for the page).

    ``state`` is ``ok | warning | alarm | unknown``; ``play`` the latest observable estimate in
    arcmin with its standard deviation; ``trend`` the wear rate against the trend's clock and
    ``forecast`` when the trend reaches the limit (or why there is none), in the words of
    ``history`` (:func:`~online_backlash.history.text.wear_figures`); ``clock`` that clock;
    ``last_seen`` the time of the latest estimate (UTC, the estimates' clock).
    """

    gearbox: str
    state: str
    state_reason: str
    play: str
    trend: str
    forecast: str
    last_seen: str
    n_estimates: int
    clock: str = ""


def _fmt(value: float | None, fmt: str) -> str:
    return "-" if value is None or not math.isfinite(value) else format(value, fmt)


def _play(report: WearReport) -> str:
    play = report.status.play_arcmin
    if play is None:
        return "-"
    rows = [r for r in report.rows() if report.status.play_time_unix_s == r["time_unix_s"]]
    std = rows[-1]["backlash_std_arcmin"] if rows else None
    return f"{play:.2f} ± {_fmt(std, '.2f')}" if std is not None else f"{play:.2f}"


def fleet_row(report: WearReport) -> FleetRow:
    """The table row of one gearbox's report."""
    rows = report.rows()
    figures = wear_figures(report)
    return FleetRow(
        gearbox=report.gearbox.id,
        state=report.status.state,
        state_reason=report.status.reason,
        play=_play(report),
        trend=figures.trend_short,
        forecast=figures.forecast_short,
        last_seen=rows[-1]["time"][:19].replace("T", " ") if rows else "never",
        n_estimates=len(rows),
        clock=figures.clock,
    )


def fleet_rows(store: HistoryStore, max_age_h: float) -> list[FleetRow]:
    """A row per gearbox in the store, in id order; ``max_age_h`` as in ``history --check``."""
    return [fleet_row(wear_report(store, gearbox_id, max_age_h=max_age_h)) for gearbox_id in store.gearbox_ids()]
