"""The wear-history store, run against SQLite and a real PostgreSQL server (see conftest.py)."""

from __future__ import annotations

import math
import os
import sqlite3
import threading

import pytest
from sqlalchemy import Double, create_engine, inspect, select, text

from online_backlash.errors import HistoryError
from online_backlash.history import store as store_module
from online_backlash.history.store import SCHEMA_VERSION, HistoryStore, metadata, resolve_url


def estimate_row(index: int, backlash_deg: float = 0.2, **changes) -> dict:
    row = dict(
        sample_index=index,
        time_unix_s=1.7e9 + index,
        backlash_deg=backlash_deg,
        backlash_std_deg=0.01,
        c_left_deg=backlash_deg / 2,
        c_right_deg=backlash_deg / 2,
        m_left=1.0,
        m_right=1.0,
        residual_rms_deg=0.001,
        n_samples=index,
        operating_hours=index / 3.6e6,
        load_revolutions=index / 1e4,
        reversals=index // 1000,
    )
    row.update(changes)
    return row


def snapshot(db: str) -> dict:
    """Every row of every table (a logical dump), to show that a refused operation wrote nothing."""
    engine = create_engine(resolve_url(db))
    try:
        with engine.connect() as conn:
            names = sorted(inspect(conn).get_table_names())
            return {
                name: sorted(map(tuple, conn.execute(text(f'SELECT * FROM "{name}"')).all()), key=repr)
                for name in names
            }
    finally:
        engine.dispose()


def sql(db: str, *statements: str) -> None:
    engine = create_engine(resolve_url(db))
    try:
        with engine.begin() as conn:
            for statement in statements:
                conn.execute(text(statement))
    finally:
        engine.dispose()


@pytest.fixture
def filled(store_db):
    """A store with gearbox g1 (ratio 30), one complete run with three estimates."""
    with HistoryStore(store_db, create=True) as store:
        gearbox, run = store.begin_run("g1", 30.0, "day1.csv", "a" * 64, 1.7e9, limit_arcmin=21.0)
        gearbox, run = store.commit(gearbox, run, 3000, {"state": 1}, [estimate_row(i) for i in (1000, 2000, 3000)])
        store.commit(
            gearbox,
            run,
            3500,
            {"state": 2},
            counters=dict(frames=3500, samples=3500, corrupt=0, skipped=0, gaps=1),
            ended_unix_s=1.7e9 + 3.5,
        )
    return store_db


def test_create_register_commit_read(store_db):
    with HistoryStore(store_db, create=True) as store:
        assert store.schema_version == SCHEMA_VERSION
        assert store.gearbox_ids() == []
        gearbox, run = store.begin_run("g1", -30.0, "day1.csv", "a" * 64, 1.7e9)
        assert (gearbox.id, gearbox.ratio, gearbox.checkpoint, gearbox.revision) == ("g1", -30.0, None, 0)
        assert (run.status, run.samples_done, run.started_unix_s) == ("running", 0, 1.7e9)
        gearbox, run = store.commit(
            gearbox, run, 2000, {"theta": [0.1, 1 / 3]}, [estimate_row(1000), estimate_row(2000)]
        )
        assert gearbox.checkpoint == {"theta": [0.1, 1 / 3]}  # floats round-trip exactly
        assert (gearbox.revision, run.samples_done) == (1, 2000)
    with HistoryStore(store_db) as store:  # reopened without create
        rows = store.estimates("g1")
        assert [r.sample_index for r in rows] == [1000, 2000]
        assert rows[0].backlash_deg == 0.2 and rows[1].reversals == 2
        assert store.gearbox("g1").ratio == -30.0


def test_same_log_returns_the_stored_run(filled):
    with HistoryStore(filled) as store:
        before = snapshot(filled)
        _, run = store.begin_run("g1", 30.0, "copy-of-day1.csv", "a" * 64, 1.7e9)
        assert run.complete and run.samples_done == 3500 and run.frames == 3500 and run.gaps == 1
        assert snapshot(filled) == before
        _, other = store.begin_run("g1", 30.0, "day2.csv", "b" * 64, 1.7e9 + 86400)
        assert other.id != run.id and other.status == "running"
        assert [r.source for r in store.runs("g1")] == ["day1.csv", "day2.csv"]


def test_contradicting_ratio_is_refused_and_nothing_written(filled):
    before = snapshot(filled)
    with HistoryStore(filled) as store, pytest.raises(HistoryError, match=r"stored with ratio 30.*--ratio 35"):
        store.begin_run("g1", 35.0, "day2.csv", "b" * 64, 1.7e9)
    assert snapshot(filled) == before


def test_new_limit_replaces_the_stored_one(filled):
    with HistoryStore(filled) as store:
        assert store.gearbox("g1").limit_arcmin == 21.0
        store.begin_run("g1", 30.0, "day2.csv", "b" * 64, None, limit_arcmin=18.0)
        assert store.gearbox("g1").limit_arcmin == 18.0


def test_unknown_gearbox_names_the_known_ones(filled):
    with HistoryStore(filled) as store:
        with pytest.raises(HistoryError, match="holds no gearbox 'g9'; it holds g1"):
            store.estimates("g9")
        with pytest.raises(HistoryError, match="holds no gearbox"):
            store.gearbox("g9")


def test_a_failing_commit_writes_nothing(filled):
    with HistoryStore(filled) as store:
        gearbox, run = store.begin_run("g1", 30.0, "day2.csv", "b" * 64, None)
        before = snapshot(filled)
        # the second row repeats a sample index: the unique key refuses it, and the first row,
        # the checkpoint and the resume point must all be rolled back with it
        with pytest.raises(HistoryError, match="nothing was written"):
            store.commit(gearbox, run, 2000, {"state": 3}, [estimate_row(1000), estimate_row(1000)])
        assert snapshot(filled) == before


def test_a_stale_writer_is_refused(filled):
    with HistoryStore(filled) as store:
        gearbox, run = store.begin_run("g1", 30.0, "day2.csv", "b" * 64, None)
        store.commit(gearbox, run, 1000, {"state": "first writer"}, [estimate_row(1000)])
        before = snapshot(filled)
        with pytest.raises(HistoryError, match="updated by another process"):
            store.commit(gearbox, run, 1000, {"state": "second writer"}, [estimate_row(1000, 0.3)])
        assert snapshot(filled) == before


def test_non_finite_values_are_stored_as_null(store_db):
    with HistoryStore(store_db, create=True) as store:
        gearbox, run = store.begin_run("g1", 30.0, "x", None, None)
        store.commit(gearbox, run, 10, {}, [estimate_row(10, backlash_std_deg=math.nan, residual_rms_deg=math.inf)])
        (row,) = store.estimates("g1")
        assert row.backlash_std_deg is None and row.residual_rms_deg is None


def test_missing_store_is_not_created_for_reading(store_db):
    with pytest.raises(HistoryError, match="no history store"):
        HistoryStore(store_db)
    if "://" not in store_db:
        assert not os.path.exists(store_db)
    else:
        assert snapshot(store_db) == {}


def test_newer_schema_is_refused_untouched(filled):
    sql(filled, f"UPDATE meta SET value = '{SCHEMA_VERSION + 1}' WHERE key = 'schema_version'")
    before = snapshot(filled)
    with pytest.raises(HistoryError, match=f"schema version {SCHEMA_VERSION + 1}, newer"):
        HistoryStore(filled)
    with pytest.raises(HistoryError, match="newer"):
        HistoryStore(filled, create=True)
    assert snapshot(filled) == before


def test_foreign_database_is_refused_untouched(store_db):
    sql(store_db, "CREATE TABLE customers (id INTEGER PRIMARY KEY, name TEXT)", "INSERT INTO customers VALUES (1, 'x')")
    before = snapshot(store_db)
    with pytest.raises(HistoryError, match=r"not an online-backlash history store.*customers"):
        HistoryStore(store_db, create=True)
    assert snapshot(store_db) == before


def test_foreign_meta_table_is_refused(store_db):
    sql(store_db, "CREATE TABLE meta (key TEXT, value TEXT)", "INSERT INTO meta VALUES ('application', 'other')")
    with pytest.raises(HistoryError, match="meta table is foreign"):
        HistoryStore(store_db, create=True)


@pytest.mark.parametrize("content", [b"time,motor,load\n0,0,0\n", b"\x00" * 4096, bytes(range(256)) * 8])
def test_file_that_is_not_sqlite_is_refused_untouched(tmp_path, content):
    path = tmp_path / "notastore.db"
    path.write_bytes(content)
    for create in (False, True):
        with pytest.raises(HistoryError, match="not an online-backlash history store"):
            HistoryStore(path, create=create)
    assert path.read_bytes() == content
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notastore.db"]


def test_sqlite_store_is_in_wal_mode(tmp_path):
    path = tmp_path / "wear.db"
    HistoryStore(path, create=True).close()
    with sqlite3.connect(path) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_unsupported_url_is_refused():
    with pytest.raises(HistoryError, match="unsupported database 'mysql'"):
        HistoryStore("mysql://user@host/db")


def _add_note_column(conn):
    conn.execute(text("ALTER TABLE gearboxes ADD COLUMN note VARCHAR(100)"))
    conn.execute(text("UPDATE gearboxes SET note = 'migrated'"))


def test_migration_upgrades_an_older_store(filled, monkeypatch):
    before = snapshot(filled)
    monkeypatch.setattr(store_module, "SCHEMA_VERSION", SCHEMA_VERSION + 1)
    monkeypatch.setitem(store_module.MIGRATIONS, SCHEMA_VERSION, _add_note_column)
    with HistoryStore(filled) as store:
        assert store.schema_version == SCHEMA_VERSION + 1
        assert [e.sample_index for e in store.estimates("g1")] == [1000, 2000, 3000]
    after = snapshot(filled)
    assert after["estimates"] == before["estimates"] and after["runs"] == before["runs"]
    assert ("schema_version", str(SCHEMA_VERSION + 1)) in after["meta"]
    assert all(row[-1] == "migrated" for row in after["gearboxes"])


def test_failing_migration_leaves_the_store_as_it_was(filled, monkeypatch):
    def broken(conn):
        _add_note_column(conn)
        conn.execute(text("SELECT no_such_column FROM gearboxes"))

    before = snapshot(filled)
    monkeypatch.setattr(store_module, "SCHEMA_VERSION", SCHEMA_VERSION + 1)
    monkeypatch.setitem(store_module.MIGRATIONS, SCHEMA_VERSION, broken)
    with pytest.raises(HistoryError, match=f"migrating .* from schema version {SCHEMA_VERSION} failed"):
        HistoryStore(filled)
    assert snapshot(filled) == before  # the ALTER TABLE was rolled back too


def test_missing_migration_is_an_error(filled, monkeypatch):
    monkeypatch.setattr(store_module, "SCHEMA_VERSION", SCHEMA_VERSION + 1)
    with pytest.raises(HistoryError, match=f"no migration from version {SCHEMA_VERSION}"):
        HistoryStore(filled)


def test_schema_matches_the_table_definitions(filled):
    engine = create_engine(resolve_url(filled))
    try:
        with engine.connect() as conn:
            found = inspect(conn)
            for table in metadata.sorted_tables:
                assert {c["name"] for c in found.get_columns(table.name)} == set(table.columns.keys())
            assert conn.execute(
                select(text("value")).select_from(text("meta")).where(text("key = 'schema_version'"))
            ).scalar() == str(SCHEMA_VERSION)
    finally:
        engine.dispose()
    assert isinstance(metadata.tables["estimates"].c.backlash_deg.type, Double)


def test_concurrent_creation_makes_one_store(store_db):
    start = threading.Barrier(4)
    errors = []

    def open_store():
        start.wait()
        try:
            HistoryStore(store_db, create=True).close()
        except HistoryError as exc:
            errors.append(exc)

    threads = [threading.Thread(target=open_store) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    # SQLite serialises the creators (BEGIN IMMEDIATE); a PostgreSQL creator that loses the race
    # gets a clear HistoryError instead of a half-made store
    assert len(errors) <= 3 and all("creating the history store" in str(e) for e in errors)
    if "://" not in store_db:
        assert errors == []
    assert sorted(snapshot(store_db)["meta"]) == [
        ("application", "online-backlash"),
        ("schema_version", str(SCHEMA_VERSION)),
    ]
