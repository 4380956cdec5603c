"""The job table, the worker table and the table of a tiled job's parts (SQLAlchemy 2
declarative models).

The job row is the single source of truth about a job: its status, stage and progress, its
heartbeat and attempts (for recovering from lost workers), its cancel flag and its owner. A job
whose scan is tiled also has rows in ``job_tiles``: its plan, one per tile and its merge, each
with the status, attempts and heartbeat of a queue task. The queue only carries ids.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    DateTime,
    Float,
    Integer,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.engine import Dialect
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column
from sqlalchemy.types import TypeDecorator

#: ``jobs.kind`` of a model learnt from corrected jobs (``POST /v1/models``); a scan's job has
#: none (NULL), so rows from before models need no migration.
MODEL_KIND = "model"


def utcnow() -> datetime:
    """The current time, timezone-aware UTC."""
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """Timezone-aware UTC datetimes on every backend (SQLite stores them naive)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


class Base(DeclarativeBase):
    """Declarative base of the service's tables."""


class Job(Base):
    """One uploaded scan and what became of it."""

    __tablename__ = "jobs"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    filename: Mapped[str] = mapped_column(String(255))
    format: Mapped[str] = mapped_column(String(16))
    size_bytes: Mapped[int] = mapped_column(BigInteger, default=0)
    status: Mapped[str] = mapped_column(String(16), index=True, default="queued")
    stage: Mapped[str | None] = mapped_column(String(32), nullable=True)
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    points: Mapped[int | None] = mapped_column(BigInteger, nullable=True)
    timings: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    config: Mapped[dict[str, Any]] = mapped_column(JSON)
    network: Mapped[str] = mapped_column(String(32))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, index=True, default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    heartbeat_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    worker: Mapped[str | None] = mapped_column(String(128), nullable=True)
    #: Who submitted it: :func:`server.api.auth.owner_of` its API key (never the key); None for
    #: a job of an open service or from before tenants (only admin keys and open mode see it).
    #: Added to older tables by :func:`server.state.db.add_missing_columns`.
    owner: Mapped[str | None] = mapped_column(String(64), nullable=True, index=True)
    #: The job this one re-runs with another frame (``POST /v1/jobs/{id}/rerun``), else None.
    rerun_of: Mapped[str | None] = mapped_column(String(32), nullable=True)
    #: :data:`MODEL_KIND` for a model learnt from corrections (the same queue, workers,
    #: heartbeats and requeue as a scan's job, which is why it is a row here); None for a scan.
    kind: Mapped[str | None] = mapped_column(String(16), nullable=True, index=True)
    #: A finished model's summary: its card's ``adapted`` section (scans, versions, points).
    summary: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)


class LabelVersion(Base):
    """One correction of a succeeded job's labels: version ``version`` (1, 2, ...) of job
    ``job_id``.

    Version 0 is the job's own result and has no row. The per-point classes the user gave
    live in ``jobs/<id>/labels/v<version>.npy``, written before the row is committed; the
    unique (job, version) pair is what makes two concurrent corrections on the same version
    end with one winner.
    """

    __tablename__ = "label_versions"
    __table_args__ = (UniqueConstraint("job_id", "version", name="uq_label_versions_job_version"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    job_id: Mapped[str] = mapped_column(String(32), index=True)
    version: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    #: :func:`server.api.auth.owner_of` the correcting key; None in open mode.
    owner: Mapped[str | None] = mapped_column(String(64), nullable=True)
    #: Points whose label this version's edits changed (against the version before).
    points_changed: Mapped[int] = mapped_column(BigInteger, default=0)
    #: Points whose label differs from version 0's.
    points_corrected: Mapped[int] = mapped_column(BigInteger, default=0)
    #: Edits in the request that made this version.
    edits: Mapped[int] = mapped_column(Integer, default=0)


class Worker(Base):
    """A worker process that announced itself; alive while ``seen_at`` is recent."""

    __tablename__ = "workers"

    id: Mapped[str] = mapped_column(String(128), primary_key=True)
    hostname: Mapped[str] = mapped_column(String(255))
    pid: Mapped[int] = mapped_column(Integer)
    started_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    seen_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    job_id: Mapped[str | None] = mapped_column(String(32), nullable=True)


class JobTile(Base):
    """One part of a tiled job: ``kind`` ``plan`` (made by the job's own task), ``tile``
    (``tile`` = its index in the plan) or ``merge``.

    A tile and the merge are queue tasks of their own: claimed by one worker at a time
    (``attempts`` fences a stale worker's writes, as on the job row), stamped alive through
    ``heartbeat_at``, re-queued by the reaper when the stamps stop. ``status``: ``waiting``
    (the merge until every tile is done), ``queued``, ``running``, then ``done``, ``failed`` or
    ``cancelled`` (skipped: the job was cancelled or failed).
    """

    __tablename__ = "job_tiles"

    job_id: Mapped[str] = mapped_column(String(32), primary_key=True)
    kind: Mapped[str] = mapped_column(String(8), primary_key=True)
    tile: Mapped[int] = mapped_column(Integer, primary_key=True)
    status: Mapped[str] = mapped_column(String(16), index=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    worker: Mapped[str | None] = mapped_column(String(128), nullable=True)
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    seconds: Mapped[float | None] = mapped_column(Float, nullable=True)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    queued_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    started_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    heartbeat_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
