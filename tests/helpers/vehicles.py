"""Helpers for sim-vehicle tests: a tiny pymavlink GCS link and a process runner."""

from __future__ import annotations

import contextlib
import math
import os
import queue
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "missions" / "demo.yaml"


FREE_PORTS_FROM = 20000
"""Ports for tools that cannot take port 0 come from below the kernel's ephemeral range
(32768 and up on Linux): a port the kernel once handed out as free may be handed out again
to another socket (any process's client socket) before the tool binds it, and the tool then
fails with "Address already in use". Each pytest-xdist worker takes its own block of
:data:`FREE_PORTS_PER_WORKER`."""
FREE_PORTS_PER_WORKER = 1000
_next_port = iter(range(10**9))


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A free loopback port of this worker's block (:data:`FREE_PORTS_FROM`), not handed
    out before in this process (for tools that cannot take port 0)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    base = FREE_PORTS_FROM + FREE_PORTS_PER_WORKER * (int(worker) % 12 if worker.isdigit() else 0)
    for _ in range(FREE_PORTS_PER_WORKER):
        port = base + next(_next_port) % FREE_PORTS_PER_WORKER
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        return port
    raise RuntimeError(f"no free loopback port in {base}..{base + FREE_PORTS_PER_WORKER - 1}")


def udp_port_bound(port: int, host: str = "127.0.0.1") -> bool:
    """Someone has bound UDP ``host:port`` (binding it ourselves fails)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return True
    return False


def wait_for(cond: Callable[[], Any], timeout: float, what: str = "condition",
             interval: float = 0.02) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = cond()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


class GcsLink:
    """A UDP MAVLink endpoint (sysid 255, comp 190) using pymavlink only as a codec.

    ``GcsLink.listen()`` binds 127.0.0.1:0 (vehicles with ``udpout`` send to it);
    ``GcsLink.to(host, port)`` sends to a vehicle listening with ``udpin``.
    ``drop_tx`` (callable msg -> bool) lets a test lose some of its own sends.
    """

    def __init__(self, remote: tuple[str, int] | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.remote = remote
        self.mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.mav.robust_parsing = True
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.drop_tx: Callable[[Any], bool] | None = None
        self.received: list[Any] = []  # everything, in order (when keep=True)
        self.keep = False
        self._backlog: list[Any] = []
        self.heartbeat_s: float | None = None
        """Send the GCS HEARTBEAT this often (wall seconds) while polling, as a ground station
        does: a flight longer than the vehicle's GCS failsafe (5 s) needs it."""
        self._heartbeat_at = -math.inf

    @classmethod
    def listen(cls) -> GcsLink:
        return cls()

    @classmethod
    def to(cls, host: str, port: int) -> GcsLink:
        return cls((host, port))

    @property
    def port(self) -> int:
        return self.sock.getsockname()[1]

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> GcsLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def pack(self, msg: Any) -> bytes:
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        return bytes(data)

    def send(self, msg: Any) -> None:
        if self.drop_tx is not None and self.drop_tx(msg):
            return
        self.send_raw(self.pack(msg))

    def send_raw(self, data: bytes) -> None:
        assert self.remote is not None, "no vehicle address yet"
        self.sock.sendto(data, self.remote)

    def poll(self) -> list[Any]:
        """Receive whatever is there now (non-blocking-ish); the GCS heartbeat when due."""
        now = time.monotonic()
        if self.heartbeat_s is not None and self.remote is not None \
                and now - self._heartbeat_at >= self.heartbeat_s:
            self._heartbeat_at = now
            self.send(mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE,
                3))
        out: list[Any] = []
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (TimeoutError, BlockingIOError):
                break
            if self.remote is None:
                self.remote = addr
            for m in self.parser.parse_buffer(data) or []:
                if isinstance(m, mavlink.MAVLink_bad_data):
                    continue
                out.append(m)
            self.sock.settimeout(0.0)
        self.sock.settimeout(0.05)
        if self.keep:
            self.received.extend(out)
        return out

    def recv_match(self, mtype: str | tuple[str, ...], cond: Callable[[Any], bool] | None = None,
                   timeout: float = 5.0) -> Any:
        types = (mtype,) if isinstance(mtype, str) else mtype
        deadline = time.monotonic() + timeout
        while True:
            while self._backlog:
                m = self._backlog.pop(0)
                if m.get_type() in types and (cond is None or cond(m)):
                    return m
            if time.monotonic() > deadline:
                raise TimeoutError(f"no {types} within {timeout} s")
            self._backlog.extend(self.poll())

    def flush(self) -> None:
        self._backlog.clear()
        self.poll()
        self._backlog.clear()

    def command_long(self, target: int, cmd: int, *params: float, timeout: float = 5.0) -> Any:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(mavlink.MAVLink_command_long_message(target, 1, cmd, 0, *p))
        return self.recv_match("COMMAND_ACK", lambda m: m.command == cmd, timeout)

    # mission transfers (GCS side) ------------------------------------------------------

    def upload(self, target: int, items: list[Any], timeout: float = 10.0,
               mission_type: int = 0) -> int:
        """Upload MISSION_ITEM_INT messages; answer requests until the ACK; return its type."""
        self.send(mavlink.MAVLink_mission_count_message(target, 1, len(items), mission_type))
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = self.recv_match(("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"),
                                timeout=max(0.01, deadline - time.monotonic()))
            if m.get_type() == "MISSION_ACK":
                return m.type
            it = items[m.seq]
            it.seq = m.seq
            it.target_system, it.target_component = target, 1
            self.send(it)
        raise TimeoutError("upload did not finish")

    def download(self, target: int, legacy: bool = False, timeout: float = 10.0,
                 mission_type: int = 0) -> list[Any]:
        self.send(mavlink.MAVLink_mission_request_list_message(target, 1, mission_type))
        count = self.recv_match("MISSION_COUNT", timeout=timeout).count
        items = []
        want = "MISSION_ITEM" if legacy else "MISSION_ITEM_INT"
        for seq in range(count):
            req = (mavlink.MAVLink_mission_request_message if legacy
                   else mavlink.MAVLink_mission_request_int_message)
            self.send(req(target, 1, seq, mission_type))
            items.append(self.recv_match(want, _seq_is(seq), timeout=timeout))
        self.send(mavlink.MAVLink_mission_ack_message(target, 1, 0, mission_type))
        return items


def _seq_is(seq: int) -> Callable[[Any], bool]:
    """A ``recv_match`` condition: the message's ``seq`` is ``seq``."""
    return lambda m: bool(m.seq == seq)


def item_int(seq: int, command: int, lat: float = 0.0, lon: float = 0.0, alt: float = 0.0,
             p1: float = 0.0, p2: float = 0.0, p3: float = 0.0, p4: float = 0.0,
             frame: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, current: int = 0,
             target: int = 1) -> Any:
    return mavlink.MAVLink_mission_item_int_message(
        target, 1, seq, frame, command, current, 1, p1, p2, p3, p4,
        int(round(lat * 1e7)), int(round(lon * 1e7)), alt, 0)


def sim_vehicle_cmd() -> list[str]:
    exe = shutil.which("sim-vehicle", path=os.path.dirname(sys.executable))
    return [exe] if exe else [sys.executable, "-m", "sim_vehicle.cli"]


class VehicleProcess:
    """Run ``sim-vehicle`` as a subprocess; logs are kept and shown only on failure.

    Use as a context manager; ``ready_address`` is parsed from the vehicle's
    ``ready on KIND:HOST:PORT`` line (so ``tcpin:127.0.0.1:0`` works). ``timeout`` bounds
    the wait for that line: start-up (Python, numpy, numba's cached tracer) is no test's
    claim, and on a loaded 2-core machine it took over 30 s.
    """

    def __init__(self, *args: str, mission: Path | str = DEMO, sysid: int = 1,
                 connect: str = "udpout:127.0.0.1:14550", extra: list[str] | None = None,
                 timeout: float = 60.0) -> None:
        self.log = tempfile.NamedTemporaryFile(  # noqa: SIM115 - closed in __exit__
            "w+b", prefix="sim-vehicle-", suffix=".log", delete=False)
        self.cmd = [*sim_vehicle_cmd(), "--sysid", str(sysid), "--mission", str(mission),
                    "--connect", connect, *args, *(extra or [])]
        self.timeout = timeout
        self.proc: subprocess.Popen[bytes] | None = None
        self.ready_address: tuple[str, str, int] | None = None
        self.returncode: int | None = None

    def start(self) -> VehicleProcess:
        self.proc = subprocess.Popen(self.cmd, stdout=self.log, stderr=subprocess.STDOUT,
                                     cwd=REPO)
        pattern = re.compile(rb"ready on (\w+):([\d.]+):(\d+)")

        def ready() -> bool:
            assert self.proc is not None
            if self.proc.poll() is not None:
                raise RuntimeError(f"sim-vehicle exited with {self.proc.returncode}:\n"
                                   + self.output())
            m = pattern.search(Path(self.log.name).read_bytes())
            if m:
                self.ready_address = (m[1].decode(), m[2].decode(), int(m[3]))
            return m is not None

        try:
            wait_for(ready, self.timeout, "sim-vehicle ready line")
        except BaseException:
            self.stop()
            print(self.output(), file=sys.stderr)
            raise
        return self

    @property
    def port(self) -> int:
        assert self.ready_address is not None
        return self.ready_address[2]

    def output(self) -> str:
        with contextlib.suppress(OSError):
            return Path(self.log.name).read_text(errors="replace")
        return ""

    def stop(self, timeout: float = 30.0) -> int | None:
        """terminate -> wait -> kill; returns the exit status. A vehicle that exits on
        SIGTERM does so at once on an idle machine; ``timeout`` leaves room for a loaded one
        (at load 17 on 2 cores, 5 s was not enough) before the kill."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.returncode = self.proc.returncode
        return self.returncode

    def __enter__(self) -> VehicleProcess:
        return self.start()

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        self.stop()
        if exc_type is not None:
            print(f"--- sim-vehicle log ({' '.join(self.cmd)}) ---\n{self.output()}",
                  file=sys.stderr)
        self.log.close()
        with contextlib.suppress(OSError):
            os.unlink(self.log.name)


@contextlib.contextmanager
def inproc_vehicle(mission_path: Path | str = DEMO, sysid: int = 1, speedup: float = 50.0,
                   connect: str = "udpin:127.0.0.1:0", autopilot: str = "px4",
                   companion: bool = True, **overrides: Any) -> Iterator[Any]:
    """A MavlinkVehicle on a thread, listening on an ephemeral loopback port (by default
    PX4 habits with the tracer on board)."""
    from econdor_gcs.config import load_mission
    from sim_vehicle.mavlink_vehicle import AUTOPILOTS, MavlinkVehicle

    mission = load_mission(mission_path)
    v = MavlinkVehicle.from_mission(mission, sysid=sysid, connect=connect, speedup=speedup,
                                    autopilot=AUTOPILOTS[autopilot], companion=companion,
                                    **overrides)
    v.start()
    try:
        yield v
    finally:
        v.stop()


def mavproxy_exe() -> str:
    exe = shutil.which("mavproxy.py", path=os.path.dirname(sys.executable))
    if exe is None:
        raise RuntimeError("mavproxy.py not installed in this environment (pip install MAVProxy)")
    return exe


class LineReader:
    """Collect a process's output lines on a thread; wait for a line containing text."""

    def __init__(self, stream) -> None:
        self.lines: list[str] = []
        self.q: queue.Queue[str] = queue.Queue()
        self.t = threading.Thread(target=self._run, args=(stream,), daemon=True)
        self.t.start()

    def _run(self, stream) -> None:
        for raw in iter(stream.readline, b""):
            line = raw.decode(errors="replace").rstrip()
            self.lines.append(line)
            self.q.put(line)

    def wait(self, text: str, timeout: float) -> str:
        deadline = time.monotonic() + timeout
        while True:
            try:
                line = self.q.get(timeout=max(0.01, deadline - time.monotonic()))
            except queue.Empty:
                raise TimeoutError(f"MAVProxy never printed {text!r}:\n"
                                   + "\n".join(self.lines[-40:])) from None
            if text in line:
                return line


class MavproxyShell:
    """MAVProxy on a master, driven over its command line (stdin) with waits on its output.

    MAVProxy's --non-interactive mode runs --cmd only once at start-up, before the link is
    up; a pipe lets a test wait for each step. Always stopped on exit (EOF, then terminate,
    then kill); its output is kept in ``lines``.
    """

    def __init__(self, master: str, cwd: Path, source_system: int = 255) -> None:
        self.proc = subprocess.Popen(
            [mavproxy_exe(), f"--master={master}", "--no-state",
             f"--source-system={source_system}", "--source-component=190"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=cwd)
        assert self.proc.stdout is not None
        self.reader = LineReader(self.proc.stdout)

    @property
    def lines(self) -> list[str]:
        return self.reader.lines

    def cmd(self, text: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write((text + "\n").encode())
        self.proc.stdin.flush()

    def wait(self, text: str, timeout: float) -> str:
        return self.reader.wait(text, timeout)

    def close(self) -> None:
        p = self.proc
        if p.stdin is not None and not p.stdin.closed:
            with contextlib.suppress(BrokenPipeError):
                p.stdin.close()  # EOF on its command line makes MAVProxy quit
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            p.terminate()
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        if p.stdout is not None:
            p.stdout.close()

    def __enter__(self) -> MavproxyShell:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
