"""Run a fleet: one task per gearbox, on Dask (``dask.distributed``) or serially in this process.

Within one gearbox the logs run in order, in one task, so its estimator sees them as ``track``
would; gearboxes are independent and run in parallel. A task writes its rows and checkpoint to
the store as it goes (each estimate in one transaction with the checkpoint), so a worker killed
mid-log loses nothing: the scheduler gives the task to another worker (Dask's
``distributed.scheduler.allowed-failures``, 3 by default), and the task resumes the log from the
gearbox's checkpoint exactly as ``track`` run again does. A task that raises something other
than a reported error (the task returns those in its :class:`GearboxOutcome`) is retried
``retries`` times. The rows end identical to tracking every gearbox serially.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from .manifest import GearboxJob

#: ``task(job) -> GearboxOutcome``: tracks one gearbox (a module-level function, so Dask can send it).
GearboxTask = Callable[[GearboxJob], "GearboxOutcome"]
#: ``on_done(outcome)``: called in this process as each gearbox finishes, in the order they finish.
OutcomeCallback = Callable[["GearboxOutcome"], None]


@dataclass
class GearboxOutcome:
    """What the task of one gearbox did.

    Attributes
    ----------
    gearbox_id : str
        The gearbox.
    results : list
        One :class:`~online_backlash.tracking.TrackResult` per log, in the order tracked.
    error : str or None
        The error that stopped the gearbox (its logs before it are stored), None if none.
    elapsed_s : float
        Wall-clock seconds of the task (its last attempt).
    cpu_s : float
        CPU seconds of the task's process meanwhile (its last attempt).
    worker : str
        ``host:pid`` of the process that ran it.
    """

    gearbox_id: str
    results: list[Any] = field(default_factory=list)
    error: str | None = None
    elapsed_s: float = 0.0
    cpu_s: float = 0.0
    worker: str = ""

    @property
    def samples_fed(self) -> int:
        """Samples fed to the estimator by this task."""
        return sum(int(r.samples_fed) for r in self.results)


def default_workers() -> int:
    """Workers of a local cluster when none are asked for: the machine's cores."""
    return os.cpu_count() or 1


def run_fleet(
    jobs: Sequence[GearboxJob],
    task: GearboxTask,
    workers: int | None = None,
    scheduler: str | None = None,
    on_done: OutcomeCallback | None = None,
    retries: int = 2,
) -> list[GearboxOutcome]:
    """Track every gearbox of a fleet; returns their outcomes in the order of ``jobs``.

    Parameters
    ----------
    jobs : sequence of GearboxJob
        The gearboxes (:func:`~online_backlash.fleet.load_manifest`).
    task : callable
        ``task(job) -> GearboxOutcome``, importable by the workers (it is sent by reference).
    workers : int, optional
        Worker processes of a local cluster (one thread each); default :func:`default_workers`;
        0 runs the gearboxes one after another in this process, without Dask.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://HOST:PORT``) to use instead of a local cluster;
        its workers must reach the logs and the store under the same paths and URL.
    on_done : callable, optional
        ``on_done(outcome)`` as each gearbox finishes.
    retries : int
        Retries of a task that raised (a worker lost meanwhile is handled by the scheduler).
    """
    if workers is not None and workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    if scheduler is None and workers == 0:
        outcomes = []
        for job in jobs:
            outcomes.append(task(job))
            if on_done is not None:
                on_done(outcomes[-1])
        return outcomes
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        n = workers or default_workers()
        cluster = LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=logging.ERROR
        )
    try:
        with Client(cluster if cluster is not None else scheduler) as client:
            futures = {
                client.submit(task, job, key=f"track-{job.id}", retries=retries, pure=False): job.id for job in jobs
            }
            done: dict[str, GearboxOutcome] = {}
            for future in as_completed(futures):
                outcome = future.result()
                done[futures[future]] = outcome
                if on_done is not None:
                    on_done(outcome)
    finally:
        if cluster is not None:
            cluster.close()
    return [done[job.id] for job in jobs]
