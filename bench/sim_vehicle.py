"""Benchmark: how fast and how much can N ``sim-vehicle`` processes deliver?

For each vehicle count (default 1, 5, 20) and requested speedup (default 20x, 100x) it starts
N ``sim-vehicle`` processes (udpout to one listening socket), uploads a long lawnmower +
trace mission to each (pymavlink codec, routed by system id), arms and starts them, and then
measures for a window of wall time:

* achieved sim-time speedup per vehicle: delta time_boot_ms of its GLOBAL_POSITION_INT over
  delta wall time at the listening socket (median / min over vehicles);
* telemetry delivered: GLOBAL_POSITION_INT and NAMED_VALUE_FLOAT("FIELD") per wall second and
  per sim second (per vehicle, median);
* samples lost: FIELD samples that never arrived, from the gaps in their ``time_boot_ms``
  (the vehicle samples every ``1 / sample_rate_hz`` of sim time, 100 ms here, and sends
  each one; a step of 300 ms means two samples were lost), summed over the vehicles;
* CPU%: utime+stime of the vehicle processes from /proc over the window (sum over vehicles,
  and per vehicle), plus the bench's own receiver.

The receiver decodes only MAVLink 2 headers (and the first payload word of
GLOBAL_POSITION_INT) so that it is not itself the bottleneck.

    python bench/sim_vehicle.py [--quick] [--counts 1,5,20] [--speedups 20,100] [--window 6]
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from econdor_gcs.config import load_mission  # noqa: E402

MISSION = REPO / "missions" / "demo.yaml"
ID_GPI = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
ID_NVF = mavlink.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT
ID_HB = mavlink.MAVLINK_MSG_ID_HEARTBEAT
CLK = os.sysconf("SC_CLK_TCK")
SAMPLE_MS = 100  # the demo mission's vehicles sample at 10 Hz of sim time
WANTED = {ID_HB, mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_INT, mavlink.MAVLINK_MSG_ID_MISSION_ACK,
          mavlink.MAVLINK_MSG_ID_COMMAND_ACK}


def cpu_s(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / CLK


class Router:
    """One UDP socket; full pymavlink decode only when asked, fast header counting otherwise."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 24)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.addr: dict[int, tuple[str, int]] = {}
        self.mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True

    @property
    def port(self) -> int:
        return self.sock.getsockname()[1]

    def send(self, sysid: int, msg) -> None:
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.sock.sendto(data, self.addr[sysid])

    def recv_decoded(self, timeout: float) -> list:
        out = []
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                data, addr = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            if len(data) >= 10 and data[0] == 0xFD:
                # decode only what the set-up needs; telemetry is skipped unparsed
                self.addr[data[5]] = addr
                if (data[7] | (data[8] << 8) | (data[9] << 16)) not in WANTED:
                    continue
            for m in self.parser.parse_buffer(data) or []:
                if isinstance(m, mavlink.MAVLink_bad_data):
                    continue
                self.addr[m.get_srcSystem()] = addr
                out.append(m)
            if out:
                return out
        return out

    def wait(self, sysid: int, mtype: str, cond=lambda m: True, timeout: float = 10.0):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for m in self.recv_decoded(0.1):
                if m.get_srcSystem() == sysid and m.get_type() == mtype and cond(m):
                    return m
        raise TimeoutError(f"vehicle {sysid}: no {mtype}")


def mission_items(origin, sysid: int, field) -> list:
    """A long mission: takeoff, 5 x lawnmower (10 m spacing), 2 trace items (~6 km)."""
    def item(seq: int, cmd: int, x: float = 0.0, y: float = 0.0, alt: float = 20.0,
             p1: float = 0.0, p2: float = 0.0, p3: float = 0.0, p4: float = 0.0) -> Any:
        lat, lon, _ = origin.to_global(x, y) if (x or y) else (0.0, 0.0, 0.0)
        return mavlink.MAVLink_mission_item_int_message(
            sysid, 1, seq, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, cmd, int(seq == 0), 1,
            p1, p2, p3, p4, int(round(lat * 1e7)), int(round(lon * 1e7)), alt, 0)

    pts = []
    for _rep in range(5):
        for i, col in enumerate(range(5, 100, 10)):
            ys = (5, 95) if i % 2 == 0 else (95, 5)
            pts += [(float(col), float(ys[0])), (float(col), float(ys[1]))]
    items = [item(0, mavlink.MAV_CMD_NAV_TAKEOFF)]
    for x, y in pts:
        items.append(item(len(items), mavlink.MAV_CMD_NAV_WAYPOINT, x, y))
    for pid, (x, y) in enumerate([(30.0, 30.0), (70.0, 60.0)]):
        items.append(item(len(items), 31000, x, y, p1=float(field(x, y)), p2=10, p3=300,
                          p4=pid))
    return items


def upload(r: Router, sysid: int, items: list, attempts: int = 3) -> None:
    for attempt in range(attempts):
        try:
            return _upload(r, sysid, items)
        except RuntimeError:
            if attempt == attempts - 1:
                raise


def _upload(r: Router, sysid: int, items: list) -> None:
    r.send(sysid, mavlink.MAVLink_mission_count_message(sysid, 1, len(items), 0))
    end = time.monotonic() + 30
    while time.monotonic() < end:
        for m in r.recv_decoded(0.1):
            if m.get_srcSystem() != sysid:
                continue
            if m.get_type() == "MISSION_REQUEST_INT":
                r.send(sysid, items[m.seq])
            elif m.get_type() == "MISSION_ACK":
                if m.type != 0:
                    raise RuntimeError(f"vehicle {sysid}: upload rejected ({m.type})")
                return
    raise TimeoutError(f"vehicle {sysid}: upload timed out")


def command(r: Router, sysid: int, cmd: int, *p: float) -> None:
    params = list(p) + [0.0] * (7 - len(p))
    r.send(sysid, mavlink.MAVLink_command_long_message(sysid, 1, cmd, 0, *params))
    ack = r.wait(sysid, "COMMAND_ACK", lambda m: m.command == cmd)
    if ack.result != 0:
        raise RuntimeError(f"vehicle {sysid}: command {cmd} -> {ack.result}")


def measure(r: Router, sysids: list[int], pids: list[int], window: float) -> dict:
    first: dict[int, tuple[float, int]] = {}
    last: dict[int, tuple[float, int]] = {}
    n_gpi = dict.fromkeys(sysids, 0)
    n_nvf = dict.fromkeys(sysids, 0)
    last_sample_ms: dict[int, int] = {}
    lost = 0
    # drop what queued up before the window, or its arrival times would be stale
    r.sock.setblocking(False)
    while True:
        try:
            r.sock.recv(65535)
        except BlockingIOError:
            break
    cpu0 = [cpu_s(p) for p in pids]
    self0 = time.process_time()
    t0 = time.monotonic()
    r.sock.settimeout(0.02)
    hdr = struct.Struct("<BBBBBBBHB")
    while True:
        now = time.monotonic()
        if now - t0 >= window:
            break
        try:
            data = r.sock.recv(65535)
        except TimeoutError:
            continue
        if len(data) < 14 or data[0] != 0xFD:
            continue
        _, _, _, _, _, sysid, _, lo, hi = hdr.unpack_from(data)
        msgid = lo | (hi << 16)
        if sysid not in n_gpi:
            continue
        if msgid == ID_GPI:
            n_gpi[sysid] += 1
            tb = struct.unpack_from("<I", data + b"\0\0\0\0", 10)[0]
            if sysid not in first:
                first[sysid] = (now, tb)
            last[sysid] = (now, tb)
        elif msgid == ID_NVF and data[18:23] == b"FIELD":
            n_nvf[sysid] += 1
            tb = struct.unpack_from("<I", data, 10)[0]
            if sysid in last_sample_ms:
                lost += max(0, round((tb - last_sample_ms[sysid]) / SAMPLE_MS) - 1)
            last_sample_ms[sysid] = tb
    wall = time.monotonic() - t0
    cpu = [cpu_s(p) - c for p, c in zip(pids, cpu0, strict=True)]
    speed, gpi_w, nvf_w, gpi_s, nvf_s = [], [], [], [], []
    for s in sysids:
        if s in first and last[s][0] > first[s][0]:
            dsim = (last[s][1] - first[s][1]) / 1000.0
            speed.append(dsim / (last[s][0] - first[s][0]))
            gpi_s.append(n_gpi[s] / dsim if dsim > 0 else 0.0)
            nvf_s.append(n_nvf[s] / dsim if dsim > 0 else 0.0)
        else:
            speed.append(0.0)
        gpi_w.append(n_gpi[s] / wall)
        nvf_w.append(n_nvf[s] / wall)
    return {
        "speed_med": statistics.median(speed), "speed_min": min(speed),
        "gpi_wall": statistics.median(gpi_w), "nvf_wall": statistics.median(nvf_w),
        "gpi_sim": statistics.median(gpi_s) if gpi_s else 0.0,
        "nvf_sim": statistics.median(nvf_s) if nvf_s else 0.0,
        "cpu_total": 100 * sum(cpu) / wall, "cpu_per": 100 * statistics.median(cpu) / wall,
        "bench_cpu": 100 * (time.process_time() - self0) / wall,
        "lost": lost, "samples": sum(n_nvf.values()),
    }


def run_config(count: int, speedup: float, window: float) -> dict:
    mission = load_mission(MISSION)
    field = mission.build_field()
    r = Router()
    exe = [sys.executable, "-m", "sim_vehicle.cli"]
    procs = [subprocess.Popen([*exe, "--sysid", str(i + 1), "--mission", str(MISSION),
                               "--speedup", str(speedup), "--companion",
                               "--connect", f"udpout:127.0.0.1:{r.port}"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO)
             for i in range(count)]
    sysids = list(range(1, count + 1))
    try:
        for s in sysids:
            r.wait(s, "HEARTBEAT", timeout=120)  # 20 cold starts on a small machine: slow
        for s in sysids:  # all uploads first, then start them together
            upload(r, s, mission_items(mission.origin, s, field))
        for s in sysids:
            command(r, s, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            command(r, s, mavlink.MAV_CMD_MISSION_START)
        time.sleep(0.3)  # let the takeoffs start (not part of the window)
        return measure(r, sysids, [p.pid for p in procs], window)
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        r.sock.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="counts 1,5; speedups 20,100; 2 s")
    ap.add_argument("--counts", default=None)
    ap.add_argument("--speedups", default="20,50,100")
    ap.add_argument("--window", type=float, default=None, help="measurement window, wall s")
    a = ap.parse_args()
    counts = [int(c) for c in (a.counts or ("1,5" if a.quick else "1,5,20")).split(",")]
    speedups = [float(s) for s in a.speedups.split(",")]
    window = a.window or (2.0 if a.quick else 5.0)
    print(f"sim-vehicle bench: {os.cpu_count()} CPUs, window {window:g} s wall, "
          f"demo mission (10 Hz samples)")
    print(f"{'N':>3} {'req x':>6} {'got x med':>9} {'got x min':>9} {'GPI/s wall':>10} "
          f"{'FIELD/s wall':>12} {'GPI/s sim':>9} {'FIELD/s sim':>11} {'CPU% sum':>8} "
          f"{'CPU%/veh':>8} {'bench CPU%':>10} {'samples':>8} {'lost':>5}")
    for n in counts:
        for s in speedups:
            res = run_config(n, s, window)
            print(f"{n:>3} {s:>6g} {res['speed_med']:>9.1f} {res['speed_min']:>9.1f} "
                  f"{res['gpi_wall']:>10.0f} {res['nvf_wall']:>12.0f} {res['gpi_sim']:>9.1f} "
                  f"{res['nvf_sim']:>11.1f} {res['cpu_total']:>8.0f} {res['cpu_per']:>8.0f} "
                  f"{res['bench_cpu']:>10.0f} {res['samples']:>8} {res['lost']:>5}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
