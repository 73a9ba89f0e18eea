"""One gearbox's wear history as a report: its estimates, the trend and the forecast.

:func:`wear_report` reads the store and runs :func:`~online_backlash.history.trend.summarise`;
:meth:`WearReport.as_dict` is the JSON of ``online-backlash history --json`` (a contract: keys
``gearbox``, ``estimates`` with ``time``, ``backlash_deg``, ``backlash_std_deg``,
``operating_hours``, then ``trend_deg_per_hour``, ``forecast_hours_to_limit``,
``forecast_date``, ``state`` (:mod:`.alarms`), ``limit_exceeded_since``, ``n_observable``,
``n_not_observable``, and more). Estimates whose data did not show the play
(``play_observable`` false, e.g. a preloaded drive) are listed and counted but left out of the
trend, the forecast and the alarm state: their apparent play is a load condition, not wear.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import InvalidParameterError
from ..output_columns import ARCMIN_PER_DEG, HISTORY_CSV_COLUMNS, arcmin
from .alarms import DEFAULT_MAX_AGE_H, AlarmStatus, check_alarm_levels, evaluate_alarm
from .clock import Recording, recording
from .kalman import estimator_lag_hours
from .store import Estimate, Gearbox, HistoryStore, Run
from .trend import WearSummary, iso_time, summarise

__all__ = [
    "ARCMIN_PER_DEG",
    "HISTORY_CSV_COLUMNS",
    "WearReport",
    "estimate_column",
    "estimate_dict",
    "observable_mask",
    "wear_report",
]


def estimate_dict(e: Estimate) -> dict:
    """An estimate as a flat dict: ISO time, the stored columns, backlash also in arcmin
    (every column of ``history --csv``, :data:`~online_backlash.output_columns.HISTORY_CSV_COLUMNS`)."""
    d = asdict(e)
    d.pop("gearbox_id")
    return {
        "time": iso_time(e.time_unix_s),
        **d,
        "backlash_arcmin": arcmin(e.backlash_deg),
        "backlash_std_arcmin": arcmin(e.backlash_std_deg),
    }


@dataclass(frozen=True)
class WearReport:
    """A gearbox, its estimates in order of use, and their trend and forecast.

    ``limit_arcmin`` is the limit the forecast used (given, else the stored one, else None);
    ``status`` the alarm state against it and the warning level (:mod:`.alarms`) at ``now_unix_s``.
    """

    gearbox: Gearbox
    estimates: list[Estimate]
    limit_arcmin: float | None
    summary: WearSummary
    status: AlarmStatus
    now_unix_s: float

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
            "n_observable": int(self.observable.sum()),
            "n_not_observable": int(len(self.estimates) - self.observable.sum()),
            "estimates": self.rows(),
            **self.summary.as_dict(),
            **self.status_dict(),
        }

    def status_dict(self) -> dict:
        """``state``, ``state_reason``, ``play_arcmin``, ``warn_arcmin``, ``limit_exceeded_since`` (ISO, UTC),
        ``checked_at``."""
        s = self.status
        return {
            "state": s.state,
            "state_reason": s.reason,
            "play_arcmin": s.play_arcmin,
            "play_time": iso_time(s.play_time_unix_s),
            "warn_arcmin": s.warn_arcmin,
            "limit_exceeded_since": iso_time(s.limit_exceeded_since_unix_s),
            "checked_at": iso_time(self.now_unix_s),
        }

    @property
    def observable(self) -> np.ndarray:
        """Per estimate: did its data show the play (:func:`observable_mask`)? Only those make the trend."""
        return observable_mask(self.estimates)

    def column(self, name: str) -> np.ndarray:
        """One estimate column as a float array (None as NaN)."""
        return estimate_column(self.estimates, name)


def estimate_column(estimates: list[Estimate], name: str) -> np.ndarray:
    """Column ``name`` of the estimates as a float array (None as NaN)."""
    return np.array([np.nan if getattr(e, name) is None else getattr(e, name) for e in estimates], dtype=float)


def observable_mask(estimates: list[Estimate]) -> np.ndarray:
    """True for the estimates whose data showed the play (``play_observable``) and that hold one."""
    return np.array([bool(e.play_observable) and e.backlash_deg is not None for e in estimates], dtype=bool)


def logs_recording(runs: list[Run], estimates: list[Estimate]) -> Recording:
    """How much of the calendar a gearbox's logs recorded (:class:`~.clock.Recording`), from its runs' first and
    last samples (a run whose end is not stored: its last estimate)."""
    last_estimate: dict[int, float] = {}
    for e in estimates:
        last_estimate[e.run_id] = max(e.time_unix_s, last_estimate.get(e.run_id, -math.inf))
    starts, ends = [], []
    for r in runs:
        if r.started_unix_s is None:
            continue
        end = r.ended_unix_s if r.ended_unix_s is not None else last_estimate.get(r.id, r.started_unix_s)
        starts.append(r.started_unix_s)
        ends.append(end)
    return recording(np.array(starts), np.array(ends))


def estimator_lag(gearbox: Gearbox, estimates: list[Estimate]) -> float:
    """The lag of the gearbox's recursive estimator in operating hours (:func:`.kalman.estimator_lag_hours`).

    The memory settings come from the checkpoint's saved estimator settings (``params``, as
    ``state_dict`` writes them); the use per reversal from the last estimate. 0 if unknown.
    """
    params = ((gearbox.checkpoint or {}).get("estimator") or {}).get("params") or {}
    last = estimates[-1] if estimates else None
    per_reversal = last.operating_hours / last.reversals if last is not None and last.reversals > 0 else None
    return estimator_lag_hours(params.get("memory_reversals"), params.get("memory_s"), per_reversal)


def wear_report(
    store: HistoryStore,
    gearbox_id: str,
    limit_arcmin: float | None = None,
    confidence: float = 0.95,
    recent_days: float = 7.0,
    method: str = "theil-sen",
    warn_arcmin: float | None = None,
    now_unix_s: float | None = None,
    max_age_h: float = DEFAULT_MAX_AGE_H,
) -> WearReport:
    """Read a gearbox's history, fit its trend and find its alarm state.

    ``limit_arcmin`` and ``warn_arcmin`` override the stored levels; ``method`` is the trend
    (``theil-sen`` or ``kalman``, see :func:`~online_backlash.history.trend.summarise`);
    ``now_unix_s`` the present for the state (default: the wall clock) and ``max_age_h`` the age
    after which an estimate is no longer recent (:mod:`.alarms`). Raises HistoryError if the
    store does not hold ``gearbox_id``, InvalidParameterError if the levels are invalid.
    """
    gearbox = store.gearbox(gearbox_id)
    estimates = store.estimates(gearbox_id)
    limit = limit_arcmin if limit_arcmin is not None else gearbox.limit_arcmin
    warn = warn_arcmin if warn_arcmin is not None else gearbox.warn_arcmin
    try:
        check_alarm_levels(warn, limit)
    except InvalidParameterError as exc:
        raise InvalidParameterError(
            f"gearbox {gearbox.id!r} in {store.name}: {exc} (store valid levels with track "
            "--warn-arcmin/--limit-arcmin)"
        ) from exc
    names = ("time_unix_s", "operating_hours", "load_revolutions", "backlash_deg", "backlash_std_deg", "machine_hours")
    arrays = {name: estimate_column(estimates, name) for name in names}
    seen = observable_mask(estimates)
    summary = summarise(
        **arrays,
        limit_deg=None if limit is None else limit / ARCMIN_PER_DEG,
        confidence=confidence,
        recent_days=recent_days,
        method=method,
        lag_hours=estimator_lag(gearbox, estimates),
        observable=seen,
        recorded=logs_recording(store.runs(gearbox_id), estimates),
        group=np.array([e.run_id for e in estimates], dtype=np.int64),
    )
    now = time.time() if now_unix_s is None else now_unix_s
    play = np.where(seen, arrays["backlash_deg"], np.nan)  # a play not observed raises no alarm and clears none
    status = evaluate_alarm(arrays["time_unix_s"], play, arrays["backlash_std_deg"], warn, limit, now, max_age_h)
    return WearReport(gearbox, estimates, limit, summary, status, now)
