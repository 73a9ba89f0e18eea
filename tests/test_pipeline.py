"""The pipeline (chunks -> estimator -> a row every N s of data), the declared estimate row, and that the pipeline's
modules never print (the import rules: tests/test_imports.py)."""

from __future__ import annotations

import ast
import csv
import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from online_backlash import BacklashRLS
from online_backlash.cli import main
from online_backlash.errors import InvalidParameterError, LogFormatError
from online_backlash.history.store import ESTIMATE_FIELDS, Estimate, HistoryStore, estimates_table
from online_backlash.output_columns import (
    FIELDS,
    HISTORY_CSV_COLUMNS,
    REPORT_KEYS,
    STORE_COLUMNS,
    TRACE_COLUMNS,
    EstimateRow,
)
from online_backlash.pipeline import DataClock, Pipeline
from online_backlash.simulation import synthetic
from online_backlash.simulation.rig import simulate_rig
from online_backlash.stream import SampleChunk

PACKAGE = Path(__import__("online_backlash").__file__).resolve().parent


@pytest.fixture(scope="module")
def rig30():
    return simulate_rig(duration_s=30.0, ratio=30.0, play_deg=0.5, seed=5).to_chunk()


def pieces(chunk: SampleChunk, cuts: list[int]) -> list[SampleChunk]:
    edges = [0, *cuts, len(chunk)]
    return [
        SampleChunk(
            chunk.time_s[a:b], chunk.motor_deg[a:b], chunk.load_deg[a:b], chunk.torque_Nm[a:b], chunk.after_gap[a:b]
        )
        for a, b in itertools.pairwise(edges)
    ]


def run_rows(chunks, every_s=2.0, estimator=None):
    pipe = Pipeline(estimator or BacklashRLS(), 30.0, every_s)
    rows = [s.row for s in pipe.run(chunks) if s.row is not None]
    return rows, pipe


# -- the clock ---------------------------------------------------------------------------------


def test_rows_do_not_depend_on_how_the_stream_is_cut(rig30):
    whole, pipe_whole = run_rows([rig30])
    cuts = sorted(np.random.default_rng(1).choice(np.arange(1, len(rig30)), 40, replace=False).tolist())
    cut, pipe_cut = run_rows(pieces(rig30, cuts))
    assert len(whole) == 10  # after the 10 s warm start: 10, 12, ..., 28 s of data
    assert cut == whole
    assert pipe_cut.estimator.state_dict() == pipe_whole.estimator.state_dict()
    assert pipe_cut.clock.state_dict() == pipe_whole.clock.state_dict()


def test_a_row_every_s_seconds_of_data_not_of_clock_time(rig30):
    t = rig30.time_s.copy()
    gap_at = 15000
    t[gap_at:] += 100.0  # 100 s without data
    gap = np.zeros(t.size, bool)
    gap[gap_at] = True
    chunk = dataclasses.replace(rig30, time_s=t, after_gap=gap)
    pipe = Pipeline(BacklashRLS(), 30.0, every_s=2.0)
    data_s = [pipe.clock.data_ns / 1e9 for s in pipe.run([chunk]) if s.row is not None]
    # the step across the gap counts nothing: 29.998 s of data, rows where it reaches 10, 12, ..., 28 s
    assert np.allclose(data_s, np.arange(10.0, 29.0, 2.0), atol=1e-9)
    assert pipe.clock.data_ns == round((t.size - 2) * 1e6)


def test_the_pipeline_refers_once_and_passes_time_torque_and_gaps_through(rig30):
    class Recorder:
        started = False

        def __init__(self):
            self.calls = []

        def learn_many(self, u, y, after_gap, *, time_s, torque_Nm, assume_finite=False, snapshot_at=None):
            self.calls.append((u, y, after_gap, time_s, torque_Nm))

    chunk = dataclasses.replace(
        rig30, torque_Nm=np.linspace(-1.0, 1.0, len(rig30)), after_gap=np.arange(len(rig30)) % 7000 == 0
    )
    rec = (
        Recorder()
    )  # every flag reaches the estimator: which gaps are bridged is its decision (tests/test_gap_bridging.py)
    steps = list(Pipeline(rec, -30.0, every_s=3.0).run(pieces(chunk, [4321, 17000])))
    u, y, gap, t, q = (np.concatenate(c) for c in zip(*rec.calls))
    np.testing.assert_array_equal(u, chunk.motor_deg / -30.0)
    np.testing.assert_array_equal(np.concatenate([s.u_deg for s in steps]), u)
    for got, given in ((y, chunk.load_deg), (gap, chunk.after_gap), (t, chunk.time_s), (q, chunk.torque_Nm)):
        np.testing.assert_array_equal(got, given)
    assert steps[-1].samples == len(chunk) and all(s.row is None for s in steps)  # never started: no row


def test_a_resumed_pipeline_continues_the_rows_of_an_uninterrupted_one(rig30):
    whole, _ = run_rows([rig30], every_s=1.5)
    first, second = pieces(rig30, [18_123])
    rows, pipe = run_rows([first], every_s=1.5)
    saved = json.loads(json.dumps({"estimator": pipe.estimator.state_dict(), "clock": pipe.clock.state_dict()}))
    resumed = Pipeline(BacklashRLS.from_state(saved["estimator"]), 30.0, 1.5, DataClock.from_state(1.5, saved["clock"]))
    rows += [s.row for s in resumed.run([second]) if s.row is not None]
    assert rows == whole


def test_finish_closes_the_stream_with_one_last_row(rig30):
    rows, pipe = run_rows([rig30], every_s=4.0)
    last = pipe.finish()
    assert last is not None and last.time_s == rig30.time_s[-1] and last.n_samples == len(rig30)
    assert rows[-1].time_s < last.time_s
    assert pipe.finish() is None  # nothing learnt since
    quiet = Pipeline(BacklashRLS(), 30.0, every_s=None)  # no rows on the way (they cost time): only the last
    assert [s.row for s in quiet.run([rig30])] == [None] and quiet.finish() == last


def test_bad_settings_and_an_empty_stream_are_clear_errors(rig30):
    for every in (0.0, -1.0, float("nan"), "1"):
        with pytest.raises(InvalidParameterError, match="every_s"):
            Pipeline(BacklashRLS(), 30.0, every)
    with pytest.raises(InvalidParameterError, match="ratio"):
        Pipeline(BacklashRLS(), 0.0, 1.0)
    with pytest.raises(LogFormatError, match=r"empty\.csv.*no data rows"):
        list(Pipeline(BacklashRLS(), 30.0).run([], "empty.csv"))


# -- the declared row ----------------------------------------------------------------------------


def test_every_output_is_a_selection_of_the_declared_fields():
    names = {f.name for f in FIELDS.values()}
    for view in (REPORT_KEYS, TRACE_COLUMNS, STORE_COLUMNS, HISTORY_CSV_COLUMNS):
        assert set(view) <= names and len(set(view)) == len(view)
    # the store's table and its record type are derived from (or agree with) the declaration
    assert [c.name for c in estimates_table.columns] == ["id", "gearbox_id", "run_id", *STORE_COLUMNS]
    assert ESTIMATE_FIELDS == ("gearbox_id", "run_id", *STORE_COLUMNS)
    assert tuple(f.name for f in dataclasses.fields(Estimate)) == ESTIMATE_FIELDS
    for name in STORE_COLUMNS:
        column = estimates_table.c[name]
        field = FIELDS.get(name) or next(f for f in FIELDS.values() if f.name == name and f.kind is not str)
        assert column.nullable == field.nullable


def test_the_contracts_keep_their_names_and_order():
    assert TRACE_COLUMNS == (
        "time",
        "backlash_deg",
        "backlash_std_deg",
        "c_left_deg",
        "c_right_deg",
        "m_left",
        "m_right",
    )
    assert REPORT_KEYS == (
        "backlash_deg", "backlash_arcmin", "c_left_deg", "c_right_deg", "m_left", "m_right", "samples",
        "residual_rms_deg", "method", "play_observable", "torque_reversals", "backlash_lower_bound_deg",
        "stiffness_nm_per_arcmin", "stiffness_left_nm_per_arcmin", "stiffness_right_nm_per_arcmin",
        "lost_motion_arcmin", "hysteresis_loss_arcmin",
        # issue 27: the path of the play and the verdict on it
        "backlash_upper_bound_deg", "reason", "play_method", "play_method_reason",
    )  # fmt: skip
    assert HISTORY_CSV_COLUMNS == (
        "time", "time_unix_s", "operating_hours", "load_revolutions", "reversals", "backlash_deg", "backlash_std_deg",
        "backlash_arcmin", "backlash_std_arcmin", "c_left_deg", "c_right_deg", "m_left", "m_right", "residual_rms_deg",
        "n_samples", "run_id", "sample_index", "play_observable", "torque_mean_nm", "torque_rms_nm", "torque_reversals",
        "stiffness_nm_per_arcmin", "machine_hours",
        "play_method", "play_method_reason", "reason", "backlash_lower_bound_deg", "backlash_upper_bound_deg",
    )  # fmt: skip


def test_a_row_reads_the_estimator_and_is_none_before_it_starts(rig30):
    est = BacklashRLS()
    u, y = rig30.referred(30.0)
    est.learn_many(u[:5000], y[:5000])
    assert EstimateRow.from_estimator(est, 5.0) is None
    est.learn_many(u[5000:], y[5000:])
    row = EstimateRow.from_estimator(est, 29.999)
    assert row is not None and row.backlash_deg == est.backlash_ and row.n_reversals == est.n_reversals_
    assert row.trace() == {"time": 29.999, **{k: getattr(est, k.removesuffix("_deg") + "_") for k in TRACE_COLUMNS[1:]}}


# -- what diagnose finds, tracked ----------------------------------------------------------------


@pytest.fixture(scope="module")
def te_logs(tmp_path_factory):
    """Two 30 s logs of a 30:1 rig with a transmission error (UNIX times, one day apart).

    30 s, not less: the diagnosis adds a term only if it holds on held-out reversal cycles, and
    a 20 s log has too few cycles to show the motor-order error out of sample."""
    folder = tmp_path_factory.mktemp("te")
    paths = []
    for k in range(2):
        rec = simulate_rig(duration_s=30.0, seed=40 + k)
        t, m, y, _ = synthetic.transmission_error(rec)
        path = folder / f"te{k}.csv"
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["time", "motor", "load"])
            w.writerows([f"{a + 1.7e9 + k * 86400:.6f}", f"{b:.9f}", f"{c:.9f}"] for a, b, c in zip(t, m, y))
        paths.append(path)
    return paths


def test_diagnose_trace_tracks_the_backlash_with_the_effects_found(te_logs, tmp_path, capsys):
    trace = tmp_path / "trace.csv"
    assert main(["diagnose", str(te_logs[0]), "--ratio", "30", "--json", "--trace", str(trace), "--every", "2"]) == 0
    found = json.loads(capsys.readouterr().out)
    assert [e["name"] for e in found["effects"]] == ["transmission_error"]
    with open(trace, newline="") as f:
        reader = csv.DictReader(f)
        assert tuple(reader.fieldnames) == TRACE_COLUMNS
        rows = list(reader)
    assert len(rows) == 11  # 10, 12, ..., 28 s of data, and the end
    assert float(rows[-1]["backlash_deg"]) == pytest.approx(0.5, abs=0.005)


def test_track_diagnose_keeps_the_effects_in_the_checkpoint(te_logs, tmp_path, capsys):
    plain, diagnosed, split = tmp_path / "plain.db", tmp_path / "diagnosed.db", tmp_path / "split.db"
    common = ["--ratio", "30", "--gearbox", "g1", "--every", "4", "--quiet"]
    assert main(["track", *map(str, te_logs), *common, "--db", str(plain)]) == 0
    assert main(["track", *map(str, te_logs), *common, "--db", str(diagnosed), "--diagnose"]) == 0
    # one log per process: the second finds the gearbox known and continues with the effects of its checkpoint
    for log in te_logs:
        assert main(["track", str(log), *common, "--db", str(split), "--diagnose"]) == 0
    capsys.readouterr()
    with HistoryStore(plain) as a, HistoryStore(diagnosed) as b, HistoryStore(split) as c:
        saved = b.gearbox("g1").checkpoint["estimator"]["params"]["effects"]
        assert [e["name"] for e in saved] == ["transmission_error"] and saved[0]["params"]["ratio"] == 30.0
        assert not a.gearbox("g1").checkpoint["estimator"]["params"].get("effects")
        without, with_effects, resumed = a.estimates("g1"), b.estimates("g1"), c.estimates("g1")
    assert len(without) == len(with_effects) == 12  # every 4 s of data over the two 30 s logs, after the warm start
    assert resumed == with_effects  # restored from the checkpoint by name: the same estimates, bit for bit
    # the effect tracked with the play explains the residual the plain model leaves
    assert with_effects[-1].residual_rms_deg < 0.6 * without[-1].residual_rms_deg
    assert with_effects[-1].backlash_deg == pytest.approx(0.5, abs=0.003)


def test_the_pipeline_modules_never_print():
    for name in ("pipeline.py", "output_columns.py", "tracking.py", "log_fit.py"):
        calls = [n for n in ast.walk(ast.parse((PACKAGE / name).read_text())) if isinstance(n, ast.Call)]
        assert not [c for c in calls if isinstance(c.func, ast.Name) and c.func.id == "print"], name
