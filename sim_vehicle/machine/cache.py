"""numba's on-disk cache of the machine: one compilation shared by processes, never stale.

numba checks a cached function against its own source file only. The machine's functions
call one another across the package's modules and inline the kinematics, the fence tests,
the sensor and :func:`~econdor_gcs.core.fields.gaussian_sum_at` from elsewhere: after an
edit of a callee alone the cache of its callers would still hand out the old code. A digest
of every source they are built from, kept beside the cache, decides when to forget it all
(:func:`drop_stale_cache`). Processes starting together take turns on a lock file in the
cache directory (:func:`cache_lock`): one compiles, the others load its result.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any  # a dispatcher: its stubs say Dispatcher, at runtime a CPUDispatcher

from numba.core.registry import CPUDispatcher

log = logging.getLogger(__name__)


def _cache_dir(dispatcher: Any) -> Path | None:
    path = dispatcher.stats.cache_path
    return Path(path) if path else None


@contextlib.contextmanager
def cache_lock(dispatcher: Any) -> Iterator[None]:
    """Hold an exclusive lock on the compiled cache of ``dispatcher``'s package. No lock
    where the cache directory cannot be written."""
    cache_dir = _cache_dir(dispatcher)
    try:
        f = (cache_dir / "machine.lock").open("a") if cache_dir else None
    except OSError:
        f = None
    if f is None:
        yield
        return
    with f:
        fcntl.flock(f, fcntl.LOCK_EX)
        yield


def drop_stale_cache(dispatcher: Any, modules: list[ModuleType],
                     sources: list[ModuleType]) -> None:
    """Flush the cache of every compiled function of ``modules`` unless the digest of
    ``modules`` and ``sources`` is the one the cache was made from."""
    files = [Path(str(m.__file__)) for m in (*modules, *sources)]
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in files)).hexdigest()
    cache_dir = _cache_dir(dispatcher)
    if cache_dir is None:
        return
    caches = [getattr(d, "_cache", None) for m in modules for d in vars(m).values()
              if isinstance(d, CPUDispatcher) and d.__module__ == m.__name__]
    stamp = cache_dir / "machine-sources.sha256"
    try:
        with cache_lock(dispatcher):
            if stamp.is_file() and stamp.read_text(encoding="ascii") == digest:
                return
            for cache in caches:
                if cache is not None:
                    cache.flush()
            stamp.write_text(digest, encoding="ascii")
    except OSError as exc:  # a read-only cache: numba itself then compiles in memory
        log.warning("tracer: cannot check the compiled cache at %s: %s", stamp.parent, exc)


def package_modules(package: str) -> list[ModuleType]:
    """The imported modules of ``package`` (itself and its submodules), by name."""
    return [sys.modules[name] for name in sorted(sys.modules)
            if name == package or name.startswith(package + ".")]
