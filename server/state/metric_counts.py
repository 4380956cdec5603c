"""What ``GET /metrics`` reads from the job table at each scrape (:mod:`server.metrics`): a few
grouped counts, each one indexed query."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from server.state.models import Job, JobTile, Worker, utcnow


def metric_counts(session: Session, *, timeout_s: float) -> dict[str, Any]:
    """Jobs by status, jobs and tiles waiting in the queue, and workers whose lease (seen
    within ``timeout_s``) is live."""
    jobs = {
        str(status): int(n)
        for status, n in session.execute(select(Job.status, func.count()).group_by(Job.status))
    }
    tiles = session.scalar(
        select(func.count()).select_from(JobTile).where(JobTile.status == "queued")
    )
    cutoff = utcnow() - timedelta(seconds=timeout_s)
    live = session.scalar(select(func.count()).select_from(Worker).where(Worker.seen_at >= cutoff))
    return {
        "jobs": jobs,
        "queued_jobs": jobs.get("queued", 0),
        "queued_tiles": int(tiles or 0),
        "live_workers": int(live or 0),
    }
