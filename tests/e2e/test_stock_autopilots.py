"""Acceptance (issue 10): exported missions in ordinary tools, stock autopilots in econdor run,
and a watcher attached with --forward.

* an exported waypoint WPL loads with pymavlink's mavwp, and MAVProxy's ``wp load`` puts it
  into ``sim-vehicle --autopilot ardupilot``, which flies it to its end;
* an exported ``.plan`` goes through MAVSDK's QGroundControl-plan import and is uploaded to
  ``sim-vehicle`` (mission, geofence, rally point);
* ``econdor run missions/demo.yaml --autopilot ardupilot`` (three ArduPilot vehicles without
  companion) reaches <= -20 dB final MAE, while MAVProxy attached through ``--forward`` sees
  every vehicle's heartbeat and position.

(``econdor upload --start`` on both personalities is in ``test_upload.py``.)
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from econdor_gcs.app.export import export_cli
from econdor_gcs.files.autopilot_files import read_mission_file, read_wpl
from econdor_gcs.link.tlog import read_tlog
from tests.helpers.vehicles import (
    DEMO,
    REPO,
    MavproxyShell,
    VehicleProcess,
    free_port,
    mavproxy_exe,
    udp_port_bound,
    wait_for,
)

pytestmark = pytest.mark.interop


def export(tmp: Path, fmt: str) -> Path:
    out = tmp / ("demo.waypoints" if fmt == "wpl" else "demo.plan")
    export_cli(argparse.Namespace(
        source=DEMO, out=out, format=fmt, style="waypoints", alt_m=15.0, speed_mps=10.0,
        tolerance_m=1.0, vehicles=1, spacing_m=None, fence_margin_m=10.0, iteration=None,
        vehicle=None))
    return out


def stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_exported_wpl_in_mavwp_and_mavproxy_flown_by_ardupilot(tmp_path):
    from pymavlink import mavwp

    path = export(tmp_path, "wpl")
    ours = read_wpl(path)
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(path)) == len(ours) == 8
    for it, w in zip(ours, (loader.wp(i) for i in range(loader.count())), strict=True):
        assert (w.seq, w.frame, w.command) == (it.seq, it.frame, it.command)
        assert (round(w.x * 1e7), round(w.y * 1e7), w.z) == (it.x, it.y, it.z)
    last = len(ours) - 1
    with VehicleProcess("--speedup", "50", "--autopilot", "ardupilot", "--prearm-s", "1",
                        connect="tcpin:127.0.0.1:0") as veh, \
            MavproxyShell(f"tcp:127.0.0.1:{veh.port}", cwd=tmp_path) as mp:
        mp.wait("Mode STABILIZE", 20)  # ArduCopter's boot mode, decoded by MAVProxy
        mp.cmd(f"wp load {path}")
        mp.wait("MISSION_ACK: TYPE_MISSION: ACCEPTED", 15)
        mp.cmd("mode guided")
        mp.wait("Mode GUIDED", 10)
        mp.cmd("arm throttle")
        mp.wait("ARMED", 10)  # the pre-arm checks (1 s after boot) have passed by now
        mp.cmd("mode auto")
        mp.wait(f"waypoint {last}", 60)  # the RTL item: the mission's end
        mp.wait("AP: landed, disarmed", 30)
        mp.wait("DISARMED", 10)
    # MAVProxy's "waypoint N" lines (a prompt like "AUTO> " may come first)
    reached = [int(m[1]) for line in mp.lines
               if (m := re.search(r"(?:^|> )waypoint (\d+)$", line.strip()))]
    assert reached == sorted(reached) and reached[-1] == last


def test_exported_plan_through_mavsdk_import_to_sim_vehicle(tmp_path):
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.mission_raw.mission_raw import MissionRaw

    path = export(tmp_path, "plan")
    ours = read_mission_file(path)
    port = free_port()
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        assert int(sdk.add_any_connection(f"udpin://127.0.0.1:{port}")) == 0
        with VehicleProcess("--speedup", "20", connect=f"udpout:127.0.0.1:{port}"):
            system = sdk.first_autopilot(15.0)
            assert system is not None, "MAVSDK did not discover the vehicle"
            raw = MissionRaw(system)
            data = raw.import_qgroundcontrol_mission(str(path))
            # PX4: plannedHomePosition is not an item, the rest is ours item for item
            assert len(data.mission_items) == len(ours.items) - 1
            for a, b in zip(ours.items[1:], data.mission_items, strict=True):
                assert (a.command, a.x, a.y, a.z) == (b.command, b.x, b.y, b.z)
            assert len(data.geofence_items) == 4 and len(data.rally_items) == 1
            raw.upload_mission(data.mission_items)
            raw.upload_geofence(data.geofence_items)
            raw.upload_rally_points(data.rally_items)
            back = raw.download_mission()
            assert [(b.command, b.x, b.y) for b in back] == \
                [(b.command, b.x, b.y) for b in data.mission_items]
            fence = raw.download_geofence()
            assert [(f.x, f.y) for f in fence] == [(f.x, f.y) for f in ours.fence]
            rally = raw.download_rallypoints()
            assert [(r.x, r.y) for r in rally] == [(r.x, r.y) for r in ours.rally]
    finally:
        sdk.destroy()


def test_run_with_three_stock_ardupilots_and_mavproxy_watching(tmp_path):
    port = free_port()
    watch = tmp_path / "watch.tlog"
    mavproxy = subprocess.Popen(
        [mavproxy_exe(), f"--master=udpin:127.0.0.1:{port}", f"--logfile={watch}",
         "--non-interactive", "--source-system=250"],
        stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
        cwd=tmp_path)
    out = tmp_path / "run"
    try:
        wait_for(lambda: udp_port_bound(port) or mavproxy.poll() is not None, 30,
                 "MAVProxy binding its port")
        assert mavproxy.poll() is None, "MAVProxy exited"
        # 20x, as SITL runs: a stock ArduPilot's Lua script samples while it hovers between
        # iterations (10 Hz of its time: 2,000 samples a wall second at 200x), and it gives up
        # an upload after 8 s of its time without an item (40 ms of wall time at 200x): much
        # faster, three of them outrun the station's answers to their item requests
        # (docs/experiments/2026-12-05-ardupilot-pause.md)
        run = subprocess.run(
            [sys.executable, "-m", "econdor", "run", str(DEMO), "--autopilot", "ardupilot",
             "--speedup", "20", "--forward", f"udpout:127.0.0.1:{port}", "--out", str(out),
             "--quiet"], capture_output=True, text=True, timeout=300, cwd=REPO)
        assert run.returncode == 0, run.stderr
    finally:
        stop(mavproxy)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["final_mae_db"] <= -20.0
    assert [v["mode"] for v in summary["fleet"]] == ["waypoints"] * 3
    assert all(v["tasks_flown"]["trace"] == 0 < v["tasks_flown"]["waypoints"]
               for v in summary["fleet"])
    assert [v["autopilot"] for v in summary["fleet"]] == ["ardupilot"] * 3
    fwd = summary["forward"]
    assert fwd["forwarded"] > 1000 and fwd["relayed"] == 0
    assert fwd["from_watcher"] == fwd["dropped"] > 0  # MAVProxy's requests went nowhere
    # the tlog MAVProxy wrote: every vehicle's heartbeat and position
    msgs = wait_for(lambda: watch.exists() and read_tlog(watch), 5, "MAVProxy's tlog")
    for sysid in (1, 2, 3):
        kinds = {m.get_type() for m in msgs if m.get_srcSystem() == sysid}
        assert {"HEARTBEAT", "GLOBAL_POSITION_INT"} <= kinds, (sysid, kinds)
