"""Columns computed once per record and shared by the detectors (a memo with a byte budget).

Several detectors of one round of the loop build the same full-length columns: the harmonics of
the load angle (the transmission error and the per-flank generic term), the smooth functions of
the speed (the drift's rival and the generic velocity function), held through the same dead
band. :class:`RecordCache` keeps them, keyed by what they are (a tuple) and checked against the
arrays they were built from (by identity: the record and the engaged samples of the round), so
a cached array is never served for other data. Past :data:`CACHE_BYTES` nothing more is kept
(a long record rebuilds instead; same values).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable

import numpy as np

#: most memory one record's cache keeps (bytes)
CACHE_BYTES = 512 * 2**20


class RecordCache:
    """``get(key, sources, build)``: ``build()``, computed once for ``key`` while ``sources`` are the same objects."""

    def __init__(self, budget_bytes: int = CACHE_BYTES) -> None:
        self.budget_bytes = int(budget_bytes)
        self.used_bytes = 0
        self._items: dict[Hashable, tuple[tuple[object, ...], np.ndarray]] = {}

    def can_hold(self, key: Hashable, nbytes: int) -> bool:
        """True when ``key`` is kept or an array of ``nbytes`` more would be."""
        return key in self._items or self.used_bytes + nbytes <= self.budget_bytes

    def get(self, key: Hashable, sources: tuple[object, ...], build: Callable[[], np.ndarray]) -> np.ndarray:
        """The array ``build()`` gives, from the cache when ``key`` was built from these very ``sources``.

        The array is marked read-only: callers share it.
        """
        hit = self._items.get(key)
        if hit is not None and len(hit[0]) == len(sources) and all(a is b for a, b in zip(hit[0], sources)):
            return hit[1]
        value = build()
        if hit is not None:  # built from other data: replaced
            self.used_bytes -= hit[1].nbytes
            del self._items[key]
        if self.used_bytes + value.nbytes <= self.budget_bytes:
            value.flags.writeable = False
            self._items[key] = (sources, value)
            self.used_bytes += value.nbytes
        return value
