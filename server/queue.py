"""The job queue: Huey, with SQLite, PostgreSQL or Redis storage, carrying job ids only.

The API and the workers build the same Huey instance from :class:`Settings` and register the
same task, :func:`run_job`; only a worker process installs a handler that does the work
(:func:`set_handler`). Everything about a job other than its id lives in the job row.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from urllib.parse import urlsplit, urlunsplit

from huey import Huey, RedisHuey, SqliteHuey

from jointseg.exceptions import QueueUnavailable
from server.settings import Settings

log = logging.getLogger(__name__)

_handler: Callable[[str], None] | None = None


def set_handler(handler: Callable[[str], None] | None) -> None:
    """Install what :func:`run_job` calls in this process (a worker's job runner)."""
    global _handler
    _handler = handler


def run_job(job_id: str) -> None:
    """The Huey task: hand ``job_id`` to this process's handler."""
    if _handler is None:
        raise RuntimeError("no job handler installed in this process (not a worker)")
    _handler(job_id)


def peewee_url(database_url: str) -> str:
    """A SQLAlchemy PostgreSQL URL as peewee's ``db_url`` understands it (no ``+driver``)."""
    parts = urlsplit(database_url)
    scheme = parts.scheme.split("+", 1)[0]
    if scheme == "postgres":
        scheme = "postgresql"
    return urlunsplit((scheme, *parts[1:]))


def make_huey(settings: Settings) -> Huey:
    """The Huey instance for ``settings.queue`` (results are not stored: the job row has them)."""
    name = settings.queue_name
    if settings.queue == "redis":
        assert settings.redis_url is not None  # checked by Settings
        return RedisHuey(name, url=settings.redis_url, results=False)
    if settings.queue == "postgres":
        return _sql_huey(name, peewee_url(settings.database_url_resolved))
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    return SqliteHuey(name, filename=str(settings.data_dir / "queue.sqlite3"), results=False)


def _sql_huey(name: str, url: str, attempts: int = 5) -> Huey:
    """Huey's SQL storage; it creates its tables on start, and when the API and workers start
    at once PostgreSQL can refuse one of two concurrent ``CREATE TABLE``: try again."""
    # deferred: peewee and Huey's SQL storage load only for the postgres queue
    import peewee
    from huey.contrib.sql_huey import SqlHuey

    for attempt in range(attempts):
        try:
            return SqlHuey(name, database=url, results=False)
        except (peewee.IntegrityError, peewee.ProgrammingError, peewee.OperationalError) as exc:
            if attempt == attempts - 1:
                raise
            log.debug("creating the queue tables collided (%s); retrying", exc)
            time.sleep(0.2 * (attempt + 1))
    raise AssertionError("unreachable")


class JobQueue:
    """Enqueue job ids and report the queue's health."""

    def __init__(self, settings: Settings) -> None:
        self.kind = settings.queue
        self.huey = make_huey(settings)
        self._task = self.huey.task(retries=0, name="run_job")(run_job)

    def enqueue(self, job_id: str) -> None:
        """Put ``job_id`` in the queue.

        Raises
        ------
        QueueUnavailable
            When the queue's storage cannot be reached.
        """
        try:
            self._task(job_id)
        except Exception as exc:
            log.exception("cannot enqueue job %s", job_id)
            raise QueueUnavailable(f"the {self.kind} queue is unavailable: {exc}") from exc

    def pending(self) -> int:
        """Job ids waiting in the queue (raises when the storage is unreachable)."""
        return int(self.huey.pending_count())

    def pending_ids(self) -> set[str]:
        """The job ids waiting in the queue (reads the whole queue: call it rarely)."""
        return {str(task.args[0]) for task in self.huey.pending() if task.args}

    def close(self) -> None:
        """Release the storage's connections."""
        close = getattr(self.huey.storage, "close", None)
        if close is not None:
            try:
                close()
            except Exception:  # noqa: BLE001 - closing is best effort
                log.debug("closing the queue storage failed", exc_info=True)
