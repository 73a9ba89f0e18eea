"""Wear history: a store of estimates per gearbox, usage, trend and forecast.

This package stores and reads rows; it never imports a reader or an estimator. Feeding a
gearbox's estimator from logs or a live source, with checkpoints in the store, is
:mod:`online_backlash.tracking` (above this package).

* :mod:`.store`: :class:`HistoryStore`, the SQLAlchemy schema (SQLite or PostgreSQL), schema
  version and migrations.
* :mod:`.usage`: :class:`UsageCounter`, operating hours, load revolutions and reversals.
* :mod:`.trend`: Theil-Sen trend, its confidence and prediction bands, and forecast.
* :mod:`.kalman`: the Kalman local linear trend (``history --trend kalman``).
* :mod:`.alarms`: alarm state ``ok | warning | alarm | unknown`` and the plugin line of ``history --check``.
* :mod:`.report`: :func:`wear_report`, a gearbox's estimates with their trend and forecast.
* :mod:`.plot`: :func:`plot_wear`.
* :mod:`.series`: the bundled multi-day wear series.
"""

from .alarms import AlarmStatus, evaluate_alarm
from .kalman import KalmanTrend, fit_kalman_trend
from .plot import plot_wear
from .report import WearReport, wear_report
from .series import WearSeries, bundled_wear_series
from .store import SCHEMA_VERSION, HistoryStore
from .trend import WearForecast, WearSummary, WearTrend, fit_trend, summarise
from .usage import UsageCounter

__all__ = [
    "SCHEMA_VERSION",
    "AlarmStatus",
    "HistoryStore",
    "KalmanTrend",
    "UsageCounter",
    "WearForecast",
    "WearReport",
    "WearSeries",
    "WearSummary",
    "WearTrend",
    "bundled_wear_series",
    "evaluate_alarm",
    "fit_kalman_trend",
    "fit_trend",
    "plot_wear",
    "summarise",
    "wear_report",
]
