"""sim-vehicle against ordinary MAVLink tools: MAVProxy 1.8.x and MAVSDK-Python 4.x."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from vehicle_helpers import DEMO, MavproxyShell, VehicleProcess, free_port, wait_for

from econdor_gcs.config import load_mission

pytestmark = pytest.mark.interop

ORIGIN = load_mission(DEMO).origin

WPL = """QGC WPL 110
0\t1\t0\t16\t0\t0\t0\t0\t{home_lat:.7f}\t{home_lon:.7f}\t488.000000\t1
1\t0\t3\t22\t0\t0\t0\t0\t0.000000\t0.000000\t20.000000\t1
2\t0\t3\t16\t0\t0\t0\t0\t47.3981234\t8.5459876\t20.000000\t1
3\t0\t3\t31000\t42.500000\t10.000000\t0.000000\t3.000000\t47.3980011\t8.5460022\t25.000000\t1
4\t0\t3\t178\t1.000000\t6.000000\t-1.000000\t0.000000\t0.000000\t0.000000\t0.000000\t1
5\t0\t0\t16\t0\t0\t0\t0\t47.3979000\t8.5457000\t510.500000\t1
6\t0\t3\t20\t0\t0\t0\t0\t0.000000\t0.000000\t0.000000\t1
"""


def parse_wpl(path: Path) -> list[list[float]]:
    lines = path.read_text().splitlines()
    assert lines[0].strip() == "QGC WPL 110"
    return [[float(v) for v in line.split()] for line in lines[1:] if line.strip()]


def test_mavproxy_wp_load_and_save_round_trip(tmp_path):
    src = tmp_path / "in.waypoints"
    src.write_text(WPL.format(home_lat=ORIGIN.lat_deg, home_lon=ORIGIN.lon_deg))
    out = tmp_path / "out.waypoints"
    with VehicleProcess("--speedup", "10", "--companion", connect="tcpin:127.0.0.1:0") as veh, \
            MavproxyShell(f"tcp:127.0.0.1:{veh.port}", cwd=tmp_path) as mp:
        mp.wait("Mode ", 20)  # heartbeat seen, flight mode decoded (PX4 encoding)
        mp.cmd(f"wp load {src}")
        mp.wait("MISSION_ACK: TYPE_MISSION: ACCEPTED", 15)
        mp.cmd(f"wp save {out}")
        mp.wait("Saved 7 waypoints", 15)
    a, b = parse_wpl(src), parse_wpl(out)
    assert len(a) == len(b) == 7
    for ra, rb in zip(a, b, strict=True):
        # seq current frame command p1..p4 x y z autocontinue
        assert ra[:4] == rb[:4] and ra[11] == rb[11], (ra, rb)
        assert rb[4:8] == pytest.approx(ra[4:8], abs=1e-6)
        # MAVProxy writes lat/lon with %f (6 decimals): half a unit of the last digit
        assert rb[8:10] == pytest.approx(ra[8:10], abs=5.1e-7)
        assert rb[10] == pytest.approx(ra[10], abs=1e-4)


def test_mavsdk_mission_raw_upload_fly_download():
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.mission_raw.mission_raw import MissionItem, MissionRaw
    from mavsdk.plugins.telemetry import Telemetry

    port = free_port()
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        assert int(sdk.add_any_connection(f"udpin://127.0.0.1:{port}")) == 0  # SUCCESS
        with VehicleProcess("--speedup", "20", connect=f"udpout:127.0.0.1:{port}"):
            system = sdk.first_autopilot(15.0)
            assert system is not None, "MAVSDK did not discover the vehicle"
            mission_raw, action, telemetry = MissionRaw(system), Action(system), Telemetry(system)
            items = []
            for i, (x, y) in enumerate([(20, 20), (45, 60), (75, 35), (30, 10)]):
                lat, lon, _ = ORIGIN.to_global(x, y)
                items.append(MissionItem(i, 6, 16, int(i == 0), 1, 0.0, 1.0, 0.0, float("nan"),
                                         int(round(lat * 1e7)), int(round(lon * 1e7)),
                                         15.0 + i, 0))
            mission_raw.upload_mission(items)
            wait_for(telemetry.health_all_ok, 10, "MAVSDK health all ok")
            progress: list[tuple[int, int]] = []
            mission_raw.subscribe_mission_progress(
                lambda p, *_: progress.append((p.current, p.total)))
            action.arm()
            wait_for(telemetry.armed, 5, "armed")
            mission_raw.start_mission()
            wait_for(mission_raw.is_mission_finished, 60, "mission finished")
            wait_for(lambda: progress and progress[-1] == (4, 4), 5, "final progress")
            assert [c for c, _ in progress] == sorted(c for c, _ in progress)
            back = mission_raw.download_mission()
            assert len(back) == len(items)
            for a, b in zip(items, back, strict=True):
                for f in ("seq", "frame", "command", "current", "autocontinue", "param1",
                          "param2", "param3", "x", "y", "z", "mission_type"):
                    assert getattr(a, f) == getattr(b, f), f
                assert math.isnan(b.param4)
            assert sum(it.current for it in back) == 1
    finally:
        sdk.destroy()
