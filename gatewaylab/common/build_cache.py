"""What the parts of one rig build share: files every section reads, parsed once for the whole build.

A rig of 100 ``kind = "esi"`` slaves names the same two ESI files 100 times; each section asks the build's
cache for the one object of its kind (``cache.part(EsiFiles)``) instead of reading its file again. The cache
belongs to the build (the rig hands it to every factory through ``RigContext.build_cache``), never to a
module: two rigs built in one process share nothing, and a rig built again reads its files again.
"""

from __future__ import annotations

from typing import TypeVar, cast

__all__ = ["BuildCache"]

T = TypeVar("T")


class BuildCache:
    """One instance per class for the build (made on first use with no arguments), dropped with the build."""

    def __init__(self) -> None:
        self._parts: dict[type, object] = {}

    def part(self, cls: type[T]) -> T:
        """The build's one ``cls`` (a cache of parsed files of one format), made now if this is the first ask."""
        found = self._parts.get(cls)
        if found is None:
            found = self._parts[cls] = cls()
        return cast(T, found)

    def clear(self) -> None:
        """Forget every part (the build is over: parsed files need not stay in memory)."""
        self._parts.clear()
