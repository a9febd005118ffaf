"""A bounded in-process memo: values built from a key, the oldest dropped past a size.

Used for what depends on a capture's angle layout alone (slice groupings, the isotropy test's
neighbour indices): a folder of files measured with one angle program builds them once.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

V = TypeVar("V")


class BoundedMemo(Generic[V]):
    """``memo.get(key, build)``: the value for ``key``, built by ``build()`` on a miss; past
    ``maxsize`` entries the oldest one is dropped (first in, first out)."""

    def __init__(self, maxsize: int):
        if maxsize < 1:
            raise ValueError(f"maxsize must be at least 1, got {maxsize}")
        self.maxsize = maxsize
        self._entries: dict[Hashable, V] = {}

    def get(self, key: Hashable, build: Callable[[], V]) -> V:
        try:
            return self._entries[key]
        except KeyError:
            value = build()
        self._entries[key] = value
        while len(self._entries) > self.maxsize:
            del self._entries[next(iter(self._entries))]
        return value

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def clear(self) -> None:
        self._entries.clear()
