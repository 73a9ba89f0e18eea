"""``fit_recursive`` of the 10-million-sample Parquet and MDF4 files in one long-running process, beside ``learn_many``.

``bench/measurement_files.py`` times every case in a fresh interpreter, so its "warm" rows
still load the readers' and the bookkeeping's compiled loops (numba's cache) and touch new
memory inside the timing. A long-running process (``track`` over a folder of logs, a fleet
worker) reads one log after another; this script times that: the files that
``bench/measurement_files.py`` writes are fitted several times in one process, interleaved
with the reference (``BacklashRLS.learn_many`` on the same samples in memory, blocks of 262,144),
with the per-block bookkeeping (the play's per-cycle scatter, the dwell test) on the estimator's
thread (``BOOKKEEPING_AHEAD = 0``) and in its ordered worker thread (the default), both with the
file read one block ahead in a reader thread. Prints the fastest and median of each.

    python bench/measurement_files.py --repeat 1   # writes the files once (kept in /tmp)
    python bench/steady_state_fit.py [--rounds 4] [--dir /tmp] [--samples 10000000]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import online_backlash.fitting as fitting
from online_backlash import BacklashRLS
from online_backlash.replay.mdf import MdfLog
from online_backlash.replay.parquet import ParquetLog


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--dir", default="/tmp")
    ap.add_argument("--samples", type=int, default=10_000_000)
    args = ap.parse_args()
    stem = os.path.join(args.dir, f"online-backlash-rig-{args.samples}")
    logs = {
        "MDF4": lambda: MdfLog(stem + ".mf4", columns={"motor": "Motor", "load": "Load"}),
        "Parquet": lambda: ParquetLog(stem + ".parquet"),
    }
    with logs["MDF4"]() as log:
        chunks = list(log.iter_chunks())
    u = np.concatenate([c.motor_deg for c in chunks]) / 30.0
    y = np.concatenate([c.load_deg for c in chunks])
    del chunks
    BacklashRLS().learn_many(u[:20000], y[:20000])  # numba's cache load, outside the timing

    def reference() -> None:
        est = BacklashRLS()
        for i in range(0, u.size, 262144):
            est.learn_many(u[i : i + 262144], y[i : i + 262144])

    times: dict[str, list[float]] = {}
    for _ in range(args.rounds):
        t = time.perf_counter()
        reference()
        times.setdefault("`learn_many`, samples in memory (reference)", []).append(time.perf_counter() - t)
        for kind, open_log in logs.items():
            for depth, where in ((0, "on the estimator's thread"), (fitting.BOOKKEEPING_AHEAD, "in the worker thread")):
                saved, fitting.BOOKKEEPING_AHEAD = fitting.BOOKKEEPING_AHEAD, depth
                try:
                    t = time.perf_counter()
                    with open_log() as log:
                        fitting.fit_recursive(log.iter_chunks(), 30.0, ahead=1)
                    times.setdefault(f"{kind}, bookkeeping {where}", []).append(time.perf_counter() - t)
                finally:
                    fitting.BOOKKEEPING_AHEAD = saved
    best_reference = min(next(iter(times.values())))
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end, {args.rounds} rounds")
    print("| what | fastest, s | median, s | vs learn_many (fastest) |")
    print("|---|---:|---:|---:|")
    for name, values in times.items():
        values.sort()
        print(f"| {name} | {values[0]:.3f} | {values[len(values) // 2]:.3f} | {best_reference / values[0]:.0%} |")


if __name__ == "__main__":
    main()
