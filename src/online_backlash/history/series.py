"""The multi-day wear series bundled with the package, and replaying it into a history store.

``src/online_backlash/data/wear/`` holds daily logs of one synthetic gearbox wearing and
``series.json`` describing them (gearbox id, ratio, limit, reader options, estimator settings
and the true wear), made by ``scripts/make_wear_series.py``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from typing import Any

from .store import HistoryStore
from .track import GearboxTracker, ProgressCallback, TrackResult


@dataclass(frozen=True)
class WearSeries:
    """A series of logs of one gearbox, in the order recorded, with its description.

    Attributes
    ----------
    manifest : dict
        The parsed ``series.json``: ``gearbox``, ``ratio``, ``limit_arcmin``, ``log_options``,
        ``estimator_params``, ``every_s``, ``true_rate_deg_per_hour``, ``true_hours_at_limit``, ``logs``.
    files : list
        The logs (``importlib.resources`` traversables).
    """

    manifest: dict[str, Any]
    files: list

    @property
    def gearbox(self) -> str:
        return self.manifest["gearbox"]

    def track(self, store: HistoryStore, progress: ProgressCallback | None = None) -> list[TrackResult]:
        """Track every log into ``store`` under the series' gearbox id (a log already there adds nothing)."""
        m = self.manifest
        tracker = GearboxTracker(
            store, m["gearbox"], m["ratio"], every_s=m["every_s"], limit_arcmin=m["limit_arcmin"], estimator_params=m["estimator_params"]
        )
        results = []
        for item in self.files:
            with resources.as_file(item) as path:
                results.append(tracker.track_log(path, m["log_options"], progress=progress))
        return results


def bundled_wear_series() -> WearSeries:
    """The series shipped in ``src/online_backlash/data/wear`` (12 daily 25 s logs, play 0.20 -> 0.30 deg)."""
    folder = resources.files("online_backlash") / "data" / "wear"
    manifest = json.loads((folder / "series.json").read_text(encoding="utf-8"))
    return WearSeries(manifest, [folder / log["file"] for log in manifest["logs"]])
