"""The multi-day wear series bundled with the package (:func:`online_backlash.tracking.track_series` replays it into a
store).

``src/online_backlash/data/wear/`` holds daily snapshot logs of one synthetic gearbox wearing,
with the machine's hour meter as a column, and ``series.json`` describing them (gearbox id,
ratio, limit, reader options, the hour-meter column, estimator settings and the true wear
against the machine's hours), made by ``scripts/make_wear_series.py``.
"""

from __future__ import annotations

import datetime as dt
import json
import math
from dataclasses import dataclass
from importlib import resources
from typing import Any


@dataclass(frozen=True)
class WearSeries:
    """A series of logs of one gearbox, in the order recorded, with its description.

    Attributes
    ----------
    manifest : dict
        The parsed ``series.json``: ``gearbox``, ``ratio``, ``limit_arcmin``, ``log_options``,
        ``hours_column`` (the hour meter), ``estimator_params``, ``every_s``, ``hours_per_day``,
        ``true_rate_deg_per_hour`` (per machine hour), ``true_hours_at_limit`` (the hour meter when
        the play reaches the limit), ``true_limit_date``, ``logs``.
    files : list
        The logs (``importlib.resources`` traversables).
    """

    manifest: dict[str, Any]
    files: list

    @property
    def gearbox(self) -> str:
        return self.manifest["gearbox"]

    def start_unix_s(self, item: Any) -> float:
        """Calendar time of the first sample of log ``item`` (one of :attr:`files`), UNIX seconds."""
        name = getattr(item, "name", str(item))
        start = next(log["start"] for log in self.manifest["logs"] if log["file"] == name)
        return dt.datetime.fromisoformat(start).timestamp()

    def shift_to_end_before(self, now_unix_s: float) -> float:
        """Whole days to move the series by so that its last log starts at most one day before ``now_unix_s``,
        seconds."""
        last = self.start_unix_s(self.files[-1])
        return math.floor((now_unix_s - last) / 86400.0) * 86400.0


def bundled_wear_series() -> WearSeries:
    """The series shipped in ``src/online_backlash/data/wear`` (60 daily 60 s snapshots, play 12 -> 18 arcmin)."""
    folder = resources.files("online_backlash") / "data" / "wear"
    manifest = json.loads((folder / "series.json").read_text(encoding="utf-8"))
    return WearSeries(manifest, [folder / log["file"] for log in manifest["logs"]])
