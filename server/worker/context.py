"""What a worker process's job, tile and merge tasks share: its settings and services, its
identity, the claim it is working on (for the heartbeat) and its loaded networks.

Handed to both :class:`server.worker.runner.JobRunner` and
:class:`server.worker.fanout.FanOut`, so neither reaches into the other.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from typing import TYPE_CHECKING

from jointseg.exceptions import JointsegError
from jointseg.lru import LRUCache
from jointseg.pipeline import PipelineConfig, load_predictor
from server.model_weights import model_file, model_ref
from server.queue import JobQueue
from server.settings import Settings
from server.state import lifecycle, parts
from server.state.db import SessionFactory
from server.storage import Storage
from server.weights import resolve_job_weights

if TYPE_CHECKING:  # only for annotations: jointseg.network imports torch
    from jointseg.network import Predictor
    from server.worker.pulse import Pulse

#: Networks kept loaded per process (one per configuration).
MAX_PREDICTORS = 2

log = logging.getLogger(__name__)


def machine_cores() -> int:
    """The cores this process may run on (its CPU affinity: a container's or taskset's share),
    else every core of the machine."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


class WorkerContext:
    """One worker process's shared state; tasks run one at a time, so no lock is needed."""

    def __init__(
        self,
        settings: Settings,
        sessions: SessionFactory,
        storage: Storage,
        queue: JobQueue,
        stopping: threading.Event,
    ) -> None:
        self.settings = settings
        self.sessions = sessions
        self.storage = storage
        self.queue = queue
        self.stopping = stopping
        self.worker = lifecycle.worker_id()
        self._current: lifecycle.Claim | parts.PartClaim | None = None
        #: The heartbeat process (:mod:`server.worker.pulse`), told of every claim.
        self.pulse: Pulse | None = None
        self.predictors: LRUCache[str, Predictor] = LRUCache(MAX_PREDICTORS)

    @property
    def current(self) -> lifecycle.Claim | parts.PartClaim | None:
        """The job or tile claim being worked on: the heartbeat keeps it alive."""
        return self._current

    @current.setter
    def current(self, claim: lifecycle.Claim | parts.PartClaim | None) -> None:
        self._current = claim
        if self.pulse is not None:
            self.pulse.claim(claim)

    def fit_threads(self) -> int:
        """The torch (and OpenVINO) threads for the next job or tile: ``torch_threads`` when
        set, else this machine's cores shared among the workers live on it (counted at each
        claim, so workers started by hand, or later, divide the cores too). Networks loaded
        for another count are dropped: OpenVINO fixes its threads when it compiles."""
        import torch

        wanted = self.settings.torch_threads
        if wanted is None:
            host = self.worker.rpartition(":")[0]
            try:
                with self.sessions() as session:
                    live = lifecycle.live_on_host(
                        session, host, timeout_s=self.settings.heartbeat_timeout_s
                    )
            except Exception:  # noqa: BLE001 - keep the threads it has
                log.warning("worker %s: could not count this machine's workers", self.worker)
                return int(torch.get_num_threads())
            wanted = max(1, machine_cores() // max(1, live))
        if wanted != torch.get_num_threads():
            log.info("worker %s: %d torch threads (%s)", self.worker, wanted,
                     "set" if self.settings.torch_threads else "this machine's share")  # fmt: skip
            torch.set_num_threads(wanted)
            self.predictors.clear()
        return wanted

    def predictor(self, config: PipelineConfig) -> tuple[Predictor, float]:
        """The loaded network for ``config.network`` and the seconds loading took (0 if kept)."""
        key = json.dumps(config.network.model_dump(mode="json"), sort_keys=True)
        network = config.network
        given = network.weights
        ref = model_ref(given)
        # a model of this service: asked again each time (it may have been deleted since)
        model = None if ref is None else model_file(self.sessions, self.storage, ref)
        kept = self.predictors.get(key)
        if kept is not None:
            return kept, 0.0
        started = time.perf_counter()
        if given is None:
            predictor = load_predictor(network)
        else:  # opened only inside the weights folders, or a model of this service
            resolved = model or resolve_job_weights(given, self.settings)
            try:
                predictor = load_predictor(network.model_copy(update={"weights": resolved}))
            except JointsegError as exc:  # named as the job named them, not by their path here
                raise type(exc)(str(exc).replace(str(resolved), os.fspath(given))) from exc
        self.predictors.put(key, predictor)
        return predictor, time.perf_counter() - started
