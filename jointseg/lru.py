"""A bounded map of loaded things, shared by threads: the bound on what a long-running process
keeps loaded.

A pipeline process keeps the extra networks a choice needs (:mod:`jointseg.network.choice`), a
worker its loaded networks (``server.worker.context``), the viewer its loaded scenes
(``web.scene``): each must stop growing with the number of distinct configurations or files
seen. The one implementation of the three.

The order of eviction is cachetools' ``LRUCache``. What this class adds, and why the library
alone does not do:

- a lock: cachetools' caches are not thread-safe (its documentation says so), and the viewer's
  callbacks run on viser's threads;
- :meth:`LRUCache.get_or_load` loads outside the lock, so a load that takes seconds (a network)
  never blocks readers of other entries;
- size 0 keeps nothing: ``cachetools.LRUCache(0)`` raises ValueError ("value too large") on
  every store instead.

``functools.lru_cache`` does not fit: its key is a function's arguments (a network's options are
a dict, unhashable), its bound is per function rather than per owner (each viewer has its own
scene cache), and nothing can be dropped or replaced by key.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

import cachetools

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class LRUCache(Generic[K, V]):
    """At most ``size`` entries; the least recently used one is dropped first (0: keep none)."""

    def __init__(self, size: int) -> None:
        if size < 0:
            raise ValueError(f"LRU cache size must not be negative, got {size}")
        self.size = size
        self._entries: cachetools.LRUCache[K, V] = cachetools.LRUCache(maxsize=max(size, 1))
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: object) -> bool:
        return key in self._entries

    def get(self, key: K) -> V | None:
        """The entry for ``key`` (now the most recently used), None when absent."""
        with self._lock:
            return self._entries.get(key)

    def put(self, key: K, value: V) -> None:
        """Store ``value`` as the most recently used entry, dropping the oldest beyond size."""
        if self.size == 0:
            return
        with self._lock:
            self._entries[key] = value

    def get_or_load(self, key: K, loader: Callable[[], V]) -> V:
        """The entry for ``key``, loaded by ``loader`` (outside the lock) and kept when absent."""
        with self._lock:
            if key in self._entries:
                return self._entries[key]
        value = loader()
        self.put(key, value)
        return value

    def clear(self) -> None:
        """Drop every entry."""
        with self._lock:
            self._entries.clear()
