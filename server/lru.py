"""A small thread-safe LRU map: the bound on what a long-running process keeps loaded.

Workers keep a few loaded networks and the viewer a few loaded scenes; both must stop growing
with the number of distinct configurations or files seen. Loading happens outside the lock
(the caller calls :meth:`get`, loads on a miss, then :meth:`put`), so a slow load never blocks
readers of other entries.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class LRUCache(Generic[K, V]):
    """At most ``size`` entries; the least recently used one is dropped first (0: keep none)."""

    def __init__(self, size: int) -> None:
        if size < 0:
            raise ValueError(f"LRU cache size must not be negative, got {size}")
        self.size = size
        self._entries: OrderedDict[K, V] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: object) -> bool:
        return key in self._entries

    def get(self, key: K) -> V | None:
        """The entry for ``key`` (now the most recently used), None when absent."""
        with self._lock:
            if key not in self._entries:
                return None
            self._entries.move_to_end(key)
            return self._entries[key]

    def put(self, key: K, value: V) -> None:
        """Store ``value`` as the most recently used entry, dropping the oldest beyond size."""
        with self._lock:
            self._entries[key] = value
            self._entries.move_to_end(key)
            while len(self._entries) > self.size:
                self._entries.popitem(last=False)

    def clear(self) -> None:
        """Drop every entry."""
        with self._lock:
            self._entries.clear()
