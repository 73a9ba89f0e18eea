"""Issue 11, speed and item 8: reading ahead in a thread, and time from the frame counter.

* :func:`~online_backlash.pipeline.read_ahead` reads a file's blocks in a thread while the
  (``nogil``) estimator learns; the estimates are those of reading on one thread, to the last digit;
* with ``--period`` and a rolling counter, a sample's time is ``t0 + n * period``
  (:class:`~online_backlash.codecs.gaps.CounterClock`): a log whose host timestamps come in
  1-5 ms bursts traces like the same log with regular timestamps, live and replayed alike;
* ``--wrap-deg`` per signal (``motor=360,load=none``) and ``listen can --units``.
Files are written by the real libraries (pyarrow, asammdf, python-can, cantools).
"""

from __future__ import annotations

import csv
import json
import threading

import can
import numpy as np
import pytest
from live_run import run_live, send_frames
from measurement_cases import rig_mdf
from rig_can import RIG_CAN
from test_dbc_units import dbc, frame

from online_backlash.cli import main
from online_backlash.codecs.blockpairing import BlockPipeline
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder, parse_wrap_deg, wrap_per_signal
from online_backlash.codecs.gaps import CounterClock
from online_backlash.codecs.pairing import FramePipeline
from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.estimators import _rls_kernels
from online_backlash.log_fit import fit_recursive
from online_backlash.pipeline import read_ahead
from online_backlash.replay import LOG_READERS
from online_backlash.replay.mdf import MdfLog
from online_backlash.replay.parquet import ParquetLog
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames
from online_backlash.stream import SampleChunk

T0 = 1.7e9


def chunk_of(values: np.ndarray) -> SampleChunk:
    n = values.size
    return SampleChunk(
        values.astype(float), values.astype(float), values.astype(float), np.full(n, np.nan), np.zeros(n, bool)
    )


# -- reading ahead ------------------------------------------------------------------------------
def test_read_ahead_gives_every_chunk_in_order_from_a_reader_thread():
    readers = []

    def chunks():
        for i in range(50):
            readers.append(threading.current_thread().name)
            yield chunk_of(np.arange(i * 10, i * 10 + 10))

    got = list(read_ahead(chunks(), depth=2))
    assert np.array_equal(np.concatenate([c.time_s for c in got]), np.arange(500.0))
    assert set(readers) == {"online-backlash-read-ahead"}
    assert [len(c) for c in read_ahead(iter([chunk_of(np.arange(3))]), depth=0)] == [3]  # depth 0: no thread


def test_read_ahead_raises_the_readers_error_after_the_chunks_before_it():
    def chunks():
        yield chunk_of(np.arange(5))
        raise LogFormatError("run.parquet", 6, "cannot read the rows after this one")

    got = []
    with pytest.raises(LogFormatError, match=r"run\.parquet:6"):
        for c in read_ahead(chunks()):
            got.append(len(c))
    assert got == [5]


def test_read_ahead_stopped_early_closes_the_source_and_ends_its_thread():
    closed = threading.Event()

    def chunks():
        try:
            for i in range(1000):
                yield chunk_of(np.arange(i, i + 1))
        finally:
            closed.set()

    stream = read_ahead(chunks(), depth=1)
    assert len(next(stream)) == 1
    stream.close()
    assert closed.is_set()
    assert not any(t.name == "online-backlash-read-ahead" for t in threading.enumerate())


def test_the_compiled_estimator_loops_release_the_gil():
    for loop in (_rls_kernels.backlash_run, _rls_kernels.cascade_run):
        assert loop.targetoptions.get("nogil") is True


def test_the_compiled_estimator_loops_count_no_references():
    """The loops' machine code makes no reference-counting call: numba counted the arrays each inlined step binds,
    per sample (atomic operations its pruning pass left in the steps' branches: half the loops' time)."""
    from numba import njit, types

    vec, flags = types.float64[::1], types.boolean[::1]
    signatures = {
        _rls_kernels.backlash_run: (
            vec,
            vec,
            vec,
            vec,
            flags,
            types.int8[::1],
            types.int64[::1],
            types.float64[:, ::1],
        ),
        _rls_kernels.cascade_run: (vec, vec, vec, vec, flags, vec, vec),
    }
    for loop, signature in signatures.items():
        options = {k: v for k, v in loop.targetoptions.items() if k not in ("nopython", "cache")}
        fresh = njit(**options)(loop.py_func)  # compiled anew: numba's cached code cannot be inspected
        fresh.compile(signature)
        code = fresh.inspect_llvm(signature)
        assert "NRT_incref" not in code and "NRT_decref" not in code, loop.py_func.__name__


@pytest.fixture(scope="module")
def measurement_files(tmp_path_factory):
    """The rig (60 s at 1 kHz, 0.5 deg of play) as Parquet (pyarrow, row groups of 7,000) and MDF4 (asammdf)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rec = simulate_rig(duration_s=60.0, ratio=30.0, play_deg=0.5, seed=21)
    folder = tmp_path_factory.mktemp("ahead")
    parquet, mf4 = folder / "rig.parquet", folder / "rig.mf4"
    pq.write_table(
        pa.table({"time": rec.time_s, "motor": rec.motor_deg, "load": rec.load_deg}), parquet, row_group_size=7000
    )
    rig_mdf(mf4, rec)
    return {
        "parquet": lambda: ParquetLog(parquet, block_rows=4096),
        "mf4": lambda: MdfLog(mf4, columns={"motor": "Motor", "load": "Load"}, fragment_bytes=1 << 16),
    }


@pytest.mark.parametrize("kind", ["parquet", "mf4"])
def test_reading_ahead_gives_the_estimates_of_reading_on_one_thread_to_the_last_digit(measurement_files, kind):
    results = []
    for ahead in (0, 2):
        rows = []
        with measurement_files[kind]() as source:
            report, _ = fit_recursive(source.iter_chunks(), 30.0, every_s=5.0, trace=rows.append, ahead=ahead)
            counters = source.counters.as_dict()
        results.append((report.as_dict(), [r.trace() for r in rows], counters))
    assert results[0] == results[1]
    assert results[0][0]["backlash_deg"] == pytest.approx(0.5, abs=0.01) and len(results[0][1]) >= 10
    assert results[0][2]["samples"] == 60000


def test_the_registry_names_every_python_can_log_format_without_importing_python_can():
    from can.io.player import MESSAGE_READERS

    from online_backlash.replay.registry import CAN_LOG_SUFFIXES

    assert set(CAN_LOG_SUFFIXES) == set(MESSAGE_READERS) - {".csv", ".mf4"}
    assert {LOG_READERS[s].__name__ for s in CAN_LOG_SUFFIXES} == {"_can_log"}


# -- time from the counter ----------------------------------------------------------------------
def burst_times(n: int, rng: np.random.Generator) -> np.ndarray:
    """Host timestamps of a USB adapter at 1 kHz: each sample stamped at the end of its 1-5 ms burst (frames 20 us
    apart)."""
    ends = np.cumsum(rng.integers(1, 6, size=n) * 1e-3)
    nominal = np.arange(n) * 1e-3
    burst = np.searchsorted(ends, nominal + 1e-9)
    within = np.arange(n) - np.searchsorted(burst, burst)
    return ends[np.minimum(burst, n - 1)] + within * 2e-5


def test_the_counter_clock_turns_bursts_into_the_nominal_grid_and_counts_lost_frames():
    rng = np.random.default_rng(3)
    host = T0 + burst_times(3000, rng)
    seq = np.arange(3000) % 16
    keep = np.ones(3000, bool)
    keep[[100, 101, 102]] = False  # three frames lost: the counter shows them
    keep[2000:2016] = False  # a whole cycle lost: only the timestamps show it
    clock = CounterClock(16, 1e-3)
    times = clock.times(host[keep], seq[keep])
    expected = host[0] + np.flatnonzero(keep) * 1e-3
    assert np.array_equal(times, expected)


def test_the_counter_clock_sample_by_sample_equals_block_by_block_whatever_the_blocks():
    rng = np.random.default_rng(4)
    n = 4000
    host = T0 + burst_times(n, rng) + np.where(np.arange(n) > 3000, 0.5, 0.0)  # a long gap
    seq = (np.arange(n) + rng.integers(0, 3, n).cumsum()) % 16  # lost frames
    seq[rng.choice(n, 40, replace=False)] = -1  # samples without a counter value
    one = CounterClock(16, 1e-3)
    per_sample = np.array([one.time(t, int(q)) for t, q in zip(host.tolist(), seq.tolist())])
    blocks = CounterClock(16, 1e-3)
    cuts = np.sort(rng.choice(np.arange(1, n), 30, replace=False))
    by_block = np.concatenate([blocks.times(h, q) for h, q in zip(np.split(host, cuts), np.split(seq, cuts))])
    assert np.array_equal(per_sample, by_block)
    assert np.all(np.diff(per_sample) >= 0) and np.all(np.diff(per_sample) <= 0.6)
    with pytest.raises(InvalidParameterError):
        CounterClock(1, 1e-3)
    with pytest.raises(InvalidParameterError):
        CounterClock(16, 0.0)


@pytest.fixture(scope="module")
def rig_frames():
    """The rig's frames (two messages per sample, 4-bit counter), 20 s; regular and bursty host timestamps."""
    rec = simulate_rig(duration_s=20.0, ratio=30.0, play_deg=0.5, seed=6)
    frames = list(rig_can_frames(rec, DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count")))
    bursts = burst_times(rec.time_s.size, np.random.default_rng(0))
    regular = bursts[0] + rec.time_s  # the same first timestamp
    return frames, regular, bursts


def stamped(frames, times):
    out = []
    for i, msg in enumerate(frames):
        out.append(
            can.Message(
                timestamp=T0 + times[i // 2] + (i % 2) * 1e-5,
                arbitration_id=msg.arbitration_id,
                data=msg.data,
                is_extended_id=msg.is_extended_id,
            )
        )
    return out


def write_blf(path, frames):
    with can.Logger(str(path)) as writer:
        for msg in frames:
            writer.on_message_received(msg)
    return path


def test_the_per_frame_and_block_paths_give_the_counter_time(rig_frames):
    frames, regular, bursts = rig_frames
    messages = stamped(frames, bursts)
    decoder = DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count")
    per_frame = FramePipeline(decoder, period_s=1e-3)
    rows = [r for r in map(per_frame.feed_row, messages) if r is not None]
    block = BlockPipeline(decoder, period_s=1e-3)
    chunks = [block.feed_frames(messages[i : i + 1000]) for i in range(0, len(messages), 1000)]
    times = np.concatenate([c.time_s for c in chunks])
    assert np.array_equal(times, np.array([r[0] for r in rows]))
    assert np.array_equal(times, T0 + regular[0] + np.arange(regular.size) * 1e-3)
    assert per_frame.counters.gaps == block.counters.gaps == 0
    unpaced = BlockPipeline(decoder)  # no period: the timestamps, as before
    assert np.array_equal(unpaced.feed_frames(messages[:200]).time_s, T0 + bursts[:100])


def trace_rows(tmp_path, capsys, log, *extra):
    trace = tmp_path / f"{log.stem}-{len(extra)}.csv"
    assert (
        main(
            [
                "estimate",
                str(log),
                "--ratio",
                "30",
                "--json",
                "--every",
                "1",
                "--trace",
                str(trace),
                *RIG_CAN,
                *extra,
            ]
        )
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    with open(trace, newline="") as f:
        return out, list(csv.DictReader(f))


def test_a_bursty_log_with_period_traces_as_the_same_log_with_regular_timestamps(tmp_path, capsys, rig_frames):
    frames, regular, bursts = rig_frames
    bursty = write_blf(tmp_path / "bursty.blf", stamped(frames, bursts))
    even = write_blf(tmp_path / "even.blf", stamped(frames, regular))
    out_b, rows_b = trace_rows(tmp_path, capsys, bursty, "--period", "0.001")
    out_e, rows_e = trace_rows(tmp_path, capsys, even, "--period", "0.001")
    assert rows_b == rows_e and out_b == out_e and out_b["gaps"] == 0 and len(rows_b) >= 10
    _, rows_plain = trace_rows(tmp_path, capsys, bursty)  # without --period: the rows fall on the bursts' timestamps
    assert [r["time"] for r in rows_plain] != [r["time"] for r in rows_e]


def test_listen_can_with_bursts_and_period_replays_to_the_same_estimate(tmp_path, capsys):
    rec = simulate_rig(duration_s=4.0, ratio=30.0, play_deg=0.5, seed=9, reversal_s=(0.4, 0.8))
    frames = list(rig_can_frames(rec, DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count")))
    messages = stamped(frames, burst_times(rec.time_s.size, np.random.default_rng(5)))
    argv = [
        "listen",
        "can",
        "--interface",
        "virtual",
        "--channel",
        "burst-can",
        *RIG_CAN,
        "--ratio",
        "30",
        "--period",
        "0.001",
        "--every",
        "0.5",
        "--raw-log",
        str(tmp_path / "raw"),
        "--json",
    ]
    assert run_live(argv, lambda _: send_frames("burst-can", messages)) == 0
    live = json.loads(capsys.readouterr().out)
    assert live["samples"] == 4000 and live["gaps"] == 0
    assert main(["estimate", str(tmp_path / "raw"), *RIG_CAN, "--ratio", "30", "--period", "0.001", "--json"]) == 0
    replayed = json.loads(capsys.readouterr().out)
    keys = (
        "backlash_deg",
        "c_left_deg",
        "c_right_deg",
        "m_left",
        "m_right",
        "residual_rms_deg",
        "samples",
        "gaps",
        "n_reversals",
    )
    assert {k: replayed[k] for k in keys} == {k: live[k] for k in keys}


# -- wrap per signal, listen can --units --------------------------------------------------------
def test_parse_wrap_deg_for_both_or_per_signal():
    assert parse_wrap_deg("360") == 360.0 and parse_wrap_deg("none") is None
    assert parse_wrap_deg("motor=360, load=none") == {"motor": 360.0, "load": None}
    assert parse_wrap_deg("LOAD=90") == {"load": 90.0}
    assert wrap_per_signal({"load": 90.0}) == (None, 90.0) and wrap_per_signal(None) == (None, None)
    for bad in ("-360", "motor=0", "motor=360,motor=180", "torque=360", "motor:360", "nan", "motor=x"):
        with pytest.raises(InvalidParameterError, match="--wrap-deg"):
            parse_wrap_deg(bad)
    with pytest.raises(InvalidParameterError, match="torque"):
        wrap_per_signal({"torque": 360.0})


SHAFTS = (
    'BO_ 256 Angles: 8 RIG\n SG_ Motor : 0|32@1- (0.001,0) [-2000000|2000000] "{unit}" RIG\n'
    ' SG_ Load : 32|16@1+ (0.01,0) [0|655.35] "{unit}" RIG\n'
)


def shaft_frames(db, rec):
    """The motor multi-turn, the load as a single-turn angle in [0, 360)."""
    return [
        frame(db, "Angles", {"Motor": round(m, 3), "Load": round(y % 360.0, 2)}, T0 + t)
        for t, m, y in zip(rec.time_s.tolist(), rec.motor_deg.tolist(), rec.load_deg.tolist())
    ]


def test_a_wrap_for_the_load_signal_alone_unwraps_it_and_leaves_the_motor_multi_turn():
    rec = simulate_rig(duration_s=3.0, ratio=30.0, play_deg=0.5, seed=2)
    db = dbc(SHAFTS.format(unit="deg"))
    frames = shaft_frames(db, rec)
    for wrap in ({"load": 360.0}, parse_wrap_deg("motor=none,load=360")):
        decoder = DbcDecoder(db, "Motor", "Load", counter_signal=None, checksum_signal=None, wrap_deg=wrap)
        assert decoder.motor.modulus is None and decoder.load.modulus == 36000
        chunk = FramePipeline(decoder).feed_frames(frames)
        load = chunk.load_deg - chunk.load_deg[0] + rec.load_deg[0] % 360.0
        assert load == pytest.approx(rec.load_deg - rec.load_deg[0] + rec.load_deg[0] % 360.0, abs=0.006)
        assert chunk.motor_deg == pytest.approx(rec.motor_deg, abs=6e-4)


def test_listen_can_units_overrides_the_dbc_unit_and_wrap_deg_per_signal(tmp_path, capsys):
    rec = simulate_rig(duration_s=4.0, ratio=30.0, play_deg=0.5, seed=8, reversal_s=(0.4, 0.8))
    (tmp_path / "shafts.dbc").write_text('VERSION ""\nBU_: RIG\n' + SHAFTS.format(unit="mil"))
    db = dbc(SHAFTS.format(unit="mil"))
    messages = shaft_frames(db, rec)
    base = [
        "listen",
        "can",
        "--interface",
        "virtual",
        "--channel",
        "units-can",
        "--dbc",
        str(tmp_path / "shafts.dbc"),
        "--motor-signal",
        "Motor",
        "--load-signal",
        "Load",
        "--counter-signal",
        "none",
        "--checksum-signal",
        "none",
        "--ratio",
        "30",
        "--json",
        "--wrap-deg",
        "motor=none,load=360",
        "--raw-log",
        str(tmp_path / "raw"),
    ]
    assert main([*base, "--duration", "0.1"]) != 0  # a unit it cannot read, named
    assert "mil" in capsys.readouterr().err
    assert run_live([*base, "--units", "deg"], lambda _: send_frames("units-can", messages)) == 0
    live = json.loads(capsys.readouterr().out)
    assert live["samples"] == rec.time_s.size and live["backlash_deg"] == pytest.approx(0.5, abs=0.05)


def test_estimate_of_a_long_mdf_read_prints_nothing_but_its_json(measurement_files, tmp_path, capsys, monkeypatch):
    """asammdf prints a ``MB/s`` line on stdout when a channel group takes over 10 s to read (any long file)."""
    import time

    clock = iter(range(0, 10**9, 11))  # every call 11 s later: asammdf thinks each fragment took 11 s
    monkeypatch.setattr(time, "perf_counter", lambda: float(next(clock)))
    mf4 = measurement_files["mf4"]().path
    assert main(["estimate", mf4, "--ratio", "30", "--json", "--columns", "motor=Motor,load=Load"]) == 0
    monkeypatch.undo()
    assert json.loads(capsys.readouterr().out)["samples"] == 60000
