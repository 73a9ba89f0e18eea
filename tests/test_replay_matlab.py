"""MATLAB (.mat v5 and v7.3) and HDF5 files replayed as sample streams.

v5 files are written by scipy.io.savemat; v7.3 files by h5py the way MATLAB writes them (a 512-byte
header "MATLAB 7.3 MAT-file", column-major arrays stored transposed, ``MATLAB_class`` attributes,
structs as groups, char arrays as UTF-16 code units, chunked and deflated); HDF5 files by h5py as
Python and LabVIEW write them (``group/dataset``, a ``units`` attribute).
"""

from __future__ import annotations

import json
import tracemalloc

import h5py
import numpy as np
import pytest
import scipy.io
from hypothesis import given
from hypothesis import strategies as st
from measurement_cases import FUZZ, assert_same_estimate_as_csv, check_damaged_file, damaged, read_all, rig_recording

from online_backlash.cli import main
from online_backlash.errors import LogFormatError
from online_backlash.inspection import inspect_file
from online_backlash.replay import open_log
from online_backlash.replay.hdf5 import Hdf5Log

MATLAB_HEADER = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Sun Nov 29 08:00:00 2026 HDF5 schema 1.00 ."


def write_mat73(path, variables: dict) -> None:
    """A MATLAB v7.3 file as MATLAB's ``save -v7.3`` lays it out (h5py underneath, as MATLAB's HDF5 library)."""
    with h5py.File(path, "w", userblock_size=512, libver="earliest") as f:
        for name, value in variables.items():
            _put(f, name, value)
    header = MATLAB_HEADER.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"
    with open(path, "r+b") as f:
        f.write(header.ljust(512, b"\x00"))


def _put(group, name: str, value) -> None:
    if isinstance(value, dict):
        sub = group.create_group(name)
        sub.attrs["MATLAB_class"] = np.bytes_("struct")
        fields = np.empty(len(value), dtype=h5py.vlen_dtype(np.dtype("S1")))
        for i, key in enumerate(value):
            fields[i] = np.frombuffer(key.encode(), dtype="S1")
        sub.attrs["MATLAB_fields"] = fields
        for key, item in value.items():
            _put(sub, key, item)
        return
    if isinstance(value, str):
        codes = np.array([[ord(c) for c in value]], dtype=np.uint16)  # a 1 x n char row, stored n x 1
        ds = group.create_dataset(name, data=codes.T)
        ds.attrs["MATLAB_class"] = np.bytes_("char")
        ds.attrs["MATLAB_int_decode"] = np.int32(2)
        return
    array = np.asarray(value)
    if array.ndim == 1:
        array = array[:, None]  # MATLAB has no 1-D arrays: a column vector
    stored = array.T  # column-major: MATLAB's N x k is HDF5's k x N
    chunks = tuple(min(n, 65536) for n in stored.shape) if array.size > 1000 else None
    ds = group.create_dataset(
        name, data=stored, chunks=chunks, compression="gzip" if chunks else None, compression_opts=1 if chunks else None
    )
    ds.attrs["MATLAB_class"] = np.bytes_(
        {"float64": "double", "float32": "single"}.get(array.dtype.name, array.dtype.name)
    )


@pytest.fixture(scope="module")
def rec():
    return rig_recording()


def test_a_v5_struct_with_column_and_row_vectors_gives_the_csv_estimate(capsys, tmp_path, rec):
    path = tmp_path / "rig.mat"
    meas = {"t": rec.time_s[:, None], "EncMotor_deg": rec.motor_deg[:, None], "EncLoad_deg": rec.load_deg[None, :]}
    scipy.io.savemat(path, {"meas": meas, "operator": "K. Lab"})
    cols = "time=meas.t,motor=meas.EncMotor_deg,load=meas.EncLoad_deg"
    assert_same_estimate_as_csv(capsys, tmp_path, rec, path, "--columns", cols)


def test_a_simulink_structure_with_time_export_finds_its_time_beside_the_values(tmp_path, rec):
    path = tmp_path / "simout.mat"
    signals = {"values": np.column_stack([rec.motor_deg, rec.load_deg]), "dimensions": 2, "label": ""}
    scipy.io.savemat(
        path, {"simout": {"time": rec.time_s[:, None], "signals": signals, "blockName": "rig/To Workspace"}}
    )
    values, counters = read_all(
        path, columns={"motor": "simout.signals.values(:,1)", "load": "simout.signals.values(:,2)"}
    )
    np.testing.assert_array_equal(values[:, 0], rec.time_s)
    np.testing.assert_array_equal(values[:, 1], rec.motor_deg)
    np.testing.assert_array_equal(values[:, 2], rec.load_deg)
    assert counters.samples == counters.frames == rec.time_s.size
    with pytest.raises(
        LogFormatError, match=r"is a 20000x2 matrix: name one column, e\.g\. simout\.signals\.values\(:,1\)"
    ):
        read_all(path, columns={"motor": "simout.signals.values", "load": "simout.signals.values(:,2)"})


def test_timeseries_saved_as_structs_with_units_and_another_rate(tmp_path):
    t = np.arange(2000) * 1e-3
    slow = np.arange(200) * 1e-2
    path = tmp_path / "ts.mat"
    scipy.io.savemat(
        path,
        {
            "motor": {"Time": t[:, None], "Data": np.radians(30 * np.sin(t))[:, None], "Units": "rad"},
            "load": {"Time": slow[:, None], "Data": np.sin(slow)[:, None]},
        },
    )
    values, counters = read_all(path, columns={"motor": "motor", "load": "load"})
    np.testing.assert_allclose(values[:, 1], 30 * np.sin(values[:, 0]))  # rad -> deg from the Units field
    np.testing.assert_allclose(values[:, 2], np.sin(values[:, 0]), atol=1e-4)  # interpolated from 100 Hz
    assert counters.skipped == 9 and counters.samples == 1991  # motor samples after the load's last one


def test_a_v73_file_as_matlab_writes_it_gives_the_csv_estimate(capsys, tmp_path, rec):
    path = tmp_path / "rig73.mat"
    write_mat73(
        path,
        {
            "meas": {
                "t": rec.time_s,
                "EncMotor_deg": rec.motor_deg,
                "EncLoad_deg": rec.load_deg[None, :],
                "units": "deg",
            }
        },
    )
    with h5py.File(path, "r") as f:
        assert f["meas/t"].shape == (1, rec.time_s.size) and f["meas/EncLoad_deg"].shape == (rec.time_s.size, 1)
    with open(path, "rb") as f:
        assert f.read(19) == b"MATLAB 7.3 MAT-file"
    got = assert_same_estimate_as_csv(
        capsys, tmp_path, rec, path, "--columns", "time=meas.t,motor=meas.EncMotor_deg,load=meas.EncLoad_deg"
    )
    assert got["samples"] == rec.time_s.size


def test_a_v73_matrix_column_and_counts_with_cpr(tmp_path, rec):
    path = tmp_path / "counts73.mat"
    counts = np.column_stack([np.round(rec.motor_deg / 360 * 4096), np.round(rec.load_deg / 360 * 8192)])
    write_mat73(path, {"time": rec.time_s, "enc": counts})
    values, _ = read_all(
        path, columns={"motor": "enc(:,1)", "load": "enc(:,2)"}, units="counts", motor_cpr=4096, load_cpr=8192
    )
    np.testing.assert_allclose(values[:, 1], counts[:, 0] * 360 / 4096)
    np.testing.assert_allclose(values[:, 2], counts[:, 1] * 360 / 8192)


def test_an_hdf5_file_with_group_dataset_names_and_units_attributes(capsys, tmp_path, rec):
    path = tmp_path / "rig.h5"
    with h5py.File(path, "w") as f:
        f["rig/time"] = rec.time_s
        f["rig/time"].attrs["units"] = "s"
        f.create_dataset("rig/encoders/motor", data=np.radians(rec.motor_deg), chunks=(4096,)).attrs["units"] = "rad"
        f["rig/encoders/load"] = rec.load_deg
        f["rig/encoders/load"].attrs["unit"] = b"deg"
        f["rig/note"] = "bench 3"
    values, _ = read_all(path, columns={"time": "rig/time", "motor": "rig/encoders/motor", "load": "rig/encoders/load"})
    np.testing.assert_allclose(values[:, 1], rec.motor_deg)
    out = assert_same_estimate_as_csv(
        capsys, tmp_path, rec, path, "--columns", "time=rig/time,motor=rig/encoders/motor,load=rig/encoders/load"
    )
    assert out["samples"] == rec.time_s.size


def test_inspect_lists_variables_with_shape_dtype_and_length(capsys, tmp_path, rec):
    v5, v73, h5 = tmp_path / "a.mat", tmp_path / "b.mat", tmp_path / "c.hdf5"
    scipy.io.savemat(
        v5,
        {
            "meas": {"t": rec.time_s[:, None], "m": rec.motor_deg.astype(np.float32)[None, :]},
            "c": np.zeros((2, 3), np.int16),
        },
    )
    write_mat73(v73, {"meas": {"t": rec.time_s, "m": rec.motor_deg, "units": "deg"}})
    with h5py.File(h5, "w") as f:
        f["g/x"] = np.zeros((500, 3))
        f["g/x"].attrs["units"] = "rad"
    listed = {
        p: {c.name: (c.shape, c.dtype, c.samples, c.unit) for c in inspect_file(p).channels} for p in (v5, v73, h5)
    }
    rates = {c.name: c.rate_hz for c in inspect_file(v73).channels}
    assert rates == {"meas.t": None, "meas.m": 1000.0}  # the rate of the time vector beside it
    n = rec.time_s.size
    assert listed[v5] == {
        "meas.t": (f"{n}x1", "float64", n, None),
        "meas.m": (f"1x{n}", "float32", n, None),
        "c": ("2x3", "int16", 2, None),
    }
    assert listed[v73] == {"meas.t": (f"{n}x1", "float64", n, None), "meas.m": (f"{n}x1", "float64", n, None)}
    assert listed[h5] == {"g/x": ("500x3", "float64", 500, "rad")}
    assert [inspect_file(p).kind for p in (v5, v73, h5)] == ["mat", "mat-v7.3", "hdf5"]
    assert main(["inspect", str(v5)]) == 0
    out = capsys.readouterr().out
    assert "mat, 3 variables" in out and "shape" in out.splitlines()[1] and f"1x{n}" in out
    assert main(["inspect", str(h5), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["channels"][0]["shape"] == "500x3"


def test_a_missing_variable_lists_the_closest_names(tmp_path, rec):
    path = tmp_path / "rig.mat"
    scipy.io.savemat(
        path,
        {
            "meas": {
                "t": rec.time_s[:, None],
                "EncMotor_deg": rec.motor_deg[:, None],
                "EncLoad_deg": rec.load_deg[:, None],
            }
        },
    )
    with pytest.raises(LogFormatError, match=r"no variable 'meas.EncMotor' for motor \(closest: \['meas.EncMotor_deg'"):
        read_all(path, columns={"motor": "meas.EncMotor", "load": "meas.EncLoad_deg"})
    with pytest.raises(LogFormatError, match=r"no time vector for motor 'EncMotor_deg'.*--columns time=NAME"):
        scipy.io.savemat(path, {"EncMotor_deg": rec.motor_deg[:, None], "EncLoad_deg": rec.load_deg[:, None]})
        read_all(path, columns={"motor": "EncMotor_deg", "load": "EncLoad_deg"})


def test_a_matlab_object_is_named_not_read(tmp_path, rec):
    path = tmp_path / "obj.mat"
    write_mat73(path, {"t": rec.time_s, "load": rec.load_deg})
    with h5py.File(path, "a") as f:  # a timeseries object: MATLAB's opaque object reference, not numbers
        ds = f.create_dataset("motor", data=np.array([[3707764736], [2], [1], [1], [1], [1]], dtype=np.uint32))
        ds.attrs["MATLAB_class"] = np.bytes_("timeseries")
        ds.attrs["MATLAB_object_decode"] = np.int32(3)
    with pytest.raises(LogFormatError, match=r"motor 'motor' is a MATLAB timeseries, not numbers; save it as a struct"):
        read_all(path, columns={"motor": "motor", "load": "load"})


def test_open_log_picks_the_reader_by_content_and_suffix(tmp_path, rec):
    v5, v73, h5 = tmp_path / "a.mat", tmp_path / "b.mat", tmp_path / "c.h5"
    scipy.io.savemat(v5, {"time": rec.time_s[:, None], "motor": rec.motor_deg[:, None], "load": rec.load_deg[:, None]})
    write_mat73(v73, {"time": rec.time_s, "motor": rec.motor_deg, "load": rec.load_deg})
    with h5py.File(h5, "w") as f:
        for name in ("time", "motor", "load"):
            f[name] = getattr(rec, {"time": "time_s", "motor": "motor_deg", "load": "load_deg"}[name])
    kinds = []
    for path in (v5, v73, h5):
        with open_log(path) as log:
            kinds.append(type(log).__name__)
        np.testing.assert_array_equal(read_all(path)[0][:, 2], rec.load_deg)
    assert kinds == ["MatV5Log", "Hdf5Log", "Hdf5Log"]


def test_a_large_v73_file_streams_with_flat_memory(tmp_path):
    """A 72 MB v7.3 recording read in blocks: the peak of memory allocated while reading stays near a few blocks
    (4 MB measured; read in blocks of a third of the file, 64 MB). The first block is read before measuring:
    it compiles the block checks, whose compiler allocates what no later block does."""
    n = 3_000_000
    t = np.arange(n) * 1e-3
    path = tmp_path / "long.mat"
    write_mat73(path, {"time": t, "motor": 30 * np.sin(t), "load": np.sin(t)})
    block = 65536
    with Hdf5Log(path, block_rows=block) as log:
        chunks = log.iter_chunks()
        rows = len(next(chunks))
        tracemalloc.start()
        try:
            rows += sum(len(chunk) for chunk in chunks)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
    assert rows == n
    whole = 3 * n * 8
    assert peak < 16 * block * 8 < whole / 8, f"peak {peak / 2**20:.1f} MB reading {whole / 2**20:.0f} MB of samples"


@pytest.fixture(scope="module")
def small_files(tmp_path_factory):
    """A small v5 and a small v7.3 file of 300 samples, for the fuzzing below."""
    d = tmp_path_factory.mktemp("matlab")
    t = np.arange(300) * 1e-3
    columns = {"time": t, "motor": 30 * np.sin(t), "load": np.sin(t)}
    scipy.io.savemat(d / "small5.mat", {k: v[:, None] for k, v in columns.items()})
    write_mat73(d / "small73.mat", columns)
    return {"v5": (d / "small5.mat").read_bytes(), "v73": (d / "small73.mat").read_bytes()}


@FUZZ
@given(data=st.data())
@pytest.mark.parametrize("kind", ["v5", "v73"])
def test_fuzz_bit_flips_and_truncation(small_files, tmp_path, kind, data):
    path = tmp_path / f"fuzz-{kind}.mat"
    path.write_bytes(damaged(small_files[kind], data.draw))
    check_damaged_file(path)


def test_track_and_diagnose_read_a_v73_file_and_its_copy_in_v5_is_the_same_log(capsys, tmp_path, rec):
    """``track`` and ``diagnose`` take a .mat like any log; the same recording saved as v5 after v7.3 is the
    log already imported (a log is its samples, not its bytes)."""
    v73, v5 = tmp_path / "rig73.mat", tmp_path / "rig5.mat"
    meas = {"t": rec.time_s, "EncMotor_deg": rec.motor_deg, "EncLoad_deg": rec.load_deg}
    write_mat73(v73, {"meas": meas})
    scipy.io.savemat(v5, {"meas": {k: v[:, None] for k, v in meas.items()}})
    mapping = ["--columns", "time=meas.t,motor=meas.EncMotor_deg,load=meas.EncLoad_deg"]
    assert main(["diagnose", str(v73), "--ratio", "30", *mapping, "--json"]) == 0, capsys.readouterr().err
    diagnosis = json.loads(capsys.readouterr().out)
    assert diagnosis["samples"] == rec.time_s.size and abs(diagnosis["backlash_before_deg"] - 0.5) < 0.02
    track = ["--ratio", "30", "--db", str(tmp_path / "wear.db"), "--gearbox", "gb1", "--every", "5", "--quiet"]
    track += mapping
    assert main(["track", str(v73), *track]) == 0, capsys.readouterr().err
    assert f"gb1: {v73}: {rec.time_s.size} samples, " in capsys.readouterr().out
    assert main(["track", str(v5), *track]) == 0, capsys.readouterr().err
    assert "already imported" in capsys.readouterr().out


def test_arrays_that_hold_no_signal_are_refused_by_name(tmp_path, rec):
    """A 3-D array, an empty one, a cell array and a column past the matrix's last: each a one-line error naming it."""
    path = tmp_path / "odd.mat"
    cells = np.empty((1, 2), dtype=object)
    cells[0, 0], cells[0, 1] = rec.motor_deg, rec.load_deg
    scipy.io.savemat(
        path,
        {
            "time": rec.time_s[:, None],
            "load": rec.load_deg[:, None],
            "cube": np.zeros((20000, 2, 2)),
            "none": np.zeros((0, 1)),
            "cells": cells,
            "pair": np.zeros((20000, 2)),
        },
    )
    for motor, message in (
        ("cube", r"motor 'cube' is a 20000x2x2 array: name a vector or a matrix's column"),
        ("none", r"motor 'none' is empty \(0x1\)"),
        ("cells", r"motor 'cells' is a cell or struct array, not numbers"),
        ("pair(:,3)", r"motor 'pair\(:,3\)' has 2 columns \(20000x2\)"),
    ):
        with pytest.raises(LogFormatError, match=message):
            read_all(path, columns={"motor": motor, "load": "load"})
