"""ASAM MDF4 measurement files, written by asammdf in the tests, replayed as sample streams."""

from __future__ import annotations

import can
import numpy as np
import pytest
from asammdf import MDF, Signal
from hypothesis import given
from hypothesis import strategies as st
from measurement_cases import (
    FUZZ,
    assert_same_estimate_as_csv,
    check_damaged_file,
    damaged,
    read_all,
    rig_mdf,
    rig_recording,
)

from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.replay import open_log
from online_backlash.replay.mdf import MdfLog
from online_backlash.replay.registry import format_of

MAP = {"motor": "Motor", "load": "Load"}
MAP_T = {**MAP, "torque": "Torque"}


def write_mdf(path, groups):
    """Write an MDF 4.10 file: ``groups`` is a list of lists of Signals (one channel group each)."""
    mdf = MDF(version="4.10")
    for signals in groups:
        mdf.append(signals)
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


@pytest.fixture(scope="module")
def rec():
    return rig_recording()


@pytest.fixture
def small(tmp_path):
    """200 samples at 1 kHz: motor and load in one group, torque in a 100 Hz group."""
    t = np.arange(200) * 1e-3
    t_slow = np.arange(20) * 1e-2
    return write_mdf(
        tmp_path / "small.mf4",
        [
            [Signal(30 * np.sin(t), t, name="Motor", unit="deg"), Signal(np.sin(t), t, name="Load", unit="deg")],
            [Signal(2.0 + t_slow, t_slow, name="Torque", unit="Nm")],
        ],
    )


def test_estimate_of_an_mdf4_equals_the_csv_of_the_same_recording(capsys, tmp_path, rec):
    path = rig_mdf(tmp_path / "rig.mf4", rec)
    assert_same_estimate_as_csv(capsys, tmp_path, rec, path, "--columns", "motor=Motor,load=Load")


def test_channels_in_counts_with_a_conversion_and_counts_per_revolution(capsys, tmp_path, rec):
    # raw counts stored as integers with a linear conversion 1 count -> 1 count (+0): the unit decides
    t = rec.time_s
    motor = Signal(rec.motor_counts().astype(np.int64), t, name="EncM", unit="counts", conversion={"a": 1.0, "b": 0.0})
    load = Signal(rec.load_counts().astype(np.int64), t, name="EncL", unit="inc")
    path = write_mdf(tmp_path / "counts.mf4", [[motor, load]])
    argv = ["--columns", "motor=EncM,load=EncL", "--motor-cpr", str(2**14), "--load-cpr", str(2**17)]
    csv_path = tmp_path / "counts.csv"
    rec.write_csv(csv_path, units="counts")
    from measurement_cases import estimate_json

    expected = estimate_json(capsys, csv_path, "--units", "counts", "--motor-cpr", str(2**14), "--load-cpr", str(2**17))
    assert estimate_json(capsys, path, *argv)["backlash_deg"] == expected["backlash_deg"]


def test_conversion_is_applied_and_units_convert_to_degrees(tmp_path):
    t = np.arange(100) * 1e-3
    raw = np.arange(100, dtype=np.uint16)
    path = write_mdf(
        tmp_path / "conv.mf4",
        [
            [
                Signal(raw, t, name="M", unit="rev", conversion={"a": 0.01, "b": 1.0}),
                Signal(np.full(100, np.pi), t, name="L", unit="RAD"),
            ]
        ],
    )
    values, counters = read_all(path, columns={"motor": "M", "load": "L"})
    np.testing.assert_allclose(values[:, 1], (raw * 0.01 + 1.0) * 360.0)
    np.testing.assert_allclose(values[:, 2], 180.0)
    np.testing.assert_allclose(values[:, 0], t)
    assert counters.frames == counters.samples == 100
    # units= overrides the channels' own units
    values, _ = read_all(path, columns={"motor": "M", "load": "L"}, units="deg")
    np.testing.assert_allclose(values[:, 2], np.pi)


def test_groups_at_other_rates_are_put_on_the_motor_time_base(small):
    values, counters = read_all(small, columns=MAP_T)
    assert values.shape[0] == 191  # motor samples after the torque's last sample (0.19 s) are outside its span
    assert counters.skipped == 9 and counters.frames == 200
    np.testing.assert_allclose(values[:, 3], 2.0 + values[:, 0])  # torque interpolated at the motor's times
    np.testing.assert_allclose(values[:, 1], 30 * np.sin(values[:, 0]))


def test_a_load_channel_at_a_lower_rate_is_interpolated(tmp_path):
    t = np.arange(1000) * 1e-3
    slow = np.arange(200) * 5e-3
    path = write_mdf(
        tmp_path / "rates.mf4",
        [[Signal(t * 10, t, name="Motor", unit="deg")], [Signal(slow * 2, slow, name="Load", unit="deg")]],
    )
    values, counters = read_all(path, columns=MAP)
    np.testing.assert_allclose(values[:, 2], 2 * values[:, 0], atol=1e-12)
    assert counters.samples + counters.skipped == 1000


def test_max_samples_bounds_the_blocks(small):
    with MdfLog(small, columns=MAP_T, fragment_bytes=1024) as log:
        sizes = [len(c) for c in log.iter_chunks(max_samples=32)]
    assert max(sizes) <= 32 and sum(sizes) == 191


def test_a_missing_channel_names_the_closest(small):
    with pytest.raises(LogFormatError, match=r"small\.mf4: no channel 'Motr' for motor \(closest: \['Motor'"):
        read_all(small, columns={"motor": "Motr", "load": "Load"})


def test_unknown_unit_and_counts_without_cpr_name_the_channel(tmp_path):
    t = np.arange(10) * 1e-3
    volts = write_mdf(
        tmp_path / "v.mf4", [[Signal(t, t, name="Motor", unit="V"), Signal(t, t, name="Load", unit="deg")]]
    )
    with pytest.raises(
        LogFormatError,
        match=r"v\.mf4: motor channel 'Motor' has unit 'V', not an angle.*load channel 'Load' has unit 'deg'",
    ):
        read_all(volts, columns=MAP)
    counts = write_mdf(
        tmp_path / "c.mf4", [[Signal(t, t, name="Motor", unit="deg"), Signal(t, t, name="Load", unit="")]]
    )
    with pytest.raises(LogFormatError, match=r"load channel 'Load' is in encoder counts.*load_cpr"):
        read_all(counts, columns=MAP)
    with pytest.raises(InvalidParameterError, match="unknown column roles"):
        MdfLog(counts, columns={"moter": "Motor"})


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_samples_raise_or_are_counted(tmp_path, bad):
    t = np.arange(50) * 1e-3
    load = np.sin(t)
    load[17] = bad
    path = write_mdf(
        tmp_path / "nan.mf4", [[Signal(t, t, name="Motor", unit="deg"), Signal(load, t, name="Load", unit="deg")]]
    )
    with pytest.raises(LogFormatError, match=r"nan\.mf4:17: non-finite value in load 'Load'"):
        read_all(path, columns=MAP)
    values, counters = read_all(path, columns=MAP, skip_bad=True)
    assert counters.corrupt == 1 and values.shape[0] == 49 and np.all(np.isfinite(values[:, :3]))


def test_time_going_backwards_raises_or_is_counted(tmp_path):
    t = np.arange(50) * 1e-3
    t[30] = 0.0
    path = write_mdf(
        tmp_path / "back.mf4", [[Signal(t, t, name="Motor", unit="deg"), Signal(t, t, name="Load", unit="deg")]]
    )
    with pytest.raises(LogFormatError, match=r"back\.mf4:30: time goes backwards"):
        read_all(path, columns=MAP)
    values, counters = read_all(path, columns=MAP, skip_bad=True)
    assert counters.corrupt == 1 and np.all(np.diff(values[:, 0]) >= 0)


def test_a_truncated_file_is_a_log_format_error(small, tmp_path):
    data = small.read_bytes()
    for cut in (10, len(data) // 2, len(data) - 100):
        path = tmp_path / f"cut{cut}.mf4"
        path.write_bytes(data[:cut])
        with pytest.raises(LogFormatError, match=str(path)):
            read_all(path, columns=MAP)


def test_a_bus_logging_mf4_is_still_a_can_log(tmp_path, small):
    path = tmp_path / "bus.mf4"
    with can.Logger(str(path)) as writer:
        for i in range(10):
            writer.on_message_received(can.Message(arbitration_id=0x100, data=bytes(8), timestamp=i * 0.01))
    assert format_of(path).kind == "can" and format_of(small).kind == "mdf"
    from online_backlash.codecs.dbc import RIG_DBC
    from online_backlash.replay.canlog import CanLog

    with open_log(path, dbc=RIG_DBC, motor_signal="MotorAngle.Count", load_signal="LoadAngle.Count") as log:
        assert isinstance(log, CanLog)
    with open_log(small, columns=MAP) as log:
        assert isinstance(log, MdfLog)


@FUZZ
@given(data=st.data())
def test_fuzz_bit_flips_and_truncation(small, tmp_path, data):
    path = tmp_path / "fuzz.mf4"
    path.write_bytes(damaged(small.read_bytes(), data.draw))
    check_damaged_file(path, columns=MAP_T)
