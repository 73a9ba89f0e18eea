"""The per-block bookkeeping of ``fit_recursive`` (play scatter, dwells) in a worker thread (issue 11, speed).

With a reader thread (``ahead`` > 0) the scatter and dwell updates run in an ordered worker
(:class:`~online_backlash.pipeline.OrderedWorker`), handed each block and a snapshot of the
estimate at that block (:meth:`RecursivePlayScatter.snapshot`). The results are bit for bit those
of the inline path (``ahead=0``) on logs with gaps and many ticks, also when the worker lags many
blocks behind (then the estimator has moved on and only the snapshot is right); an exception of
the worker is raised on the caller's thread.
"""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest
from davinci_runs import DAVINCI

from online_backlash import log_fit
from online_backlash.estimators import uncertainty
from online_backlash.estimators.uncertainty import RecursivePlayScatter
from online_backlash.log_fit import fit_recursive
from online_backlash.output_columns import EstimateRow
from online_backlash.pipeline import OrderedWorker, Pipeline
from online_backlash.replay.csv import CsvLog
from online_backlash.simulation.rig import simulate_rig
from online_backlash.stream import SampleChunk

COUNTS = {"units": "counts", "motor_cpr": 4096 * 35, "load_cpr": 8192}


def _gapped_chunks(seed: int = 4, size: int = 2_777) -> list[SampleChunk]:
    """A 90 s rig log at 1 kHz with a bridged gap (a few missing samples), a long gap (10 s, restart) and
    a clock that repeats, cut into chunks of ``size`` samples."""
    rec = simulate_rig(90.0, ratio=30.0, play_deg=0.4, seed=seed)
    n = rec.time_s.size
    keep = np.ones(n, dtype=bool)
    keep[20_000:20_003] = False  # 3 ms missing: bridged
    time_s = rec.time_s.copy()
    time_s[50_000:] += 10.0  # 10 s missing: the estimator restarts
    time_s[70_000] = time_s[69_999]  # a repeated timestamp
    after_gap = np.zeros(n, dtype=bool)
    after_gap[20_003] = after_gap[50_000] = True
    whole = SampleChunk(
        time_s[keep], rec.motor_deg[keep], rec.load_deg[keep], np.full(keep.sum(), np.nan), after_gap[keep]
    )
    return [whole.slice(i, min(i + size, len(whole))) for i in range(0, len(whole), size)]


def _fit(chunks, ahead: int, every_s: float | None = 0.7, ratio: float = 30.0) -> tuple[str, list[str]]:
    """The report (``as_dict`` as JSON text: NaN compared as text, floats by repr) and the trace rows
    (every ``every_s`` s of data; None: no trace, only the scatter's ticks)."""
    rows: list[EstimateRow] = []
    trace = rows.append if every_s is not None else None
    report, _ = fit_recursive(chunks, ratio, every_s=every_s or 1.0, trace=trace, ahead=ahead)
    return json.dumps(report.as_dict(), sort_keys=True), [json.dumps(r.trace(), sort_keys=True) for r in rows]


def _slow_books(monkeypatch, threads: set[str], delay_s: float = 0.002) -> None:
    """Make the bookkeeping slow (so the worker lags) and note the threads it runs on."""
    keep = log_fit._update_scatter

    def slow(*args, **kwargs):
        threads.add(threading.current_thread().name)
        time.sleep(delay_s)
        keep(*args, **kwargs)

    monkeypatch.setattr(log_fit, "_update_scatter", slow)


@pytest.mark.parametrize("every_s", [0.7, None], ids=["trace", "ticks-only"])
def test_threaded_bookkeeping_equals_inline_on_a_log_with_gaps(every_s):
    chunks = _gapped_chunks()
    inline_report, inline_rows = _fit(chunks, 0, every_s)
    threaded_report, threaded_rows = _fit(chunks, 1, every_s)
    assert threaded_report == inline_report
    assert threaded_rows == inline_rows
    report = json.loads(inline_report)
    assert report["backlash_std_deg"] is not None  # the scatter was measured
    assert report["gaps_bridged"] == 1 and report["gap_longest_s"] > 9.0  # both gaps were seen
    if every_s is not None:
        assert len(inline_rows) > 60  # many ticks


def _scatters(monkeypatch) -> list[RecursivePlayScatter]:
    """The :class:`RecursivePlayScatter` of each fit from now on, to compare their per-cycle plays."""
    made: list[RecursivePlayScatter] = []

    def keep(est):
        made.append(RecursivePlayScatter(est))
        return made[-1]

    monkeypatch.setattr(log_fit, "RecursivePlayScatter", keep)
    return made


def test_a_worker_far_behind_the_estimator_still_reads_the_estimate_of_its_tick(monkeypatch):
    chunks = _gapped_chunks(seed=7, size=1_013)
    scatters = _scatters(monkeypatch)
    expected = _fit(chunks, 0)
    threads: set[str] = set()
    _slow_books(monkeypatch, threads)
    monkeypatch.setattr(log_fit, "BOOKKEEPING_AHEAD", 64)  # the estimator runs up to 64 blocks ahead
    assert _fit(chunks, 1) == expected
    assert threads == {"online-backlash-bookkeeping"}  # not the caller's thread: the threaded path ran
    inline, threaded = scatters
    assert (
        inline.scatter.plays_deg.size >= 10
        and inline.scatter.plays_deg.tobytes() == threaded.scatter.plays_deg.tobytes()
    )
    assert inline.scatter.noise_var_deg2.tobytes() == threaded.scatter.noise_var_deg2.tobytes()


def test_the_scatter_gives_up_before_the_start_as_inline_does(monkeypatch):
    """More samples held before the estimator starts than the scatter keeps: it gives up at the same block."""
    monkeypatch.setattr(uncertainty, "MAX_HELD_SAMPLES", 5_000)  # the warm start takes 10 s: 10 000 samples
    chunks = _gapped_chunks(size=1_013)
    scatters = _scatters(monkeypatch)
    expected = _fit(chunks, 0, every_s=None)
    _slow_books(monkeypatch, set())
    monkeypatch.setattr(log_fit, "BOOKKEEPING_AHEAD", 64)
    assert _fit(chunks, 1, every_s=None) == expected
    assert [s.scatter.plays_deg.size for s in scatters] == [0, 0]  # given up in both


def test_a_late_reader_of_the_estimator_would_differ():
    """The snapshot matters: measured with the final estimate instead of each tick's, the plays differ."""
    chunks = _gapped_chunks()
    est = log_fit.recursive_estimator(chunks[0], 30.0)
    pipeline = Pipeline(est, 30.0, 0.7)
    on_time, late = RecursivePlayScatter(est), RecursivePlayScatter(est)
    steps = []
    for step in pipeline.run(chunks):
        on_time.update(step.u_deg, step.chunk.load_deg, step.chunk.after_gap, due=step.due, estimate=on_time.snapshot())
        steps.append(step)
    for step in steps:  # the estimator has learned the whole log by now
        late.update(step.u_deg, step.chunk.load_deg, step.chunk.after_gap, due=step.due)
    assert on_time.scatter.plays_deg.size >= 10
    assert on_time.scatter.plays_deg.tobytes() != late.scatter.plays_deg.tobytes()


@pytest.mark.parametrize("name", ["tool4_L_run00_0.1Hz_torque10pct.csv", "tool4_L_run20_0.3Hz_torque10pct.csv"])
@pytest.mark.parametrize("torque", [False, True], ids=["kinematic", "torque"])
def test_threaded_equals_inline_on_measured_runs(name, torque):
    columns = {"time": "time_s", "motor": "motor_counts", "load": "spindle_counts"}
    if torque:
        columns["torque"] = "backend_torque_Nm"
    results = []
    for ahead in (0, 1):
        with CsvLog(DAVINCI / name, columns=columns, block_rows=1_500, **COUNTS) as log:
            results.append(_fit(log.iter_chunks(), ahead, every_s=0.5, ratio=-1.0))
    assert results[0] == results[1]
    assert len(results[0][1]) > 10


def test_an_error_in_the_worker_is_raised_on_the_callers_thread(monkeypatch):
    calls = []

    def broken(*args, **kwargs):
        calls.append(threading.current_thread().name)
        if len(calls) == 3:
            raise RuntimeError("bookkeeping failed at block 3")

    monkeypatch.setattr(log_fit, "_update_scatter", broken)
    with pytest.raises(RuntimeError, match="block 3"):
        fit_recursive(_gapped_chunks(), 30.0, ahead=1)
    assert calls[0] == "online-backlash-bookkeeping" and len(calls) == 3  # the blocks after the failure are skipped
    assert not any(t.name == "online-backlash-bookkeeping" for t in threading.enumerate())  # joined


def test_ordered_worker_keeps_the_order_and_joins():
    seen: list[int] = []
    with OrderedWorker(2) as worker:
        for i in range(200):
            worker.call(seen.append, i)
    assert seen == list(range(200))
    inline: list[str] = []
    OrderedWorker(0).call(lambda: inline.append(threading.current_thread().name))
    assert inline == [threading.current_thread().name]


def test_ordered_worker_raises_at_the_next_call_or_join_and_drops_calls_when_the_caller_fails():
    def fail() -> None:
        raise ValueError("bad block")

    worker = OrderedWorker(1)
    worker.call(fail)
    with pytest.raises(ValueError, match="bad block"):
        worker.join()
    seen: list[int] = []
    with pytest.raises(KeyError):
        with OrderedWorker(4) as worker:
            worker.call(worker.stopped.wait)  # busy until the caller has failed
            for i in range(3):
                worker.call(seen.append, i)
            raise KeyError("caller failed")
    assert seen == []  # the calls queued when the caller failed were dropped
