"""Batches built one step ahead in a background thread, for training and for inference.

Why: a step is crops and KD-tree searches (numpy and scipy, which release the GIL in their heavy
parts), then the network. With a spare core the next batch is built while the network runs on
this one. The thread is the only consumer of the source iterator (and of any random generator it
draws from) and keeps its order, so the batches are exactly those of a plain loop.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Generic, TypeVar

T = TypeVar("T")

#: How often a blocked producer looks whether it should stop (seconds).
_POLL = 0.1
_DONE = object()


class Prefetcher(Generic[T]):
    """Iterates over ``items``, each computed ``depth`` ahead in a thread.

    An exception raised by the source is raised from ``next()`` at the item it belongs to. Use
    as a context manager (or call :meth:`close`) so an interrupted loop stops the thread.
    """

    def __init__(self, items: Iterable[T], *, depth: int = 1) -> None:
        self._items: queue.Queue[tuple[bool, object]] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._finished = False
        self._thread = threading.Thread(
            target=self._produce, args=(iter(items),), name="batch-prefetch", daemon=True
        )
        self._thread.start()

    def _put(self, item: tuple[bool, object]) -> bool:
        while not self._stop.is_set():
            try:
                self._items.put(item, timeout=_POLL)
                return True
            except queue.Full:
                continue
        return False

    def _produce(self, items: Iterator[T]) -> None:
        while True:
            try:
                item: tuple[bool, object] = (True, next(items))
            except StopIteration:
                self._put((True, _DONE))
                return
            except BaseException as exc:  # handed to the consumer, which re-raises it
                self._put((False, exc))
                return
            if not self._put(item):
                return

    def __iter__(self) -> Iterator[T]:
        return self

    def __next__(self) -> T:
        if self._finished:
            raise StopIteration
        ok, value = self._items.get()
        if value is _DONE or not ok:
            self._finished = True
        if value is _DONE:
            raise StopIteration
        if not ok:
            assert isinstance(value, BaseException)
            raise value
        return value  # type: ignore[return-value]

    def close(self) -> None:
        """Stop the producer and wait for it."""
        self._stop.set()
        self._thread.join()

    def __enter__(self) -> Prefetcher[T]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def calls(make: Callable[[], T], count: int) -> Iterator[T]:
    """``count`` results of ``make()``, in order (a source for :class:`Prefetcher`, or a plain
    loop where threads are unwelcome)."""
    for _ in range(count):
        yield make()
