"""``online-backlash history`` and ``track`` from the command line: output formats and bad input."""

from __future__ import annotations

import csv
import datetime as dt
import io
import json
import re
import sqlite3

import numpy as np
import pytest
from live_run import run_live, send_frames
from rig_can import RIG_CAN

from online_backlash.cli import main
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.history.store import SCHEMA_VERSION, HistoryStore
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames

DAY = 86400.0
T0 = 1.7e9
RATE = 0.01  # deg per operating hour


def dump(db):
    with sqlite3.connect(db) as conn:
        names = [r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name")]
        return {n: conn.execute(f'SELECT * FROM "{n}"').fetchall() for n in names}


@pytest.fixture
def history_db(tmp_path):
    """A store holding gearbox g1 (ratio 30, limit 21 arcmin): 20 daily estimates, 0.5 h a day, 0.01 deg/h."""
    db = tmp_path / "wear.db"
    rng = np.random.default_rng(0)
    with HistoryStore(db, create=True) as store:
        for day in range(20):
            gearbox, run = store.begin_run(
                "g1", 30.0, f"day{day}.csv", f"{day:064x}", T0 + day * DAY, limit_arcmin=21.0
            )
            hours = 0.5 * (day + 1)
            backlash = 0.2 + RATE * hours + rng.normal(0, 0.0005)
            row = dict(
                sample_index=1800_000,
                time_unix_s=T0 + day * DAY + 1800,
                backlash_deg=backlash,
                backlash_std_deg=0.001,
                c_left_deg=backlash / 2,
                c_right_deg=backlash / 2,
                m_left=1.0,
                m_right=1.0,
                residual_rms_deg=0.002,
                n_samples=1800_000 * (day + 1),
                operating_hours=hours,
                load_revolutions=150.0 * hours,
                reversals=400 * (day + 1),
            )
            gearbox, run = store.commit(gearbox, run, 1800_000, {"format": 1}, [row])
            store.commit(
                gearbox, run, 1800_000, {"format": 1}, counters=dict(frames=1, samples=1, corrupt=0, skipped=0, gaps=0)
            )
    return db


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_history_table_trend_and_forecast(capsys, history_db):
    code, out, err = run_cli(capsys, "history", "--db", history_db, "--gearbox", "g1")
    assert code == 0 and err == ""
    lines = out.splitlines()
    assert lines[0] == "gearbox g1: ratio 30, limit 21 arcmin, 20 estimates"
    assert "backlash deg" in lines[1] and "arcmin" in lines[1] and "op. hours" in lines[1]
    first = lines[3].split()
    assert first[:2] == ["2023-11-14", "22:43:20"] and first[2] == "-" and float(first[3]) == 0.5  # no hour meter
    assert float(first[8]) == pytest.approx(float(first[6]) * 60, abs=0.01)  # degrees and arcmin agree
    assert sum(line.startswith("2023-") for line in lines) == 20
    # one estimate a day after 0.5 h of logging: snapshots without an hour meter, so the trend runs on calendar days
    assert next(line for line in lines if line.startswith("clock:")).startswith("clock: calendar days: snapshot logs")
    trend = next(line for line in lines if line.startswith("trend:"))
    assert trend.split()[2:6] == ["arcmin", "per", "calendar", "day"]
    assert float(trend.split()[1]) == pytest.approx(RATE * 0.5 * 60, rel=0.05)  # arcmin per day
    assert any(line.startswith("forecast: limit 21 arcmin in ") and " calendar days [" in line for line in lines)


def test_history_json_contract(capsys, history_db):
    code, out, _ = run_cli(capsys, "history", "--db", history_db, "--gearbox", "g1", "--json")
    d = json.loads(out)
    assert code == 0
    for key in ("gearbox", "estimates", "trend_deg_per_hour", "forecast_hours_to_limit", "forecast_date"):
        assert key in d
    assert d["gearbox"] == "g1" and len(d["estimates"]) == 20
    e = d["estimates"][0]
    assert dt.datetime.fromisoformat(e["time"]).timestamp() == T0 + 1800
    assert e["backlash_std_deg"] == 0.001 and e["operating_hours"] == 0.5
    assert e["backlash_arcmin"] == pytest.approx(e["backlash_deg"] * 60)
    assert d["trend_deg_per_hour"] == pytest.approx(RATE, rel=0.05)
    hours_at_limit = (0.35 - 0.2) / RATE
    assert d["forecast_hours_to_limit"] == pytest.approx(hours_at_limit - 10.0, rel=0.05)
    days_left = (hours_at_limit - 10.0) / 0.5
    expected = dt.datetime.fromtimestamp(T0 + 19 * DAY + 1800 + days_left * DAY, dt.timezone.utc).date()
    assert abs((dt.date.fromisoformat(d["forecast_date"]) - expected).days) <= 1
    lo, hi = d["forecast_hours_to_limit_interval"]
    assert lo < d["forecast_hours_to_limit"] < hi


def test_history_limit_option_overrides_the_stored_limit(capsys, history_db):
    _, out, _ = run_cli(capsys, "history", "--db", history_db, "--gearbox", "g1", "--json", "--limit-arcmin", "15")
    d = json.loads(out)
    assert d["limit_arcmin"] == 15 and d["stored_limit_arcmin"] == 21
    assert d["forecast_hours_to_limit"] == pytest.approx((0.25 - 0.2) / RATE - 10.0, abs=0.3)


def test_history_csv(capsys, history_db):
    code, out, _ = run_cli(capsys, "history", "--db", history_db, "--gearbox", "g1", "--csv")
    rows = list(csv.DictReader(io.StringIO(out)))
    assert code == 0 and len(rows) == 20
    assert float(rows[-1]["operating_hours"]) == 10.0
    assert float(rows[3]["backlash_arcmin"]) == pytest.approx(60 * float(rows[3]["backlash_deg"]))


def test_history_plot(capsys, history_db, tmp_path):
    png = tmp_path / "wear.png"
    code, out, _ = run_cli(capsys, "history", "--db", history_db, "--gearbox", "g1", "--plot", png)
    assert code == 0 and f"wear plot: {png}" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_history_without_limit_or_trend(capsys, tmp_path):
    db = tmp_path / "w.db"
    with HistoryStore(db, create=True) as store:
        store.begin_run("new", 30.0, "x.csv", "f" * 64, T0)
    code, out, _ = run_cli(capsys, "history", "--db", db, "--gearbox", "new")
    assert code == 0 and "0 estimates" in out and "trend: needs at least 3 estimates" in out
    _, out, _ = run_cli(capsys, "history", "--db", db, "--gearbox", "new", "--json")
    d = json.loads(out)
    assert d["estimates"] == [] and d["trend_deg_per_hour"] is None and d["forecast_date"] is None


# -- bad input: a clear error, the store untouched ---------------------------------------------


@pytest.mark.parametrize("content", [b"time,motor,load\n0,0,0\n", b"PK\x03\x04" + bytes(200)])
def test_history_file_that_is_not_a_store(capsys, tmp_path, content):
    path = tmp_path / "notes.db"
    path.write_bytes(content)
    code, _, err = run_cli(capsys, "history", "--db", path, "--gearbox", "g1")
    assert code == 1 and err == f"error: {path} is not an online-backlash history store (not an SQLite database)\n"
    assert path.read_bytes() == content


def test_history_newer_schema(capsys, history_db):
    with sqlite3.connect(history_db) as conn:
        conn.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'", (str(SCHEMA_VERSION + 1),))
    before = dump(history_db)
    code, _, err = run_cli(capsys, "history", "--db", history_db, "--gearbox", "g1")
    assert code == 1 and f"schema version {SCHEMA_VERSION + 1}, newer than this online-backlash understands" in err
    assert dump(history_db) == before


def test_history_unknown_gearbox(capsys, history_db):
    before = dump(history_db)
    code, _, err = run_cli(capsys, "history", "--db", history_db, "--gearbox", "g9")
    assert code == 1 and err == f"error: {history_db} holds no gearbox 'g9'; it holds g1\n"
    assert dump(history_db) == before


def test_history_missing_store_is_not_created(capsys, tmp_path):
    code, _, err = run_cli(capsys, "history", "--db", tmp_path / "nope.db", "--gearbox", "g1")
    assert code == 1 and "no history store at" in err
    assert list(tmp_path.iterdir()) == []


# -- track from the command line --------------------------------------------------------------


@pytest.fixture(scope="module")
def short_log(tmp_path_factory):
    rec = simulate_rig(duration_s=25.0, play_deg=0.3, seed=7)
    rec.time_s = rec.time_s + T0
    path = tmp_path_factory.mktemp("logs") / "run.csv"
    rec.write_csv(path)
    return path


def test_track_then_again(capsys, tmp_path, short_log):
    db = tmp_path / "w.db"
    code, out, err = run_cli(capsys, "track", short_log, "--ratio", 30, "--db", db, "--gearbox", "g1", "--every", 5)
    assert code == 0 and err == ""  # not a terminal: no progress bar
    assert out.startswith(f"g1: {short_log}: 25000 samples, 3 estimates added; backlash 0.3")
    before = dump(db)
    code, out, _ = run_cli(capsys, "track", short_log, "--ratio", 30, "--db", db, "--gearbox", "g1", "--json")
    d = json.loads(out)
    assert code == 0 and d["already_imported"] and d["estimates_added"] == 0 and d["counters"]["samples"] == 25000
    assert dump(db) == before


def test_track_ratio_contradicting_the_store(capsys, history_db, short_log):
    before = dump(history_db)
    code, _, err = run_cli(capsys, "track", short_log, "--ratio", 35, "--db", history_db, "--gearbox", "g1")
    assert code == 1
    assert (
        err == "error: gearbox 'g1' is stored with ratio 30; --ratio 35 contradicts it (use another gearbox id for "
        "another gearbox)\n"
    )
    assert dump(history_db) == before


def test_track_into_a_file_that_is_not_a_store(capsys, tmp_path, short_log):
    path = tmp_path / "log.csv"
    path.write_bytes(short_log.read_bytes())
    code, _, err = run_cli(capsys, "track", short_log, "--ratio", 30, "--db", path, "--gearbox", "g1")
    assert code == 1 and "not an online-backlash history store" in err
    assert path.read_bytes() == short_log.read_bytes()


def test_track_progress_bar_only_on_a_terminal(capsys, monkeypatch, tmp_path, short_log):
    monkeypatch.setattr("sys.stderr.isatty", lambda: True)
    code, _, err = run_cli(
        capsys, "track", short_log, "--ratio", 30, "--db", tmp_path / "a.db", "--gearbox", "g1", "--every", 5
    )
    assert code == 0 and "samples/s" in err and "backlash 0.3" in err
    code, _, err = run_cli(
        capsys, "track", short_log, "--ratio", 30, "--db", tmp_path / "b.db", "--gearbox", "g1", "--quiet"
    )
    assert code == 0 and err == ""


def test_track_start_option(capsys, tmp_path):
    rec = simulate_rig(duration_s=15.0, seed=8)  # times from 0: not UNIX times
    path = tmp_path / "relative.csv"
    rec.write_csv(path)
    db = tmp_path / "w.db"
    code, _, _ = run_cli(
        capsys,
        "track",
        path,
        "--ratio",
        30,
        "--db",
        db,
        "--gearbox",
        "g1",
        "--every",
        12,
        "--start",
        "2026-03-01T06:00:00",
    )
    assert code == 0
    with HistoryStore(db) as store:
        (run,) = store.runs("g1")
        (estimate,) = store.estimates("g1")
    start = dt.datetime(2026, 3, 1, 6, tzinfo=dt.timezone.utc).timestamp()
    assert run.started_unix_s == start
    assert estimate.time_unix_s == pytest.approx(start + 12.0, abs=0.002)


def test_track_live_can_then_the_raw_log_gives_the_same_history(capsys, tmp_path):
    """``track --listen can`` on a virtual bus until Ctrl-C; tracking its raw log again gives identical estimates."""
    rec = simulate_rig(duration_s=14.0, play_deg=0.3, seed=12)
    frames = list(rig_can_frames(rec, DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count"), T0))
    channel = "track-live"
    live_db, replay_db = tmp_path / "live.db", tmp_path / "replay.db"
    argv = [
        "track",
        "--listen",
        "can",
        "--interface",
        "virtual",
        "--channel",
        channel,
        *RIG_CAN,
        "--raw-log",
        tmp_path / "raw",
        "--ratio",
        30,
        "--db",
        live_db,
        "--gearbox",
        "g1",
        "--every",
        1,
    ]
    code = run_live(argv, lambda _: send_frames(channel, frames))  # then Ctrl-C: the frames waiting are learned too
    out = capsys.readouterr().out
    assert code == 0 and out.startswith(f"g1: can virtual {channel}: {rec.time_s.size} samples, 4 estimates added")
    (raw,) = sorted((tmp_path / "raw").iterdir())
    code, out, _ = run_cli(
        capsys, "track", raw, *RIG_CAN, "--ratio", 30, "--db", replay_db, "--gearbox", "g1", "--every", 1
    )
    assert code == 0
    live, replayed = dump(live_db), dump(replay_db)
    assert len(live["estimates"]) == 4 and live["estimates"] == replayed["estimates"]
    assert live["estimates"][-1][4] == pytest.approx(T0 + 13.0, abs=0.01)  # time of the sample, from the frames


@pytest.mark.postgres
def test_track_and_history_on_postgresql(capsys, postgres_db, short_log):
    code, out, _ = run_cli(
        capsys,
        "track",
        short_log,
        "--ratio",
        30,
        "--db",
        postgres_db,
        "--gearbox",
        "rig-7",
        "--every",
        5,
        "--limit-arcmin",
        30,
    )
    assert code == 0 and "3 estimates added" in out
    code, out, _ = run_cli(capsys, "history", "--db", postgres_db, "--gearbox", "rig-7", "--json")
    d = json.loads(out)
    assert code == 0 and d["gearbox"] == "rig-7" and len(d["estimates"]) == 3 and d["stored_limit_arcmin"] == 30
    assert d["estimates"][-1]["backlash_deg"] == pytest.approx(0.3, abs=0.02)
    code, out, _ = run_cli(capsys, "track", short_log, "--ratio", 30, "--db", postgres_db, "--gearbox", "rig-7")
    assert code == 0 and "already imported" in out


def test_demo_replays_the_bundled_wear_series(capsys, tmp_path):
    assert main(["demo", "--plot", str(tmp_path / "fit.png")]) == 0
    out = capsys.readouterr().out
    wear = out[out.index("wear history:") :]
    assert "60 daily 60 s snapshots of gearbox demo-30to1 on a machine running 16 h a day" in wear
    assert "(true play 12.0 -> 18.0 arcmin)" in wear
    assert re.search(r"^clock: machine hours: the machine's hour meter was given with every log$", wear, re.M)
    trend = float(re.search(r"^trend: ([+-][0-9.]+) arcmin per 1,000 machine hours \[", wear, re.M).group(1))
    true_rate = float(re.search(r"^true wear: +([+-][0-9.]+) arcmin per 1,000 machine hours", wear, re.M).group(1))
    assert trend == pytest.approx(true_rate, rel=0.05)
    assert re.search(r"^use: 16 machine hours per calendar day recently$", wear, re.M)
    forecast = re.search(
        r"^forecast: limit 21 arcmin in ([0-9,]+) machine hours \[([0-9,]+), ([0-9,]+)\] from the last estimate, "
        r"around (\S+) \[(\S+), (\S+)\] \(UTC\) at 16 machine hours per calendar day$",
        wear,
        re.M,
    )
    hours, low, high = (float(forecast.group(k).replace(",", "")) for k in (1, 2, 3))
    true_left = re.search(r"on the hour meter, ([0-9,]+) machine hours after the last estimate", wear).group(1)
    true_left = float(true_left.replace(",", ""))
    assert low <= hours <= high and hours == pytest.approx(true_left, rel=0.10)
    true_date = re.search(r"after the last estimate, on (\S+)$", wear, re.M).group(1)
    assert abs((dt.date.fromisoformat(forecast.group(4)) - dt.date.fromisoformat(true_date)).days) <= 3
    assert "the demo shifts it by" in wear and "dates are UTC on that shifted clock" in wear
    today = dt.datetime.now(dt.timezone.utc).date().isoformat()
    assert today <= forecast.group(5) <= forecast.group(4) <= forecast.group(6)  # ahead of today, not in the past
    png = tmp_path / "wear-demo.png"
    assert f"wear plot:      {png}" in wear and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
