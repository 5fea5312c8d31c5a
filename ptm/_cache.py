"""A bounded least-recently-used memo with hit statistics.

Used to memoise per-set appearance evidence and per-partition odometry
likelihoods (docs/model.md §3.3, step 3): results are deterministic functions of their
key, so a cache hit returns exactly what a miss would have computed.

    >>> cache = BoundedCache(maxsize=2)
    >>> cache.put("a", 1.0); cache.get("a"), cache.hit_rate
    (1.0, 1.0)
"""

from __future__ import annotations

from collections import OrderedDict

_MISSING = object()


class BoundedCache:
    """LRU dictionary holding at most ``maxsize`` entries; counts hits and misses."""

    def __init__(self, maxsize: int = 100_000):
        if int(maxsize) != maxsize or maxsize < 1:
            raise ValueError(f"maxsize must be a positive integer, got {maxsize!r}")
        self.maxsize = int(maxsize)
        self._entries: OrderedDict = OrderedDict()
        self.hits = 0
        self.misses = 0

    def get(self, key, default=None):
        """The cached value (counted as a hit) or ``default`` (counted as a miss)."""
        value = self._entries.get(key, _MISSING)
        if value is _MISSING:
            self.misses += 1
            return default
        self.hits += 1
        self._entries.move_to_end(key)
        return value

    def put(self, key, value) -> None:
        self._entries[key] = value
        self._entries.move_to_end(key)
        if len(self._entries) > self.maxsize:
            self._entries.popitem(last=False)

    def __contains__(self, key) -> bool:
        """Whether ``key`` is cached (not counted as a lookup, and not moved to the end)."""
        return key in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def hit_rate(self) -> float:
        """Fraction of lookups answered from the cache (nan before the first lookup)."""
        total = self.hits + self.misses
        return self.hits / total if total else float("nan")

    def stats(self) -> dict:
        return {"cache_hits": self.hits, "cache_misses": self.misses,
                "cache_hit_rate": self.hit_rate, "cache_size": len(self)}
