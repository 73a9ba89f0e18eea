"""Alarm state, the Nagios/Icinga plugin line of ``history --check``, and the stored alarm levels."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from fleet_store import fill_gearbox
from sqlalchemy import create_engine, inspect, text

from online_backlash.cli import main
from online_backlash.errors import HistoryError, InvalidParameterError
from online_backlash.history import store as store_module
from online_backlash.history.alarms import (
    AlarmStatus,
    check_alarm_levels,
    evaluate_alarm,
    plugin_line,
    worst_state,
)
from online_backlash.history.store import SCHEMA_VERSION, HistoryStore, resolve_url
from online_backlash.simulation.rig import simulate_rig

HOUR = 3600.0
NOW = time.time()


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# -- levels ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("warn", "limit", "message"),
    [
        (None, -1.0, "the limit must be a finite positive angle in arcmin, got -1.0"),
        (None, 0.0, "the limit must be a finite positive angle"),
        (None, math.nan, "the limit must be a finite positive angle in arcmin, got nan"),
        (math.inf, None, "the warning level must be a finite positive angle in arcmin, got inf"),
        (True, None, "the warning level must be a finite positive angle"),
        (25.0, 21.0, "the warning level 25 arcmin is above the limit 21 arcmin"),
    ],
)
def test_bad_levels_are_refused(warn, limit, message):
    with pytest.raises(InvalidParameterError, match=message):
        check_alarm_levels(warn, limit)


def test_good_levels_pass():
    check_alarm_levels(21.0, 21.0)
    check_alarm_levels(None, None)
    check_alarm_levels(18.0, None)


# -- state ---------------------------------------------------------------------------------------


def _evaluate(play_arcmin, std=0.001, warn=18.0, limit=21.0, now=None, times=None, max_age_h=168.0):
    play = np.asarray(play_arcmin, dtype=float)
    t = np.arange(play.size) * HOUR if times is None else np.asarray(times, dtype=float)
    now = t[-1] + 60.0 if now is None else now
    return evaluate_alarm(t, play / 60.0, np.broadcast_to(std, play.shape), warn, limit, now, max_age_h)


def test_states_follow_the_latest_observable_estimate():
    assert _evaluate([10.0, 12.0]).state == "ok"
    assert _evaluate([10.0, 18.5]).state == "warning"
    assert _evaluate([18.0, 18.0]).state == "ok"  # at the level is not above it
    status = _evaluate([10.0, 22.0])
    assert (status.state, status.exit_code, status.plugin_status) == ("alarm", 2, "CRITICAL")
    assert _evaluate([10.0, 22.0], warn=None).state == "alarm"
    assert _evaluate([10.0, 19.0], warn=None).state == "ok"


def test_limit_exceeded_since_the_start_of_the_trailing_run_above_it():
    play = [10.0, 21.5, 20.0, 21.2, 22.0, 23.0]  # above, dips below, then above for good
    status = _evaluate(play)
    assert status.state == "alarm" and status.limit_exceeded_since_unix_s == 3 * HOUR
    assert _evaluate([22.0, 23.0]).limit_exceeded_since_unix_s == 0.0
    assert _evaluate([10.0, 20.0]).limit_exceeded_since_unix_s is None


def test_an_estimate_without_std_is_not_observable():
    std = np.array([0.001, 0.001, np.nan])
    status = _evaluate([10.0, 12.0, 25.0], std=std)
    assert status.state == "ok" and status.play_arcmin == pytest.approx(12.0)
    status = _evaluate([25.0, 25.0], std=np.array([np.nan, np.nan]))
    assert status.state == "unknown" and status.reason == "no observable estimate" and status.play_arcmin is None


def test_unknown_when_stale_or_without_a_limit():
    stale = _evaluate([10.0, 22.0], now=1 * HOUR + 169 * HOUR)
    assert (stale.state, stale.exit_code) == ("unknown", 3)
    # old data are named as old, with their age and date, not as a missing estimate
    old = "7.0 days old (1970-01-01 01:00 UTC)"
    assert stale.reason == f"the latest observable estimate is {old}, more than the 168 h allowed"
    assert stale.play_arcmin == pytest.approx(22.0)
    assert _evaluate([10.0, 22.0], now=1 * HOUR + 2 * HOUR, max_age_h=1.5).state == "unknown"
    assert _evaluate([10.0, 22.0], now=1 * HOUR + 2 * HOUR, max_age_h=2.5).state == "alarm"
    assert _evaluate([10.0, 22.0], warn=None, limit=None).reason == "no limit known"
    assert _evaluate([], times=[], now=0.0).state == "unknown"
    with pytest.raises(InvalidParameterError, match="max_age_h must be positive"):
        _evaluate([10.0], max_age_h=0.0)


def test_worst_state_puts_unknown_between_warning_and_alarm():
    assert worst_state(["ok", "warning", "ok"]) == "warning"
    assert worst_state(["ok", "unknown", "warning"]) == "unknown"
    assert worst_state(["unknown", "alarm", "ok"]) == "alarm"
    assert worst_state([]) == "unknown"


@pytest.mark.parametrize(
    ("status", "forecast", "line"),
    [
        (
            AlarmStatus("warning", "", 19.2, 0.0, 18.0, 21.0),
            "in 310 machine hours, around 2026-12-01",
            "BACKLASH WARNING - GB-7 play 19.2 arcmin, limit 21 in 310 machine hours, around 2026-12-01 "
            "| play_arcmin=19.2;18;21",
        ),
        (
            AlarmStatus("ok", "", 12.04, 0.0, None, 21.0),
            "no wear measured",
            "BACKLASH OK - GB-7 play 12.0 arcmin, limit 21 no wear measured | play_arcmin=12.0;;21",
        ),
        (
            AlarmStatus("alarm", "", 22.3, 0.0, 18.0, 21.0, 0.0),
            "exceeded since 2026-11-20T08:00:00+00:00",
            "BACKLASH CRITICAL - GB-7 play 22.3 arcmin, limit 21 exceeded since 2026-11-20T08:00:00+00:00 | "
            "play_arcmin=22.3;18;21",
        ),
        (
            AlarmStatus("unknown", "no observable estimate", None, None, 18.0, 21.0),
            "no forecast yet",
            "BACKLASH UNKNOWN - GB-7 no observable estimate | play_arcmin=U;18;21",
        ),
    ],
)
def test_plugin_line_format(status, forecast, line):
    assert plugin_line("GB-7", status, forecast) == line


# -- stored levels and migration -------------------------------------------------------------------


def test_alarm_levels_are_stored_and_checked_together(store_db):
    with HistoryStore(store_db, create=True) as store:
        g = store.set_alarm_levels("g1", 30.0, warn_arcmin=18.0, limit_arcmin=21.0)
        assert (g.warn_arcmin, g.limit_arcmin) == (18.0, 21.0)
        assert store.set_alarm_levels("g1", 30.0, warn_arcmin=19.5).limit_arcmin == 21.0
        with pytest.raises(InvalidParameterError, match="warning level 22 arcmin is above the limit 21"):
            store.set_alarm_levels("g1", 30.0, warn_arcmin=22.0)
        with pytest.raises(InvalidParameterError, match="the limit must be a finite positive angle"):
            store.begin_run("g1", 30.0, "day.csv", "a" * 64, 1.7e9, limit_arcmin=-1.0)
        with pytest.raises(HistoryError, match="stored with ratio 30"):
            store.set_alarm_levels("g1", 35.0, warn_arcmin=10.0)
        g = store.gearbox("g1")
        assert (g.warn_arcmin, g.limit_arcmin) == (19.5, 21.0) and store.runs("g1") == []


def test_migration_from_schema_1_adds_warn_arcmin(store_db):
    with HistoryStore(store_db, create=True) as store:
        store.set_alarm_levels("g1", 30.0, limit_arcmin=21.0)
    engine = create_engine(resolve_url(store_db))
    with engine.begin() as conn:  # make it a version-1 store
        conn.execute(text("ALTER TABLE gearboxes DROP COLUMN warn_arcmin"))
        conn.execute(text("UPDATE meta SET value = '1' WHERE key = 'schema_version'"))
    with HistoryStore(store_db) as store:
        assert store.schema_version == SCHEMA_VERSION >= 2
        g = store.gearbox("g1")
        assert (g.limit_arcmin, g.warn_arcmin) == (21.0, None)
        assert store.set_alarm_levels("g1", 30.0, warn_arcmin=18.0).warn_arcmin == 18.0
    with engine.connect() as conn:
        assert "warn_arcmin" in {c["name"] for c in inspect(conn).get_columns("gearboxes")}
    engine.dispose()
    assert 1 in store_module.MIGRATIONS


# -- the command line ----------------------------------------------------------------------------


def _fill(store, gearbox_id, play_arcmin, end_unix_s):
    """Hourly estimates of ``play_arcmin`` ending at ``end_unix_s``, one run (standard error 0.002 deg)."""
    fill_gearbox(store, gearbox_id, play_arcmin, end_unix_s, with_parameters=False, std_deg=0.002)


@pytest.fixture
def fleet_db(tmp_path):
    db = tmp_path / "fleet.db"
    with HistoryStore(db, create=True) as store:
        _fill(store, "GB-1", np.linspace(10.0, 12.0, 12), NOW - 60.0)  # ok, growing
        _fill(store, "GB-2", np.linspace(15.0, 19.2, 12), NOW - 60.0)  # warning
        _fill(store, "GB-3", [18.0, 19.0, 20.0, 21.5, 22.0, 22.5, 22.0, 22.4, 22.6, 22.8], NOW - 60.0)  # over the limit
        _fill(store, "GB-4", np.linspace(10.0, 12.0, 12), NOW - 30 * 86400.0)  # stale
    return db


def test_check_one_gearbox_each_state(capsys, fleet_db):
    expected = {
        "GB-1": (0, "BACKLASH OK - GB-1 play 12.0 arcmin, limit 21 in "),
        "GB-2": (1, "BACKLASH WARNING - GB-2 play 19.2 arcmin, limit 21 in "),
        "GB-3": (2, "BACKLASH CRITICAL - GB-3 play 22.8 arcmin, limit 21 exceeded since "),
        "GB-4": (3, "BACKLASH UNKNOWN - GB-4 the latest observable estimate is 30.0 days old ("),
    }
    for gearbox, (code_expected, start) in expected.items():
        code, out, err = run_cli(capsys, "history", "--db", fleet_db, "--gearbox", gearbox, "--check")
        assert code == code_expected and err == "" and out.startswith(start) and out.count("\n") == 1, out
        assert out.rstrip().endswith(";18;21")
    code, out, _ = run_cli(capsys, "history", "--db", fleet_db, "--gearbox", "GB-4", "--check", "--max-age-h", 24 * 31)
    assert code == 0 and out.startswith("BACKLASH OK - GB-4")


def test_check_all_exits_with_the_worst(capsys, fleet_db):
    code, out, _ = run_cli(capsys, "history", "--db", fleet_db, "--check", "--all")
    lines = out.splitlines()
    assert code == 2 and [line.split(" - ")[1].split()[0] for line in lines] == ["GB-1", "GB-2", "GB-3", "GB-4"]
    assert [line.split()[1] for line in lines] == ["OK", "WARNING", "CRITICAL", "UNKNOWN"]


def test_check_errors_are_unknown(capsys, fleet_db, tmp_path):
    code, out, _ = run_cli(capsys, "history", "--db", fleet_db, "--gearbox", "nope", "--check")
    assert code == 3 and out.startswith("BACKLASH UNKNOWN - error: ") and "holds no gearbox 'nope'" in out
    code, out, _ = run_cli(capsys, "history", "--db", tmp_path / "missing.db", "--all", "--check")
    assert code == 3 and out.startswith("BACKLASH UNKNOWN - error: no history store at")
    code, out, _ = run_cli(capsys, "history", "--db", fleet_db, "--check")
    assert code == 3 and out == "BACKLASH UNKNOWN - give --gearbox ID or --all with --check\n"
    code, _, err = run_cli(capsys, "history", "--db", fleet_db)
    assert code == 1 and "give --gearbox ID" in err


def test_history_json_and_text_say_since_when_the_limit_is_exceeded(capsys, fleet_db, tmp_path):
    code, out, _ = run_cli(capsys, "history", "--db", fleet_db, "--gearbox", "GB-3", "--json")
    d = json.loads(out)
    assert code == 0 and d["state"] == "alarm" and d["warn_arcmin"] == 18.0 and d["play_arcmin"] == pytest.approx(22.8)
    since = d["limit_exceeded_since"]
    assert since == d["estimates"][3]["time"]
    # the trend crossed in the past: dated on the estimates' clock, not extrapolated to decades ago
    assert d["forecast_hours_to_limit"] < 0 and d["forecast_date"] >= d["estimates"][0]["time"][:10]
    code, out, _ = run_cli(capsys, "history", "--db", fleet_db, "--gearbox", "GB-3", "--plot", tmp_path / "gb3.png")
    assert code == 0 and f"forecast: limit 21 arcmin exceeded since {since} (UTC), play now 22.80 arcmin" in out
    assert "state: alarm (play above the limit;" in out
    assert (tmp_path / "gb3.png").stat().st_size > 10_000
    code, out, _ = run_cli(capsys, "history", "--db", fleet_db, "--gearbox", "GB-2", "--json")
    d = json.loads(out)
    assert d["state"] == "warning" and d["limit_exceeded_since"] is None


def test_track_stores_and_checks_the_levels(capsys, tmp_path):
    rec = simulate_rig(duration_s=12.0, play_deg=0.3, seed=7)
    rec.time_s = rec.time_s + NOW - 60.0
    log = tmp_path / "run.csv"
    rec.write_csv(log)
    db = tmp_path / "w.db"
    base = ("track", log, "--ratio", 30, "--db", db, "--gearbox", "g1", "--every", 5)
    code, _, err = run_cli(capsys, *base, "--limit-arcmin", -1)
    assert (
        code == 1
        and err == "error: the limit must be a finite positive angle in arcmin, got -1.0\n"
        and not db.exists()
    )
    code, _, err = run_cli(capsys, *base, "--limit-arcmin", 21, "--warn-arcmin", 25)
    assert code == 1 and "the warning level 25 arcmin is above the limit 21 arcmin" in err and not db.exists()
    code, _, _ = run_cli(capsys, *base, "--limit-arcmin", 21, "--warn-arcmin", 17)
    assert code == 0
    with HistoryStore(db) as store:
        g = store.gearbox("g1")
    assert (g.warn_arcmin, g.limit_arcmin) == (17.0, 21.0)
    code, out, _ = run_cli(capsys, "history", "--db", db, "--gearbox", "g1", "--check")
    assert (
        code == 1
        and out.startswith("BACKLASH WARNING - g1 play 18.0 arcmin, limit 21")
        and out.rstrip().endswith(";17;21")
    )
    code, _, err = run_cli(capsys, "track", log, "--ratio", 30, "--db", db, "--gearbox", "g1", "--warn-arcmin", 22)
    assert code == 1 and "the warning level 22 arcmin is above the limit 21 arcmin" in err
