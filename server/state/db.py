"""The job table's database: engine and session factory built from :class:`Settings`.

SQLite (the embedded default) runs in WAL mode with a busy timeout, so the API and several worker
processes can read and write the same file; PostgreSQL needs nothing special.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from sqlalchemy import Engine, create_engine, event, text
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session, sessionmaker

from server.settings import Settings
from server.state.models import Base

log = logging.getLogger(__name__)

SessionFactory = sessionmaker[Session]


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.execute("PRAGMA busy_timeout=30000")
    cursor.close()


def make_engine(settings: Settings) -> Engine:
    """An engine for ``settings.database_url`` (default: SQLite file in the data directory)."""
    url = settings.database_url_resolved
    if url.startswith("sqlite"):
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        engine = create_engine(
            url, connect_args={"timeout": 30, "check_same_thread": False}, pool_pre_ping=False
        )
        event.listen(engine, "connect", _sqlite_pragmas)
        return engine
    return create_engine(_with_driver(url), pool_pre_ping=True, pool_size=5, max_overflow=10)


def _with_driver(url: str) -> str:
    """A PostgreSQL URL without a driver gets psycopg2, the driver Huey's SQL storage uses too
    (SQLAlchemy 2.1 would pick psycopg 3, which is not installed)."""
    for scheme in ("postgresql://", "postgres://"):
        if url.startswith(scheme):
            return "postgresql+psycopg2://" + url[len(scheme) :]
    return url


def make_sessions(engine: Engine) -> SessionFactory:
    """A session factory; objects stay readable after commit (views are built from them)."""
    return sessionmaker(engine, expire_on_commit=False)


def init_db(engine: Engine, *, attempts: int = 5) -> None:
    """Create the tables that are missing.

    Several processes may start at once (API and workers); on PostgreSQL two concurrent
    ``CREATE TABLE`` can collide, so a failure is retried after the other has finished.
    """
    for attempt in range(attempts):
        try:
            Base.metadata.create_all(engine)
            return
        except DBAPIError as exc:  # pragma: no cover - race only (IntegrityError on pg_type)
            if attempt == attempts - 1:
                raise
            log.debug("create tables collided (%s); retrying", exc)
            time.sleep(0.2 * (attempt + 1))


def ping(engine: Engine) -> bool:
    """Whether the database answers a trivial query."""
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
        return True
    except Exception:  # noqa: BLE001 - any failure means "not reachable" for the health check
        log.warning("database ping failed", exc_info=True)
        return False
