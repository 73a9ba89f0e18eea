"""The pipeline's fast path: the compiled data clock, ticks without rows, one finiteness check per chunk.

The clock's blocks equal those of the numpy reference below (the clock before it was compiled)
on streams with gaps, repeated and backward timestamps, cut anywhere; a pipeline that makes no
rows ticks at the same samples as one that does; a non-finite sample stops the pipeline before
the estimator sees any of its chunk.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from online_backlash import BacklashRLS, log_fit
from online_backlash.errors import InvalidParameterError
from online_backlash.estimators.uncertainty import SCATTER_EVERY_S, RecursivePlayScatter
from online_backlash.log_fit import fit_recursive
from online_backlash.pipeline import DataClock, Pipeline
from online_backlash.simulation.rig import simulate_rig
from online_backlash.stream import SampleChunk


def reference_blocks(
    clock: DataClock, time_s: np.ndarray, after_gap: np.ndarray
) -> list[tuple[int, int, bool, int, int | None]]:
    """The numpy clock: ``(start, end, due, data_ns, next_due_ns)`` per block, ``clock`` advanced."""
    out = []
    if clock.next_due_ns is None and clock.every_ns is not None:
        clock.next_due_ns = clock.data_ns + clock.every_ns
    previous = np.concatenate(([np.nan if clock.prev_time_s is None else clock.prev_time_s], time_s[:-1]))
    step = time_s - previous
    step[after_gap | ~(step > 0.0)] = 0.0
    data_ns = clock.data_ns + np.cumsum(np.rint(step * 1e9).astype(np.int64))
    n, start = time_s.size, 0
    while start < n:
        due_ns = clock.next_due_ns
        reach = n if due_ns is None else start + int(np.searchsorted(data_ns[start:], due_ns, side="left"))
        due = reach < n
        end = reach + 1 if due else n
        clock.data_ns, clock.prev_time_s = int(data_ns[end - 1]), float(time_s[end - 1])
        while due_ns is not None and clock.every_ns is not None and due_ns <= clock.data_ns:
            due_ns += clock.every_ns
        clock.next_due_ns = due_ns
        out.append((start, end, due, clock.data_ns, clock.next_due_ns))
        start = end
    return out


@pytest.mark.parametrize("seed", range(12))
def test_the_compiled_clock_cuts_where_the_numpy_clock_cut(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 20_000))
    steps = rng.choice(
        [1e-3, 1e-3, 1e-3, 0.0, -0.004, 0.25, 1e-3 / 3], size=n
    )  # repeats, a clock that went back, jumps
    time_s = 1000.0 + np.cumsum(steps)
    after_gap = rng.random(n) < 0.01
    every_s = float(rng.choice([0.05, 0.7, 10.0]))
    ours, ref = DataClock(every_s), DataClock(every_s)
    if seed % 3 == 0:  # mark_gap and restored clocks
        ours.mark_gap()
        ref.mark_gap()
    cuts = (
        np.sort(rng.choice(np.arange(1, max(2, n)), size=min(5, max(0, n - 1)), replace=False)).tolist()
        if n > 1
        else []
    )
    for a, b in zip([0, *cuts], [*cuts, n]):
        got = [
            (a + s, a + e, due, ours.data_ns, ours.next_due_ns)
            for s, e, due in ours.blocks(time_s[a:b], after_gap[a:b])
        ]
        want = [(a + s, a + e, due, d, nd) for s, e, due, d, nd in reference_blocks(ref, time_s[a:b], after_gap[a:b])]
        assert got == want
        assert ours.state_dict() == ref.state_dict()
    ticking, ref_ticks = (
        DataClock(every_s),
        DataClock(every_s),
    )  # DataClock.ticks: the due blocks' ends, the clock at the chunk's end
    if seed % 3 == 0:
        ticking.mark_gap()
        ref_ticks.mark_gap()
    for a, b in zip([0, *cuts], [*cuts, n]):
        want_ticks = tuple(e for _, e, due, *_ in reference_blocks(ref_ticks, time_s[a:b], after_gap[a:b]) if due)
        assert ticking.ticks(time_s[a:b], after_gap[a:b]) == want_ticks
        assert ticking.state_dict() == ref_ticks.state_dict()
    quiet, ref_quiet = DataClock(None), DataClock(None)  # no rows: one block per chunk, the clock still counts
    assert [(s, e, d) for s, e, d in quiet.blocks(time_s, after_gap)] == [
        (s, e, d) for s, e, d, *_ in reference_blocks(ref_quiet, time_s, after_gap)
    ]
    assert quiet.state_dict() == ref_quiet.state_dict()


def test_a_pipeline_without_rows_ticks_where_one_with_rows_does():
    chunk = simulate_rig(duration_s=40.0, ratio=30.0, play_deg=0.4, seed=2).to_chunk()
    parts = [chunk.slice(a, a + 6000) for a in range(0, len(chunk), 6000)]
    with_rows, without = (
        Pipeline(BacklashRLS(), 30.0, every_s=3.0),
        Pipeline(BacklashRLS(), 30.0, every_s=3.0, rows=False),
    )
    a, b = list(with_rows.run(parts)), list(without.run(parts))
    ticks = [s.samples for s in a if s.due]
    assert [
        s.samples - len(s.chunk) + t for s in b for t in s.ticks
    ] == ticks  # whole chunks, the same ticks inside them
    assert [s.samples for s in b] == [6000 * (k + 1) for k in range(len(parts) - 1)] + [len(chunk)]
    assert (
        all(s.row is None for s in b) and sum(s.row is not None for s in a) == len(ticks) - 3
    )  # none before the 10 s warm start
    # the estimate at each tick, recorded inside the estimator's loop, is the row's
    at_ticks = [at for s in b for at in s.estimates]
    rows = {s.samples: s.row for s in a if s.due}
    assert [at.started for at in at_ticks] == [rows[t] is not None for t in ticks]
    assert [(at.backlash_deg, at.m_left, at.m_right) for at in at_ticks if at.started] == [
        (r.backlash_deg, r.m_left, r.m_right) for r in rows.values() if r is not None
    ]
    assert with_rows.finish() == without.finish()
    assert with_rows.samples_since_row == without.samples_since_row == 0


@pytest.mark.parametrize("size", [None, 7_777, 100_000], ids=["one-chunk", "chunks-of-7777", "chunks-of-100000"])
@pytest.mark.parametrize("ahead", [0, 1], ids=["inline", "threaded"])
def test_the_std_does_not_depend_on_whether_rows_are_traced(monkeypatch, size, ahead):
    """Without a trace the scatter ticks at the clock's due flags, with one at the rows: the same instants.
    Without a trace the ticks do not cut the chunks (the estimate is recorded at each inside the
    estimator's loop); with one they do: the per-cycle plays and the whole report are the same, bit for bit."""
    scatters: list[RecursivePlayScatter] = []
    monkeypatch.setattr(
        log_fit, "RecursivePlayScatter", lambda est: scatters.append(RecursivePlayScatter(est)) or scatters[-1]
    )
    chunk = simulate_rig(duration_s=90.0, ratio=30.0, play_deg=0.5, seed=4).to_chunk()
    parts = [chunk] if size is None else [chunk.slice(a, min(a + size, len(chunk))) for a in range(0, len(chunk), size)]
    quiet, _ = fit_recursive(parts, 30.0, ahead=ahead)
    rows: list = []
    traced, _ = fit_recursive(parts, 30.0, every_s=SCATTER_EVERY_S, trace=rows.append, ahead=ahead)
    assert len(rows) > 5
    assert (
        quiet.extra["backlash_std_deg"] == traced.extra["backlash_std_deg"]
        and quiet.backlash_deg == traced.backlash_deg
    )
    assert repr(quiet.as_dict()) == repr(traced.as_dict())
    plays = [s.scatter.plays_deg for s in scatters]
    assert plays[0].size >= 10 and plays[0].tobytes() == plays[1].tobytes()
    assert scatters[0].scatter.noise.total == scatters[1].scatter.noise.total


@pytest.mark.parametrize("column", ["motor_deg", "load_deg"])
def test_a_non_finite_sample_stops_the_pipeline_before_the_estimator_sees_its_chunk(column):
    chunk = simulate_rig(duration_s=20.0, ratio=30.0, seed=1).to_chunk()
    est = BacklashRLS()
    pipe = Pipeline(est, 30.0, every_s=1.0)
    first = chunk.slice(0, 12000)
    bad = SampleChunk(
        *(getattr(chunk, k)[12000:].copy() for k in ("time_s", "motor_deg", "load_deg", "torque_Nm", "after_gap"))
    )
    getattr(bad, column)[4321] = math.inf if column == "motor_deg" else math.nan
    list(pipe.feed(first))
    seen = est.n_samples_seen_
    with pytest.raises(
        InvalidParameterError,
        match=rf"^{'u' if column == 'motor_deg' else 'y'} .* first at index 4321 of the chunk \(time 16.321 s\)",
    ):
        list(pipe.feed(bad))
    assert est.n_samples_seen_ == seen  # nothing of the chunk was learned
    with pytest.raises(InvalidParameterError, match="non-finite"):  # learn_many called directly keeps its own check
        est.learn_many(bad.motor_deg / 30.0, bad.load_deg)


@pytest.mark.parametrize("rows", [False, True])
def test_with_a_reader_thread_the_chunks_are_referred_there_and_a_bad_one_stops_at_its_place(rows):
    """``run(..., ahead=1)`` refers and checks each chunk in the reader thread: the same steps as on one
    thread, and a non-finite chunk raises when the estimator reaches it, the chunks before it learned."""
    chunk = simulate_rig(duration_s=30.0, ratio=30.0, seed=4).to_chunk()
    pieces = [chunk.slice(i, min(i + 7000, len(chunk))) for i in range(0, len(chunk), 7000)]
    steps = {}
    for ahead in (0, 1):
        pipe = Pipeline(BacklashRLS(), 30.0, every_s=2.0, rows=rows)
        steps[ahead] = [(s.samples, s.due, s.ticks, s.u_deg.tobytes()) for s in pipe.run(pieces, "log", ahead)]
        assert pipe.estimator.n_samples_seen_ == len(chunk)
    assert steps[0] == steps[1]
    bad = SampleChunk(
        *(getattr(pieces[2], k).copy() for k in ("time_s", "motor_deg", "load_deg", "torque_Nm", "after_gap"))
    )
    bad.load_deg[17] = math.nan
    est = BacklashRLS()
    with pytest.raises(InvalidParameterError, match=r"^y .* first at index 17 of the chunk"):
        list(Pipeline(est, 30.0, every_s=2.0, rows=rows).run([*pieces[:2], bad, *pieces[3:]], "log", 1))
    assert est.n_samples_seen_ == 14000  # the two chunks before it, nothing of it


@pytest.mark.parametrize("dtype", ["float64", "float32", "int64", "strided"])
@pytest.mark.parametrize("ratio", [30.0, -35, 7.3])
def test_the_compiled_referral_gives_the_numbers_of_sample_chunk_referred(dtype, ratio):
    """The pipeline divides and checks in one compiled pass: the same ``u`` as ``SampleChunk.referred``, bit for bit,
    whatever the motor column's dtype (numpy divides float32 in float32) and layout, with and without rows."""
    chunk = simulate_rig(duration_s=15.0, ratio=30.0, seed=3).to_chunk()
    motor = {"float64": chunk.motor_deg, "float32": chunk.motor_deg.astype(np.float32),
             "int64": np.rint(chunk.motor_deg * 100).astype(np.int64),
             "strided": np.repeat(chunk.motor_deg, 2)[::2]}[dtype]  # fmt: skip
    source = SampleChunk(chunk.time_s, motor, chunk.load_deg, chunk.torque_Nm, chunk.after_gap)
    want = np.asarray(source.referred(ratio)[0], dtype=float)
    for rows in (False, True):
        steps = list(Pipeline(BacklashRLS(), ratio, every_s=2.0, rows=rows).feed(source))
        got = np.concatenate([s.u_deg for s in steps])
        assert got.dtype == np.float64 and got.tobytes() == want.tobytes()
