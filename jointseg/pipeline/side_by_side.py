"""The network and the geometry side by side: the two first stages do not depend on each other,
so they run in two threads (torch and scipy's KD-tree release the GIL in their heavy parts).
One shared cancel token reaches both, and when either fails the other is stopped before the
error propagates, so no stage keeps burning CPU after the pipeline has returned.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import FIRST_EXCEPTION, Future, ThreadPoolExecutor, wait
from typing import Any, TypeVar

from jointseg.exceptions import Cancelled
from jointseg.geometry import GeometryResult, ResolvedGeometryParams, segment
from jointseg.pipeline.config import PipelineConfig
from jointseg.progress import CancelToken, ProgressFn
from jointseg.scan import Scan

T = TypeVar("T")


class _AnyOf:
    """A cancel token set when the caller's token or the pipeline's own stop event is."""

    def __init__(self, outer: CancelToken | None, stop: threading.Event) -> None:
        self.outer = outer
        self.stop = stop

    def is_set(self) -> bool:
        return self.stop.is_set() or (self.outer is not None and self.outer.is_set())


def network_and_geometry(
    scan: Scan,
    config: PipelineConfig,
    network: Callable[[ProgressFn, CancelToken], T],
    progress: ProgressFn | None,
    cancel: CancelToken | None,
    timings: dict[str, float],
    *,
    resolved: ResolvedGeometryParams | None = None,
    geometry_scan: Scan | None = None,
) -> tuple[T, GeometryResult]:
    """The network (``network(progress, cancel)``) and the geometry, side by side when
    ``config.concurrent`` (their times go into ``timings``); ``resolved`` fixes the geometry's
    thresholds and ``geometry_scan`` gives the geometry fewer points than the network (a tile
    of a big scan: the network needs a wider margin than the geometry).

    Raises
    ------
    Cancelled
        When ``cancel`` was set; the other stage is stopped first.
    """
    lock = threading.Lock()

    def serialised(stage: str, fraction: float) -> None:
        if progress is not None:
            with lock:
                progress(stage, fraction)

    stop = threading.Event()
    token = _AnyOf(cancel, stop)
    seed = config.seed

    def network_stage() -> T:
        return network(serialised, token)

    def geometry_stage() -> GeometryResult:
        return segment(
            geometry_scan if geometry_scan is not None else scan,
            config.geometry,
            serialised,
            token,
            seed=seed,
            resolved=resolved,
        )

    if config.concurrent:
        return _both(network_stage, geometry_stage, stop, cancel, timings)
    return _timed(network_stage, timings, "network"), _timed(geometry_stage, timings, "geometry")


def _timed(fn: Callable[[], T], timings: dict[str, float], name: str) -> T:
    t = time.perf_counter()
    out = fn()
    timings[name] = time.perf_counter() - t
    return out


def _both(
    network_stage: Callable[[], T],
    geometry_stage: Callable[[], GeometryResult],
    stop: threading.Event,
    cancel: CancelToken | None,
    timings: dict[str, float],
) -> tuple[T, GeometryResult]:
    """Run both stages in two threads; the first failure stops the other, then is raised."""
    with ThreadPoolExecutor(max_workers=2, thread_name_prefix="jointseg-stage") as pool:
        net_f: Future[T] = pool.submit(_timed, network_stage, timings, "network")
        geo_f: Future[GeometryResult] = pool.submit(_timed, geometry_stage, timings, "geometry")
        both: list[Future[Any]] = [net_f, geo_f]
        try:
            wait(both, return_when=FIRST_EXCEPTION)
        except BaseException:
            stop.set()  # e.g. Ctrl-C: stop both stages rather than wait for them to finish
            raise
        if any(f.done() and f.exception() is not None for f in both):
            stop.set()
        # leaving the block waits for the other stage, which stops at its next check
    errors = [e for e in (net_f.exception(), geo_f.exception()) if e is not None]
    if errors:
        stop.set()
        if cancel is not None and cancel.is_set():
            raise Cancelled("cancelled by request")
        # the stage that failed first, not the one it stopped
        real = [e for e in errors if not isinstance(e, Cancelled)]
        raise (real or errors)[0]
    return net_f.result(), geo_f.result()
