"""The LRU map bounding what workers (networks) and the viewer (scenes) keep loaded."""

from __future__ import annotations

import pytest

from server.lru import LRUCache


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
