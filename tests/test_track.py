"""Tracking a gearbox: usage counters, estimates every S seconds, resume after a kill, a month of wear."""

from __future__ import annotations

import dataclasses
import datetime as dt
import signal
import sqlite3
import subprocess
import sys

import numpy as np
import pytest
from live_run import kill_mid_work

from online_backlash.errors import HistoryError, LogFormatError
from online_backlash.history.report import wear_report
from online_backlash.history.series import bundled_wear_series
from online_backlash.history.store import HistoryStore
from online_backlash.history.usage import UsageCounter
from online_backlash.simulation.rig import simulate_rig
from online_backlash.tracking import GearboxTracker, track_series

DAY = 86400.0
T0 = 1.7e9  # 2023-11-14 22:13:20 UTC: logs carry UNIX times


def write_wear_logs(folder, days, duration_s, play_at_hours, seed=0, every_days=1.0):
    """Daily rig logs (UNIX time column); ``play_at_hours(h)`` is the play after h hours of running."""
    paths, recordings = [], []
    for k in range(days):
        hours_before = k * duration_s / 3600.0
        rec = simulate_rig(
            duration_s=duration_s, play_deg=lambda t, h=hours_before: play_at_hours(h + t / 3600.0), seed=seed + k
        )
        rec.time_s = rec.time_s + T0 + k * every_days * DAY
        path = folder / f"day{k:02d}.csv"
        rec.write_csv(path)
        paths.append(path)
        recordings.append(rec)
    return paths, recordings


# -- usage counter ---------------------------------------------------------------------------


def test_usage_counts_travel_reversals_and_motion_time():
    rec = simulate_rig(duration_s=60.0, play_deg=0.2, seed=3)
    u = rec.motor_deg / rec.ratio
    counter = UsageCounter()
    counter.update(rec.time_s, u)
    true_travel = np.abs(np.diff(rec.u_true_deg)).sum() / 360.0
    true_reversals = np.count_nonzero(np.diff(np.sign(np.diff(rec.u_true_deg))[np.diff(rec.u_true_deg) != 0]))
    assert counter.load_revolutions == pytest.approx(true_travel, rel=0.01)
    assert counter.reversals == true_reversals
    assert 0.97 * 60 / 3600 < counter.operating_hours <= 60 / 3600


def test_usage_ignores_standing_still_jitter_and_gaps():
    t = np.arange(0.0, 100.0, 0.001)
    step = 360.0 / 2**14 / 30  # one motor count, load side
    u = np.where(t < 10.0, 3.0 * t, 30.0) + step * np.random.default_rng(0).integers(-1, 2, t.size)
    counter = UsageCounter()
    counter.update(t, u)
    assert counter.operating_hours * 3600 == pytest.approx(10.0, abs=0.6)  # 90 s of jitter are not motion
    assert counter.reversals == 0
    gap = np.zeros(t.size, bool)
    gap[50_000] = True
    jump = UsageCounter()
    jump.update(t, np.where(t < 50.0, 0.0, 500.0), gap)  # a jump across a gap is not travel
    assert jump.load_revolutions == 0.0 and jump.operating_hours == 0.0


def test_usage_state_round_trip_and_chunking_give_the_same_counts():
    rec = simulate_rig(duration_s=20.0, seed=4)
    u = rec.motor_deg / rec.ratio
    whole = UsageCounter()
    whole.update(rec.time_s, u)
    parts = UsageCounter()
    for lo, hi in ((0, 777), (777, 9000), (9000, u.size)):
        parts = UsageCounter.from_state(parts.state_dict())
        parts.update(rec.time_s[lo:hi], u[lo:hi])
    assert parts.state_dict() == whole.state_dict()


# -- tracking logs ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def wear_logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("wear_logs")
    paths, _ = write_wear_logs(folder, days=3, duration_s=40.0, play_at_hours=lambda h: 0.2 + 0.5 * h, seed=10)
    return paths


def snapshot(db):
    """The history in a store: gearboxes with their checkpoints, runs, estimates (not the gearbox's ``revision``, which
    counts transactions: a replay commits the estimates it makes within tracking.COMMIT_EVERY_S together)."""
    with sqlite3.connect(db) as conn:
        return {
            "gearboxes": conn.execute(
                "SELECT id, ratio, limit_arcmin, checkpoint FROM gearboxes ORDER BY id"
            ).fetchall(),
            "runs": conn.execute(
                "SELECT id, gearbox_id, source, log_sha256, status, started_unix_s, ended_unix_s, samples_done, "
                "frames, samples, corrupt, skipped, gaps FROM runs ORDER BY id"
            ).fetchall(),
            "estimates": conn.execute("SELECT * FROM estimates ORDER BY id").fetchall(),
        }


def test_estimates_every_s_seconds_of_data_across_logs(tmp_path, wear_logs):
    with HistoryStore(tmp_path / "w.db", create=True) as store:
        tracker = GearboxTracker(store, "g1", 30.0, every_s=15.0, limit_arcmin=20.0)
        results = [tracker.track_log(p) for p in wear_logs]
        estimates = store.estimates("g1")
        runs = store.runs("g1")
    # 3 logs of 40 s (39.999 s of steps each): estimates at 15, 30, 45, ... seconds of data;
    # the first waits for the estimator's warm start (10 000 samples)
    data_s = np.array([(r.sample_index - 1) * 0.001 + 39.999 * (r.run_id - 1) for r in estimates])
    assert np.allclose(data_s / 15.0, np.round(data_s / 15.0), atol=1e-6)
    assert [round(x / 15.0) for x in data_s] == list(range(1, 8))
    assert sum(r.estimates_added for r in results) == 7
    assert all(r.complete and r.samples == 40_000 and r.frames == 40_000 for r in runs)
    assert [r.started_unix_s for r in runs] == [T0 + k * DAY for k in range(3)]
    for e in estimates:  # calendar time of the sample the estimate was taken at
        assert e.time_unix_s == pytest.approx(T0 + (e.run_id - 1) * DAY + (e.sample_index - 1) * 0.001, abs=1e-6)
    assert np.all(np.diff([e.operating_hours for e in estimates]) > 0)
    # 15 000 samples apart, one more where the step from one log to the next (not data time) lies between
    crossings = np.diff([e.run_id for e in estimates])
    assert np.array_equal(np.diff([e.n_samples for e in estimates]), 15_000 + crossings)


def test_same_log_twice_adds_nothing(tmp_path, wear_logs):
    db = tmp_path / "w.db"
    with HistoryStore(db, create=True) as store:
        GearboxTracker(store, "g1", 30.0, every_s=10.0).track_log(wear_logs[0])
    before = snapshot(db)
    copy = tmp_path / "renamed.csv"
    copy.write_bytes(wear_logs[0].read_bytes())  # the hash, not the name, identifies a log
    with HistoryStore(db) as store:
        result = GearboxTracker(store, "g1", 30.0, every_s=10.0).track_log(copy)
    assert result.already_imported and result.estimates_added == 0 and result.samples_fed == 0
    assert snapshot(db) == before


def test_contradicting_ratio_and_bad_logs_leave_the_store_untouched(tmp_path, wear_logs):
    db = tmp_path / "w.db"
    with HistoryStore(db, create=True) as store:
        GearboxTracker(store, "g1", 30.0).track_log(wear_logs[0])
    before = snapshot(db)
    bad = tmp_path / "bad.csv"
    bad.write_text("when,a,b\n0,1,2\n")
    with HistoryStore(db) as store:
        with pytest.raises(HistoryError, match="stored with ratio 30"):
            GearboxTracker(store, "g1", 50.0).track_log(wear_logs[1])
        with pytest.raises(LogFormatError, match="header has no column"):
            GearboxTracker(store, "g2", 30.0).track_log(bad)
        with pytest.raises(FileNotFoundError):
            GearboxTracker(store, "g2", 30.0).track_log(tmp_path / "missing.csv")
    assert snapshot(db) == before


class Interrupt(Exception):
    pass


def stop_at(call: int):
    """A ``progress`` callback of ``track_log`` that raises :class:`Interrupt` at its ``call``-th call (between
    blocks), counting across the logs it is handed to."""
    calls = 0

    def stop(samples, backlash):
        nonlocal calls
        calls += 1
        if calls == call:
            raise Interrupt

    return stop


def interrupted_then_tracked(store, wear_logs, stop_after: int) -> list:
    """``wear_logs`` tracked into ``store`` as gearbox g1, interrupted at the ``stop_after``-th progress call, then
    all of them tracked again (the results of the second pass)."""
    tracker = GearboxTracker(store, "g1", 30.0, every_s=7.0)
    stop = stop_at(stop_after)
    with pytest.raises(Interrupt):
        for p in wear_logs:
            tracker.track_log(p, progress=stop)
    return [tracker.track_log(p) for p in wear_logs]


@pytest.mark.parametrize("stop_after", [1, 3, 6, 11])
def test_resume_after_an_interruption_equals_an_uninterrupted_run(tmp_path, wear_logs, stop_after):
    """Stop inside ``track`` at the n-th progress call (between blocks), then run again."""
    reference = tmp_path / "reference.db"
    with HistoryStore(reference, create=True) as store:
        for p in wear_logs:
            GearboxTracker(store, "g1", 30.0, every_s=7.0).track_log(p)
    db = tmp_path / "interrupted.db"
    with HistoryStore(db, create=True) as store:
        results = interrupted_then_tracked(store, wear_logs, stop_after)
    # the first block ends before the estimator's warm start, so nothing was committed to resume from
    assert any(r.resumed_from > 0 for r in results) == (stop_after > 1)
    assert snapshot(db) == snapshot(reference)


def test_a_replay_commits_its_estimates_together_and_an_error_those_before_it(tmp_path, wear_logs):
    """Estimates a replay makes milliseconds apart share transactions (the gearbox's revision counts them; one per
    estimate before); a log that stops on a bad row in its second block has the estimates of the first stored, as
    tracking the first block alone stores them."""
    with HistoryStore(tmp_path / "w.db", create=True) as store:
        tracker = GearboxTracker(store, "g1", 30.0, every_s=1.0)
        added = sum(tracker.track_log(p).estimates_added for p in wear_logs)
        assert added > 80 and store.gearbox("g1").revision < added / 4
    rec = simulate_rig(duration_s=120.0, play_deg=0.3, seed=4)
    rec.time_s = rec.time_s + T0
    whole, first_block = tmp_path / "whole.csv", tmp_path / "first_block.csv"
    rec.write_csv(whole)
    lines = whole.read_text().splitlines(keepends=True)
    first_block.write_text("".join(lines[: 1 + 65536]))  # the reader's first block of rows
    lines[1 + 100_000] = lines[1 + 100_000].rsplit(",", 1)[0] + ",nan\n"  # the load angle of row 100,000
    whole.write_text("".join(lines))
    with HistoryStore(tmp_path / "bad.db", create=True) as store:
        with pytest.raises(LogFormatError, match="non-finite"):
            GearboxTracker(store, "g2", 30.0, every_s=1.0).track_log(whole)
        (run,) = store.runs("g2")
        stored = [dataclasses.astuple(e) for e in store.estimates("g2")]
    with HistoryStore(tmp_path / "reference.db", create=True) as store:
        GearboxTracker(store, "g2", 30.0, every_s=1.0).track_log(first_block)
        reference = [dataclasses.astuple(e) for e in store.estimates("g2")]
    assert run.status == "running" and len(stored) > 40 and stored == reference


def test_sigkill_mid_log_then_restart_gives_the_uninterrupted_history(tmp_path):
    # logs long enough (450 estimates each) that the second is still being tracked after its first transactions
    paths, _ = write_wear_logs(tmp_path, days=2, duration_s=900.0, play_at_hours=lambda h: 0.25 + 0.2 * h, seed=20)
    argv = [str(p) for p in paths] + ["--ratio", "30", "--gearbox", "g1", "--every", "2", "--quiet"]
    command = [
        sys.executable,
        "-c",
        "import sys; from online_backlash.cli import main; sys.exit(main(sys.argv[1:]))",
        "track",
    ]
    reference, db = tmp_path / "reference.db", tmp_path / "killed.db"
    with HistoryStore(reference, create=True) as store:  # what the command does, uninterrupted
        tracker = GearboxTracker(store, "g1", 30.0, every_s=2.0)
        for p in paths:
            tracker.track_log(p)

    # cwd: run the installed package, not the source tree (drivers/ and replay/ are mapped at install)
    proc = subprocess.Popen(
        [*command, *argv, "--db", str(db)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=tmp_path
    )

    def inside_the_second_log() -> bool:
        assert proc.poll() is None, f"track ended before it could be killed mid-log: {proc.communicate()[1].decode()}"
        if not db.exists():
            return False
        try:
            with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=0) as conn:
                estimates = conn.execute("SELECT count(*) FROM estimates WHERE run_id = 2").fetchone()[0]
                status = conn.execute("SELECT status FROM runs WHERE id = 2").fetchone()
                return estimates >= 10 and status == ("running",)
        except sqlite3.OperationalError:  # tables not created yet
            return False

    kill_mid_work(proc.pid, inside_the_second_log, "10 estimates of the second log stored, the log not complete")
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    killed = snapshot(db)
    assert [r[4] for r in killed["runs"]] == ["complete", "running"]  # killed inside the second log
    assert 0 < len(killed["estimates"]) < len(snapshot(reference)["estimates"])

    done = subprocess.run([*command, *argv, "--db", str(db)], check=True, capture_output=True, text=True, cwd=tmp_path)
    assert "day00.csv: already imported" in done.stdout and "resumed after" in done.stdout
    assert snapshot(db) == snapshot(reference)  # no duplicate, no hole, bit-identical estimates


# -- a month of wear --------------------------------------------------------------------------

DAYS, LOG_S = 30, 120.0
TOTAL_H = DAYS * LOG_S / 3600.0
RATE = 0.10 / TOTAL_H  # play grows 0.20 -> 0.30 deg over the month's operating hours


def test_a_month_of_wear_trend_and_forecast(tmp_path):
    with HistoryStore(tmp_path / "month.db", create=True) as store:
        tracker = GearboxTracker(store, "g1", 30.0, every_s=60.0, limit_arcmin=0.35 * 60)
        travel_before = [0.0]  # true load revolutions before each log
        for k in range(DAYS):
            h0 = k * LOG_S / 3600.0
            rec = simulate_rig(
                duration_s=LOG_S, play_deg=lambda t, h0=h0: 0.20 + RATE * (h0 + t / 3600.0), seed=100 + k
            )
            rec.time_s = rec.time_s + T0 + k * DAY
            tracker.track_chunks([rec.to_chunk()], f"day {k}", key=f"day-{k}")
            travel = np.abs(np.diff(rec.u_true_deg)) / 360.0
            travel_before.append(travel_before[-1] + travel.sum())
        report = wear_report(store, "g1")
    s = report.summary.as_dict()
    last = report.estimates[-1]
    # the last estimate is taken at a whole minute of data, before the end of the last log
    last_k, last_i = last.run_id - 1, last.sample_index - 1
    assert last.operating_hours == pytest.approx((last_k * LOG_S + last_i * 0.001) / 3600.0, rel=0.01)
    travel_to_last = travel_before[last_k] + np.abs(np.diff(rec.u_true_deg[: last_i + 1])).sum() / 360.0
    assert last.load_revolutions == pytest.approx(travel_to_last, rel=0.01)
    assert s["trend_deg_per_hour"] == pytest.approx(RATE, rel=0.10)
    lo, hi = s["trend_deg_per_hour_interval"]
    assert lo < s["trend_deg_per_hour"] < hi
    true_hours_at_limit = (0.35 - 0.20) / RATE
    assert last.operating_hours + s["forecast_hours_to_limit"] == pytest.approx(true_hours_at_limit, rel=0.10)
    # at 2 minutes a day the remaining 0.5 h take about 15 more days after the last log
    assert s["usage_hours_per_day"] == pytest.approx(LOG_S / 3600.0, rel=0.05)
    true_date = dt.datetime.fromtimestamp(
        T0 + (DAYS - 1) * DAY + (true_hours_at_limit - TOTAL_H) * 3600 / LOG_S * DAY, dt.timezone.utc
    )
    assert abs((dt.date.fromisoformat(s["forecast_date"]) - true_date.date()).days) <= 2
    assert len(report.estimates) >= 55


def test_interrupted_tracking_on_each_backend_equals_uninterrupted_sqlite(tmp_path, wear_logs, store_db):
    """The same resume guarantee on PostgreSQL as on SQLite, and the same numbers on both."""
    with HistoryStore(tmp_path / "reference.db", create=True) as store:
        for p in wear_logs:
            GearboxTracker(store, "g1", 30.0, every_s=7.0).track_log(p)
        reference = [dataclasses.replace(e, run_id=0) for e in store.estimates("g1")]
    with HistoryStore(store_db, create=True) as store:
        results = interrupted_then_tracked(store, wear_logs, 8)
        assert [r.already_imported for r in results] == [True, False, False] and results[1].resumed_from > 0
        assert [dataclasses.replace(e, run_id=0) for e in store.estimates("g1")] == reference
        assert [r.status for r in store.runs("g1")] == ["complete"] * 3


def test_the_bundled_wear_series_shows_its_true_wear(tmp_path):
    series = bundled_wear_series()
    with HistoryStore(tmp_path / "w.db", create=True) as store:
        results = track_series(series, store)
        again = track_series(series, store)
        report = wear_report(store, series.gearbox)
    m = series.manifest
    assert len(results) == len(m["logs"]) == 60 and not any(r.already_imported for r in results)
    assert all(r.already_imported for r in again)
    s = report.summary.as_dict()
    # two months of daily 60 s snapshots with the hour meter: the trend runs on machine hours, one point a snapshot
    assert s["trend_clock"] == "machine_hours" and s["snapshot_logs"] and s["trend_points"] >= 55
    assert s["trend_deg_per_hour"] == pytest.approx(m["true_rate_deg_per_hour"], rel=0.05)
    assert report.summary.last_hours + s["forecast_hours_to_limit"] == pytest.approx(m["true_hours_at_limit"], rel=0.01)
    assert s["usage_hours_per_day"] == pytest.approx(m["hours_per_day"], rel=0.02)
    assert abs(dt.date.fromisoformat(s["forecast_date"]) - dt.date.fromisoformat(m["true_limit_date"][:10])).days <= 1
    assert s["limit_arcmin"] == m["limit_arcmin"]
    assert results[-1].machine_hours == pytest.approx(m["logs"][-1]["meter_start_h"] + 60.0 / 3600.0, abs=0.002)


def test_a_run_resumed_after_another_log_does_not_join_their_samples(tmp_path, wear_logs):
    """Interrupt log A, track log B, then resume A: A's next sample follows a gap, not B's last sample."""
    with HistoryStore(tmp_path / "w.db", create=True) as store:
        tracker = GearboxTracker(store, "g1", 30.0, every_s=7.0)
        with pytest.raises(Interrupt):
            tracker.track_log(wear_logs[0], progress=stop_at(4))
        tracker.track_log(wear_logs[1])
        resumed = tracker.track_log(wear_logs[0])
        checkpoint = store.gearbox("g1").checkpoint
    assert resumed.resumed_from > 0 and checkpoint["run_id"] == resumed.run_id
    # data time: every step within a log, none between logs or at the resumption (40 000 samples each)
    # (each 1 ms step is read from UNIX times of about 1.7e9 s, to about 0.2 us)
    assert checkpoint["data_ns"] == pytest.approx((2 * (40_000 - 1) - 1) * 1_000_000, abs=100_000)
