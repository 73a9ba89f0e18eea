"""Wear history: a store of estimates per gearbox, resume after restarts, trend and forecast.

* :mod:`.store`: :class:`HistoryStore`, the SQLAlchemy schema (SQLite or PostgreSQL), schema
  version and migrations.
* :mod:`.usage`: :class:`UsageCounter`, operating hours, load revolutions and reversals.
* :mod:`.track`: :class:`GearboxTracker`, feeding a gearbox's recursive estimator from logs or a
  live source, with checkpoints in the store.
* :mod:`.trend`: Theil-Sen trend, band and forecast.
* :mod:`.report`: :func:`wear_report`, a gearbox's estimates with their trend and forecast.
* :mod:`.plot`: :func:`plot_wear`.
* :mod:`.series`: the bundled multi-day wear series.
"""

from .plot import plot_wear
from .report import WearReport, wear_report
from .series import WearSeries, bundled_wear_series
from .store import SCHEMA_VERSION, HistoryStore
from .track import GearboxTracker, TrackResult
from .trend import WearForecast, WearSummary, WearTrend, fit_trend, summarise
from .usage import UsageCounter

__all__ = [
    "SCHEMA_VERSION",
    "GearboxTracker",
    "HistoryStore",
    "TrackResult",
    "UsageCounter",
    "WearForecast",
    "WearReport",
    "WearSeries",
    "WearSummary",
    "WearTrend",
    "bundled_wear_series",
    "fit_trend",
    "plot_wear",
    "summarise",
    "wear_report",
]
