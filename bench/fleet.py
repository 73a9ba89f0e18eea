"""The fleet on Dask: a task's CPU against the same gearbox tracked in-process, 1 worker against 2, the same rows.

A fleet of simulated rigs (``--gearboxes`` gearboxes x ``--logs`` daily CSV logs of ``--seconds``
seconds at 1 kHz, UNIX times, play growing per gearbox) and its manifest are written to a
temporary folder; then the fleet is tracked into a fresh SQLite store by what ``online-backlash
track --manifest`` runs (:func:`online_backlash.fleet.run_fleet` with the CLI's task), serially
in this process (``--workers 0``) and on Dask ``LocalCluster``s of 1 and 2 worker processes (one
thread each), given to ``run_fleet`` as running schedulers (as ``--scheduler`` does). The clusters are
started once; every process first tracks a warm-up fleet of the same kind (imports, numba's compiled
loops loaded: its logs are long enough to start the estimator), untimed. Then ``--rounds`` rounds, each
tracking the fleet serially, on 1 worker and on 2, one after another (the compared runs meet the same
machine). Each run's rows are compared with the first serial run's.

Per run: the wall time of ``run_fleet``, the fleet's samples per second and the speed-up over the
serial run of the same round, and the sum of the tasks' CPU seconds (each task's process CPU while it
ran, :attr:`~online_backlash.fleet.GearboxOutcome.cpu_s`) against the serial run's of the same round:
what a Dask task costs beyond the same gearbox tracked in the CLI's process. Medians of the rounds,
the range beside them; the 1-minute load average at the start and end.

    python bench/fleet.py [--gearboxes 4] [--logs 3] [--seconds 120] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

from dask.distributed import LocalCluster

from online_backlash.cli.track import parse_track_argv, track_command_line_options, track_defaults, track_gearbox
from online_backlash.fleet import load_manifest, run_fleet
from online_backlash.fleet.simulated import write_simulated_fleet
from online_backlash.history.store import HistoryStore


def rows(db: Path) -> dict:
    """Every stored estimate (sample, time, play, hours) of every gearbox."""
    with HistoryStore(db) as store:
        return {
            g: [(e.sample_index, e.time_unix_s, e.backlash_deg, e.operating_hours) for e in store.estimates(g)]
            for g in store.gearbox_ids()
        }


def track_fleet(manifest: Path, db: Path, address: str | None) -> list:
    """The fleet into a fresh store ``db``: serially here (``address`` None) or on the scheduler at ``address``."""
    jobs = load_manifest(manifest, str(db), parse_track_argv, track_defaults(), track_command_line_options())
    with HistoryStore(db, create=True):
        pass
    outcomes = run_fleet(jobs, track_gearbox, workers=0 if address is None else None, scheduler=address)
    errors = [o.error for o in outcomes if o.error]
    if errors:
        raise SystemExit(f"{address or 'serial'}: {errors}")
    return outcomes


def spread(values: list[float], fmt: str = "{:.2f}") -> str:
    """The median with the range of ``values``."""
    return f"{fmt.format(statistics.median(values))} ({fmt.format(min(values))}-{fmt.format(max(values))})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--gearboxes", type=int, default=4)
    parser.add_argument("--logs", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--rounds", type=int, default=3)
    opts = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        manifest = write_simulated_fleet(folder / "fleet", opts.gearboxes, opts.logs, opts.seconds, every_s=10.0)
        warm = write_simulated_fleet(folder / "warm", 2, 1, 20.0, every_s=10.0)
        samples = round(opts.gearboxes * opts.logs * opts.seconds * 1000)
        load = [os.getloadavg()[0]]
        started = time.perf_counter()
        clusters = {
            n: LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0") for n in (1, 2)
        }
        try:
            addresses = {0: None, **{n: c.scheduler_address for n, c in clusters.items()}}
            for n, address in addresses.items():  # every process: imports, compiled loops loaded
                for k in range(max(n, 1)):
                    track_fleet(warm, folder / f"warm-{n}-{k}.db", address)
            ready = time.perf_counter() - started
            runs: dict[int, list[tuple[float, float, int]]] = {n: [] for n in addresses}
            reference = None
            for r in range(opts.rounds):
                for n, address in addresses.items():
                    db = folder / f"round{r}-{n}.db"
                    wall = time.perf_counter()
                    outcomes = track_fleet(manifest, db, address)
                    wall = time.perf_counter() - wall
                    got = rows(db)
                    reference = got if reference is None else reference
                    runs[n].append((wall, sum(o.cpu_s for o in outcomes), got == reference))
        finally:
            for cluster in clusters.values():
                cluster.close()
        load.append(os.getloadavg()[0])
    print(
        f"fleet: {opts.gearboxes} gearboxes x {opts.logs} logs x {opts.seconds:g} s at 1 kHz = {samples:,} samples; "
        f"{opts.rounds} rounds"
    )
    print(
        f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, load average "
        f"{load[0]:.1f} at the start, {load[1]:.1f} at the end; clusters started and warmed in {ready:.1f} s\n"
    )
    print(
        "| run | tracking wall s | samples/s (wall) | speed-up over serial | sum of task CPU s | task CPU / in-process "
        "| rows equal to serial |"
    )
    print("|---|---:|---:|---:|---:|---:|---|")
    serial = runs[0]
    for n, got in runs.items():
        label = "serial (--workers 0)" if n == 0 else f"Dask LocalCluster, {n} worker{'s' if n > 1 else ''}"
        walls, cpus = [w for w, _, _ in got], [c for _, c, _ in got]
        print(
            f"| {label} | {spread(walls)} | {spread([samples / w for w in walls], '{:,.0f}')} "
            f"| {spread([s[0] / w for s, w in zip(serial, walls)])} | {spread(cpus)} "
            f"| {spread([c / s[1] for s, c in zip(serial, cpus)])} | {all(e for _, _, e in got)} |"
        )


if __name__ == "__main__":
    main()
