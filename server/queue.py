"""The job queue: Huey, with SQLite, PostgreSQL or Redis storage, carrying ids only.

The API and the workers build the same Huey instance from :class:`Settings` and register the
same tasks: :func:`run_job` (a job id), and for a job whose scan is cut into tiles
:func:`run_tile` (job id, tile index) and :func:`merge_tiles` (job id). Only a worker process
installs the handlers that do the work (:func:`set_handler`). Everything about a job other than
its id lives in the job row, everything about a tile in its row of ``job_tiles``.
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

#: The tasks' names in the queue; a part of a tiled job is ``(job id, "tile" | "merge", index)``.
RUN_JOB, RUN_TILE, MERGE_TILES = "run_job", "run_tile", "merge_tiles"
PART_TASKS = {RUN_TILE: "tile", MERGE_TILES: "merge"}

_handlers: dict[str, Callable[..., None]] = {}


def set_handler(handler: Callable[..., None] | None, task: str = RUN_JOB) -> None:
    """Install what the task ``task`` calls in this process (a worker's job runner)."""
    if handler is None:
        _handlers.pop(task, None)
    else:
        _handlers[task] = handler


def _dispatch(task: str, *args: object) -> None:
    handler = _handlers.get(task)
    if handler is None:
        raise RuntimeError(f"no {task} handler installed in this process (not a worker)")
    handler(*args)


def run_job(job_id: str) -> None:
    """The Huey task: hand ``job_id`` to this process's handler."""
    _dispatch(RUN_JOB, job_id)


def run_tile(job_id: str, tile: int) -> None:
    """The Huey task of one tile of a tiled job."""
    _dispatch(RUN_TILE, job_id, tile)


def merge_tiles(job_id: str) -> None:
    """The Huey task of the merge of a tiled job."""
    _dispatch(MERGE_TILES, job_id)


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
        self._task = self.huey.task(retries=0, name=RUN_JOB)(run_job)
        self._tile = self.huey.task(retries=0, name=RUN_TILE)(run_tile)
        self._merge = self.huey.task(retries=0, name=MERGE_TILES)(merge_tiles)

    def enqueue(self, job_id: str) -> None:
        """Put ``job_id`` in the queue.

        Raises
        ------
        QueueUnavailable
            When the queue's storage cannot be reached.
        """
        self._put(f"job {job_id}", self._task, job_id)

    def enqueue_part(self, job_id: str, kind: str, tile: int = 0) -> None:
        """Put a part of a tiled job in the queue: tile ``tile``, or (``kind="merge"``) its
        merge.

        Raises
        ------
        QueueUnavailable
        """
        if kind == "merge":
            self._put(f"job {job_id} merge", self._merge, job_id)
        else:
            self._put(f"job {job_id} tile {tile}", self._tile, job_id, tile)

    def _put(self, what: str, task: Callable[..., object], *args: object) -> None:
        try:
            task(*args)
        except Exception as exc:
            log.exception("cannot enqueue %s", what)
            raise QueueUnavailable(f"the {self.kind} queue is unavailable: {exc}") from exc

    def pending(self) -> int:
        """Job ids waiting in the queue (raises when the storage is unreachable)."""
        return int(self.huey.pending_count())

    def pending_ids(self) -> set[str]:
        """The job ids waiting in the queue (reads the whole queue: call it rarely)."""
        return {
            str(task.args[0]) for task in self.huey.pending() if task.args and task.name == RUN_JOB
        }

    def pending_parts(self) -> set[tuple[str, str, int]]:
        """The parts of tiled jobs waiting in the queue, as ``(job id, kind, tile)`` (reads the
        whole queue: call it rarely)."""
        parts: set[tuple[str, str, int]] = set()
        for task in self.huey.pending():
            kind = PART_TASKS.get(task.name)
            if kind is not None and task.args:
                tile = int(task.args[1]) if kind == "tile" and len(task.args) > 1 else 0
                parts.add((str(task.args[0]), kind, tile))
        return parts

    def close(self) -> None:
        """Release the storage's connections."""
        close = getattr(self.huey.storage, "close", None)
        if close is not None:
            try:
                close()
            except Exception:  # noqa: BLE001 - closing is best effort
                log.debug("closing the queue storage failed", exc_info=True)
