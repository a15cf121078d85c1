"""`Lru`: a bounded cache that drops its least recently used entry, for what an environment
builds per body shape (a compiled character, a clip retargeted onto it) and meets again when the
sampler's shape buffer repeats a shape."""

from __future__ import annotations

import collections
from typing import Callable, Generic, Hashable, TypeVar

V = TypeVar("V")


class Lru(Generic[V]):
    """At most `size` values by key (at least one is kept); `get` builds a missing one."""

    def __init__(self, size: int):
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise ValueError(f"cache size {size!r} must be an integer >= 1")
        self.size = size
        self._entries: collections.OrderedDict[Hashable, V] = collections.OrderedDict()

    def get(self, key: Hashable, build: Callable[[], V]) -> V:
        """The value of `key`, made the most recently used; `build()` when absent, stored, and
        the least recently used entries dropped beyond `size`."""
        if key in self._entries:
            self._entries.move_to_end(key)
            return self._entries[key]
        value = self._entries[key] = build()
        while len(self._entries) > self.size:
            self._entries.popitem(last=False)
        return value

    def clear(self) -> None:
        self._entries.clear()

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    def __len__(self) -> int:
        return len(self._entries)
