"""A private, throwaway PostgreSQL server on localhost, from Debian's server binaries.

Used by ``conftest.py``, which starts one for the test session unless ``ONLINE_BACKLASH_TEST_PG_URL``
names a server; by hand, to keep one for many sessions (export the URL it prints). Standard library only::

    python tests/pg_server.py start DIR     # prints the server URL; DIR holds data and log
    python tests/pg_server.py stop DIR
"""

from __future__ import annotations

import glob
import os
import pwd
import subprocess
import sys
from pathlib import Path

from free_port import PortTaken, on_a_free_port


class PostgresUnavailable(RuntimeError):
    """The server binaries are missing or the server did not start."""


def postgres_bin() -> Path:
    """The newest ``/usr/lib/postgresql/*/bin`` that has ``initdb``."""
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(Path(p).parts[-3]))
    if not found:
        raise PostgresUnavailable(
            "PostgreSQL server binaries not found (/usr/lib/postgresql/*/bin/initdb): install Debian's "
            "'postgresql' package (scripts/test does) or set ONLINE_BACKLASH_TEST_PG_URL to a server URL"
        )
    return Path(found[-1]).parent


def _as_postgres(folder: Path) -> list[str]:
    """Run as the ``postgres`` user when root (initdb refuses to run as root)."""
    if os.geteuid() != 0:
        return []
    user = pwd.getpwnam("postgres")
    os.chown(folder, user.pw_uid, user.pw_gid)
    return ["runuser", "-u", "postgres", "--"]


def start(folder: Path) -> str:
    """Create a cluster in ``folder`` (trust auth, localhost only) and start it on a free port; returns its URL."""
    bindir = postgres_bin()
    folder.mkdir(parents=True, exist_ok=True)
    as_postgres = _as_postgres(folder)
    data, log = folder / "data", folder / "server.log"

    def run(*cmd: str) -> None:
        done = subprocess.run([*as_postgres, *cmd], capture_output=True, text=True)
        if done.returncode != 0:
            raise PostgresUnavailable(f"{' '.join(cmd)} failed: {done.stderr or done.stdout}")

    def start_on(port: int) -> str:
        logged_before = log.stat().st_size if log.exists() else 0
        options = f"-c listen_addresses=127.0.0.1 -c port={port} -c unix_socket_directories={folder} -c fsync=off"
        try:
            run(str(bindir / "pg_ctl"), "-D", str(data), "-l", str(log), "-w", "-t", "60", "-o", options, "start")
        except PostgresUnavailable:
            if "Address already in use" in log.read_bytes()[logged_before:].decode(errors="replace"):
                raise PortTaken(f"port {port} was taken before PostgreSQL could listen on it") from None
            raise
        return f"postgresql://postgres@127.0.0.1:{port}/postgres"

    run(str(bindir / "initdb"), "-D", str(data), "-A", "trust", "-U", "postgres", "-E", "UTF8", "--no-sync")
    try:
        return on_a_free_port(start_on)
    except PortTaken as exc:
        raise PostgresUnavailable(str(exc)) from exc


def stop(folder: Path) -> None:
    """Stop the server started in ``folder`` (immediate shutdown; it holds only test data)."""
    cmd = [str(postgres_bin() / "pg_ctl"), "-D", str(folder / "data"), "-m", "immediate", "stop"]
    subprocess.run([*_as_postgres(folder), *cmd], capture_output=True)


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] not in ("start", "stop"):
        sys.exit("usage: python tests/pg_server.py start|stop DIR")
    action, where = sys.argv[1], Path(sys.argv[2])
    try:
        if action == "start":
            print(start(where))
        else:
            stop(where)
    except PostgresUnavailable as exc:
        sys.exit(f"error: {exc}")
