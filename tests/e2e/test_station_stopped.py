"""A ground station stopped by a signal writes its run whole, even when a second signal comes
while it does (Ctrl-C pressed again, a scheduler repeating its SIGTERM): one line, exit
130, the summary written and every sample received in ``samples.csv``."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
from pathlib import Path

from tests.helpers.missions import write_small_mission
from tests.helpers.pool_jobs import process_gone
from tests.helpers.vehicles import wait_for


def _rows(path: Path) -> int:
    if not path.exists():
        return 0
    with path.open(newline="") as f:
        return max(0, sum(1 for _ in csv.reader(f)) - 1)


def _children(pid: int) -> set[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return {int(c) for c in path.read_text().split()} if path.exists() else set()


def _stopping(log: Path) -> bool:
    """The station has taken the first signal: its clean-up has begun."""
    return log.exists() and "run failed: interrupted" in log.read_text(errors="replace")


def test_a_second_signal_during_the_clean_up_does_not_cut_it_short(tmp_path):
    mission = write_small_mission(tmp_path, "stopped", vehicles=2, iterations=3, speedup=20)
    out = tmp_path / "run"
    station = subprocess.Popen(
        [sys.executable, "-m", "econdor.cli", "run", str(mission), "--out", str(out), "--quiet"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    vehicles: set[int] = set()
    try:
        wait_for(lambda: _rows(out / "samples_received.csv") > 200, 120, "samples arriving")
        vehicles = _children(station.pid)
        station.send_signal(signal.SIGTERM)
        wait_for(lambda: _stopping(out / "log.jsonl") or station.poll() is not None, 60,
                 "the clean-up to begin", interval=0.001)
        # the second signals reach a station still cleaning up (else this tests nothing)
        assert station.poll() is None, "the clean-up was over before the second signal"
        station.send_signal(signal.SIGTERM)
        station.send_signal(signal.SIGINT)
        _, err = station.communicate(timeout=60)
    finally:
        if station.poll() is None:
            station.kill()
            station.wait()
    assert station.returncode == 130, err
    assert err.splitlines() == ["econdor: interrupted"]
    assert json.loads((out / "summary.json").read_text())["error"] == "interrupted"
    assert _rows(out / "samples.csv") == _rows(out / "samples_received.csv") > 200
    wait_for(lambda: all(process_gone(p) for p in vehicles), 30, "the vehicles to end")
