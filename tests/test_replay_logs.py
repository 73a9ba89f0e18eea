"""Replay of recorded CAN logs in every python-can format, decoded with the shipped DBC."""

from __future__ import annotations

import gzip
import shutil

import can
import numpy as np
import pytest

from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.codecs.options import CanDecoding
from online_backlash.codecs.pairing import FramePipeline
from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.replay import LOG_READERS, open_log, read_log_arrays
from online_backlash.replay.canlog import CanLog
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames

SPLIT = {"dbc": RIG_DBC, "motor_signal": "MotorAngle.Count", "load_signal": "LoadAngle.Count"}
T0 = 1_700_000_000.0


@pytest.fixture(scope="module")
def frames():
    rec = simulate_rig(duration_s=1.0, rate_hz=1000.0, seed=7)
    out = list(rig_can_frames(rec, DbcDecoder(RIG_DBC, SPLIT["motor_signal"], SPLIT["load_signal"]), T0, skew_s=1e-4))
    out.insert(10, can.Message(timestamp=out[9].timestamp, arbitration_id=0x3AB, data=b"\xde\xad"))  # other traffic
    return out


@pytest.fixture(scope="module")
def expected(frames):
    pipe = FramePipeline(DbcDecoder(RIG_DBC, SPLIT["motor_signal"], SPLIT["load_signal"]))
    return [s for s in map(pipe.feed, frames) if s is not None]


def write_log(path, frames):
    with can.Logger(path) as writer:
        for f in frames:
            writer.on_message_received(f)
    return path


def angles(samples):
    return [(s.motor_deg, s.load_deg, s.seq, s.after_gap) for s in samples]


def test_every_python_can_format_is_registered():
    for suffix in (".asc", ".blf", ".log", ".trc"):
        assert suffix in LOG_READERS
    assert LOG_READERS[".csv"].__name__ == "CsvLog"  # ours, not python-can's


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log", ".trc", ".asc.gz", ".log.gz"])
def test_round_trip_gives_the_samples_decoded_from_the_frames(tmp_path, frames, expected, suffix):
    path = write_log(tmp_path / f"run{suffix}", frames)
    log = open_log(path, **SPLIT)
    got = list(log)
    assert angles(got) == angles(expected)
    assert np.allclose([s.time_s for s in got], [s.time_s for s in expected], rtol=0, atol=1e-3)
    c = log.counters
    assert (c.frames, c.skipped, c.corrupt, c.unpaired) == (len(frames), 1, 0, 0)
    assert c.samples == len(expected) == 1000


def test_realtime_replay_gives_the_same_samples(tmp_path, frames, expected):
    path = write_log(tmp_path / "run.blf", frames[:41])
    assert angles(CanLog(path, CanDecoding(**SPLIT), realtime=True)) == angles(expected[:20])


def test_a_raw_log_directory_is_read_in_name_order(tmp_path, frames, expected):
    write_log(tmp_path / "can-20260101T000000_000000Z-0000.asc", frames[:1001])
    write_log(tmp_path / "can-20260101T000000_000000Z-0001.asc", frames[1001:])
    (tmp_path / "notes.txt").write_text("not a log")
    assert angles(CanLog(tmp_path, CanDecoding(**SPLIT))) == angles(expected)


def test_open_log_and_read_log_arrays_take_a_raw_log_directory(tmp_path, frames, expected):
    write_log(tmp_path / "can-20260101T000000_000000Z-0000.blf", frames[:1001])
    write_log(tmp_path / "can-20260101T000000_000000Z-0001.blf", frames[1001:])
    log = open_log(tmp_path, **SPLIT)
    assert angles(log) == angles(expected) and log.counters.frames == len(frames)
    arrays = read_log_arrays(tmp_path, **SPLIT)
    assert arrays.load_deg.tolist() == [s.load_deg for s in expected]


def test_a_serial_capture_directory_reads_as_one_capture(tmp_path):
    from online_backlash.simulation.rig_logs import write_rig_serial_capture

    write_rig_serial_capture(tmp_path / "whole.serial", "binary", duration_s=0.2)
    data = (tmp_path / "whole.serial").read_bytes()
    split = tmp_path / "raw"
    split.mkdir()
    (split / "serial-20260101T000000_000000Z-0000.serial").write_bytes(data[:1001])  # cut inside a frame
    (split / "serial-20260101T000000_000000Z-0001.serial").write_bytes(data[1001:])
    options = {"serial_format": "binary", "motor_cpr": 2**14, "load_cpr": 2**17}
    whole, parts = read_log_arrays(tmp_path / "whole.serial", **options), read_log_arrays(split, **options)
    assert len(parts) == 200 and parts.motor_deg.tolist() == whole.motor_deg.tolist()


def test_a_log_directory_must_hold_one_format(tmp_path, frames):
    with pytest.raises(LogFormatError, match="empty directory"):
        open_log(tmp_path, **SPLIT)
    write_log(tmp_path / "a.blf", frames[:10])
    (tmp_path / "b.serial").write_bytes(b"0.0,1.0,2.0\n")
    with pytest.raises(LogFormatError, match=r"one format, found suffixes \['\.blf', '\.serial'\]"):
        open_log(tmp_path, **SPLIT)
    csvs = tmp_path / "csvs"
    csvs.mkdir()
    (csvs / "a.csv").write_text("time,motor,load\n0,0,0\n")
    with pytest.raises(LogFormatError, match="not supported; give one file"):
        open_log(csvs)


def test_a_truncated_blf_names_the_file_and_the_frame(tmp_path, frames):
    path = write_log(tmp_path / "run.blf", frames)
    data = path.read_bytes()
    cut = tmp_path / "cut.blf"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(
        LogFormatError, match=r"cut\.blf:\d+: truncated: \d+ of the \d+ bytes its header announces"
    ) as info:
        list(open_log(cut, **SPLIT))
    assert 0 < info.value.line < len(frames)
    log = open_log(cut, **SPLIT, skip_bad=True)
    n = len(list(log))
    assert n > 0 and log.counters.corrupt == 1
    assert log.counters.frames == log.counters.skipped + log.counters.corrupt + log.counters.unpaired + 2 * n


def test_a_malformed_candump_line_names_the_frame(tmp_path, frames):
    path = write_log(tmp_path / "run.log", frames[:20])
    lines = path.read_text().splitlines(keepends=True)
    lines[7] = "(1700000000.000000) vcan0 1Z1#zz\n"
    path.write_text("".join(lines))
    with pytest.raises(LogFormatError, match=r"run\.log:7: unreadable frame"):
        list(open_log(path, **SPLIT))


def test_missing_file_and_missing_dbc_options(tmp_path):
    with pytest.raises(LogFormatError, match="cannot open"):
        list(open_log(tmp_path / "nope.blf", **SPLIT))
    with pytest.raises(InvalidParameterError, match="--dbc"):
        open_log(tmp_path / "x.blf")


def test_gzip_of_a_damaged_file_is_a_log_format_error(tmp_path, frames):
    path = write_log(tmp_path / "run.blf", frames)
    with open(path, "rb") as src, gzip.open(tmp_path / "run.blf.gz", "wb") as dst:
        shutil.copyfileobj(src, dst)
    raw = (tmp_path / "run.blf.gz").read_bytes()
    (tmp_path / "bad.blf.gz").write_bytes(raw[: len(raw) // 3])
    with pytest.raises(LogFormatError, match=r"bad\.blf\.gz"):
        list(open_log(tmp_path / "bad.blf.gz", **SPLIT))


def test_simulated_rig_logs_for_the_readme_examples(tmp_path):
    from online_backlash.simulation.rig_logs import write_rig_can_log, write_rig_serial_capture

    assert write_rig_can_log(tmp_path / "rig.trc", duration_s=0.5) == 1000
    log = open_log(tmp_path / "rig.trc", **SPLIT)
    assert len(list(log)) == 500 and log.counters.corrupt == 0 and log.counters.gaps == 0
    write_rig_serial_capture(tmp_path / "rig.serial", "binary", duration_s=0.5)
    cap = open_log(tmp_path / "rig.serial", serial_format="binary", motor_cpr=2**14, load_cpr=2**17)
    assert len(list(cap)) == 500 and cap.counters.frames == 500


def test_estimate_max_skew_pairs_frames_further_apart_than_the_default(tmp_path, capsys):
    """Paired by time (``--counter-signal none``): the load frame 3 ms after the motor's is an orphan
    under the default 1 ms, a pair under ``--max-skew 0.004``."""
    import json

    from online_backlash.cli import main

    rec = simulate_rig(duration_s=20.0, rate_hz=100.0, seed=3, reversal_s=(2.0, 4.0))
    path = write_log(
        tmp_path / "skewed.blf",
        rig_can_frames(rec, DbcDecoder(RIG_DBC, SPLIT["motor_signal"], SPLIT["load_signal"]), T0, skew_s=3e-3),
    )
    argv = [
        "estimate",
        str(path),
        "--dbc",
        "rig",
        "--motor-signal",
        SPLIT["motor_signal"],
        "--load-signal",
        SPLIT["load_signal"],
        "--counter-signal",
        "none",
        "--ratio",
        "30",
        "--json",
        "--method",
        "batch",
    ]
    assert main(argv) != 0  # every frame an orphan: no samples
    assert "error:" in capsys.readouterr().err
    assert main([*argv, "--max-skew", "0.004"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["samples"], out["unpaired"]) == (rec.time_s.size, 0)
    assert out["backlash_deg"] == pytest.approx(0.5, abs=0.02)
    with pytest.raises(SystemExit) as usage:  # argparse's usage error, no traceback
        main([*argv, "--max-skew", "-1"])
    assert usage.value.code == 2 and "--max-skew: expected a positive number" in capsys.readouterr().err
