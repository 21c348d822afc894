"""The worker pool never outlives its parent, and stopping it ends each job through its
``finally`` blocks."""

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from econdor_lab.workers import WorkerPool
from tests.helpers import pool_jobs
from tests.helpers.pool_jobs import process_gone
from tests.helpers.vehicles import wait_for

ROOT = Path(__file__).resolve().parents[2]


def _marks(d: Path, kind: str) -> set[int]:
    return {int(p.name.split("-")[1]) for p in d.glob(f"{kind}-*")}


def test_a_pool_left_normally_runs_every_job():
    with WorkerPool(2) as pool:
        assert list(pool.map(pool_jobs.square, range(6))) == [0, 1, 4, 9, 16, 25]


def test_a_pool_left_on_an_error_stops_its_jobs_through_their_finally(tmp_path):
    with pytest.raises(RuntimeError, match="stop here"), WorkerPool(2) as pool:
        futs = [pool.submit(pool_jobs.hold, str(tmp_path)) for _ in range(4)]
        started = wait_for(lambda: len(_marks(tmp_path, "started")) == 2 and
                           _marks(tmp_path, "started"), 60, "both workers' jobs to start")
        raise RuntimeError("stop here")
    # both running jobs went through their finally; the two queued never started
    assert _marks(tmp_path, "cleaned") == started == _marks(tmp_path, "started")
    assert all(process_gone(pid) for pid in started)
    assert not any(f.done() and not f.cancelled() and f.exception() is None for f in futs)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_second_sigterm_does_not_cut_a_jobs_finally_short(tmp_path):
    """When one worker ends, the executor sends SIGTERM to every worker again: a job already
    on its way out through its ``finally`` must still finish it."""
    os.mkfifo(tmp_path / "release")
    with pytest.raises(RuntimeError, match="stop here"), WorkerPool(1) as pool:
        fut = pool.submit(pool_jobs.hold_through_cleanup, str(tmp_path))
        (pid,) = wait_for(lambda: _marks(tmp_path, "started"), 60, "the job to start")
        os.kill(pid, signal.SIGTERM)
        wait_for(lambda: _marks(tmp_path, "cleaning"), 60, "the job's finally to begin")
        os.kill(pid, signal.SIGTERM)
        wait_for(lambda: not pool_jobs.signal_pending(pid, signal.SIGTERM), 60,
                 "the second SIGTERM to be delivered")
        fd = os.open(tmp_path / "release", os.O_RDWR)  # never blocks, reader or none
        os.write(fd, b"go")
        os.close(fd)
        wait_for(lambda: process_gone(pid), 60, "the worker to end")
        raise RuntimeError("stop here")
    assert _marks(tmp_path, "cleaned") == {pid}
    assert not fut.done() or fut.cancelled() or fut.exception() is not None


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_workers_end_with_a_parent_killed_outright(tmp_path):
    """SIGKILL gives the parent no chance to stop anything: the kernel tells the workers."""
    script = textwrap.dedent(f"""
        import sys, threading
        sys.path.insert(0, {str(ROOT)!r})
        from econdor_lab.workers import WorkerPool
        from tests.helpers import pool_jobs
        if __name__ == "__main__":
            with WorkerPool(2) as pool:
                for _ in range(2):
                    pool.submit(pool_jobs.hold, {str(tmp_path)!r})
                threading.Event().wait()
    """)
    parent = subprocess.Popen([sys.executable, "-c", script], cwd=tmp_path,
                              stderr=subprocess.DEVNULL)
    try:
        started = wait_for(lambda: len(_marks(tmp_path, "started")) == 2 and
                           _marks(tmp_path, "started"), 60, "both workers' jobs to start")
        parent.kill()
        parent.wait()
        wait_for(lambda: all(process_gone(pid) for pid in started), 30, "the workers to end")
        assert _marks(tmp_path, "cleaned") == started
    finally:
        if parent.poll() is None:
            parent.kill()
        for pid in _marks(tmp_path, "started"):
            if not process_gone(pid):
                os.kill(pid, signal.SIGKILL)
