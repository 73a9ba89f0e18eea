"""``online-backlash estimate``: JSON contract, --trace, both methods on a simulated 30:1 log."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from online_backlash import BacklashRLS
from online_backlash.cli import main
from online_backlash.log_fit import TRACE_COLUMNS, fit_recursive
from online_backlash.replay import CsvLog, read_csv_arrays
from online_backlash.simulation.rig import simulate_rig

BATCH_KEYS = [
    "backlash_deg",
    "backlash_arcmin",
    "c_left_deg",
    "c_right_deg",
    "m_left",
    "m_right",
    "samples",
    "residual_rms_deg",
    "method",
]


@pytest.fixture(scope="module")
def log30(tmp_path_factory):
    """A 30:1 rig log (1 kHz, 14-bit motor, 17-bit load, noise) with a total play of 0.5 degrees."""
    rec = simulate_rig(duration_s=40.0, ratio=30.0, play_deg=0.5, seed=21)
    path = tmp_path_factory.mktemp("logs") / "rig30.csv"
    rec.write_csv(path)
    return path, rec


def _estimate(capsys, *argv: str) -> dict:
    assert main(["estimate", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("method", ["recursive", "batch"])
def test_both_methods_find_the_play_of_a_30_to_1_log(capsys, log30, method):
    path, rec = log30
    out = _estimate(capsys, str(path), "--ratio", "30", "--method", method)
    assert list(out)[: len(BATCH_KEYS)] == BATCH_KEYS
    assert out["method"] == method
    assert out["samples"] == rec.time_s.size
    assert out["backlash_deg"] == pytest.approx(0.5, rel=0.02)
    assert out["backlash_arcmin"] == pytest.approx(60 * out["backlash_deg"])
    if method == "recursive":
        assert 0 < out["backlash_std_deg"] < 0.01


def test_recursive_is_the_default_and_agrees_with_batch(capsys, log30):
    path, _ = log30
    rec = _estimate(capsys, str(path), "--ratio", "30")
    batch = _estimate(capsys, str(path), "--ratio", "30", "--method", "batch")
    assert rec["method"] == "recursive"
    assert rec["backlash_deg"] == pytest.approx(batch["backlash_deg"], rel=0.01)
    assert rec["c_left_deg"] == pytest.approx(batch["c_left_deg"], abs=0.005)


@pytest.mark.parametrize("every, expected_rows", [(None, 31), ("5", 7)])
def test_trace_has_the_documented_columns_and_one_row_per_period(capsys, log30, tmp_path, every, expected_rows):
    path, rec = log30
    trace = tmp_path / "trace.csv"
    argv = [str(path), "--ratio", "30", "--trace", str(trace)] + (["--every", every] if every else [])
    final = _estimate(capsys, *argv)
    with open(trace, newline="") as f:
        reader = csv.DictReader(f)
        assert tuple(reader.fieldnames) == TRACE_COLUMNS
        rows = [{k: float(v) for k, v in row.items()} for row in reader]
    # rows start once the warm start (10 s) has run; then one per period, and a last one at the end
    assert len(rows) == expected_rows
    times = np.array([r["time"] for r in rows])
    assert np.all(np.diff(times) > 0) and times[-1] == pytest.approx(rec.time_s[-1])
    assert rows[-1]["backlash_deg"] == pytest.approx(final["backlash_deg"])
    assert all(abs(r["backlash_deg"] - 0.5) < 0.01 for r in rows)


def test_streaming_fit_reads_chunks_and_passes_gaps(log30, tmp_path):
    _, rec = log30
    keep = np.r_[0:20000, 22000 : rec.time_s.size]  # two seconds missing
    rec.time_s, rec.motor_deg, rec.load_deg = rec.time_s[keep], rec.motor_deg[keep], rec.load_deg[keep]
    path = tmp_path / "gap.csv"
    rec.write_csv(path)
    with CsvLog(path, block_rows=3000) as log:  # many chunks
        small, est = fit_recursive(log.iter_chunks(), 30.0)
        assert log.counters.gaps == 1
    with CsvLog(path) as log:
        large, _ = fit_recursive(log.iter_chunks(), 30.0)
    assert small.as_dict() == large.as_dict()  # the chunk size changes nothing
    whole = read_csv_arrays(path)
    assert np.flatnonzero(whole.after_gap).tolist() == [20000]
    direct = BacklashRLS(full_engagement=True)  # the kinematic path's estimator (log_fit.KINEMATIC)
    direct.learn_many(whole.motor_deg / 30.0, whole.load_deg, after_gap=whole.after_gap)
    assert est.estimator.state_dict()["state"] == direct.state_dict()["state"]
    assert est.n_samples_seen_ == small.samples == keep.size


def test_trace_needs_the_recursive_method(capsys, log30, tmp_path):
    path, _ = log30
    assert main(["estimate", str(path), "--ratio", "30", "--method", "batch", "--trace", str(tmp_path / "t.csv")]) == 1
    assert "--trace needs --method recursive" in capsys.readouterr().err


def test_a_log_without_reversals_is_an_error(capsys, tmp_path):
    path = tmp_path / "one_way.csv"
    t = np.arange(2000) / 1000.0
    with open(path, "w") as f:
        f.write("time,motor,load\n")
        for ti in t:
            f.write(f"{ti:.3f},{300 * ti:.6f},{10 * ti:.6f}\n")
    assert main(["estimate", str(path), "--ratio", "30"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error:") and "reverses" in err
