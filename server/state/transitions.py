"""The state changes jobs and their parts (tiles, merges) have in common, written once.

Why: a job row and a part row move through the same life (queued, claimed by a worker,
released on shutdown, reaped when its worker goes silent), each step one conditional UPDATE
whose WHERE names the attempt. The values each step writes and the verdict on a stale row are
the same for both tables; only the extra columns differ (a job's ``stage``, a part's
``queued_at``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from datetime import datetime
from typing import Any

from sqlalchemy import update
from sqlalchemy.orm import Session

from server.state.models import Job, JobTile

#: A table whose rows have a worker's claim: attempts, worker, progress, heartbeats.
Claimable = type[Job] | type[JobTile]


def move(
    session: Session,
    table: Claimable,
    where: Iterable[Any],
    values: Mapping[str, Any],
    *,
    commit: bool = True,
) -> bool:
    """One conditional UPDATE; True when it changed a row (the condition still held)."""
    result = session.execute(update(table).where(*where).values(**values))
    if commit:
        session.commit()
    return bool(result.rowcount)  # type: ignore[attr-defined]


def claimed(table: Claimable, worker: str, now: datetime) -> dict[str, Any]:
    """What a claim writes: running for ``worker``, one more attempt, fresh heartbeat."""
    return {
        "status": "running",
        "attempts": table.attempts + 1,
        "worker": worker,
        "started_at": now,
        "heartbeat_at": now,
        "progress": 0.0,
        "error": None,
    }


def released(table: Claimable) -> dict[str, Any]:
    """What a release on the worker's shutdown writes: queued again, the attempt not counted
    (the row did nothing wrong)."""
    return {
        "status": "queued",
        "attempts": table.attempts - 1,
        "worker": None,
        "progress": 0.0,
        "started_at": None,
        "heartbeat_at": None,
    }


def lost_condition(table: Claimable, cutoff: datetime, dead: str | None) -> Any:
    """SQL condition on a running row whose worker is lost: no heartbeat since ``cutoff``, or,
    with ``dead`` (a worker id whose process is known to have exited), held by that worker."""
    if dead is not None:
        return table.worker == dead
    return table.heartbeat_at < cutoff


def lost_worker(worker: str | None, timeout_s: float, *, dead: bool = False) -> str:
    """Why a stale row was reaped, in the words of its error."""
    if dead:
        return f"worker {worker} died"
    return f"worker {worker} stopped responding (no heartbeat for {timeout_s:g} s)"


def stale_verdict(*, stop: bool, attempts: int, max_attempts: int) -> str:
    """What becomes of a running row whose worker went silent: ``cancelled`` when it should
    stop anyway, ``failed`` when its attempts are spent, else ``queued`` for another worker."""
    if stop:
        return "cancelled"
    if attempts >= max_attempts:
        return "failed"
    return "queued"
