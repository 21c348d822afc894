"""sim-vehicle as a process: its command line's errors, a fleet on ``udpout``, and its exit on
SIGTERM and SIGINT."""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

from tests.helpers.vehicles import DEMO, GcsLink, VehicleProcess, sim_vehicle_cmd


def test_cli_errors_are_one_line(tmp_path):
    r = subprocess.run([*sim_vehicle_cmd(), "--mission", str(tmp_path / "nope.yaml")],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text("field: {model: paper}\nvehicles: {speed_mps: -1}\n")
    r = subprocess.run([*sim_vehicle_cmd(), "--mission", str(bad)],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and "vehicles.speed_mps" in r.stderr and r.stderr.count("\n") == 1
    r = subprocess.run([*sim_vehicle_cmd(), "--mission", str(DEMO), "--connect", "udp:x"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and "bad endpoint" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([*sim_vehicle_cmd(), "--mission", str(DEMO), "--speedup", "fast"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_process_udpout_count_and_sigterm():
    with GcsLink.listen() as gcs, VehicleProcess(
            "--count", "2", "--sysid-base", "5", "--speedup", "20",
            connect=f"udpout:127.0.0.1:{gcs.port}") as proc:
        seen = set()
        deadline = time.monotonic() + 10
        while seen != {5, 6} and time.monotonic() < deadline:
            for m in gcs.poll():
                if m.get_type() == "HEARTBEAT":
                    seen.add(m.get_srcSystem())
        assert seen == {5, 6}
        # the GCS can talk back through the udpout vehicle's source address
        gcs.remote = None
        gcs.recv_match("HEARTBEAT", lambda m: m.get_srcSystem() == 5)
        gcs.flush()
        t0 = time.monotonic()
        gpi0 = gcs.recv_match("GLOBAL_POSITION_INT", lambda m: m.get_srcSystem() == 6)
        gpi1 = gcs.recv_match("GLOBAL_POSITION_INT",
                              lambda m: m.get_srcSystem() == 6 and m.time_boot_ms
                              > gpi0.time_boot_ms + 20000, timeout=10)
        rate = (gpi1.time_boot_ms - gpi0.time_boot_ms) / 1000 / (time.monotonic() - t0)
        assert 10 < rate < 30  # sim time runs ~20x wall time
        assert proc.stop() == 0
        # each child's exit line (speed-up and counters; the log is gone after the block)
        assert proc.output().count("stopped after") == 2, proc.output()


def test_process_sigint_exit_zero():
    with GcsLink.listen() as gcs:
        p = VehicleProcess(connect=f"udpout:127.0.0.1:{gcs.port}").start()
        gcs.recv_match("HEARTBEAT", timeout=10)
        assert p.proc is not None
        p.proc.send_signal(signal.SIGINT)
        assert p.proc.wait(10) == 0
        assert "Traceback" not in p.output() and "stopped after" in p.output()
        p.stop()
    Path(p.log.name).unlink(missing_ok=True)
