"""Shared fixtures: a private PostgreSQL server for the history-store tests.

``postgres_server_url`` uses the server at ``ONLINE_BACKLASH_TEST_PG_URL`` if set; without it, it
starts a throwaway server itself (``pg_server.py``: Debian's binaries, a temporary folder, a free
localhost port, trust authentication) and stops it at the end of the session. Missing binaries make
the PostgreSQL tests fail (not skip): ``scripts/test`` installs them. ``store_db`` gives each test a
fresh store location, once
as an SQLite file and once as a new database on the PostgreSQL server.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import uuid
from pathlib import Path

import pg_server
import psycopg
import pytest

PG_URL_ENV = "ONLINE_BACKLASH_TEST_PG_URL"


@pytest.fixture(scope="session")
def postgres_server_url():
    """URL of a PostgreSQL server whose role may create databases."""
    if os.environ.get(PG_URL_ENV):
        yield os.environ[PG_URL_ENV]
        return
    folder = Path(tempfile.mkdtemp(prefix="online-backlash-pg-"))
    try:
        url = pg_server.start(folder)
    except pg_server.PostgresUnavailable as exc:
        shutil.rmtree(folder, ignore_errors=True)
        pytest.fail(str(exc), pytrace=False)
    try:
        yield url
    finally:
        pg_server.stop(folder)
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
