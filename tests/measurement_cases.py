"""Checks shared by the measurement-file reader tests (MDF, TDMS, Parquet/Arrow).

Each test module writes its files with the real library; these helpers read them back, compare
``estimate`` with the CSV of the same recording, and fuzz a real file with bit flips and
truncation (only LogFormatError escapes, it names the file, nothing non-finite is yielded, and
the counters reconcile).
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from online_backlash.cli import main
from online_backlash.errors import BacklashWarning, LogFormatError
from online_backlash.replay import open_log
from online_backlash.simulation.rig import simulate_rig

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def rig_recording(duration_s: float = 20.0):
    """A 30:1 rig recording (1 kHz) with a total play of 0.5 degrees."""
    return simulate_rig(duration_s=duration_s, ratio=30.0, play_deg=0.5, seed=5)


def rig_mdf(path: Path, rec, *more, names=("Motor", "Load"), units=("deg", "deg"), start=None) -> Path:
    """The rig recording ``rec`` written by asammdf as an MDF 4.10 file: its motor and load angles as the channels
    ``names`` (in ``units``) of one channel group, with the Signals ``more``; ``start``: the header's start time."""
    from asammdf import MDF, Signal

    mdf = MDF(version="4.10")
    if start is not None:
        mdf.header.start_time = start
    angles = (rec.motor_deg, rec.load_deg)
    mdf.append([*(Signal(a, rec.time_s, name=n, unit=u) for a, n, u in zip(angles, names, units)), *more])
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def fresh_python(script: str, *argv: str) -> list[str]:
    """The words ``script`` prints, run with ``argv`` in a fresh interpreter (which modules a path imports)."""
    done = subprocess.run([sys.executable, "-c", script, *argv], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.split()


def estimate_json(capsys, path: Path, *argv: str) -> dict:
    """``online-backlash estimate PATH --ratio 30 ARGV --json`` as a dict (exit code 0 asserted)."""
    assert main(["estimate", str(path), "--ratio", "30", *argv, "--json"]) == 0, capsys.readouterr().err
    return json.loads(capsys.readouterr().out)


def assert_same_estimate_as_csv(capsys, tmp_path: Path, rec, path: Path, *argv: str) -> dict:
    """``estimate`` of ``path`` gives the same play, flanks and sample count as the CSV of ``rec``."""
    csv_path = tmp_path / "same.csv"
    rec.write_csv(csv_path)
    expected = estimate_json(capsys, csv_path)
    got = estimate_json(capsys, path, *argv)
    assert got["samples"] == expected["samples"] == rec.time_s.size
    for key in ("backlash_deg", "c_left_deg", "c_right_deg"):
        assert got[key] == pytest.approx(expected[key], abs=1e-6)  # the CSV rounds to 1e-9 deg
    assert abs(got["backlash_deg"] - 0.5) < 0.02
    return got


def read_all(path: Path, **options):
    """Every chunk of a log concatenated (time, motor, load, torque) and the reader's counters."""
    with open_log(path, **options) as log:
        chunks = list(log.iter_chunks())
        counters = log.counters
    if not chunks:
        return np.empty((0, 4)), counters
    return np.column_stack(
        [np.concatenate([getattr(c, f) for c in chunks]) for f in ("time_s", "motor_deg", "load_deg", "torque_Nm")]
    ), counters


def damaged(data: bytes, draw) -> bytes:
    """``data`` with a few bit flips and a truncation drawn by hypothesis (``draw`` = ``st.data().draw``)."""
    buf = bytearray(data)
    for pos in draw(st.lists(st.integers(0, len(buf) * 8 - 1), max_size=6)):
        buf[pos // 8] ^= 1 << (pos % 8)
    return bytes(buf[: draw(st.integers(0, len(buf)))])


def check_damaged_file(path: Path, **options) -> None:
    """Read a damaged file: only LogFormatError naming it escapes, and what the reader warns of (a flipped
    bit can repeat a timestamp) names it too; samples are finite, in time order; counters reconcile."""
    for skip_bad in (False, True):
        try:
            with warnings.catch_warnings(record=True) as seen:
                warnings.simplefilter("always", BacklashWarning)
                values, counters = read_all(path, skip_bad=skip_bad, **options)
        except LogFormatError as exc:
            assert str(path) in str(exc)
            continue
        for w in seen:
            assert issubclass(w.category, BacklashWarning) and str(path) in str(w.message), w
        assert np.all(np.isfinite(values[:, :3]))
        assert np.all(np.diff(values[:, 0]) >= 0)
        assert counters.frames == counters.samples + counters.corrupt + counters.skipped
        assert counters.samples == values.shape[0]
        assert not np.any(np.isinf(values[:, 3]))  # torque: finite, or NaN where absent
