"""The LRU map bounding what a pipeline (extra networks), workers (networks) and the viewer
(scenes) keep loaded."""

from __future__ import annotations

import pytest

from jointseg.lru import LRUCache


def test_lru_keeps_the_most_recently_used_entries() -> None:
    cache: LRUCache[str, int] = LRUCache(2)
    cache.put("a", 1)
    cache.put("b", 2)
    assert cache.get("a") == 1  # "a" is now the most recent: "b" goes first
    cache.put("c", 3)
    assert len(cache) == 2 and "b" not in cache
    assert (cache.get("a"), cache.get("b"), cache.get("c")) == (1, None, 3)
    cache.put("c", 4)  # replacing an entry does not grow the cache
    assert len(cache) == 2 and cache.get("c") == 4
    cache.clear()
    assert len(cache) == 0


def test_an_lru_of_size_zero_keeps_nothing() -> None:
    cache: LRUCache[str, int] = LRUCache(0)
    cache.put("a", 1)
    assert len(cache) == 0 and cache.get("a") is None
    with pytest.raises(ValueError, match="negative"):
        LRUCache(-1)


class Counting:
    """A loader that counts its calls and hands out a distinct object each time."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self) -> object:
        self.calls += 1
        return object()


def test_a_loaded_entry_is_reused_and_the_oldest_dropped_beyond_the_size() -> None:
    cache: LRUCache[str, object] = LRUCache(2)
    loader = Counting()
    a = cache.get_or_load("a", loader)
    assert cache.get_or_load("a", loader) is a and loader.calls == 1
    cache.get_or_load("b", loader)
    cache.get_or_load("a", loader)  # a is now the most recent
    cache.get_or_load("c", loader)  # b, the least recent, goes
    assert len(cache) == 2 and loader.calls == 3
    assert cache.get_or_load("a", loader) is a and loader.calls == 3
    cache.get_or_load("b", loader)
    assert loader.calls == 4  # b was loaded again


def test_a_cache_of_size_zero_loads_every_time() -> None:
    cache: LRUCache[str, object] = LRUCache(0)
    loader = Counting()
    assert cache.get_or_load("a", loader) is not cache.get_or_load("a", loader)
    assert loader.calls == 2 and len(cache) == 0
