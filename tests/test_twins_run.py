"""Issue 34 point 4 in a whole run: a twin of the flying vehicle's system id and a stranger
send to the station's port; the run completes with the real vehicle alone, and both are
reported by address in the run log and in ``summary.json``."""

from __future__ import annotations

import json
import socket
import threading

import pytest
import yaml
from vehicle_helpers import DEMO, inproc_vehicle

from econdor_gcs.app.run import run_mission
from econdor_gcs.config import load_mission
from econdor_gcs.link.codec import Codec, mavlink

pytestmark = pytest.mark.e2e


def test_a_twin_and_a_stranger_are_refused_and_reported(tmp_path):
    doc = yaml.safe_load(DEMO.read_text())
    doc["vehicles"].update(count=1, speedup=100)
    doc["algorithm"].update(max_iterations=1, min_iterations=1)
    path = tmp_path / "one.yaml"
    path.write_text(yaml.safe_dump(doc))
    mission = load_mission(path)
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    out = tmp_path / "run"
    stop = threading.Event()
    impostor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    impostor.bind(("127.0.0.1", 0))

    def twin_and_stranger() -> None:
        log = out / "log.jsonl"
        # the real vehicle first: wait until the station has discovered it
        while not stop.is_set():
            if log.exists() and "discovered" in log.read_text():
                break
            stop.wait(0.02)
        hb = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR,
                                               mavlink.MAV_AUTOPILOT_PX4, 0, 0, 3, 3)
        twin, stranger = Codec(1, 1), Codec(9, 1)
        while not stop.is_set():
            for codec in (twin, stranger):
                impostor.sendto(codec.encode(hb), ("127.0.0.1", port))
            stop.wait(0.1)

    sender = threading.Thread(target=twin_and_stranger, daemon=True)
    try:
        with inproc_vehicle(path, connect=f"udpout:127.0.0.1:{port}", speedup=100.0):
            sender.start()
            summary = run_mission(mission, out, connect=f"udpin:127.0.0.1:{port}",
                                  timeout_s=30.0, figures=False, mission_path=path)
    finally:
        stop.set()
        sender.join(5)
        impostor.close()
    kinds = {(c["kind"], c["sysid"]) for c in summary["link_conflicts"]}
    assert kinds == {("twin", 1), ("foreign", 9)}
    on_disk = json.loads((out / "summary.json").read_text())["link_conflicts"]
    assert on_disk == summary["link_conflicts"]
    twin = next(c for c in on_disk if c["kind"] == "twin")
    assert twin["address"].startswith("127.0.0.1:") and twin["address"] != twin["known_address"]
    assert twin["first_message"] == "HEARTBEAT" and twin["messages"] >= 1
    log = (out / "log.jsonl").read_text()
    assert f"refused a second source of its autopilot at {twin['address']}" in log
    assert "vehicle 9" in log and "not in this run's fleet" in log
    assert summary["sysids"] == [1] and summary["iterations"] == 1
