"""Prometheus metrics of the job service: what an operator scrapes from ``GET /metrics``.

Two kinds of series, merged into one text page:

- **Counted where they happen**, in the process that sees them, through prometheus-client's
  multiprocess mode: every API and worker process writes its counters and histograms to files
  in its machine's folder (``PROMETHEUS_MULTIPROC_DIR``, by default
  ``data_dir/metrics/<hostname>``), and the page sums every machine's. Job and stage
  durations, failures by kind, upload bytes.
- **Read from the job table** at each scrape: jobs by status, the queue's depth (jobs and tiles
  waiting) and live workers. These hold across machines, since every machine shares the table.

Why the folder must be set before prometheus-client is imported: the library picks its
storage (memory or files) at import. :func:`use_folder` sets it; ``jointseg serve`` and
``jointseg worker`` call it first.
"""

from __future__ import annotations

import glob
import logging
import os
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

ENV = "PROMETHEUS_MULTIPROC_DIR"
#: Set by :func:`use_folder`: the folder holding every machine's metric folder.
ROOT_ENV = "JOINTSEG_METRICS_ROOT"
#: Job durations, seconds: a small scan takes seconds, a floor of tens of millions of points
#: an hour.
JOB_BUCKETS = (1, 2.5, 5, 10, 20, 40, 60, 120, 300, 600, 1200, 3600, 7200)
STAGE_BUCKETS = (0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300, 600, 1800)


def use_folder(data_dir: Path) -> Path:
    """Set (unless the environment already does) and create the folder of this machine's
    per-process metric files, ``data_dir/metrics/<hostname>`` (a folder per machine: process
    ids repeat across machines sharing the data directory). Call before anything imports
    prometheus_client. The files of processes that ended stay: their counts are part of the
    totals (a counter never goes down while the folder lives; remove it to start from zero)."""
    given = os.environ.get(ENV)
    folder = Path(given) if given else Path(data_dir) / "metrics" / _host()
    folder.mkdir(parents=True, exist_ok=True)
    os.environ[ENV] = str(folder)
    if not given:
        os.environ[ROOT_ENV] = str(folder.parent)
    return folder


def _host() -> str:
    name = socket.gethostname() or "localhost"
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def metric_files() -> list[str]:
    """The metric files the page sums: every machine's under ``data_dir/metrics`` when the
    folders are jointseg's own, else those of ``PROMETHEUS_MULTIPROC_DIR``."""
    root = os.environ.get(ROOT_ENV)
    if root:
        return sorted(glob.glob(os.path.join(root, "*", "*.db")))
    folder = os.environ.get(ENV)
    return sorted(glob.glob(os.path.join(folder, "*.db"))) if folder else []


class _FilesCollector:
    """prometheus-client's multiprocess merge over :func:`metric_files` (of every machine)."""

    def collect(self) -> Iterator[Any]:
        from prometheus_client.multiprocess import MultiProcessCollector

        return iter(MultiProcessCollector.merge(metric_files(), accumulate=True))


class _Series:
    """The counted series, made on first use (after :func:`use_folder`)."""

    def __init__(self) -> None:
        from prometheus_client import Counter, Histogram

        self.job_seconds = Histogram(
            "jointseg_job_duration_seconds",
            "Wall seconds of finished jobs, from start to end (tiled jobs: all their parts).",
            ["kind", "status"],
            buckets=JOB_BUCKETS,
        )
        self.stage_seconds = Histogram(
            "jointseg_stage_duration_seconds",
            "Wall seconds of each stage of succeeded jobs (the report's timings).",
            ["stage"],
            buckets=STAGE_BUCKETS,
        )
        self.failures = Counter(
            "jointseg_job_failures_total", "Jobs that failed, by kind of error.", ["error"]
        )
        self.finished = Counter(
            "jointseg_jobs_finished_total", "Jobs that ended, by status.", ["status"]
        )
        self.upload_bytes = Counter(
            "jointseg_upload_bytes_total", "Bytes of scans accepted by the API."
        )
        self.uploads = Counter("jointseg_uploads_total", "Scans accepted by the API.")


_series: _Series | None = None


def series() -> _Series:
    global _series
    if _series is None:
        _series = _Series()
    return _series


def job_finished(kind: str, status: str, timings: dict[str, float] | None,
                 error: str | None = None) -> None:  # fmt: skip
    """Count a job that ended: its duration, its stages' (succeeded), its error (failed).
    Never raises: metrics must not fail a job."""
    try:
        s = series()
        s.finished.labels(status=status).inc()
        total = (timings or {}).get("total")
        if total is not None:
            s.job_seconds.labels(kind=kind, status=status).observe(float(total))
        if status == "succeeded":
            for stage, seconds in (timings or {}).items():
                if stage != "total":
                    s.stage_seconds.labels(stage=stage).observe(float(seconds))
        if status == "failed":
            s.failures.labels(error=error or "unknown").inc()
    except Exception:  # noqa: BLE001
        log.warning("metrics: could not count a finished job", exc_info=True)


def upload_accepted(size: int) -> None:
    """Count an accepted upload of ``size`` bytes."""
    try:
        s = series()
        s.uploads.inc()
        s.upload_bytes.inc(size)
    except Exception:  # noqa: BLE001
        log.warning("metrics: could not count an upload", exc_info=True)


class TableCollector:
    """Jobs by status, the queue's depth and live workers, read from the job table at each
    scrape (``read`` returns them; see :func:`server.state.lifecycle.metric_counts`)."""

    def __init__(self, read: Any) -> None:
        self.read = read

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import GaugeMetricFamily

        counts = self.read()
        jobs = GaugeMetricFamily(
            "jointseg_jobs", "Jobs in the table, by status.", labels=["status"]
        )
        for status, n in sorted(counts["jobs"].items()):
            jobs.add_metric([status], n)
        yield jobs
        depth = GaugeMetricFamily(
            "jointseg_queue_depth", "Work waiting for a worker.", labels=["kind"]
        )
        depth.add_metric(["job"], counts["queued_jobs"])
        depth.add_metric(["tile"], counts["queued_tiles"])
        yield depth
        yield GaugeMetricFamily(
            "jointseg_live_workers", "Workers whose lease is live.", value=counts["live_workers"]
        )


def page(read: Any) -> tuple[bytes, str]:
    """The metrics page (body, content type): the counted series of every process (every
    machine's, summed; this process's alone when no folder is set) and the table's."""
    from prometheus_client import CONTENT_TYPE_LATEST, REGISTRY, CollectorRegistry, generate_latest

    series()  # the counted series exist (at zero) before anything was counted
    table = CollectorRegistry()
    table.register(TableCollector(read))
    if os.environ.get(ENV):
        counted = CollectorRegistry()
        counted.register(_FilesCollector())
        return generate_latest(counted) + generate_latest(table), CONTENT_TYPE_LATEST
    return generate_latest(REGISTRY) + generate_latest(table), CONTENT_TYPE_LATEST
