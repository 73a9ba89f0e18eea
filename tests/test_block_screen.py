"""The compiled block checks of the column readers equal plain row-by-row checks.

Parquet files (written by pyarrow) and CSV files with random damage -- NaN, inf, nulls, angles
beyond the float64 limit, times that go backwards or repeat, gaps -- are read in random block
sizes; the samples, counters, gaps, the error (its row and reason) and the repeated-time warning
are those of a reference that checks each row in plain Python, as the readers did before their
checks were compiled (``replay/screen.py``).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from online_backlash.codecs.gaps import GapDetector
from online_backlash.errors import BacklashWarning, LogFormatError
from online_backlash.replay.csv import CsvLog
from online_backlash.replay.parquet import ParquetLog
from online_backlash.replay.tabular import MAX_ANGLE_DEG

ROLES = ("time", "motor", "load", "torque")
SETTINGS = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def reference(rows: np.ndarray, block_rows: int, skip_bad: bool, first_number: int):
    """Row-by-row checks of blocks of ``rows`` (columns time, motor, load[, torque]): the kept rows, corrupt,
    repeated times, gaps (the per-sample rule) and the first error as (row number, reason)."""
    kept, corrupt, repeated, last = [], 0, 0, -math.inf
    for start in range(0, len(rows), block_rows):
        block = rows[start : start + block_rows]
        good = []
        for i, row in enumerate(block):  # by value first, over the whole block
            finite = [math.isfinite(v) for v in row]
            if not all(finite):
                reason = "non-finite value in " + ", ".join(f"{r} {r!r}" for r, ok in zip(ROLES, finite) if not ok)
            elif abs(row[1]) > MAX_ANGLE_DEG or abs(row[2]) > MAX_ANGLE_DEG:
                reason = f"angle beyond {MAX_ANGLE_DEG:g} deg in motor 'motor' or load 'load': check the units"
            else:
                good.append(i)
                continue
            if not skip_bad:
                return None, (first_number + start + i, reason)
            corrupt += 1
        for i in good:  # then by time, over the rows good by value
            t = block[i][0]
            if t < last:
                if not skip_bad:
                    return None, (first_number + start + i, f"time goes backwards in 'time' ({t:g} s after {last:g} s)")
                corrupt += 1
                continue
            repeated += t == last
            last = t
            kept.append(block[i])
    detector = GapDetector()
    gaps = [detector.check(float(r[0])) for r in kept]
    return (np.array(kept).reshape(-1, rows.shape[1]), corrupt, repeated, gaps), None


def damaged_rows(data, with_torque: bool) -> np.ndarray:
    n = data.draw(st.integers(0, 60))
    steps = data.draw(st.lists(st.sampled_from([1e-3, 1e-3, 1e-3, 0.0, -2e-3, 0.05]), min_size=n, max_size=n))
    time = np.cumsum([0.0, *steps])[:n] if n else np.empty(0)
    width = 4 if with_torque else 3
    rows = np.column_stack([time] + [np.linspace(0.0, 3.0, n) for _ in range(width - 1)])
    special = st.sampled_from([math.nan, math.inf, -math.inf, 2 * MAX_ANGLE_DEG, -2 * MAX_ANGLE_DEG, 1e300])
    for _ in range(data.draw(st.integers(0, 4)) if n else 0):
        rows[data.draw(st.integers(0, n - 1)), data.draw(st.integers(0, width - 1))] = data.draw(special)
    return rows


def check_against_reference(read, rows, block_rows, skip_bad, first_number):
    expected, error = reference(rows, block_rows, skip_bad, first_number)
    if error is not None:
        with pytest.raises(LogFormatError) as caught:
            read()
        assert (caught.value.line, caught.value.reason) == error
        return None
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        chunks, counters = read()
    kept, corrupt, repeated, gaps = expected
    width = rows.shape[1]
    fields = ("time_s", "motor_deg", "load_deg", "torque_Nm")[:width]
    got = (
        np.column_stack([np.concatenate([getattr(c, f) for c in chunks] or [np.empty(0)]) for f in fields])
        if chunks
        else np.empty((0, width))
    )
    np.testing.assert_array_equal(got.reshape(-1, width), kept)
    assert counters.corrupt == corrupt and counters.samples == len(kept) and counters.frames == len(rows)
    flags = np.concatenate([c.after_gap for c in chunks]).tolist() if chunks else []
    assert flags == [g is not None for g in gaps]
    assert list(counters.gap_log) == [g for g in gaps if g is not None]
    return repeated, [w for w in seen if issubclass(w.category, BacklashWarning)]


@SETTINGS
@given(data=st.data(), with_torque=st.booleans(), block_rows=st.integers(1, 25), skip_bad=st.booleans())
def test_parquet_blocks_are_checked_as_row_by_row(tmp_path, data, with_torque, block_rows, skip_bad):
    rows = damaged_rows(data, with_torque)
    path = tmp_path / "damaged.parquet"
    pq.write_table(pa.table({r: rows[:, i] for i, r in enumerate(ROLES[: rows.shape[1]])}), path, row_group_size=17)

    def read():
        with ParquetLog(path, skip_bad=skip_bad, block_rows=block_rows) as log:
            return list(log.iter_chunks()), log.counters

    check_whole_pass(read, rows, block_rows, skip_bad, 0)


@SETTINGS
@given(data=st.data(), block_rows=st.integers(1, 25), skip_bad=st.booleans())
def test_csv_blocks_are_checked_as_row_by_row_and_repeated_times_warned(tmp_path, data, block_rows, skip_bad):
    rows = damaged_rows(data, with_torque=False)
    path = tmp_path / "damaged.csv"
    path.write_text("time,motor,load\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in rows))

    def read():
        log = CsvLog(path, skip_bad=skip_bad, block_rows=block_rows)
        return list(log.iter_chunks()), log.counters

    check_whole_pass(read, rows, block_rows, skip_bad, 2)


def check_whole_pass(read, rows, block_rows, skip_bad, first_number):
    """:func:`check_against_reference`, then the end of the pass: a time that never advanced is an error,
    samples repeating the previous time are counted in one warning (CSV and measurement files alike)."""
    expected, _ = reference(rows, block_rows, skip_bad, first_number)
    if expected is not None and len(expected[0]) >= 2 and expected[0][0, 0] == expected[0][-1, 0]:
        with pytest.raises(LogFormatError, match="never advances"):
            read()
        return
    result = check_against_reference(read, rows, block_rows, skip_bad, first_number)
    if result is not None:
        repeated, seen = result
        assert [str(w.message).split(": ", 1)[1].split(" of ")[0] for w in seen] == (
            [str(repeated)] if repeated and len(expected[0]) >= 2 else []
        )
