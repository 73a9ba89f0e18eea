"""The fleet on Dask: 1 worker against 2 on this machine, the same fleet, the same rows.

A fleet of simulated rigs (``--gearboxes`` gearboxes x ``--logs`` daily CSV logs of ``--seconds``
seconds at 1 kHz, UNIX times, play growing per gearbox) and its manifest are written to a
temporary folder; then the fleet is tracked into a fresh SQLite store by what ``online-backlash
track --manifest`` runs (:func:`online_backlash.fleet.run_fleet` with the CLI's task), serially
in this process and on a Dask ``LocalCluster`` of 1 and 2 worker processes (one thread each),
given to ``run_fleet`` as a running scheduler (as ``--scheduler`` does). Each run first tracks a
small warm-up fleet (every process imports the package and compiles the estimator's kernels),
timed with the cluster's start; then the fleet is timed. The stores' rows are compared with the
serial one. The CPU seconds of the tasks show the work done, which does not depend on how busy
the machine is; the wall times do.

    python bench/fleet.py [--gearboxes 4] [--logs 3] [--seconds 120]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

from dask.distributed import LocalCluster

from online_backlash.cli.track import parse_track_argv, track_defaults, track_gearbox
from online_backlash.fleet import load_manifest, run_fleet
from online_backlash.fleet.simulated import write_simulated_fleet
from online_backlash.history.store import HistoryStore


def rows(db: Path) -> dict:
    with HistoryStore(db) as store:
        return {g: [(e.sample_index, e.time_unix_s, e.backlash_deg, e.operating_hours) for e in store.estimates(g)] for g in store.gearbox_ids()}


def track_fleet(manifest: Path, db: Path, workers: int, address: str | None) -> list:
    jobs = load_manifest(manifest, str(db), parse_track_argv, track_defaults())
    with HistoryStore(db, create=True):
        pass
    outcomes = run_fleet(jobs, track_gearbox, workers=workers if address is None else None, scheduler=address)
    errors = [o.error for o in outcomes if o.error]
    if errors:
        raise SystemExit(f"{workers} workers: {errors}")
    return outcomes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--gearboxes", type=int, default=4)
    parser.add_argument("--logs", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=120.0)
    opts = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        manifest = write_simulated_fleet(folder / "fleet", opts.gearboxes, opts.logs, opts.seconds, every_s=10.0)
        warm = write_simulated_fleet(folder / "warm", 2, 1, 5.0, every_s=1.0)
        samples = round(opts.gearboxes * opts.logs * opts.seconds * 1000)
        print(f"fleet: {opts.gearboxes} gearboxes x {opts.logs} logs x {opts.seconds:g} s at 1 kHz = {samples:,} samples")
        load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
        print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, load average {load}")
        print()
        print("| run | start + warm-up s | tracking wall s | samples/s (wall) | speed-up | sum of task s | sum of task CPU s | rows equal to serial |")
        print("|---|---:|---:|---:|---:|---:|---:|---|")
        reference, serial_s = None, None
        for workers in (0, 1, 2):
            started = time.perf_counter()
            cluster = None if workers == 0 else LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0")
            try:
                address = None if cluster is None else cluster.scheduler_address
                track_fleet(warm, folder / f"warm{workers}.db", workers, address)  # imports and compiles in every process
                ready = time.perf_counter()
                outcomes = track_fleet(manifest, folder / f"w{workers}.db", workers, address)
                wall = time.perf_counter() - ready
            finally:
                if cluster is not None:
                    cluster.close()
            fed = sum(o.samples_fed for o in outcomes)
            got = rows(folder / f"w{workers}.db")
            reference = got if reference is None else reference
            serial_s = wall if serial_s is None else serial_s
            label = "serial (--workers 0)" if workers == 0 else f"Dask LocalCluster, {workers} worker{'s' if workers > 1 else ''}"
            print(
                f"| {label} | {ready - started:.1f} | {wall:.1f} | {fed / wall:,.0f} | {serial_s / wall:.2f} | "
                f"{sum(o.elapsed_s for o in outcomes):.1f} | {sum(o.cpu_s for o in outcomes):.1f} | {got == reference} |"
            )


if __name__ == "__main__":
    main()
