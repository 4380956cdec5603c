"""Training batches built one step ahead in a background thread.

Why: a training step is crops, augmentation and five KD-tree searches per crop (numpy and scipy,
which release the GIL in their heavy parts), then the network. With a spare core the next batch
is built while the network runs on this one. The thread is the only user of the training
generator and draws in the same order as a plain loop, so the batches are exactly the same.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

T = TypeVar("T")

#: How often a blocked producer looks whether it should stop (seconds).
_POLL = 0.1


class Prefetcher(Generic[T]):
    """Iterates over ``count`` results of ``make()``, computed ``depth`` ahead in a thread.

    An exception in ``make`` is raised from ``next()`` at the step it belongs to. Use as a
    context manager (or call :meth:`close`) so an interrupted loop stops the thread.
    """

    def __init__(self, make: Callable[[], T], count: int, *, depth: int = 1) -> None:
        self._items: queue.Queue[tuple[bool, T | BaseException]] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._left = count
        self._thread = threading.Thread(
            target=self._produce, args=(make, count), name="batch-prefetch", daemon=True
        )
        self._thread.start()

    def _produce(self, make: Callable[[], T], count: int) -> None:
        for _ in range(count):
            try:
                item: tuple[bool, T | BaseException] = (True, make())
            except BaseException as exc:  # handed to the consumer, which re-raises it
                item = (False, exc)
            while not self._stop.is_set():
                try:
                    self._items.put(item, timeout=_POLL)
                    break
                except queue.Full:
                    continue
            if self._stop.is_set() or not item[0]:
                return

    def __iter__(self) -> Iterator[T]:
        return self

    def __next__(self) -> T:
        if self._left <= 0:
            raise StopIteration
        ok, value = self._items.get()
        self._left -= 1
        if not ok:
            self._left = 0
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


def sequential(make: Callable[[], T], count: int) -> Iterator[T]:
    """The same batches without a thread (for comparison, and where threads are unwelcome)."""
    for _ in range(count):
        yield make()
