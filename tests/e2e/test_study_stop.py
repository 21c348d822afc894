"""``econdor study`` stopped by SIGTERM (a scheduler's time limit, a ``kill``): it says so
in one line, exits non-zero, leaves no worker running, and every interrupted run keeps
the samples it had."""

import csv
import signal
import subprocess
import sys
from pathlib import Path

from tests.helpers.pool_jobs import process_gone
from tests.helpers.vehicles import wait_for

ROOT = Path(__file__).resolve().parents[2]


def _children(pid: int) -> set[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return {int(c) for c in path.read_text().split()} if path.exists() else set()


def _samples(run: Path) -> int:
    path = run / "samples.csv"
    if not path.exists():
        return 0
    with path.open(newline="") as f:
        return max(0, sum(1 for _ in csv.reader(f)) - 1)


def test_a_study_stopped_by_sigterm_stops_its_workers_and_keeps_every_run(tmp_path):
    out = tmp_path / "study"
    proc = subprocess.Popen(
        [sys.executable, "-m", "econdor.cli", "study", str(ROOT / "missions" / "plume.yaml"),
         "--seeds", "0:8", "--workers", "2", "--quiet", "--no-figures", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # both workers flying: two runs with samples on disk
        wait_for(lambda: sum(_samples(r) > 0 for r in (out / "runs").glob("*")) >= 2
                 if (out / "runs").exists() else False, 120, "two runs under way")
        workers = _children(proc.pid)
        assert len(workers) >= 2
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130
    assert err.strip().splitlines()[-1] == "econdor: interrupted"
    assert "leaked" not in err  # the pool's queues released, not left to the tracker
    wait_for(lambda: all(process_gone(p) for p in workers), 30, "the workers to end")
    runs = sorted((out / "runs").glob("*"))
    assert runs and all((r / "run.json").exists() and _samples(r) > 0 for r in runs)
    assert not (out / "summary.json").exists()
