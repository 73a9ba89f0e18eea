"""One gearbox's wear history as a report: its estimates, the trend and the forecast.

:func:`wear_report` reads the store and runs :func:`~online_backlash.history.trend.summarise`;
:meth:`WearReport.as_dict` is the JSON of ``online-backlash history --json`` (a contract: keys
``gearbox``, ``estimates`` with ``time``, ``backlash_deg``, ``backlash_std_deg``,
``operating_hours``, then ``trend_deg_per_hour``, ``forecast_hours_to_limit``,
``forecast_date``, and more).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .store import Estimate, Gearbox, HistoryStore
from .trend import WearSummary, iso_time, summarise

ARCMIN_PER_DEG = 60.0


def estimate_dict(e: Estimate) -> dict:
    """An estimate as a flat dict: ISO time, the stored columns, backlash also in arcmin."""
    d = asdict(e)
    d.pop("gearbox_id")
    std = e.backlash_std_deg
    return {
        "time": iso_time(e.time_unix_s),
        **d,
        "backlash_arcmin": e.backlash_deg * ARCMIN_PER_DEG,
        "backlash_std_arcmin": None if std is None else std * ARCMIN_PER_DEG,
    }


@dataclass(frozen=True)
class WearReport:
    """A gearbox, its estimates in order of use, and their trend and forecast.

    ``limit_arcmin`` is the limit the forecast used (given, else the stored one, else None).
    """

    gearbox: Gearbox
    estimates: list[Estimate]
    limit_arcmin: float | None
    summary: WearSummary

    def rows(self) -> list[dict]:
        """The estimates as dicts (see :func:`estimate_dict`)."""
        return [estimate_dict(e) for e in self.estimates]

    def as_dict(self) -> dict:
        """The JSON report (NaN/inf are left to the writer)."""
        return {
            "gearbox": self.gearbox.id,
            "ratio": self.gearbox.ratio,
            "stored_limit_arcmin": self.gearbox.limit_arcmin,
            "n_estimates": len(self.estimates),
            "estimates": self.rows(),
            **self.summary.as_dict(),
        }

    def column(self, name: str) -> np.ndarray:
        """One estimate column as a float array (None as NaN)."""
        return estimate_column(self.estimates, name)


def estimate_column(estimates: list[Estimate], name: str) -> np.ndarray:
    """Column ``name`` of the estimates as a float array (None as NaN)."""
    return np.array([np.nan if getattr(e, name) is None else getattr(e, name) for e in estimates], dtype=float)


def wear_report(
    store: HistoryStore,
    gearbox_id: str,
    limit_arcmin: float | None = None,
    confidence: float = 0.95,
    recent_days: float = 7.0,
) -> WearReport:
    """Read a gearbox's history and fit its trend; forecast ``limit_arcmin`` (or the stored limit).

    Raises HistoryError if the store does not hold ``gearbox_id``.
    """
    gearbox = store.gearbox(gearbox_id)
    estimates = store.estimates(gearbox_id)
    limit = limit_arcmin if limit_arcmin is not None else gearbox.limit_arcmin
    arrays = {name: estimate_column(estimates, name) for name in ("time_unix_s", "operating_hours", "load_revolutions", "backlash_deg")}
    summary = summarise(
        **arrays,
        limit_deg=None if limit is None else limit / ARCMIN_PER_DEG,
        confidence=confidence,
        recent_days=recent_days,
    )
    return WearReport(gearbox, estimates, limit, summary)
