"""A ground station killed outright (SIGKILL: an out-of-memory killer, ``kill -9``) runs no
clean-up; the simulated vehicles it started must not fly on for a station that is gone:
each ends with it (``sim-vehicle --parent-pid``), through its own clean stop."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.helpers.missions import write_small_mission
from tests.helpers.pool_jobs import process_gone
from tests.helpers.vehicles import DEMO, sim_vehicle_cmd, wait_for


def _ready(logs: Path, n: int) -> bool:
    return sum("ready on" in p.read_text(errors="replace")
               for p in logs.glob("v*.log")) >= n


def _vehicle_pids(station_pid: int) -> set[int]:
    path = Path(f"/proc/{station_pid}/task/{station_pid}/children")
    return {int(c) for c in path.read_text().split()} if path.exists() else set()


def test_the_simulated_vehicles_end_with_a_station_killed_outright(tmp_path):
    mission = write_small_mission(tmp_path, "killed", vehicles=2, iterations=3, speedup=20)
    out = tmp_path / "run"
    station = subprocess.Popen(
        [sys.executable, "-m", "econdor.cli", "run", str(mission), "--out", str(out), "--quiet"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    vehicles: set[int] = set()
    try:
        wait_for(lambda: (out / "vehicles").is_dir() and _ready(out / "vehicles", 2), 120,
                 "both vehicles ready")
        vehicles = _vehicle_pids(station.pid)
        assert len(vehicles) == 2
        station.kill()
        station.wait()
        wait_for(lambda: all(process_gone(p) for p in vehicles), 30, "the vehicles to end")
    finally:
        if station.poll() is None:
            station.kill()
        for pid in vehicles:
            if not process_gone(pid):
                subprocess.run(["kill", "-9", str(pid)], check=False)
    for log in sorted((out / "vehicles").glob("v*.log")):
        assert "stopped after" in log.read_text(errors="replace"), log  # its own clean stop


def test_a_vehicle_whose_station_has_ended_does_not_start(tmp_path):
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    r = subprocess.run([*sim_vehicle_cmd(), "--mission", str(DEMO), "--parent-pid",
                        str(gone.pid)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert r.stderr.strip() == f"sim-vehicle: error: --parent-pid {gone.pid}: that process has ended"
