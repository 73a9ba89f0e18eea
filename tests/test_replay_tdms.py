"""NI TDMS files, written by npTDMS in the tests, replayed as sample streams."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from measurement_cases import FUZZ, assert_same_estimate_as_csv, check_damaged_file, damaged, read_all, rig_recording
from nptdms import ChannelObject, TdmsWriter

from online_backlash.errors import LogFormatError
from online_backlash.replay import open_log
from online_backlash.replay.tdms import TdmsLog

MAP = {"motor": "Rig/Motor", "load": "Rig/Load"}


def wave(increment=1e-3, start=0.0, unit="deg"):
    return {"wf_increment": increment, "wf_start_offset": start, "unit_string": unit}


def write_tdms(path, channels, segments=1):
    """Write ``channels`` ((group, name, data, properties) tuples) in ``segments`` segments with TdmsWriter."""
    with TdmsWriter(str(path)) as writer:
        for k in range(segments):
            objects = []
            for group, name, data, props in channels:
                part = np.array_split(np.asarray(data), segments)[k]
                objects.append(ChannelObject(group, name, part, properties=props if k == 0 else {}))
            writer.write_segment(objects)
    return path


@pytest.fixture
def small(tmp_path):
    t = np.arange(200) * 1e-3
    return write_tdms(
        tmp_path / "small.tdms",
        [
            ("Rig", "Motor", 30 * np.sin(t), wave()),
            ("Rig", "Load", np.sin(t), wave()),
            ("Slow", "Torque", 2.0 + np.arange(20) * 1e-2, wave(1e-2, unit="Nm")),
        ],
        segments=3,
    )


def test_estimate_of_a_tdms_equals_the_csv_of_the_same_recording(capsys, tmp_path):
    rec = rig_recording()
    path = write_tdms(
        tmp_path / "rig.tdms",
        [("Rig", "Motor", rec.motor_deg, wave()), ("Rig", "Load", rec.load_deg, wave())],
        segments=4,
    )
    assert_same_estimate_as_csv(capsys, tmp_path, rec, path, "--columns", "motor=Rig/Motor,load=Load")


def test_waveform_time_segments_and_a_slower_channel_on_the_motor_time_base(small):
    values, counters = read_all(small, columns={**MAP, "torque": "Slow/Torque"})
    np.testing.assert_allclose(values[:, 0], np.arange(191) * 1e-3)
    np.testing.assert_allclose(values[:, 1], 30 * np.sin(values[:, 0]))
    np.testing.assert_allclose(values[:, 3], 2.0 + values[:, 0])
    assert counters.frames == 200 and counters.skipped == 9 and counters.samples == 191


def test_a_time_channel_and_units_from_unit_string(tmp_path):
    t = 5.0 + np.arange(100) * 2e-3
    path = write_tdms(
        tmp_path / "timed.tdms",
        [
            ("G", "t", t * 1e3, {"unit_string": "ms"}),
            ("G", "M", np.full(100, 0.5), {"unit_string": "rev"}),
            ("G", "L", np.arange(100.0), {"unit_string": "counts"}),
        ],
    )
    values, counters = read_all(path, columns={"time": "G/t", "motor": "M", "load": "L"}, load_cpr=400)
    np.testing.assert_allclose(values[:, 0], t)
    np.testing.assert_allclose(values[:, 1], 180.0)
    np.testing.assert_allclose(values[:, 2], np.arange(100) * 0.9)
    assert counters.samples == 100


def test_start_offset_and_block_size(small):
    with TdmsLog(small, columns=MAP, block_rows=64) as log:
        sizes = [len(c) for c in log.iter_chunks(max_samples=50)]
    assert max(sizes) <= 50 and sum(sizes) == 200


def test_missing_channel_lists_the_closest_and_ambiguous_names_are_refused(small, tmp_path):
    with pytest.raises(LogFormatError, match=r"small\.tdms: no channel 'Rig/Motr' for motor \(closest: \['Rig/Motor'"):
        read_all(small, columns={"motor": "Rig/Motr", "load": "Rig/Load"})
    two = write_tdms(
        tmp_path / "two.tdms",
        [("A", "Motor", np.zeros(5), wave()), ("B", "Motor", np.zeros(5), wave()), ("A", "Load", np.zeros(5), wave())],
    )
    with pytest.raises(LogFormatError, match=r"'Motor' for motor is in several groups"):
        read_all(two, columns={"motor": "Motor", "load": "Load"})


def test_no_time_and_a_unit_mismatch_are_errors(tmp_path):
    path = write_tdms(
        tmp_path / "notime.tdms",
        [("G", "Motor", np.zeros(5), {"unit_string": "deg"}), ("G", "Load", np.zeros(5), {"unit_string": "deg"})],
    )
    with pytest.raises(LogFormatError, match=r"notime\.tdms: motor channel 'G/Motor' has no wf_increment"):
        read_all(path, columns={"motor": "G/Motor", "load": "G/Load"})
    path = write_tdms(
        tmp_path / "mismatch.tdms", [("G", "Motor", np.zeros(5), wave()), ("G", "Load", np.zeros(5), wave(unit="Nm"))]
    )
    with pytest.raises(
        LogFormatError,
        match=r"load channel 'G/Load' has unit 'Nm', not an angle.*motor channel 'G/Motor' has unit 'deg'",
    ):
        read_all(path, columns={"motor": "G/Motor", "load": "G/Load"})


def test_non_finite_and_backward_time_raise_or_are_counted(tmp_path):
    t = np.arange(60) * 1e-3
    t[40] = 0.01
    motor = np.sin(t)
    motor[7] = np.nan
    path = write_tdms(
        tmp_path / "bad.tdms", [("G", "t", t, {}), ("G", "Motor", motor, {}), ("G", "Load", np.cos(t), {})]
    )
    columns = {"time": "G/t", "motor": "G/Motor", "load": "G/Load"}
    with pytest.raises(LogFormatError, match=r"bad\.tdms:7: non-finite value in motor 'G/Motor'"):
        read_all(path, columns=columns)
    values, counters = read_all(path, columns=columns, skip_bad=True)
    assert counters.corrupt == 2 and values.shape[0] == 58
    assert np.all(np.isfinite(values[:, :3])) and np.all(np.diff(values[:, 0]) >= 0)


def test_a_truncated_file_raises_or_gives_its_complete_part(small, tmp_path):
    # npTDMS reads the complete segments of a file cut short (a recorder that crashed), with only a
    # log line as a sign: the file is refused as truncated, naming what is readable; with skip_bad
    # the whole samples of both channels are read and the cut counted as corrupt (issue 26);
    # a file cut inside its first header is an error
    data = small.read_bytes()
    path = tmp_path / "cut5.tdms"
    path.write_bytes(data[:5])
    with pytest.raises(LogFormatError, match=str(path)):
        read_all(path, columns=MAP)
    for cut in (len(data) // 2, len(data) - 7):
        path = tmp_path / f"cut{cut}.tdms"
        path.write_bytes(data[:cut])
        with pytest.raises(
            LogFormatError,
            match=rf"cut{cut}.tdms: truncated: the file ends inside its last segment \(readable values: Rig/Motor",
        ):
            read_all(path, columns=MAP)
        values, counters = read_all(path, columns=MAP, skip_bad=True)
        assert 0 < values.shape[0] <= 200 and counters.frames == counters.samples + counters.skipped + counters.corrupt
        assert counters.corrupt == 1
        np.testing.assert_allclose(values[:, 1], 30 * np.sin(values[:, 0]))
        np.testing.assert_allclose(values[:, 2], np.sin(values[:, 0]), atol=1e-12)


def test_open_log_picks_the_tdms_reader(small):
    with open_log(small, columns=MAP) as log:
        assert isinstance(log, TdmsLog)


@FUZZ
@given(data=st.data())
def test_fuzz_bit_flips_and_truncation(small, tmp_path, data):
    path = tmp_path / "fuzz.tdms"
    path.write_bytes(damaged(small.read_bytes(), data.draw))
    check_damaged_file(path, columns={**MAP, "torque": "Slow/Torque"})
