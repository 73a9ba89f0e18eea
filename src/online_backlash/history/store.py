"""The wear-history store: gearboxes, runs and estimates in SQLite or PostgreSQL (SQLAlchemy 2).

``db`` is either a file path (SQLite, the embedded default, in WAL mode so a reader never
blocks the writer) or a URL: ``postgresql://user@host/dbname`` for many rigs writing to one
server (driver psycopg 3; ``postgresql+psycopg://`` is used internally) or ``sqlite:///path``.
Both speak the same schema, defined once below with SQLAlchemy Core.

Tables
------
``meta``
    ``key``/``value`` pairs: ``application`` (``online-backlash``) and ``schema_version``.
``gearboxes``
    One row per gearbox: ``id`` (the user's name for it), ``ratio`` (motor:load), the nominal
    backlash limit ``limit_arcmin`` and warning level ``warn_arcmin`` (either may be NULL;
    see :mod:`online_backlash.history.alarms`), ``created_unix_s``, and the tracker's
    ``checkpoint`` (JSON: estimator state and usage counters after the last committed sample)
    with its ``revision`` (incremented by every commit; a commit that finds another revision
    than the one it started from is refused, so two writers cannot interleave one gearbox).
``runs``
    One row per source fed into a gearbox: ``source`` (log path or live description),
    ``log_sha256`` (unique per gearbox: the same log imported twice adds nothing),
    ``status`` (``running`` or ``complete``), the calendar time of the first and last sample
    (``started_unix_s``, ``ended_unix_s``), ``imported_unix_s``, ``samples_done`` (the resume
    point: samples of this source already in the checkpoint) and the source's counters
    (``frames``, ``samples``, ``corrupt``, ``skipped``, ``gaps``).
``estimates``
    One row per estimate: ``time_unix_s``, ``backlash_deg`` and ``backlash_std_deg``, both
    sides ``c_left_deg``/``c_right_deg``, slopes ``m_left``/``m_right``, ``residual_rms_deg``,
    ``n_samples`` (samples seen by the estimator since the gearbox was new), and the usage since
    new: ``operating_hours``, ``load_revolutions``, ``reversals``; the load condition (schema 3):
    ``play_observable`` (false: the data did not show the play, e.g. a preloaded drive whose
    torque never reversed; ``backlash_deg`` is then NULL or the play last seen, and the trend
    leaves the row out), ``torque_mean_nm``, ``torque_rms_nm`` (of the data since the estimate
    before), ``torque_reversals`` and ``stiffness_nm_per_arcmin`` (NULL without torque); the
    machine's own usage (schema 4): ``machine_hours``, its hour meter at the estimate (NULL where
    the log came without one; ``operating_hours`` counts only the time in motion the logs recorded);
    the path of the play (schema 5): ``play_method`` (``torque`` or ``kinematic``) and ``play_method_reason``,
    and where the play is not reported (:func:`online_backlash.physical.play_verdict`) its ``reason``
    and the bounds the data support, ``backlash_lower_bound_deg`` and ``backlash_upper_bound_deg``.
    ``(run_id, sample_index)`` is unique, so a row can never be written twice.

Times are UNIX seconds (UTC), angles degrees on the load side.

Schema version and migrations
-----------------------------
A new store is created from the current table definitions and stamped with
:data:`SCHEMA_VERSION`. A store stamped with an older version ``k`` is upgraded on open by
running ``MIGRATIONS[k]``, ``MIGRATIONS[k + 1]``, ... (each takes the schema from version ``i``
to ``i + 1``), all in one transaction with the new stamp, so an upgrade that fails leaves the
store as it was (DDL is transactional in both SQLite and PostgreSQL). A store stamped with a
newer version than this code knows is refused rather than guessed at. To change the schema:
edit the tables, append a migration from the current version, and increment
:data:`SCHEMA_VERSION`. Version 1 is the first schema; version 2 adds ``gearboxes.warn_arcmin``;
version 3 adds the load condition of each estimate and lets ``backlash_deg`` be NULL;
version 4 adds ``estimates.machine_hours``; version 5 adds the path of each play and its
verdict, and applies that verdict to the plays stored before.

Every write that belongs together (estimate rows, the run's resume point and the gearbox's
checkpoint) is one transaction: a process killed at any instant leaves either all or none of it.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote

from sqlalchemy import (
    BigInteger,
    Boolean,
    Column,
    Connection,
    Double,
    ForeignKey,
    Integer,
    MetaData,
    String,
    Table,
    Text,
    UniqueConstraint,
    create_engine,
    event,
    inspect,
    select,
    true,
    update,
)
from sqlalchemy.engine import URL, Engine, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError, SQLAlchemyError

from ..errors import HistoryError
from ..output_columns import FIELDS, STORE_KEYS
from ..physical import figure_verdict
from .alarms import check_alarm_levels

APPLICATION = "online-backlash"

#: Version of the schema defined in this module.
SCHEMA_VERSION = 5


def _add_warn_arcmin(conn: Connection) -> None:
    """Version 1 -> 2: the gearbox's warning level ``warn_arcmin`` (NULL: none stored)."""
    column_type = Double().compile(dialect=conn.dialect)
    conn.exec_driver_sql(f"ALTER TABLE gearboxes ADD COLUMN warn_arcmin {column_type}")


#: Columns schema 3 adds to ``estimates`` (the load condition of each estimate).
_V3_COLUMNS = ("play_observable", "torque_mean_nm", "torque_rms_nm", "torque_reversals", "stiffness_nm_per_arcmin")


def _add_load_condition(conn: Connection) -> None:
    """Version 2 -> 3: each estimate's load condition, and ``backlash_deg`` may be NULL (not observable).

    Adds ``play_observable`` (the estimates stored before are taken as observable: they came from
    the kinematic estimator, whose play the trend used), ``torque_mean_nm``, ``torque_rms_nm``,
    ``torque_reversals`` and ``stiffness_nm_per_arcmin`` (NULL: not known). SQLite cannot drop a
    NOT NULL constraint, so there the table is rebuilt from the current definition and the rows
    copied; PostgreSQL alters the column.
    """
    if conn.dialect.name == "sqlite":
        conn.exec_driver_sql("ALTER TABLE estimates RENAME TO estimates_v2")
        for index in estimates_table.indexes:
            conn.exec_driver_sql(f"DROP INDEX IF EXISTS {index.name}")
        estimates_table.create(conn)  # the current definition: later versions' columns are there, NULL
        present = {c["name"] for c in inspect(conn).get_columns("estimates_v2")}
        names = ", ".join(c.name for c in estimates_table.columns if c.name in present and c.name not in _V3_COLUMNS)
        conn.exec_driver_sql(f"INSERT INTO estimates ({names}, play_observable) SELECT {names}, 1 FROM estimates_v2")
        conn.exec_driver_sql("DROP TABLE estimates_v2")
        return
    conn.exec_driver_sql("ALTER TABLE estimates ALTER COLUMN backlash_deg DROP NOT NULL")
    for name in _V3_COLUMNS:
        column = estimates_table.c[name]
        sql_type = column.type.compile(dialect=conn.dialect)
        default = " NOT NULL DEFAULT TRUE" if name == "play_observable" else ""
        conn.exec_driver_sql(f"ALTER TABLE estimates ADD COLUMN IF NOT EXISTS {name} {sql_type}{default}")


def _add_estimate_columns(conn: Connection, names: tuple[str, ...]) -> None:
    """Add to ``estimates`` those of the columns ``names`` it lacks, typed as the current definition types them
    (an SQLite store coming from version 2 has them already: version 3 rebuilt its table from that definition)."""
    present = {c["name"] for c in inspect(conn).get_columns("estimates")}
    for name in names:
        if name not in present:
            sql_type = estimates_table.c[name].type.compile(dialect=conn.dialect)
            conn.exec_driver_sql(f"ALTER TABLE estimates ADD COLUMN {name} {sql_type}")


def _add_machine_hours(conn: Connection) -> None:
    """Version 3 -> 4: each estimate's machine hours (the machine's hour meter, issue 28; NULL: not given).

    The estimates stored before keep their logged operating hours; their machine hours are not
    known.
    """
    _add_estimate_columns(conn, ("machine_hours",))


def _add_play_method(conn: Connection) -> None:
    """Version 4 -> 5: each estimate's path and verdict (issue 27), and the verdict of the plays stored before.

    Adds ``play_method``, ``play_method_reason``, ``reason``, ``backlash_lower_bound_deg`` and
    ``backlash_upper_bound_deg`` (NULL: not known). Then applies the rule of :mod:`online_backlash.physical` to every
    stored play: a play below zero, or whose standard error exceeds half its value, was never a play -- its
    ``backlash_deg`` becomes NULL, ``play_observable`` false, and ``reason`` keeps what it was (the encoders' resolution
    of those rows is not known, so a measured zero is not told apart here).
    """
    _add_estimate_columns(
        conn, ("play_method", "play_method_reason", "reason", "backlash_lower_bound_deg", "backlash_upper_bound_deg")
    )
    t = estimates_table
    stored = conn.execute(select(t.c.id, t.c.backlash_deg, t.c.backlash_std_deg).where(t.c.backlash_deg.is_not(None)))
    for row_id, play, std in stored.all():
        verdict = figure_verdict(play, std, "deg", "play")
        if verdict.value is None:
            reason = f"{verdict.reason} (stored before schema 5)"
            values: dict[str, Any] = {"backlash_deg": None, "play_observable": False, "reason": reason}
            values["backlash_upper_bound_deg"] = verdict.upper_bound
            conn.execute(update(t).where(t.c.id == row_id).values(**values))


#: ``MIGRATIONS[i]`` upgrades a store from schema version ``i`` to ``i + 1``, given a connection
#: inside the upgrade transaction.
MIGRATIONS: dict[int, Callable[[Connection], None]] = {
    1: _add_warn_arcmin,
    2: _add_load_condition,
    3: _add_machine_hours,
    4: _add_play_method,
}

_SQLITE_MAGIC = b"SQLite format 3\x00"

metadata = MetaData()

meta_table = Table(
    "meta",
    metadata,
    Column("key", String(64), primary_key=True),
    Column("value", String(256), nullable=False),
)

gearboxes_table = Table(
    "gearboxes",
    metadata,
    Column("id", String(200), primary_key=True),
    Column("ratio", Double, nullable=False),
    Column("limit_arcmin", Double),
    Column("created_unix_s", Double, nullable=False),
    Column("checkpoint", Text),
    Column("revision", Integer, nullable=False, default=0),
    Column("warn_arcmin", Double),
)

runs_table = Table(
    "runs",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("gearbox_id", String(200), ForeignKey("gearboxes.id"), nullable=False),
    Column("source", String(1000), nullable=False),
    Column("log_sha256", String(64)),
    Column("status", String(16), nullable=False),
    Column("started_unix_s", Double),
    Column("ended_unix_s", Double),
    Column("imported_unix_s", Double, nullable=False),
    Column("samples_done", BigInteger, nullable=False, default=0),
    Column("frames", BigInteger, nullable=False, default=0),
    Column("samples", BigInteger, nullable=False, default=0),
    Column("corrupt", BigInteger, nullable=False, default=0),
    Column("skipped", BigInteger, nullable=False, default=0),
    Column("gaps", BigInteger, nullable=False, default=0),
    UniqueConstraint("gearbox_id", "log_sha256", name="uq_runs_gearbox_log"),
)

#: SQL type of each kind of estimate column (online_backlash.output_columns.RowField.kind).
_SQL_TYPES: dict[type, Any] = {float: Double, int: BigInteger, bool: Boolean, str: Text}


def _estimate_column(key: str) -> Column:
    """The store column of field ``key``; ``play_observable`` defaults to true (rows written without it)."""
    f = FIELDS[key]
    return Column(
        f.name, _SQL_TYPES[f.kind], nullable=f.nullable, server_default=true() if key == "play_observable" else None
    )


estimates_table = Table(
    "estimates",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("gearbox_id", String(200), ForeignKey("gearboxes.id"), nullable=False, index=True),
    Column("run_id", Integer, ForeignKey("runs.id"), nullable=False),
    # the estimate's columns, declared once in online_backlash.output_columns
    *(_estimate_column(k) for k in STORE_KEYS),
    UniqueConstraint("run_id", "sample_index", name="uq_estimates_run_sample"),
)

#: Columns of an estimate row, in table order (without the surrogate key).
ESTIMATE_FIELDS = tuple(c.name for c in estimates_table.columns if c.name != "id")


@dataclass(frozen=True)
class Gearbox:
    """A stored gearbox; ``checkpoint`` is the tracker state (a dict) or None before the first commit.

    ``limit_arcmin`` and ``warn_arcmin`` are the alarm levels of the play, arcmin (None: not stored).
    """

    id: str
    ratio: float
    limit_arcmin: float | None
    created_unix_s: float
    checkpoint: dict | None
    revision: int
    warn_arcmin: float | None = None


@dataclass(frozen=True)
class Run:
    """A stored run (one log or live session fed into one gearbox)."""

    id: int
    gearbox_id: str
    source: str
    log_sha256: str | None
    status: str
    started_unix_s: float | None
    ended_unix_s: float | None
    imported_unix_s: float
    samples_done: int
    frames: int
    samples: int
    corrupt: int
    skipped: int
    gaps: int

    @property
    def complete(self) -> bool:
        return self.status == "complete"


@dataclass(frozen=True)
class Estimate:
    """One stored estimate; times UNIX seconds, angles degrees (load side)."""

    gearbox_id: str
    run_id: int
    sample_index: int
    time_unix_s: float
    backlash_deg: float | None
    backlash_std_deg: float | None
    c_left_deg: float | None
    c_right_deg: float | None
    m_left: float | None
    m_right: float | None
    residual_rms_deg: float | None
    n_samples: int
    operating_hours: float
    load_revolutions: float
    reversals: int
    play_observable: bool = True
    torque_mean_nm: float | None = None
    torque_rms_nm: float | None = None
    torque_reversals: int | None = None
    stiffness_nm_per_arcmin: float | None = None
    machine_hours: float | None = None
    play_method: str | None = None
    play_method_reason: str | None = None
    reason: str | None = None
    backlash_lower_bound_deg: float | None = None
    backlash_upper_bound_deg: float | None = None


def resolve_url(db: str | os.PathLike[str]) -> URL:
    """The SQLAlchemy URL of ``db``: a path means SQLite; ``postgresql://`` selects psycopg 3."""
    text = os.fspath(db)
    if "://" not in text:
        return URL.create("sqlite", database=str(Path(text).expanduser().resolve()))
    try:
        url = make_url(text)
    except ArgumentError as exc:
        raise HistoryError(f"cannot parse database URL {text!r}: {exc}") from exc
    backend = url.get_backend_name()
    if backend in ("postgresql", "postgres"):
        return url.set(drivername="postgresql+psycopg")
    if backend == "sqlite":
        return url
    raise HistoryError(f"unsupported database {url.drivername!r}: use a file path (SQLite) or postgresql://...")


def _describe(url: URL) -> str:
    return (url.database or "") if url.get_backend_name() == "sqlite" else url.render_as_string(hide_password=True)


class _NeedsMigration(Exception):
    """A store opened read-only has an older schema (it is opened again for writing, to migrate)."""


def _read_only_url(path: Path) -> URL:
    """The SQLite URI that opens ``path`` read-only; ``immutable`` where its folder cannot be written."""
    query = {"mode": "ro", "uri": "true"}
    if not os.access(path.parent, os.W_OK):
        query["immutable"] = "1"
    return URL.create("sqlite", database=f"file:{quote(str(path.resolve()), safe='/')}", query=query)


def _sqlite_file(url: URL) -> Path | None:
    """The file behind a SQLite URL (None for an in-memory database)."""
    if url.get_backend_name() != "sqlite" or url.database in (None, "", ":memory:"):
        return None
    return Path(url.database)


class HistoryStore:
    """Open (and, with ``create=True``, create) a wear-history store.

    Parameters
    ----------
    db : str or os.PathLike
        A file path (SQLite) or a URL (``postgresql://...``, ``sqlite:///...``).
    create : bool
        Create the store if ``db`` holds none yet (a missing file or an empty database). With
        False such a ``db`` raises :class:`~online_backlash.errors.HistoryError`.
    read_only : bool
        Only read (``history``, ``serve``): an SQLite file is opened read-only (``mode=ro``, and
        ``immutable`` where its folder cannot be written, since SQLite could not make its WAL
        files there), so a store in a read-only folder or on a read-only share can be read. A
        store of an older schema is opened for writing once, to migrate it.

    Raises
    ------
    HistoryError
        ``db`` is not an online-backlash store (another file, another database), its schema is
        newer than this code, or the server cannot be reached. Nothing is written in these cases.

    Examples
    --------
    >>> import tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "wear.db")
    >>> with HistoryStore(path, create=True) as store:
    ...     store.schema_version == SCHEMA_VERSION
    True
    """

    def __init__(self, db: str | os.PathLike[str], create: bool = False, read_only: bool = False) -> None:
        if create and read_only:
            raise HistoryError("a store opened read-only cannot be created")
        self.url = resolve_url(db)
        self.name = _describe(self.url)
        self._sqlite = self.url.get_backend_name() == "sqlite"
        path = _sqlite_file(self.url)
        if path is not None:
            self._check_sqlite_file(path, create)
        self.read_only = read_only and path is not None
        self.engine = self._make_engine(_read_only_url(path) if self.read_only and path is not None else self.url)
        try:
            self.schema_version = self._open_schema(create)
        except _NeedsMigration:
            self.engine.dispose()
            self.read_only = False
            self.engine = self._make_engine(self.url)
            self._open_or_dispose(create)
        except BaseException:
            self.engine.dispose()
            raise

    def _open_or_dispose(self, create: bool) -> None:
        try:
            self.schema_version = self._open_schema(create)
        except BaseException:
            self.engine.dispose()
            raise

    # -- opening ---------------------------------------------------------------------------
    def _check_sqlite_file(self, path: Path, create: bool) -> None:
        if not path.exists():
            if not create:
                raise HistoryError(f"no history store at {path}")
            if not path.parent.is_dir():
                raise HistoryError(f"cannot create {path}: folder {path.parent} does not exist")
            return
        if path.is_dir():
            raise HistoryError(f"{path} is a folder, not a history store")
        with open(path, "rb") as f:
            head = f.read(len(_SQLITE_MAGIC))
        if head and head != _SQLITE_MAGIC:
            raise HistoryError(f"{path} is not an online-backlash history store (not an SQLite database)")

    def _make_engine(self, url: URL) -> Engine:
        try:
            engine = create_engine(url)
        except ImportError as exc:  # the database driver is an extra: say which one
            raise HistoryError(
                f"{self.name}: {url.get_backend_name()} needs the driver {exc.name or 'psycopg'}, which is not "
                "installed; pip install 'online-backlash[postgres]'"
            ) from exc
        if self._sqlite:
            # pysqlite opens transactions lazily and not before DDL; take over BEGIN so that every
            # transaction (migrations included) is atomic, and take the write lock up front
            # (BEGIN IMMEDIATE) so that two writers wait for each other instead of deadlocking.
            @event.listens_for(engine, "connect")
            def _on_connect(dbapi_connection: Any, _record: Any) -> None:
                dbapi_connection.isolation_level = None
                dbapi_connection.execute("PRAGMA foreign_keys=ON")
                dbapi_connection.execute("PRAGMA busy_timeout=30000")
                # with WAL, commits survive a killed process without a sync each (only a power cut
                # may lose the latest ones, never consistency)
                dbapi_connection.execute("PRAGMA synchronous=NORMAL")

            @event.listens_for(engine, "begin")
            def _on_begin(conn: Connection) -> None:
                conn.exec_driver_sql("BEGIN IMMEDIATE" if conn.info.get("write") else "BEGIN")

        return engine

    def _connect(self, write: bool = False) -> Connection:
        try:
            conn = self.engine.connect()
        except DBAPIError as exc:
            raise HistoryError(f"cannot open history store {self.name}: {exc.orig}") from exc
        conn.info["write"] = write
        return conn

    def _open_schema(self, create: bool) -> int:
        try:
            with self._connect() as conn:
                tables = set(inspect(conn).get_table_names())
                stamp = (
                    dict(conn.execute(select(meta_table.c.key, meta_table.c.value)).all()) if "meta" in tables else None
                )
        except DBAPIError as exc:
            raise HistoryError(f"{self.name} is not an online-backlash history store ({exc.orig})") from exc
        if stamp is None:
            if tables:
                raise HistoryError(
                    f"{self.name} is not an online-backlash history store (it holds other tables: {sorted(tables)[:5]})"
                )
            if not create:
                raise HistoryError(f"no history store in {self.name} (the database is empty)")
            self._create()
            return SCHEMA_VERSION
        if stamp.get("application") != APPLICATION or not str(stamp.get("schema_version", "")).isdigit():
            raise HistoryError(f"{self.name} is not an online-backlash history store (its meta table is foreign)")
        version = int(stamp["schema_version"])
        if version > SCHEMA_VERSION:
            raise HistoryError(
                f"{self.name} has schema version {version}, newer than this online-backlash understands "
                f"({SCHEMA_VERSION}); upgrade online-backlash to read it"
            )
        if version < SCHEMA_VERSION:
            if self.read_only:
                raise _NeedsMigration
            self._migrate(version)
        return SCHEMA_VERSION

    def _create(self) -> None:
        if self._sqlite:
            with self._connect() as conn:
                # a persistent property of the file; must run outside a transaction
                sqlite_connection = conn.connection.dbapi_connection
                if sqlite_connection is None:
                    raise HistoryError(f"cannot open history store {self.name}: the SQLite connection is closed")
                _switch_to_wal(sqlite_connection)
        try:
            with self._connect(write=True) as conn, conn.begin():
                if "meta" in inspect(conn).get_table_names():
                    return  # another process created it meanwhile
                metadata.create_all(conn)
                conn.execute(
                    meta_table.insert(),
                    [
                        {"key": "application", "value": APPLICATION},
                        {"key": "schema_version", "value": str(SCHEMA_VERSION)},
                    ],
                )
        except SQLAlchemyError as exc:
            raise HistoryError(f"creating the history store in {self.name} failed: {exc}") from exc

    def _migrate(self, version: int) -> None:
        missing = [v for v in range(version, SCHEMA_VERSION) if v not in MIGRATIONS]
        if missing:
            raise HistoryError(
                f"{self.name} has schema version {version} and no migration from version {missing[0]} exists"
            )
        try:
            with self._connect(write=True) as conn, conn.begin():
                for v in range(version, SCHEMA_VERSION):
                    MIGRATIONS[v](conn)
                conn.execute(
                    update(meta_table).where(meta_table.c.key == "schema_version").values(value=str(SCHEMA_VERSION))
                )
        except SQLAlchemyError as exc:
            raise HistoryError(f"migrating {self.name} from schema version {version} failed: {exc}") from exc

    # -- lifetime --------------------------------------------------------------------------
    def close(self) -> None:
        """Release the connections."""
        self.engine.dispose()

    def __enter__(self) -> HistoryStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- reading ---------------------------------------------------------------------------
    def gearbox_ids(self) -> list[str]:
        """The ids of every stored gearbox, sorted."""
        with self._connect() as conn:
            return list(conn.execute(select(gearboxes_table.c.id).order_by(gearboxes_table.c.id)).scalars())

    def find_gearbox(self, gearbox_id: str) -> Gearbox | None:
        """The stored gearbox ``gearbox_id``, or None if the store does not hold it."""
        with self._connect() as conn:
            return _get_gearbox(conn, gearbox_id)

    def gearbox(self, gearbox_id: str) -> Gearbox:
        """The stored gearbox ``gearbox_id``; HistoryError if the store does not hold it."""
        found = self.find_gearbox(gearbox_id)
        if found is None:
            raise HistoryError(self._unknown(gearbox_id))
        return found

    def runs(self, gearbox_id: str) -> list[Run]:
        """The runs of a gearbox in the order they were started."""
        with self._connect() as conn:
            rows = conn.execute(
                select(runs_table).where(runs_table.c.gearbox_id == gearbox_id).order_by(runs_table.c.id)
            )
            return [Run(**row._mapping) for row in rows]

    def estimates(self, gearbox_id: str) -> list[Estimate]:
        """Every estimate of a gearbox in the order of its use (operating hours, then time)."""
        t = estimates_table
        with self._connect() as conn:
            if _get_gearbox(conn, gearbox_id) is None:
                raise HistoryError(self._unknown(gearbox_id))
            rows = conn.execute(
                select(*(t.c[name] for name in ESTIMATE_FIELDS))
                .where(t.c.gearbox_id == gearbox_id)
                .order_by(t.c.n_samples, t.c.time_unix_s, t.c.id)
            )
            return [Estimate(**row._mapping) for row in rows]

    def _unknown(self, gearbox_id: str) -> str:
        known = self.gearbox_ids()
        hint = f"; it holds {', '.join(known[:10])}" if known else "; it holds no gearbox yet"
        return f"{self.name} holds no gearbox {gearbox_id!r}{hint}"

    # -- writing ---------------------------------------------------------------------------
    def begin_run(
        self,
        gearbox_id: str,
        ratio: float,
        source: str,
        log_sha256: str | None,
        started_unix_s: float | None,
        limit_arcmin: float | None = None,
    ) -> tuple[Gearbox, Run]:
        """Register the gearbox if new, then find or start the run of this source, in one transaction.

        A gearbox the store has not seen is registered with ``ratio`` (and ``limit_arcmin``); a
        known one must have the same ratio (else HistoryError, nothing written); a given
        ``limit_arcmin`` replaces the stored limit. With a ``log_sha256`` already stored for this
        gearbox the existing run is returned (complete: nothing to do; running: resume it).
        """
        now = time.time()
        with self._connect(write=True) as conn, conn.begin():
            gearbox = _register_gearbox(conn, gearbox_id, ratio, now, limit_arcmin=limit_arcmin)
            run_row = None
            if log_sha256 is not None:
                run_row = conn.execute(
                    select(runs_table).where(
                        runs_table.c.gearbox_id == gearbox_id, runs_table.c.log_sha256 == log_sha256
                    )
                ).first()
            if run_row is None:
                run_row = conn.execute(
                    runs_table.insert()
                    .values(
                        gearbox_id=gearbox_id,
                        source=source[:1000],
                        log_sha256=log_sha256,
                        status="running",
                        started_unix_s=started_unix_s,
                        imported_unix_s=now,
                        samples_done=0,
                        frames=0,
                        samples=0,
                        corrupt=0,
                        skipped=0,
                        gaps=0,
                    )
                    .returning(*runs_table.c)
                ).one()
        return gearbox, Run(**run_row._mapping)

    def set_alarm_levels(
        self, gearbox_id: str, ratio: float, warn_arcmin: float | None = None, limit_arcmin: float | None = None
    ) -> Gearbox:
        """Store the gearbox's warning level and limit (arcmin), registering it with ``ratio`` if new.

        A level given as None keeps the stored one. The levels are checked together with the
        stored ones (:func:`~online_backlash.history.alarms.check_alarm_levels`: positive,
        finite, warning not above the limit); InvalidParameterError and nothing written if not.
        Returns the stored gearbox.
        """
        with self._connect(write=True) as conn, conn.begin():
            return _register_gearbox(
                conn, gearbox_id, ratio, time.time(), warn_arcmin=warn_arcmin, limit_arcmin=limit_arcmin
            )

    def commit(
        self,
        gearbox: Gearbox,
        run: Run,
        samples_done: int,
        checkpoint: dict,
        estimates: Iterable[dict[str, Any]] = (),
        counters: dict[str, int] | None = None,
        ended_unix_s: float | None = None,
    ) -> tuple[Gearbox, Run]:
        """Append estimates and move the checkpoint and the run's resume point, in one transaction.

        ``gearbox`` and ``run`` are the versions the caller started from: if another process
        committed to the same gearbox or run meanwhile, HistoryError is raised and nothing is
        written. With ``counters`` the run is marked complete. Returns the updated records.
        """
        rows = [
            {k: _finite_or_none(v) for k, v in dict(e, gearbox_id=gearbox.id, run_id=run.id).items()} for e in estimates
        ]
        run_values: dict[str, Any] = {"samples_done": samples_done}
        if ended_unix_s is not None:
            run_values["ended_unix_s"] = ended_unix_s
        if counters is not None:
            run_values.update(
                status="complete", **{k: int(counters[k]) for k in ("frames", "samples", "corrupt", "skipped", "gaps")}
            )
        state = json.dumps(checkpoint, allow_nan=True)
        try:
            return self._commit(gearbox, run, rows, run_values, state)
        except SQLAlchemyError as exc:
            raise HistoryError(f"writing to {self.name} failed, nothing was written: {exc}") from exc

    def _commit(self, gearbox: Gearbox, run: Run, rows: list, run_values: dict, state: str) -> tuple[Gearbox, Run]:
        with self._connect(write=True) as conn, conn.begin():
            moved = conn.execute(
                update(gearboxes_table)
                .where(gearboxes_table.c.id == gearbox.id, gearboxes_table.c.revision == gearbox.revision)
                .values(checkpoint=state, revision=gearbox.revision + 1)
            ).rowcount
            advanced = conn.execute(
                update(runs_table)
                .where(
                    runs_table.c.id == run.id,
                    runs_table.c.samples_done == run.samples_done,
                    runs_table.c.status == "running",
                )
                .values(**run_values)
            ).rowcount
            if moved != 1 or advanced != 1:
                raise HistoryError(
                    f"gearbox {gearbox.id!r} was updated by another process meanwhile; track one source per gearbox "
                    "at a time"
                )
            if rows:
                conn.execute(estimates_table.insert(), rows)
            new_gearbox = _require_gearbox(conn, gearbox.id)
            new_run = Run(**conn.execute(select(runs_table).where(runs_table.c.id == run.id)).one()._mapping)
        return new_gearbox, new_run


def _switch_to_wal(sqlite_connection: Any, timeout_s: float = 30.0) -> None:
    """Put a new SQLite store in WAL mode (a persistent property of the file).

    Several processes may create one store at once, and SQLite answers "database is locked" to a
    journal-mode switch at once, without calling the busy handler, while another creator holds the
    file. So the switch is retried every 10 ms until the file is in WAL mode (by this creator or
    another) or ``timeout_s`` (the connections' busy timeout) has passed.
    """
    deadline = time.monotonic() + timeout_s
    while _journal_mode(sqlite_connection) != "wal":
        try:
            sqlite_connection.execute("PRAGMA journal_mode=WAL")
        except sqlite3.OperationalError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.01)


def _journal_mode(sqlite_connection: Any) -> str:
    return str(sqlite_connection.execute("PRAGMA journal_mode").fetchone()[0]).lower()


def _finite_or_none(value: Any) -> Any:
    """NaN and infinities are stored as NULL (SQLite does so anyway; PostgreSQL would keep NaN)."""
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _register_gearbox(conn: Connection, gearbox_id: str, ratio: float, now: float, **levels: float | None) -> Gearbox:
    """Insert the gearbox if new, else check its ratio; store the given (non-None) alarm levels."""
    if not isinstance(ratio, (int, float)) or not math.isfinite(ratio) or ratio == 0:
        raise HistoryError(f"ratio must be a finite non-zero number, got {ratio!r}")
    given = {name: value for name, value in levels.items() if value is not None}
    gearbox = _get_gearbox(conn, gearbox_id)
    stored = {} if gearbox is None else {"warn_arcmin": gearbox.warn_arcmin, "limit_arcmin": gearbox.limit_arcmin}
    check_alarm_levels(**{**stored, **given})
    if gearbox is None:
        conn.execute(
            gearboxes_table.insert().values(id=gearbox_id, ratio=float(ratio), created_unix_s=now, revision=0, **given)
        )
    elif not math.isclose(gearbox.ratio, ratio, rel_tol=1e-9):
        raise HistoryError(
            f"gearbox {gearbox_id!r} is stored with ratio {gearbox.ratio:g}; --ratio {ratio:g} contradicts it "
            "(use another gearbox id for another gearbox)"
        )
    elif any(stored[name] != value for name, value in given.items()):
        conn.execute(update(gearboxes_table).where(gearboxes_table.c.id == gearbox_id).values(**given))
    return _require_gearbox(conn, gearbox_id)


def _require_gearbox(conn: Connection, gearbox_id: str) -> Gearbox:
    """The stored gearbox, which must exist (it was just written in this transaction)."""
    gearbox = _get_gearbox(conn, gearbox_id)
    if gearbox is None:
        raise HistoryError(f"gearbox {gearbox_id!r} vanished from the history store during the transaction")
    return gearbox


def _get_gearbox(conn: Connection, gearbox_id: str) -> Gearbox | None:
    row = conn.execute(select(gearboxes_table).where(gearboxes_table.c.id == gearbox_id)).first()
    if row is None:
        return None
    values = dict(row._mapping)
    values["checkpoint"] = None if values["checkpoint"] is None else json.loads(values["checkpoint"])
    return Gearbox(**values)
