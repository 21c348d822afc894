"""``econdor run --connect`` flying ArduCopter SITL with the Lua field script: the real
flight code, a real payload script and the station (issue 33's goals).

* three copters (their own system ids, one TCP link each) map the demo mission with >= 99 %
  of the samples the Lua scripts sent placed, at the sensor's rate, each where it was sensed
  (the goal of <= -40 dB is measured over many runs by ``bench/sitl.py``);
* one copter through ``econdor relay`` losing 10 % of the datagrams each way (SITL sends UDP
  itself): the run completes and every sample that reached the station is placed; its
  sensor has a known lag, so its contour missions begin with the sensor lag item, which the
  real autopilot refuses as it refuses the contour item: the contours go as waypoints.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from econdor_gcs.config import load_mission
from econdor_gcs.link.codec import mavlink
from econdor_gcs.link.tlog import read_tlog
from econdor_gcs.payload import field_script
from tests.helpers.sitl import Sitl, lua_counts, requires_sitl, sitls
from tests.helpers.vehicles import DEMO, REPO, free_port

pytestmark = [pytest.mark.e2e, pytest.mark.sitl, requires_sitl]

SPEEDUP = 20.0


def econdor_run(mission: Path, out: Path, connects: list[str], n: int, timeout_s: float,
                *extra: str) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "econdor", "run", str(mission), "--vehicles", str(n),
           "--speedup", f"{SPEEDUP:g}", "--out", str(out), "--quiet", "--timeout", "60",
           *extra]
    for c in connects:
        cmd += ["--connect", c]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, cwd=REPO)


def placed_per_vehicle(out: Path) -> np.ndarray:
    a = np.loadtxt(out / "samples.csv", delimiter=",", skiprows=1, ndmin=2)
    return a


def test_three_sitl_copters_with_the_lua_sensor_map_the_demo(tmp_path):
    mission = load_mission(DEMO)
    lua = field_script(mission)
    vehicles = [Sitl(tmp_path / f"sitl{i}", sysid=i, speedup=SPEEDUP,
                     scripts={"econdor_field.lua": lua}) for i in (1, 2, 3)]
    out = tmp_path / "run"
    with sitls(*vehicles):
        run = econdor_run(DEMO, out, [f"tcp:127.0.0.1:{v.port}" for v in vehicles], 3, 400)
        assert run.returncode == 0, run.stderr + "".join(v.explain() for v in vehicles)
    summary = json.loads((out / "summary.json").read_text())
    print(f"\nSITL x3 demo: {summary['final_mae_db']:.1f} dB, {summary['samples']} samples, "
          f"{summary['timings']['total_wall_s']:.0f} s wall, pairing {summary['sample_pairing']}")
    # the goal is -40 dB; bench/sitl.py measures it over several runs (docs/results/sitl.md).
    # One run's samples differ a little with SITL's timing on a loaded machine, and
    # E-CONDOR's levels follow them, so the suite holds a margin below the goal
    # (docs/experiments/2026-12-05-starved-sg.md), plus what must hold in every run: every
    # sample the scripts sent placed, at their rate, and sensed where it was placed (below)
    assert summary["final_mae_db"] <= -35.0
    assert [v["autopilot"] for v in summary["fleet"]] == ["ardupilot"] * 3
    assert summary["link_conflicts"] == []
    # a stock autopilot's Lua script does not answer the sample count: said, not fatal
    for rec in summary["sample_recovery"].values():
        assert "UNSUPPORTED" in rec["no_recovery"]
    received, sent = lua_counts(out / "telemetry.tlog")
    a = placed_per_vehicle(out)
    sysids = summary["sysids"]
    for index, sysid in enumerate(sysids):
        mine = a[a[:, 5] == index]
        placed = len(mine)
        assert placed >= 0.99 * sent[sysid], (sysid, placed, sent[sysid], received[sysid])
        # at the sensor's rate (10 Hz of the vehicle's time) while flying
        t = np.sort(mine[:, 0])
        steps = np.diff(t)
        flying = steps[steps < 0.5]
        assert 0.095 <= float(np.mean(flying)) <= 0.11
    # each sample was sensed where the station put it: the truth there agrees
    truth = mission.build_field(mission.seed)
    err = np.abs(a[:, 3] - truth(a[:, 1], a[:, 2]))
    assert float(np.median(err)) < 0.01 and float(np.percentile(err, 99)) < 0.1


def test_one_sitl_copter_through_a_lossy_link_keeps_every_sample_that_arrived(tmp_path):
    doc = yaml.safe_load(DEMO.read_text())
    doc["algorithm"].update(max_iterations=2, min_iterations=2)
    doc["vehicles"]["count"] = 1
    # a known sensor lag: the contour missions carry the sensor lag item before the contour
    # item, and the real ArduCopter refuses it (UNSUPPORTED) as it refuses the contour item
    doc["vehicles"]["sensor"] = {"lag_s": 0.2}
    small = tmp_path / "small.yaml"
    small.write_text(yaml.safe_dump(doc))
    mission = load_mission(small)
    relay_port, station_port = free_port(), free_port()
    relay = subprocess.Popen(
        [sys.executable, "-m", "econdor", "relay", "--listen", f"udpin:127.0.0.1:{relay_port}",
         "--to", f"udpout:127.0.0.1:{station_port}", "--drop", "10%", "--seed", "3"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=REPO)
    sitl = Sitl(tmp_path / "sitl", speedup=SPEEDUP, serial0=f"udpclient:127.0.0.1:{relay_port}",
                scripts={"econdor_field.lua": field_script(mission)})
    out = tmp_path / "run"
    try:
        with sitls(sitl):
            run = econdor_run(small, out, [f"udpin:127.0.0.1:{station_port}"], 1, 300)
            assert run.returncode == 0, run.stderr + sitl.explain()
    finally:
        relay.terminate()
        _, err = relay.communicate(timeout=10)
    dropped = [line for line in err.splitlines() if "dropped" in line]
    assert dropped, err  # the relay did drop datagrams
    summary = json.loads((out / "summary.json").read_text())
    received, _ = lua_counts(out / "telemetry.tlog")
    placed = len(placed_per_vehicle(out))
    print(f"\nSITL x1 lossy: {summary['final_mae_db']:.1f} dB, {placed} of {received[1]} "
          f"received samples placed, relay: {dropped[-1]}")
    assert placed == received[1]
    assert summary["samples_dropped_unpaired"] == 0
    # the station flew the contours as waypoints: the mission it flew has neither item
    contour_missions = 0
    for tasks_file in sorted((out / "missions").glob("iter*_v1.tasks.json")):
        tasks = json.loads(tasks_file.read_text())["tasks"]
        if not any(t["kind"] == "trace" for t in tasks):
            continue
        contour_missions += 1
        assert {t["sensor_lag_s"] for t in tasks if t["kind"] == "trace"} == {0.2}
        items = json.loads(tasks_file.with_name(
            tasks_file.name.replace(".tasks.json", ".json")).read_text())
        commands = {it["command"] for it in items}
        assert 31000 not in commands and 31013 not in commands and 16 in commands
    assert contour_missions >= 1
    refused = {m.type for m in read_tlog(out / "telemetry.tlog")
               if m.get_type() == "MISSION_ACK" and m.get_srcSystem() == 1}
    assert mavlink.MAV_MISSION_UNSUPPORTED in refused, refused
