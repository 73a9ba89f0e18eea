"""Open a history store so that nothing can be written through it."""

from __future__ import annotations

import os
from typing import Any

from sqlalchemy import event

from ..history.store import HistoryStore


def open_read_only(db: str | os.PathLike[str]) -> HistoryStore:
    """Open the store at ``db`` (SQLite path or ``postgresql://`` URL) for reading only.

    The store must exist (it is never created). Every connection handed out afterwards is
    read-only at the database: SQLite with ``PRAGMA query_only``, PostgreSQL with read-only
    transactions; a write raises the driver's error. Raises HistoryError as
    :class:`~online_backlash.history.store.HistoryStore` does.
    """
    store = HistoryStore(db, create=False)
    backend = store.url.get_backend_name()

    @event.listens_for(store.engine, "connect")
    def _read_only(dbapi_connection: Any, _record: Any) -> None:
        if backend == "sqlite":
            dbapi_connection.execute("PRAGMA query_only=ON")
        else:  # psycopg 3: every transaction of this connection is READ ONLY
            dbapi_connection.read_only = True

    store.engine.dispose()  # connections opened before the listener are not reused
    return store
