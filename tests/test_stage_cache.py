import numpy as np

from signpose.pipeline.recognize import StageCache


def test_cache_reuses_and_bounds_entries_and_bytes():
    calls = []
    cache = StageCache(max_entries=3, max_bytes=10_000)

    def make(n):
        calls.append(n)
        return np.zeros(n, np.uint8)

    a = cache.get(("a",), lambda: make(4000))
    assert cache.get(("a",), lambda: make(4000)) is a and calls == [4000]
    cache.get(("b",), lambda: make(4000))
    cache.get(("c",), lambda: make(4000))  # 12000 bytes: the least recently used ("a") goes
    assert len(cache) == 2 and cache.bytes == 8000
    cache.get(("a",), lambda: make(4000))
    assert calls == [4000] * 4
    cache.get(("huge",), lambda: make(50_000))  # alone over budget: kept, everything else dropped
    assert len(cache) == 1 and cache.bytes == 50_000
