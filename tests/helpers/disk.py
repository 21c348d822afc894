"""A disk that fills up, for tests: OSError(ENOSPC) at the write boundary, no root needed.

:class:`FullDisk` patches ``open`` (``builtins.open`` and ``io.open``, which ``pathlib``
uses) and ``os.unlink`` for the files under one directory. Until it is full, writes go to
the real files. It becomes full after the ``n``-th write to a file named ``trigger``, or once
``when()`` holds (a state of the run, looked at on every write: keep it cheap), or when
:meth:`fill` is called. From then on every write there raises ``OSError(ENOSPC)``, except as far as files
deleted since (their size) make room again, as on a real file system: what a run frees
(its space reserve) it can use for its last words.
"""

from __future__ import annotations

import builtins
import errno
import io
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any


class _File:
    """A real file whose writes go through the disk's budget."""

    def __init__(self, disk: FullDisk, real: Any, name: str) -> None:
        self._disk = disk
        self._real = real
        self._name = name

    def write(self, data: Any) -> int:
        size = len(data.encode("utf-8")) if isinstance(data, str) else len(data)
        self._disk.take(self._name, size)
        return self._real.write(data)

    def writelines(self, lines: Any) -> None:
        for line in lines:
            self.write(line)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)

    def __enter__(self) -> _File:
        return self

    def __exit__(self, *exc: object) -> None:
        self._real.close()

    def __iter__(self) -> Any:
        return iter(self._real)


class FullDisk:
    """See the module docstring; use as a context manager (patches while inside)."""

    def __init__(self, root: Path, trigger: str | None = None, n: int = 1,
                 when: Callable[[], bool] | None = None) -> None:
        self.root = Path(root).resolve()
        self.trigger, self.n = trigger, n
        self.when = when
        self.full = False
        self.room = 0
        """Bytes free once full (what deleted files gave back)."""
        self.refused: list[str] = []
        """Writes refused (file names), in order."""
        self._lock = threading.Lock()
        self._open = builtins.open
        self._unlink = os.unlink

    def _mine(self, path: Any) -> bool:
        try:
            p = Path(os.fsdecode(path)).resolve()
        except (TypeError, ValueError):
            return False
        return p == self.root or self.root in p.parents

    def fill(self) -> None:
        with self._lock:
            self.full = True

    def take(self, name: str, size: int) -> None:
        with self._lock:
            if self.full:
                if size > self.room:
                    self.refused.append(name)
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), name)
                self.room -= size
            elif Path(name).name == self.trigger:
                self.n -= 1
                if self.n <= 0:
                    self.full = True  # this write still fits: the next ones do not
            elif self.when is not None:
                self.full = self.when()  # this write still fits: the next ones do not

    def open(self, file: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        real = self._open(file, mode, *args, **kwargs)
        if isinstance(file, int) or not any(c in mode for c in "wax+") \
                or not self._mine(file):
            return real
        return _File(self, real, os.fsdecode(file))

    def unlink(self, path: Any, *args: Any, **kwargs: Any) -> None:
        size = 0
        if self._mine(path):
            try:
                size = os.stat(path).st_size
            except OSError:
                size = 0
        self._unlink(path, *args, **kwargs)
        with self._lock:
            self.room += size

    def __enter__(self) -> FullDisk:
        builtins.open = self.open  # type: ignore[assignment]
        io.open = self.open  # type: ignore[assignment]
        os.unlink = self.unlink  # type: ignore[assignment]
        return self

    def __exit__(self, *exc: object) -> None:
        builtins.open = self._open
        io.open = self._open
        os.unlink = self._unlink
