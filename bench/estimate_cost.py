"""Where ``estimate FILE --json`` spends its CPU beyond start-up, piece by piece, in one process (issue 31 item 1).

The path of ``estimate`` without ``--trace`` (:func:`online_backlash.log_fit.fit_recursive` with the reader thread,
``ahead=READ_AHEAD``, as ``cli/estimate.py`` calls it) on a file ``bench/end_to_end.py`` writes (run that first),
after a run on the 2,000-sample file of the same format (numba's cache loads, the imports: start-up, not timed).
Each piece is timed by the CPU time of the thread that runs it (``time.thread_time``, around every call):

* reading: the reader's ``iter_chunks`` (reader thread), and referring each chunk (``Pipeline._refer``);
* the RLS loop (``_rls_kernels.backlash_run``: :class:`~online_backlash.estimators.BacklashRLS`'s compiled loop);
* the estimator's full-engagement judgement (``FullEngagement.update`` / ``fit`` on the estimator's thread, or
  on its judging thread) and the uncertainty's own (the same calls on the bookkeeping thread);
* the rest of the uncertainty (``kinematic_update``: the per-cycle plays), the dwell tracker
  (``DwellTracker.update``), the snapshots (``RecursivePlayScatter.snapshot``);
* the rest: the process's CPU time over the run less the pieces (the loop, the threads' hand-offs, the warm
  start's batch fit, the report).

Then ``BacklashRLS().learn_many`` and ``BacklashRLS(**log_fit.KINEMATIC).learn_many`` on the same samples in
memory, in the same process (the denominators of issue 31's aim). ``--repeat`` runs it all that many times.

    python bench/estimate_cost.py [--big /tmp/online-backlash-e2e/rig-10000000.arrow] [--repeat 2]
"""

from __future__ import annotations

import argparse
import functools
import os
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from online_backlash import BacklashRLS, log_fit, pipeline
from online_backlash.estimators import _rls_kernels, uncertainty
from online_backlash.estimators.full_engagement import FullEngagement
from online_backlash.load_aware.observability import DwellTracker
from online_backlash.pipeline import READ_AHEAD
from online_backlash.replay import open_log

#: CPU seconds per piece, by name (summed over the threads that ran it)
SPENT: dict[str, float] = defaultdict(float)
_LOCK = threading.Lock()


def timed(name: str | Callable[[], str], fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` with the CPU time of its calls (the calling thread's) added to ``SPENT[name]``."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            spent = time.thread_time() - start
            key = name() if callable(name) else name
            with _LOCK:
                SPENT[key] += spent

    return wrapper


def _judge_name() -> str:
    """Whose judgement this is, by the thread that makes it: the estimator's (its own thread, or the judging
    thread of ``estimators/_judge_ahead.py``) or the uncertainty's (the bookkeeping thread)."""
    thread = threading.current_thread()
    if thread is threading.main_thread():
        return "full engagement (estimator)"
    if thread.name.startswith("online-backlash-judge"):
        return "full engagement (estimator, judging thread)"
    return "full engagement (uncertainty)"


def instrument() -> None:
    """Wrap the pieces (module docstring) with :func:`timed`."""
    _rls_kernels.backlash_run = timed("RLS loop (backlash_run)", _rls_kernels.backlash_run)
    FullEngagement.update = timed(_judge_name, FullEngagement.update)  # type: ignore[method-assign]
    FullEngagement.fit = timed(lambda: _judge_name() + ", fit", FullEngagement.fit)  # type: ignore[method-assign]
    uncertainty.kinematic_update = timed(
        "uncertainty: per-cycle plays (kinematic_update)", uncertainty.kinematic_update
    )
    DwellTracker.update = timed("dwell tracker", DwellTracker.update)  # type: ignore[method-assign]
    snapshot = uncertainty.RecursivePlayScatter.snapshot
    uncertainty.RecursivePlayScatter.snapshot = timed("snapshots", snapshot)  # type: ignore[method-assign]
    pipeline.Pipeline._refer = timed("reading: refer and check", pipeline.Pipeline._refer)  # type: ignore[method-assign]


def read_timed(chunks: Iterator[Any]) -> Iterator[Any]:
    """The chunks of a reader, the CPU time of each ``next`` added to ``SPENT["reading: the reader"]``."""
    while True:
        start = time.thread_time()
        chunk = next(chunks, None)
        with _LOCK:
            SPENT["reading: the reader"] += time.thread_time() - start
        if chunk is None:
            return
        yield chunk


def estimate(path: Path, options: dict[str, Any]) -> tuple[float, float, int]:
    """``estimate``'s recursive fit of ``path``: wall and process CPU seconds, samples."""
    wall, cpu = time.perf_counter(), time.process_time()
    with open_log(str(path), **options) as source:
        report, _ = log_fit.fit_recursive(read_timed(iter(source.iter_chunks())), 30.0, ahead=READ_AHEAD)
    return time.perf_counter() - wall, time.process_time() - cpu, report.samples


def arrays(path: Path, options: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The referred samples of ``path``, as the pipeline hands them (u = motor / 30, y), in memory."""
    with open_log(str(path), **options) as source:
        parts = [(c.motor_deg / 30.0, c.load_deg) for c in source.iter_chunks()]
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def learn_many_cpu(u: np.ndarray, y: np.ndarray, **options: Any) -> float:
    BacklashRLS(**options).learn_many(u[-20000:], y[-20000:])  # the compiled loop loaded, outside the timing
    start = time.process_time()
    BacklashRLS(**options).learn_many(u, y)
    return time.process_time() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--big", type=Path, default=Path("/tmp/online-backlash-e2e/rig-10000000.arrow"))
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    options = {"columns": {"motor": "Motor", "load": "Load"}} if args.big.suffix == ".mf4" else {}
    small = args.big.with_name(args.big.name.replace("rig-10000000", "rig-2000"))
    instrument()
    estimate(small, options)  # start-up: imports and numba's cache loads
    u, y = arrays(args.big, options)
    print(f"{args.big} ({u.size} samples), pid {os.getpid()}, load {os.getloadavg()[0]:.1f}")
    for rep in range(args.repeat):
        SPENT.clear()
        wall, cpu, n = estimate(args.big, options)
        pieces = dict(SPENT)
        bare = learn_many_cpu(u, y)
        configured = learn_many_cpu(u, y, **log_fit.KINEMATIC)
        print(f"\nrepetition {rep + 1}: estimate's fit {wall:.2f} s wall, {cpu:.3f} CPU-s, {n} samples")
        print("| piece | CPU s | per 10 M samples |\n|---|---:|---:|")
        for name, spent in sorted(pieces.items(), key=lambda kv: -kv[1]):
            print(f"| {name} | {spent:.3f} | {spent * 1e7 / n:.3f} |")
        rest = cpu - sum(pieces.values())
        print(f"| rest | {rest:.3f} | {rest * 1e7 / n:.3f} |\n| total | {cpu:.3f} | {cpu * 1e7 / n:.3f} |")
        print(f"learn_many in memory: BacklashRLS() {bare:.3f} CPU-s, as estimate sets it up {configured:.3f} CPU-s")


if __name__ == "__main__":
    main()
