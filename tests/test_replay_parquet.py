"""Parquet and Arrow IPC tables, written by pyarrow in the tests, replayed as sample streams."""

from __future__ import annotations

import json
import os
import re

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pyarrow.parquet as pq
import pytest
from hypothesis import given
from hypothesis import strategies as st
from measurement_cases import (
    FUZZ,
    assert_same_estimate_as_csv,
    check_damaged_file,
    damaged,
    fresh_python,
    read_all,
    rig_recording,
)

from online_backlash.cli import main
from online_backlash.errors import LogFormatError
from online_backlash.replay import open_log
from online_backlash.replay.parquet import ParquetLog

MAP = {"time": "t", "motor": "m", "load": "l"}


def small_table(n=200):
    t = np.arange(n) * 1e-3
    return pa.table({"t": t, "m": 30 * np.sin(t), "l": np.sin(t), "other": np.zeros(n)})


@pytest.fixture
def small(tmp_path):
    path = tmp_path / "small.parquet"
    pq.write_table(small_table(), path, row_group_size=64)
    return path


@pytest.mark.parametrize("suffix", [".parquet", ".arrow"])
def test_estimate_equals_the_csv_of_the_same_recording(capsys, tmp_path, suffix):
    rec = rig_recording()
    table = pa.table({"time": rec.time_s, "motor": rec.motor_deg, "load": rec.load_deg})
    path = tmp_path / f"rig{suffix}"
    if suffix == ".arrow":
        feather.write_feather(table, path, chunksize=5000)
    else:
        pq.write_table(table, path, row_group_size=7000)
    assert_same_estimate_as_csv(capsys, tmp_path, rec, path)


def test_round_trip_in_blocks_with_counters(small):
    with ParquetLog(small, columns=MAP, block_rows=50) as log:
        chunks = list(log.iter_chunks(max_samples=40))
        counters = log.counters
    assert max(len(c) for c in chunks) <= 40
    time = np.concatenate([c.time_s for c in chunks])
    np.testing.assert_allclose(time, np.arange(200) * 1e-3)
    np.testing.assert_allclose(np.concatenate([c.motor_deg for c in chunks]), 30 * np.sin(time))
    assert counters.frames == counters.samples == 200 and counters.corrupt == 0


def test_timestamp_time_integer_counts_and_unit_metadata(tmp_path):
    n = 100
    stamps = pa.array(np.datetime64("2026-01-01T00:00:00") + np.arange(n) * np.timedelta64(2, "ms"), pa.timestamp("ms"))
    schema = pa.schema(
        [
            pa.field("ts", pa.timestamp("ms")),
            pa.field("enc_m", pa.int32(), metadata={"unit": "counts"}),
            pa.field("enc_l", pa.float32(), metadata={"unit": "rad"}),
        ]
    )
    table = pa.table(
        [stamps, pa.array(np.arange(n, dtype=np.int32)), pa.array(np.full(n, np.pi / 2, np.float32))], schema=schema
    )
    path = tmp_path / "typed.parquet"
    pq.write_table(table, path)
    values, _ = read_all(path, columns={"time": "ts", "motor": "enc_m", "load": "enc_l"}, motor_cpr=360)
    np.testing.assert_allclose(np.diff(values[:, 0]), 2e-3)
    np.testing.assert_allclose(values[:, 1], np.arange(n))
    np.testing.assert_allclose(values[:, 2], 90.0, rtol=1e-6)
    with pytest.raises(LogFormatError, match=r"motor channel 'enc_m' is in encoder counts"):
        read_all(path, columns={"time": "ts", "motor": "enc_m", "load": "enc_l"})


def test_missing_column_and_a_text_column(small, tmp_path):
    with pytest.raises(LogFormatError, match=r"small\.parquet: no column 'moter' for motor \(closest: \['other'"):
        read_all(small, columns={**MAP, "motor": "moter"})
    path = tmp_path / "text.parquet"
    pq.write_table(pa.table({"time": [0.0, 1.0], "motor": ["a", "b"], "load": [0.0, 1.0]}), path)
    with pytest.raises(LogFormatError, match=r"text\.parquet:0: motor column 'motor' holds string values"):
        read_all(path)


def test_nulls_nan_and_backward_time_raise_or_are_counted(tmp_path):
    t = np.arange(50) * 1e-3
    t[30] = 0.0
    load = pa.array([None if i == 12 else float(i) for i in range(50)])
    motor = np.zeros(50)
    motor[20] = np.inf
    path = tmp_path / "bad.parquet"
    pq.write_table(pa.table({"time": t, "motor": motor, "load": load}), path)
    with pytest.raises(LogFormatError, match=r"bad\.parquet:12: non-finite value in load 'load'"):
        read_all(path)
    values, counters = read_all(path, skip_bad=True)
    assert counters.corrupt == 3 and values.shape[0] == 47 and counters.frames == 50
    assert np.all(np.isfinite(values[:, :3])) and np.all(np.diff(values[:, 0]) >= 0)


@pytest.mark.parametrize("suffix", [".parquet", ".feather"])
def test_a_truncated_file_is_a_log_format_error(tmp_path, suffix):
    path = tmp_path / f"whole{suffix}"
    (feather.write_feather if suffix == ".feather" else pq.write_table)(small_table(), path)
    data = path.read_bytes()
    for cut in (0, 7, len(data) // 2, len(data) - 3):
        cut_path = tmp_path / f"cut{cut}{suffix}"
        cut_path.write_bytes(data[:cut])
        with pytest.raises(LogFormatError, match=str(cut_path)):
            read_all(cut_path, columns=MAP)


def test_open_log_picks_the_reader_by_suffix(small, tmp_path):
    with open_log(small, columns=MAP) as log:
        assert isinstance(log, ParquetLog)


@pytest.mark.parametrize("suffix", [".parquet", ".arrow"])
@FUZZ
@given(data=st.data())
def test_fuzz_bit_flips_and_truncation(tmp_path, suffix, data):
    path = tmp_path / f"good{suffix}"
    if not path.exists():
        (feather.write_feather if suffix == ".arrow" else pq.write_table)(small_table(), path)
    fuzz = tmp_path / f"fuzz{suffix}"
    fuzz.write_bytes(damaged(path.read_bytes(), data.draw))
    check_damaged_file(fuzz, columns=MAP)


def test_track_and_diagnose_read_a_parquet_log(capsys, tmp_path):
    rec = rig_recording()
    path = tmp_path / "rig.parquet"
    pq.write_table(pa.table({"t_s": rec.time_s, "enc_motor": rec.motor_deg, "enc_load": rec.load_deg}), path)
    mapping = ["--columns", "time=t_s,motor=enc_motor,load=enc_load"]
    assert main(["diagnose", str(path), "--ratio", "30", *mapping, "--json"]) == 0, capsys.readouterr().err
    diagnosis = json.loads(capsys.readouterr().out)
    assert diagnosis["samples"] == rec.time_s.size and abs(diagnosis["backlash_before_deg"] - 0.5) < 0.02
    argv = [
        "track",
        str(path),
        "--ratio",
        "30",
        "--db",
        str(tmp_path / "wear.db"),
        "--gearbox",
        "gb1",
        "--every",
        "5",
        "--quiet",
        *mapping,
    ]
    assert main(argv) == 0, capsys.readouterr().err
    assert re.match(
        rf"gb1: {re.escape(str(path))}: {rec.time_s.size} samples, [1-9][0-9]* estimates added; backlash 0\.(49|50)",
        capsys.readouterr().out,
    )


@pytest.mark.parametrize("kind", ["float64", "float32", "int32", "uint16", "int64"])
def test_column_values_are_read_from_the_buffer_with_its_offset(kind):
    from online_backlash.replay.parquet import _as_float

    values = pa.array(np.arange(20), type=getattr(pa, kind)())
    part = values.slice(7, 9)  # a view with an offset into the shared buffer
    np.testing.assert_array_equal(_as_float(part, "motor", "m", "f.parquet", 1, []), np.arange(7, 16, dtype=float))
    with_null = pa.array([1, None, 3], type=getattr(pa, kind)())
    np.testing.assert_array_equal(_as_float(with_null, "motor", "m", "f.parquet", 1, []), [1.0, np.nan, 3.0])


def test_a_time_that_never_advances_is_an_error_and_repeated_times_warn(tmp_path):
    """The end-of-pass checks of CSV logs hold for measurement files too (a pass over the whole file)."""
    from online_backlash.errors import BacklashWarning

    n = 100
    frozen = tmp_path / "frozen.parquet"
    pq.write_table(
        pa.table({"t": np.zeros(n), "m": np.arange(n, dtype=float), "l": np.arange(n, dtype=float)}),
        frozen,
        row_group_size=30,
    )
    with (
        ParquetLog(frozen, columns=MAP, block_rows=16) as log,
        pytest.raises(LogFormatError, match="never advances") as err,
    ):
        list(log.iter_chunks())
    assert "frozen.parquet" in str(err.value)
    t = np.arange(n) * 1e-3
    t[10], t[50], t[51] = t[9], t[49], t[49]  # three samples repeat the previous time
    repeated = tmp_path / "repeated.parquet"
    pq.write_table(
        pa.table({"t": t, "m": np.arange(n, dtype=float), "l": np.arange(n, dtype=float)}), repeated, row_group_size=30
    )
    with (
        ParquetLog(repeated, columns=MAP, block_rows=16) as log,
        pytest.warns(BacklashWarning, match="3 of 100 samples repeat"),
    ):
        assert sum(len(c) for c in log.iter_chunks()) == n


def test_the_columns_are_decoded_in_pyarrows_threads_not_the_readers(tmp_path):
    """The decode (mostly snappy's decompression) runs in pyarrow's thread pool, without the GIL: the thread
    that iterates the reader spends a small part of the CPU the read costs, and the samples are the file's."""
    import threading
    import time

    rng = np.random.default_rng(5)
    n = 1_000_000
    table = pa.table({"time": np.arange(n) * 1e-3, "motor": np.cumsum(rng.normal(size=n)), "load": rng.normal(size=n)})
    path = tmp_path / "lake.parquet"
    pq.write_table(table, path, row_group_size=250_000)  # pyarrow's defaults: snappy, dictionary pages
    cpus = pa.cpu_count()
    pa.set_cpu_count(2)  # a pool of two threads even on a one-core machine
    try:
        with ParquetLog(path) as log:
            next(iter(log.iter_chunks()))  # the compiled checks loaded outside the count
            spent = {}

            def read() -> None:
                start, thread_start = time.process_time(), time.thread_time()
                spent["chunks"] = list(log.iter_chunks())
                spent["thread"], spent["process"] = time.thread_time() - thread_start, time.process_time() - start

            reader = threading.Thread(target=read)
            reader.start()
            reader.join()
    finally:
        pa.set_cpu_count(cpus)
    chunks = spent["chunks"]
    np.testing.assert_array_equal(np.concatenate([c.motor_deg for c in chunks]), table.column("motor").to_numpy())
    np.testing.assert_array_equal(np.concatenate([c.time_s for c in chunks]), table.column("time").to_numpy())
    assert spent["thread"] < 0.5 * spent["process"], spent


@pytest.mark.parametrize("compression", ["lz4", "uncompressed"])
def test_an_arrow_file_is_read_by_its_named_columns_in_any_order(tmp_path, compression):
    """Only the mapped columns of an Arrow IPC file are read (and decompressed), whatever their order in the
    file; the others may hold anything; ``inspect`` counts every batch's rows."""
    from online_backlash.replay.parquet import describe

    n = 300
    t = np.arange(n) * 1e-3
    table = pa.table({"l": np.cos(t), "note": [f"row {i}" for i in range(n)], "m": 30 * np.sin(t), "t": t})
    path = tmp_path / "wide.arrow"
    feather.write_feather(table, path, chunksize=64, compression=compression)
    values, counters = read_all(path, columns=MAP, block_rows=50)
    np.testing.assert_array_equal(values[:, 0], t)
    np.testing.assert_array_equal(values[:, 1], 30 * np.sin(t))
    np.testing.assert_array_equal(values[:, 2], np.cos(t))
    assert counters.frames == counters.samples == n
    assert [(c.name, c.samples) for c in describe(path)] == [(name, n) for name in ("l", "note", "m", "t")]


def test_an_arrow_file_streams_with_flat_memory(tmp_path):
    """An Arrow IPC file is read batch by batch, not memory-mapped (a map counts every page read as resident):
    reading 96 MB of samples leaves the resident memory within a few batches of where it started."""
    n = 4_000_000
    path = tmp_path / "big.arrow"
    feather.write_feather(
        pa.table({"time": np.arange(n) * 1e-3, "motor": np.zeros(n), "load": np.zeros(n)}),
        path,
        compression="uncompressed",
    )

    def resident_mb() -> float:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

    with ParquetLog(path) as log:
        chunks = log.iter_chunks()
        rows = len(next(chunks))
        start = resident_mb()
        rows += sum(len(chunk) for chunk in chunks)
        grown = resident_mb() - start
    assert rows == n
    assert grown < 30, f"resident memory grew {grown:.0f} MB over a 96 MB file"


def test_an_arrow_files_blocks_do_not_hold_its_record_batches(tmp_path):
    """A block of an Arrow IPC file is copied out of its record batch by the checking pass: blocks kept (read
    ahead, or waiting for the bookkeeping) hold no batch, so one batch is held at a time (pyarrow's own
    allocations come back to nothing once the file is read, whatever the blocks still held)."""
    n = 300_000
    path = tmp_path / "batches.arrow"
    table = pa.table({"time": np.arange(n) * 1e-3, "motor": 30 * np.sin(np.arange(n) * 1e-3), "load": np.zeros(n)})
    feather.write_feather(table, path, compression="uncompressed", chunksize=100_000)
    before = pa.total_allocated_bytes()
    with ParquetLog(path, block_rows=50_000) as log:
        blocks = list(log.iter_chunks())
        held = pa.total_allocated_bytes() - before
    assert sum(len(block) for block in blocks) == n
    np.testing.assert_array_equal(
        np.concatenate([block.motor_deg for block in blocks]), table.column("motor").to_numpy()
    )
    assert held < 1 << 20, f"the blocks hold {held / 2**20:.1f} MB of pyarrow's record batches"


def test_an_arrow_ipc_file_is_read_without_importing_pyarrow_parquet(tmp_path):
    """``pyarrow.parquet`` loads pyarrow's file systems (S3, GCS, Azure, HDFS): 4 MB of a replay's peak memory
    that an Arrow IPC file never uses (issue 31). In a fresh process, as ``estimate`` reads it."""
    path = tmp_path / "small.arrow"
    feather.write_feather(small_table(), path, compression="uncompressed")
    script = (
        "import sys\nfrom online_backlash.replay import open_log\n"
        "with open_log(sys.argv[1], columns={'time': 't', 'motor': 'm', 'load': 'l'}) as log:\n"
        "    print(sum(len(chunk) for chunk in log.iter_chunks()), 'pyarrow.parquet' in sys.modules)"
    )
    assert fresh_python(script, str(path)) == ["200", "False"]
