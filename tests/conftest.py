"""Shared fixtures: a private PostgreSQL server for the history-store tests.

``postgres_server_url`` starts a throwaway server from Debian's PostgreSQL binaries
(``/usr/lib/postgresql/*/bin``, installed by ``.ci/run``) in a temporary folder, on a free
localhost port with trust authentication, and stops it at the end of the session. With
``ONLINE_BACKLASH_TEST_PG_URL`` set, that server is used instead. Missing binaries make the
PostgreSQL tests fail (not skip). ``store_db`` gives each test a fresh store location, once
as an SQLite file and once as a new database on the PostgreSQL server.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
import uuid
from pathlib import Path

import psycopg
import pytest

PG_URL_ENV = "ONLINE_BACKLASH_TEST_PG_URL"


def _postgres_bin() -> Path:
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(Path(p).parts[-3]))
    if not found:
        pytest.fail(
            "PostgreSQL server binaries not found (/usr/lib/postgresql/*/bin/initdb): install Debian's "
            f"'postgresql' package (.ci/run does) or set {PG_URL_ENV} to a server URL",
            pytrace=False,
        )
    return Path(found[-1]).parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def postgres_server_url():
    """URL of a PostgreSQL server whose role may create databases."""
    if os.environ.get(PG_URL_ENV):
        yield os.environ[PG_URL_ENV]
        return
    bindir = _postgres_bin()
    folder = Path(tempfile.mkdtemp(prefix="online-backlash-pg-"))
    as_postgres: list[str] = []
    if os.geteuid() == 0:  # initdb refuses to run as root
        user = pwd.getpwnam("postgres")
        os.chown(folder, user.pw_uid, user.pw_gid)
        as_postgres = ["runuser", "-u", "postgres", "--"]
    data, log, port = folder / "data", folder / "server.log", _free_port()

    def run(*cmd: str) -> None:
        done = subprocess.run([*as_postgres, *cmd], capture_output=True, text=True)
        if done.returncode != 0:
            pytest.fail(f"{' '.join(cmd)} failed: {done.stderr or done.stdout}", pytrace=False)

    options = f"-c listen_addresses=127.0.0.1 -c port={port} -c unix_socket_directories={folder} -c fsync=off"
    run(str(bindir / "initdb"), "-D", str(data), "-A", "trust", "-U", "postgres", "-E", "UTF8", "--no-sync")
    run(str(bindir / "pg_ctl"), "-D", str(data), "-l", str(log), "-w", "-t", "60", "-o", options, "start")
    try:
        yield f"postgresql://postgres@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run([*as_postgres, str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"], capture_output=True)
        shutil.rmtree(folder, ignore_errors=True)


def _with_database(server_url: str, name: str) -> str:
    head, _, _ = server_url.rpartition("/")
    return f"{head}/{name}"


@pytest.fixture
def postgres_db(postgres_server_url):
    """A fresh, empty database on the PostgreSQL server (dropped afterwards); yields its URL."""
    name = f"ob_test_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(postgres_server_url, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    yield _with_database(postgres_server_url, name)
    with psycopg.connect(postgres_server_url, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def store_db(request, tmp_path):
    """Where a test's store lives: an SQLite file path, or a PostgreSQL URL of an empty database."""
    if request.param == "sqlite":
        return str(tmp_path / "wear.db")
    return request.getfixturevalue("postgres_db")
