"""A worker's threads (issue 68, point 3): this machine's cores shared among the workers live
on it, counted at each claim, or the ``torch_threads`` setting; workers of other machines and
dead ones do not count."""

from __future__ import annotations

import itertools
import threading
from datetime import timedelta

import pytest
import torch

from server.settings import Settings
from server.state import lifecycle
from server.state.db import init_db, make_engine, make_sessions
from server.state.models import Worker, utcnow
from server.storage import Storage
from server.worker.context import WorkerContext, machine_cores

_pids = itertools.count(10_000)


class _NoQueue:
    """The context's queue is not used by :meth:`WorkerContext.fit_threads`."""


@pytest.fixture
def context(tmp_path, request):
    threads = torch.get_num_threads()
    engine = make_engine(Settings(data_dir=tmp_path))
    init_db(engine)
    settings = Settings(data_dir=tmp_path, **getattr(request, "param", {}))
    ctx = WorkerContext(settings, make_sessions(engine), Storage(tmp_path), _NoQueue(),
                        threading.Event())  # type: ignore[arg-type]  # fmt: skip
    yield ctx
    torch.set_num_threads(threads)
    engine.dispose()


def _workers(ctx: WorkerContext, host: str, n: int, *, age_s: float = 0.0) -> None:
    seen = utcnow() - timedelta(seconds=age_s)
    with ctx.sessions() as session:
        for pid in itertools.islice(_pids, n):
            session.add(Worker(id=f"{host}:{pid}", hostname=host, pid=pid, started_at=seen,
                               seen_at=seen, job_id=None))  # fmt: skip
        session.commit()


def test_the_cores_are_shared_among_the_live_workers_of_this_machine(context) -> None:
    cores = machine_cores()
    host = context.worker.rpartition(":")[0]
    with context.sessions() as session:
        lifecycle.stamp_worker(session, context.worker, None)
    assert context.fit_threads() == cores == torch.get_num_threads()
    _workers(context, host, 1)  # a second worker on this machine
    assert context.fit_threads() == max(1, cores // 2) == torch.get_num_threads()
    _workers(context, "another-machine", 5)  # other machines' workers do not count
    _workers(context, host, 3, age_s=3600)  # nor do dead ones of this machine
    assert context.fit_threads() == max(1, cores // 2)
    _workers(context, host, 2 * cores)  # more workers than cores: one thread each
    assert context.fit_threads() == 1 == torch.get_num_threads()


@pytest.mark.parametrize("context", [{"torch_threads": 3}], indirect=True)
def test_the_setting_wins(context) -> None:
    host = context.worker.rpartition(":")[0]
    _workers(context, host, 8)
    assert context.fit_threads() == 3 == torch.get_num_threads()


def test_a_changed_count_drops_the_loaded_networks(context) -> None:
    """OpenVINO fixes its threads when it compiles: a network loaded for another count goes."""
    with context.sessions() as session:
        lifecycle.stamp_worker(session, context.worker, None)
    context.fit_threads()
    context.predictors.put("net", object())  # type: ignore[arg-type]
    context.fit_threads()  # the same count: kept
    assert "net" in context.predictors
    if machine_cores() > 1:
        _workers(context, context.worker.rpartition(":")[0], machine_cores())
        context.fit_threads()
        assert "net" not in context.predictors
