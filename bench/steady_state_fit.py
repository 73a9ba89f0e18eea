"""``fit_recursive`` of the 10-million-sample Parquet and MDF4 files in one long-running process, beside ``learn_many``.

``bench/measurement_files.py`` times every case in a fresh interpreter, so its "warm" rows
still load the readers' and the bookkeeping's compiled loops (numba's cache) and touch new
memory inside the timing. A long-running process (``track`` over a folder of logs, a fleet
worker) reads one log after another; this script times that: the files that
``bench/measurement_files.py`` writes are fitted several times in one process, interleaved
with the reference (``BacklashRLS.learn_many`` on the same samples in memory, blocks of 262,144),
with the per-block bookkeeping (the play's per-cycle scatter, the dwell test) on the estimator's
thread (``BOOKKEEPING_AHEAD = 0``) and in its ordered worker thread (the default), both with the
file read one block ahead in a reader thread, after one untimed fit of each file (the readers'
compiled checks loaded). Prints the fastest, median and slowest of each, the share of
``learn_many``'s rate in the fastest run and in the worst round (each run against the reference
of its own round; the target is every round), and the median CPU seconds of each part (``time.thread_time`` of the
estimator's thread, of the reader thread and of the bookkeeping thread; the rest of the process's CPU time is the
readers' libraries' own threads: pyarrow decodes in its pool). Against the wall time, the CPU time says how well the
parts overlapped: on a loaded machine (the load average is printed) they cannot.

    python bench/measurement_files.py --repeat 1   # writes the files once (kept in /tmp)
    python bench/steady_state_fit.py [--rounds 4] [--dir /tmp] [--samples 10000000]
"""

from __future__ import annotations

import argparse
import functools
import os
import threading
import time
from collections.abc import Callable

import numpy as np

import online_backlash.log_fit as log_fit
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

    for (
        open_log
    ) in logs.values():  # the readers' compiled checks loaded from numba's cache: a process that has read before
        _fit(open_log)
    times: dict[str, list[tuple[float, ...]]] = {}
    load_start = os.getloadavg()[0]
    for _ in range(args.rounds):
        times.setdefault("`learn_many`, samples in memory (reference)", []).append(_timed(reference))
        for kind, open_log in logs.items():
            for depth, where in ((0, "on the estimator's thread"), (log_fit.BOOKKEEPING_AHEAD, "in the worker thread")):
                saved, log_fit.BOOKKEEPING_AHEAD = log_fit.BOOKKEEPING_AHEAD, depth
                try:
                    times.setdefault(f"{kind}, bookkeeping {where}", []).append(
                        _timed(functools.partial(_fit, open_log))
                    )
                finally:
                    log_fit.BOOKKEEPING_AHEAD = saved
    references = [t[0] for t in next(iter(times.values()))]
    best_reference = min(references)
    print(
        f"{os.cpu_count()} cores, load average {load_start:.1f} at the start, {os.getloadavg()[0]:.1f} at the end, "
        f"{args.rounds} rounds"
    )
    print(
        "| what | fastest, s | median, s | slowest, s | vs learn_many (fastest) | (worst round) "
        "| CPU s: process | estimator thread | reader thread | bookkeeping thread | library threads |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, rounds in times.items():
        walls = sorted(t[0] for t in rounds)
        cpu = [sorted(t[i] for t in rounds)[len(rounds) // 2] for i in range(1, 6)]
        print(
            f"| {name} | {walls[0]:.3f} | {walls[len(walls) // 2]:.3f} | {walls[-1]:.3f} | "
            f"{best_reference / walls[0]:.0%} "
            f"| {min(r / t[0] for r, t in zip(references, rounds)):.0%} | " + " | ".join(f"{c:.3f}" for c in cpu) + " |"
        )


#: CPU seconds of each finished thread of the library, by its name (``time.thread_time`` at its end)
_THREAD_CPU: dict[str, float] = {}
_run = threading.Thread.run


def _run_and_count(self: threading.Thread) -> None:
    try:
        _run(self)
    finally:
        _THREAD_CPU[self.name] = _THREAD_CPU.get(self.name, 0.0) + time.thread_time()


threading.Thread.run = _run_and_count  # type: ignore[method-assign]


def _fit(open_log: Callable[[], MdfLog | ParquetLog]) -> None:
    with open_log() as log:
        log_fit.fit_recursive(log.iter_chunks(), 30.0, ahead=1)


def _timed(call: Callable[[], None]) -> tuple[float, ...]:
    """Wall s, and CPU s of the process, this thread, the reader thread, the bookkeeping thread and the rest."""
    _THREAD_CPU.clear()
    wall, process, own = time.perf_counter(), time.process_time(), time.thread_time()
    call()
    wall, process, own = time.perf_counter() - wall, time.process_time() - process, time.thread_time() - own
    reader, books = (
        _THREAD_CPU.get("online-backlash-read-ahead", 0.0),
        _THREAD_CPU.get("online-backlash-bookkeeping", 0.0),
    )
    return wall, process, own, reader, books, process - own - reader - books


if __name__ == "__main__":
    main()
