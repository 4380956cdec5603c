"""The job table's database: engine and session factory built from :class:`Settings`.

SQLite (the embedded default) runs in WAL mode with a busy timeout, so the API and several worker
processes can read and write the same file; PostgreSQL needs nothing special.

Tables are created when missing; a column added to a model later (``jobs.owner``) is added to an
existing table by :func:`add_missing_columns`, so an upgraded service keeps its jobs.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from sqlalchemy import Column, Engine, Table, create_engine, event, inspect, text
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.schema import CreateIndex

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
    """Create the tables that are missing, and the columns missing from older tables.

    Several processes may start at once (API and workers); on PostgreSQL two concurrent
    ``CREATE TABLE`` can collide, so a failure is retried after the other has finished.
    """
    for attempt in range(attempts):
        try:
            Base.metadata.create_all(engine)
            add_missing_columns(engine)
            return
        except DBAPIError as exc:  # pragma: no cover - race only (IntegrityError on pg_type)
            if attempt == attempts - 1:
                raise
            log.debug("create tables collided (%s); retrying", exc)
            time.sleep(0.2 * (attempt + 1))


def add_missing_columns(engine: Engine) -> list[str]:
    """Add each model column an existing table lacks (``ALTER TABLE ... ADD COLUMN``), with its
    indexes; returns the ``table.column`` names added by this call.

    Only nullable columns can be added this way: old rows get NULL (for ``jobs.owner``: a job
    that belongs to nobody in particular). Several processes may migrate at once: PostgreSQL
    uses ``IF NOT EXISTS``; on SQLite a column another process added first is not an error.

    Raises
    ------
    RuntimeError
        For a missing column that is not nullable (it needs a hand-written migration).
    """
    added: list[str] = []
    for table in Base.metadata.sorted_tables:
        present = {c["name"] for c in inspect(engine).get_columns(table.name)}
        for column in table.columns:
            if column.name in present:
                continue
            if not column.nullable:
                raise RuntimeError(
                    f"{table.name}.{column.name} is missing and not nullable: migrate by hand"
                )
            if _add_column(engine, table, column):
                added.append(f"{table.name}.{column.name}")
            for index in table.indexes:
                if column.name in index.columns:
                    with engine.begin() as conn:
                        conn.execute(CreateIndex(index, if_not_exists=True))
    if added:
        log.info("database migrated: added %s", ", ".join(added))
    return added


def _add_column(engine: Engine, table: Table, column: Column[object]) -> bool:
    """``ALTER TABLE ADD COLUMN``; False when another process added it first."""
    preparer = engine.dialect.identifier_preparer
    kind = column.type.compile(dialect=engine.dialect)
    guard = "IF NOT EXISTS " if engine.dialect.name == "postgresql" else ""
    statement = (
        f"ALTER TABLE {preparer.format_table(table)} ADD COLUMN {guard}"
        f"{preparer.format_column(column)} {kind}"
    )
    try:
        with engine.begin() as conn:
            conn.execute(text(statement))
    except DBAPIError:
        columns = {c["name"] for c in inspect(engine).get_columns(table.name)}
        if column.name not in columns:
            raise
        return False
    return True


def ping(engine: Engine) -> bool:
    """Whether the database answers a trivial query."""
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
        return True
    except Exception:  # noqa: BLE001 - any failure means "not reachable" for the health check
        log.warning("database ping failed", exc_info=True)
        return False
