"""Issue 11 item 2: the source counters and gap figures in every result (estimate, diagnose, track).

Each result carries ``frames``, ``samples``, ``corrupt``, ``skipped``, ``gaps``, ``unpaired``
(``output_columns.COUNTER_KEYS``) and the gap figures (``output_columns.GAP_KEYS``); the text report shows the non-zero
ones. The expected values come from the source's own counters read independently (``open_log``), and
from the damage each test does to a generated log.
"""

from __future__ import annotations

import json

import can
import numpy as np
import pytest
from rig_can import RIG_CAN

from online_backlash.cli import main
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.output_columns import COUNTER_KEYS, FIELDS, GAP_KEYS, describe_counts, source_counts
from online_backlash.replay import open_log
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames, write_rig_serial_capture

CAN_OPTIONS = [*RIG_CAN, "--skip-bad-rows"]
BAD_ROWS = (100, 2000, 7001)  # data rows (0-based) made unparsable
DROPPED = range(5000, 5004)  # data rows removed: one gap of 5 periods at 1 kHz


def _json(capsys, *argv: str) -> dict:
    assert main([*argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _text(capsys, *argv: str) -> str:
    assert main(list(argv)) == 0
    return capsys.readouterr().out


@pytest.fixture(scope="module")
def bad_csv(tmp_path_factory):
    """A 20 s rig CSV with three unparsable rows and a 4-row dropout."""
    path = tmp_path_factory.mktemp("counters") / "bad.csv"
    simulate_rig(duration_s=20.0, seed=3).write_csv(path)
    header, *rows = path.read_text().splitlines()
    for i in BAD_ROWS:
        rows[i] = rows[i].replace(",", ",x", 1)
    rows = [r for i, r in enumerate(rows) if i not in DROPPED]
    path.write_text("\n".join([header, *rows]) + "\n")
    return path, len(rows)


@pytest.fixture(scope="module")
def damaged_can(tmp_path_factory):
    """A 20 s rig BLF (two messages per sample) with 10 frames damaged, 5 foreign frames and one load frame lost."""
    frames = list(
        rig_can_frames(
            simulate_rig(duration_s=20.0, seed=4), DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count")
        )
    )
    for i in range(1000, 1010):
        frames[2 * i].data[1] ^= 0xFF  # the CRC no longer matches
    del frames[2 * 3000 + 1]  # the load frame of sample 3000
    foreign = [
        can.Message(timestamp=frames[i].timestamp, arbitration_id=0x300, data=b"\x01\x02", is_extended_id=False)
        for i in range(10, 15)
    ]
    frames = sorted(frames + foreign, key=lambda m: m.timestamp)
    path = tmp_path_factory.mktemp("counters") / "damaged.blf"
    with can.Logger(str(path)) as writer:
        for msg in frames:
            writer.on_message_received(msg)
    return path, len(frames)


@pytest.fixture(scope="module")
def damaged_serial(tmp_path_factory):
    """A 20 s ascii serial capture with 6 lines made unparsable."""
    path = tmp_path_factory.mktemp("counters") / "rig.serial"
    write_rig_serial_capture(path, "ascii", duration_s=20.0, seed=5)
    lines = path.read_bytes().split(b"\n")
    for i in range(3000, 3006):
        lines[i] = b"garbage," + lines[i]
    path.write_bytes(b"\n".join(lines))
    return path


def _counters_of(path, **options) -> dict[str, int]:
    with open_log(path, **options) as log:
        for _ in log.iter_chunks():
            pass
    return source_counts(log.counters.as_dict())


def _check_result(out: dict, expected: dict[str, int]) -> None:
    assert {k: out[k] for k in COUNTER_KEYS} == expected
    assert all(k in out for k in GAP_KEYS)
    assert (out["gap_longest_s"] > 0) == (expected["gaps"] > 0)
    assert out["gap_longest_s"] <= out["gap_total_s"] + 1e-12


def test_the_new_keys_are_declared_in_rows():
    for key in (*COUNTER_KEYS, *GAP_KEYS):
        assert key in FIELDS and FIELDS[key].doc
    assert source_counts({"frames": 3, "samples": 2, "corrupt": 1}) == {
        "frames": 3,
        "samples": 2,
        "corrupt": 1,
        "skipped": 0,
        "gaps": 0,
        "unpaired": 0,
    }
    assert describe_counts({"frames": 3, "samples": 3, "gaps": 0}) == "frames 3, samples 3"


@pytest.mark.parametrize("method", ["recursive", "batch"])
def test_estimate_of_a_csv_counts_rows_bad_rows_and_the_gap(capsys, bad_csv, method):
    path, n_rows = bad_csv
    out = _json(capsys, "estimate", str(path), "--ratio", "30", "--skip-bad-rows", "--method", method)
    expected = {
        "frames": n_rows,
        "samples": n_rows - len(BAD_ROWS),
        "corrupt": len(BAD_ROWS),
        "skipped": 0,
        "gaps": 1,
        "unpaired": 0,
    }
    assert _counters_of(path, skip_bad=True) == expected
    _check_result(out, expected)
    assert out["gap_longest_s"] == pytest.approx(0.005, abs=1e-6)  # 4 rows missing: a step of 5 ms
    assert out["samples"] == expected["samples"]
    text = _text(capsys, "estimate", str(path), "--ratio", "30", "--skip-bad-rows", "--method", method)
    line = next(s for s in text.splitlines() if s.startswith("source:"))
    assert f"corrupt {len(BAD_ROWS)}" in line and "gaps 1 (longest 0.005 s" in line
    assert "skipped" not in line and "unpaired" not in line  # zeros are not shown


def test_estimate_of_a_can_log_counts_corrupt_foreign_and_unpaired_frames(capsys, damaged_can):
    path, n_frames = damaged_can
    out = _json(capsys, "estimate", str(path), "--ratio", "30", *CAN_OPTIONS)
    expected = _counters_of(
        path, dbc=RIG_DBC, motor_signal="MotorAngle.Count", load_signal="LoadAngle.Count", skip_bad=True
    )
    _check_result(out, expected)
    assert (out["frames"], out["corrupt"], out["skipped"]) == (n_frames, 10, 5)
    assert out["unpaired"] >= 1 and out["gaps"] >= 2  # the lost load frame; the damaged samples are missing
    assert out["frames"] == out["skipped"] + out["corrupt"] + out["unpaired"] + 2 * out["samples"]
    line = next(
        s
        for s in _text(capsys, "estimate", str(path), "--ratio", "30", *CAN_OPTIONS).splitlines()
        if s.startswith("source:")
    )
    assert "corrupt 10" in line and "skipped 5" in line and f"unpaired {out['unpaired']}" in line


def test_estimate_of_a_serial_capture_counts_corrupt_lines(capsys, damaged_serial):
    out = _json(capsys, "estimate", str(damaged_serial), "--ratio", "30", "--serial-format", "ascii", "--skip-bad-rows")
    expected = _counters_of(damaged_serial, serial_format="ascii", skip_bad=True)
    _check_result(out, expected)
    assert out["corrupt"] == 6 and out["frames"] == out["samples"] + out["corrupt"]


def test_diagnose_carries_the_counters(capsys, bad_csv):
    path, n_rows = bad_csv
    out = _json(capsys, "diagnose", str(path), "--ratio", "30", "--skip-bad-rows")
    _check_result(out, _counters_of(path, skip_bad=True))
    assert out["corrupt"] == len(BAD_ROWS) and out["frames"] == n_rows


def test_track_carries_the_counters(capsys, bad_csv, tmp_path):
    path, _ = bad_csv

    def argv(db: str) -> list[str]:
        return ["track", str(path), "--ratio", "30", "--db", str(tmp_path / db), "--gearbox", "g", "--skip-bad-rows"]

    counters = _json(capsys, *argv("h.db"))["counters"]
    _check_result(counters, _counters_of(path, skip_bad=True))
    assert np.isclose(counters["gap_longest_s"], 0.005)
    text = _text(capsys, *argv("h2.db"))
    assert f"corrupt {len(BAD_ROWS)}" in text
