# SPDX-License-Identifier: Apache-2.0
"""
In-process reuse of objects loaded from cache files.

A process that solves many images (a loop over `commands.solve.solve_spots`, `calibrate` over
several images) loads each pattern database from disk once, not once per image (0.05-0.15 s
each, more for a narrow field's). An entry is keyed by what the object was built for and by
the file's identity (inode, size, modification time): a file rewritten or corrupted since is
read, and judged, again. At most `size` objects are held, the least recently used dropped.
`forget_all()` empties every memo (a benchmark timing a one-image process's first load).
"""
from __future__ import annotations

from collections import OrderedDict
from pathlib import Path
from typing import Generic, TypeVar

T = TypeVar("T")
_ALL: list["FileMemo"] = []  # every memo of the process (forget_all)


def forget_all() -> None:
    """Empty every FileMemo of the process: the next loads read their files again."""
    for memo in _ALL:
        memo.clear()


class FileMemo(Generic[T]):
    """Objects loaded from files, reused while their file is unchanged (module docstring)."""

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f"a memo holds at least 1 object, got {size}")
        self.size = size
        self._items: OrderedDict[tuple, T] = OrderedDict()
        _ALL.append(self)

    @staticmethod
    def _key(path: Path, identity: str) -> tuple | None:
        try:
            stat = Path(path).stat()
        except OSError:
            return None
        return identity, str(Path(path).resolve()), stat.st_ino, stat.st_size, stat.st_mtime_ns

    def get(self, path: Path, identity: str) -> T | None:
        """Return the object loaded from `path` for `identity`, if the file is unchanged since; else None."""
        key = self._key(path, identity)
        if key is None or key not in self._items:
            return None
        self._items.move_to_end(key)
        return self._items[key]

    def put(self, path: Path, identity: str, value: T) -> None:
        """Remember `value`, loaded from (or just written to) `path` for `identity`; nothing if the file is missing."""
        key = self._key(path, identity)
        if key is None:
            return
        self._items[key] = value
        self._items.move_to_end(key)
        while len(self._items) > self.size:
            self._items.popitem(last=False)

    def clear(self) -> None:
        self._items.clear()
