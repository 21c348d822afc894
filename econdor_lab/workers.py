"""A pool of spawned worker processes that never outlives the process that made it.

:class:`ProcessPoolExecutor` leaves its workers behind when its parent dies without
shutting it down (SIGTERM or SIGKILL from a scheduler's time limit, a ``kill`` of the
study): they wait on their call queue for good, or finish the job they hold and the one
queued behind it. :class:`WorkerPool` is that executor with three more rules:

- **Each worker dies with its parent**, however the parent ended
  (:func:`econdor_gcs.lifetime.die_with_parent`).
- **A worker told to stop ends its job cleanly.** SIGTERM in a worker raises
  :class:`WorkerTerminated` (a :class:`KeyboardInterrupt`) inside the job it is running,
  so the job's ``finally`` blocks run (a run directory closes with every sample it
  received); then the worker exits. Further SIGTERMs while those blocks run are ignored.
  An idle worker exits at once.
- **Leaving the pool on an exception stops it**: queued jobs are cancelled and the
  running ones are stopped as above (SIGTERM; SIGKILL for a worker still alive after
  ``stop_timeout_s``), rather than waited for. Leaving it normally waits for every job,
  as the executor does.

While the pool is entered, the BLAS thread counts of the environment are 1 (spawned
workers read them when they import numpy): several processes each spinning a thread per
core slow the dense solves down many times.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from types import FrameType, TracebackType
from typing import Any, TypeVar

from econdor_gcs.lifetime import die_with_parent

__all__ = ["WorkerPool", "WorkerTerminated"]

T = TypeVar("T")

_BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


class WorkerTerminated(KeyboardInterrupt):
    """SIGTERM in a worker, raised inside its job so the job's ``finally`` blocks run."""


# The worker's state: whether a job is running, and whether SIGTERM came.
_in_job = False
_terminating = False


def _on_sigterm(signum: int, frame: FrameType | None) -> None:
    global _terminating
    if _terminating:  # told already: the job is on its way out through its finally blocks
        return  # (the executor sends every worker SIGTERM again once one of them has ended)
    _terminating = True
    if _in_job:
        raise WorkerTerminated()
    os._exit(128 + signum)


def _init_worker(parent_pid: int) -> None:
    signal.signal(signal.SIGTERM, _on_sigterm)
    if not die_with_parent(parent_pid):  # the parent ended before the request was made
        os._exit(128 + signal.SIGTERM)


def _guarded(fn: Callable[..., T], args: tuple[Any, ...], kwargs: dict[str, Any]) -> T:
    """Run one job; after it, a worker told to stop exits (its result goes nowhere)."""
    global _in_job
    _in_job = True
    try:
        return fn(*args, **kwargs)
    finally:
        _in_job = False
        if _terminating:
            os._exit(128 + signal.SIGTERM)


class WorkerPool(ProcessPoolExecutor):
    """A :class:`ProcessPoolExecutor` of ``max_workers`` spawned processes whose workers
    end with it (module docstring). Jobs and their arguments must pickle, as for the
    executor."""

    def __init__(self, max_workers: int, stop_timeout_s: float = 10.0) -> None:
        super().__init__(max_workers=max_workers,
                         mp_context=multiprocessing.get_context("spawn"),
                         initializer=_init_worker, initargs=(os.getpid(),))
        self.stop_timeout_s = stop_timeout_s
        self._saved_env: dict[str, str | None] = {}

    def submit(self, fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> Future[T]:
        return super().submit(_guarded, fn, args, kwargs)

    def stop(self) -> None:
        """Cancel the queued jobs and stop the workers now: SIGTERM (each running job ends
        through its ``finally`` blocks), then SIGKILL for any still alive after
        ``stop_timeout_s``."""
        workers = list((getattr(self, "_processes", None) or {}).values())
        manager = getattr(self, "_executor_manager_thread", None)
        self.shutdown(wait=False, cancel_futures=True)
        for p in workers:
            p.terminate()
        for p in workers:
            p.join(self.stop_timeout_s)
            if p.is_alive():
                p.kill()
                p.join()
        if manager is not None:  # it lets go of the queues once the workers are gone
            manager.join(self.stop_timeout_s)

    def __enter__(self) -> WorkerPool:
        self._saved_env = {k: os.environ.get(k) for k in _BLAS_THREAD_VARS}
        os.environ.update({k: "1" for k in _BLAS_THREAD_VARS})
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> bool | None:
        try:
            if exc_type is not None:
                self.stop()
                return False
            return super().__exit__(exc_type, exc, tb)
        finally:
            for k, v in self._saved_env.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
