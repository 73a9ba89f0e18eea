"""``GET /metrics`` of ``serve``: the fleet's gauges in the Prometheus text format (``prometheus_client``).

A custom collector (:class:`StoreCollector`) reads the store on every scrape, so a scrape always
shows what ``history --json`` would print at that moment (:mod:`online_backlash.history.gauges`):

=========================================================  ===================================================
``online_backlash_play_arcmin{gearbox="ID"}``               the latest observable play, arcmin
``online_backlash_play_std_arcmin{gearbox="ID"}``           its standard error, arcmin
``online_backlash_state{gearbox="ID",state="S"}``           1 for the gearbox's state, 0 for the other three
``online_backlash_hours_to_limit{gearbox="ID"}``            operating hours until the trend reaches the limit
                                                            (``+Inf``: it does not)
``online_backlash_last_estimate_age_seconds{gearbox="ID"}`` seconds since the newest estimate
``online_backlash_play_observable{gearbox="ID"}``           1 if the newest estimate's data showed the play
``online_backlash_warn_arcmin``, ``..._limit_arcmin``       the levels the state is checked against, arcmin
=========================================================  ===================================================

A figure that is not known (no estimate yet, no limit, no forecast) has no sample: Prometheus
reads a missing sample as "no data", never as a number.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector, CollectorRegistry

from ..history.alarms import STATES
from ..history.gauges import GearboxGauges, gearbox_gauges
from ..history.report import wear_report
from ..history.store import HistoryStore

PREFIX = "online_backlash_"

#: name (without the prefix) -> (help text, the gauge's attribute).
GAUGES = {
    "play_arcmin": ("latest observable play (backlash) of the gearbox, arcmin", "play_arcmin"),
    "play_std_arcmin": ("standard error of that play, arcmin", "play_std_arcmin"),
    "hours_to_limit": ("operating hours until the wear trend reaches the limit (+Inf: it does not)", "hours_to_limit"),
    "last_estimate_age_seconds": ("seconds since the newest estimate of the gearbox", "last_estimate_age_s"),
    "play_observable": ("1 if the newest estimate's data showed the play, else 0", "play_observable"),
    "warn_arcmin": ("warning level of the play, arcmin", "warn_arcmin"),
    "limit_arcmin": ("limit of the play, arcmin", "limit_arcmin"),
}


class StoreCollector(Collector):
    """Every gearbox's gauges, read from ``store`` at each scrape; ``max_age_h`` as in ``history --max-age-h``."""

    def __init__(self, store: HistoryStore, max_age_h: float) -> None:
        self.store = store
        self.max_age_h = max_age_h

    def collect(self) -> Iterator[GaugeMetricFamily]:
        now = time.time()
        reports = (
            wear_report(self.store, g, max_age_h=self.max_age_h, now_unix_s=now) for g in self.store.gearbox_ids()
        )
        fleet = [gearbox_gauges(report) for report in reports]
        for name, (doc, attribute) in GAUGES.items():
            family = GaugeMetricFamily(PREFIX + name, doc, labels=["gearbox"])
            for gauges in fleet:
                value = getattr(gauges, attribute)
                if value is not None:
                    family.add_metric([gauges.gearbox], float(value))
            yield family
        yield _states(fleet)


def _states(fleet: list[GearboxGauges]) -> GaugeMetricFamily:
    doc = "alarm state of the gearbox as in history --check: 1 for its state, 0 for the others"
    family = GaugeMetricFamily(PREFIX + "state", doc, labels=["gearbox", "state"])
    for gauges in fleet:
        for state in STATES:
            family.add_metric([gauges.gearbox, state], 1.0 if gauges.state == state else 0.0)
    return family


def metrics_text(store: HistoryStore, max_age_h: float) -> bytes:
    """The scrape of ``store`` in the Prometheus text format."""
    from prometheus_client import generate_latest

    registry = CollectorRegistry(auto_describe=False)
    registry.register(StoreCollector(store, max_age_h))
    return generate_latest(registry)
