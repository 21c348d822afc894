"""ArduPilot SITL for the tests: one real ArduCopter per :class:`Sitl`, started and stopped by
its pid, in a fresh working directory (its own eeprom and logs) with ports chosen free.

The binary is ``<repo>/../shared/sitl/arducopter`` (``ECONDOR_SITL`` overrides it); tests
that need it are marked ``sitl`` and skip with the reason when it is absent. A SITL's own log
is shown only when the test using it fails (:meth:`Sitl.explain`, added to the error).
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from econdor_gcs.link.tlog import read_tlog

REPO = Path(__file__).resolve().parents[2]
SITL_ENV = "ECONDOR_SITL"
HOME = (47.397742, 8.545594, 488.0)
"""The demo missions' origin: SITL's home is the mission's."""


def sitl_binary() -> Path | None:
    env = os.environ.get(SITL_ENV)
    path = Path(env) if env else REPO.parent / "shared" / "sitl" / "arducopter"
    return path if path.is_file() and os.access(path, os.X_OK) else None


def sitl_defaults() -> Path:
    binary = sitl_binary()
    assert binary is not None
    return binary.parent / "copter.parm"


requires_sitl = pytest.mark.skipif(
    sitl_binary() is None,
    reason=f"no ArduPilot SITL: {REPO.parent / 'shared' / 'sitl' / 'arducopter'} is absent "
           f"(set {SITL_ENV} to an arducopter SITL binary)")


def _free(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


_next_base = [30000 + (os.getpid() * 40) % 20000]


def free_base_port() -> tuple[int, int]:
    """A base TCP port with base, base + 2, base + 3 free (SERIAL0-2) and a free UDP port
    for SITL's RC input. Ports are handed out in steps from a per-process start, so two
    SITLs of one test session never pick the same even before they bind."""
    for _ in range(2000):
        base = _next_base[0]
        _next_base[0] = 30000 + (base - 30000 + 10) % 20000
        if all(_free(p, socket.SOCK_STREAM) for p in (base, base + 2, base + 3)) and \
                _free(base + 5, socket.SOCK_DGRAM):
            return base, base + 5
    raise RuntimeError("no free ports for SITL")


class Sitl:
    """One ArduCopter SITL process.

    ``serial0`` is where its first MAVLink port goes: ``None`` for a TCP server on
    :attr:`port` (it starts its clock when the first client connects), or a SITL device
    string such as ``udpclient:127.0.0.1:14550`` (it starts at once and sends there).
    ``scripts`` are Lua scripts (name -> text) for its ``scripts/`` directory (scripting is
    then enabled); ``params`` are added to ArduPilot's default copter parameters.
    """

    def __init__(self, workdir: Path, *, sysid: int = 1, speedup: float = 10.0,
                 serial0: str | None = None, scripts: dict[str, str] | None = None,
                 params: dict[str, float] | None = None,
                 home: tuple[float, float, float] = HOME) -> None:
        binary = sitl_binary()
        if binary is None:
            pytest.skip("no ArduPilot SITL")
        self.binary = binary
        self.workdir = workdir
        self.sysid = sysid
        self.speedup = speedup
        self.serial0 = serial0
        self.scripts = scripts or {}
        self.params = dict(params or {})
        self.home = home
        self.port, self.rc_port = free_base_port()
        self.proc: subprocess.Popen[bytes] | None = None
        self.log_path = workdir / "sitl.log"

    @property
    def port2(self) -> int:
        """SERIAL1: a second TCP MAVLink port (a watcher)."""
        return self.port + 2

    def start(self) -> Sitl:
        self.workdir.mkdir(parents=True, exist_ok=True)
        params = dict(self.params)
        if self.scripts:
            params.setdefault("SCR_ENABLE", 1)
            params.setdefault("SCR_HEAP_SIZE", 300000)
            params.setdefault("SCR_VM_I_COUNT", 100000)
            (self.workdir / "scripts").mkdir(exist_ok=True)
            for name, text in self.scripts.items():
                (self.workdir / "scripts" / name).write_text(text)
        defaults = self.workdir / "defaults.parm"
        defaults.write_text(sitl_defaults().read_text() + "\n" + "".join(
            f"{k} {v}\n" for k, v in params.items()))
        lat, lon, alt = self.home
        cmd = [str(self.binary), "--model", "+", "--speedup", f"{self.speedup:g}",
               "--defaults", str(defaults), "--base-port", str(self.port),
               "--rc-in-port", str(self.rc_port), "--home", f"{lat},{lon},{alt},0",
               "--sysid", str(self.sysid)]
        if self.serial0 is not None:
            cmd += ["--serial0", self.serial0]
        log = self.log_path.open("wb")
        try:
            self.proc = subprocess.Popen(cmd, cwd=self.workdir, stdout=log,
                                         stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        finally:
            log.close()
        return self

    def wait_ready(self, timeout_s: float = 20.0) -> Sitl:
        """Until its MAVLink port listens (TCP) or it has started (``serial0`` given)."""
        deadline = time.monotonic() + timeout_s
        want = b"Waiting for connection" if self.serial0 is None else b"Starting SITL input"
        while True:
            assert self.proc is not None
            if self.proc.poll() is not None:
                raise RuntimeError(f"SITL exited with {self.proc.returncode}{self.explain()}")
            if want in self.log_path.read_bytes():
                return self
            if time.monotonic() > deadline:
                raise TimeoutError(f"SITL not ready within {timeout_s:g} s{self.explain()}")
            time.sleep(0.05)

    def stop(self) -> None:
        """Terminate it by its pid (then kill); idempotent."""
        proc, self.proc = self.proc, None
        if proc is None or proc.poll() is not None:
            return
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)

    def explain(self) -> str:
        """The tail of its log, for a failure message."""
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return f"\n--- SITL {self.sysid} log ({self.log_path}) ---\n{text[-3000:]}"

    def __enter__(self) -> Sitl:
        return self.start().wait_ready()

    def __exit__(self, *exc: object) -> None:
        self.stop()


@contextlib.contextmanager
def sitls(*vehicles: Sitl) -> Iterator[list[Sitl]]:
    """Start them all, stop them all; a failure inside shows their logs."""
    started: list[Sitl] = []
    try:
        for v in vehicles:
            started.append(v.start())
        for v in started:
            v.wait_ready()
        yield started
    except BaseException as exc:
        for v in started:
            exc.add_note(v.explain())
        raise
    finally:
        for v in started:
            v.stop()


class Watch:
    """A second MAVLink client of a SITL (its SERIAL1 TCP port), as a person watching: asks
    for telemetry, keeps every message, and waits on state with a typed timeout that says
    what it saw (ArduPilot autotest's ``wait_*``)."""

    def __init__(self, port: int, sysid: int = 1) -> None:
        import threading

        from econdor_gcs.link.codec import Codec, Parser, mavlink

        self.sysid = sysid
        self.mavlink = mavlink
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.codec = Codec(250, 190)
        self.parser = Parser()
        self.messages: list = []
        self._lock = threading.Lock()
        self._stop = False
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()
        self.send(mavlink.MAVLink_request_data_stream_message(
            sysid, 1, mavlink.MAV_DATA_STREAM_ALL, 4, 1))

    def send(self, msg) -> None:
        self.sock.sendall(self.codec.encode(msg))

    def _read(self) -> None:
        self.sock.settimeout(0.2)
        while not self._stop:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            msgs = self.parser.feed(data, "sitl")
            with self._lock:
                self.messages.extend(m for m in msgs if m.get_srcSystem() == self.sysid)

    def of(self, kind: str) -> list:
        with self._lock:
            return [m for m in self.messages if m.get_type() == kind]

    def wait(self, cond, timeout_s: float, what: str):
        """Until ``cond(self)`` is true (returns it); TimeoutError with the last heartbeat
        and texts otherwise."""
        deadline = time.monotonic() + timeout_s
        while True:
            got = cond(self)
            if got:
                return got
            if time.monotonic() > deadline:
                hb = self.of("HEARTBEAT")[-1:]
                texts = [m.text for m in self.of("STATUSTEXT")][-8:]
                raise TimeoutError(f"SITL {self.sysid}: no {what} within {timeout_s:g} s "
                                   f"(last heartbeat {hb}, texts {texts})")
            time.sleep(0.05)

    def mark(self) -> int:
        """Where the messages kept so far end: ``landed_after(seq, since=mark)`` looks only at
        what came after (a second flight of the same mission is not the first one's landing)."""
        with self._lock:
            return len(self.messages)

    def landed_after(self, seq: int, since: int = 0) -> bool:
        """Item ``seq`` reached, then a disarmed heartbeat: the mission flown and landed."""
        with self._lock:
            msgs = self.messages[since:]
        reached = [i for i, m in enumerate(msgs)
                   if m.get_type() == "MISSION_ITEM_REACHED" and m.seq == seq]
        if not reached:
            return False
        return any(m.get_type() == "HEARTBEAT" and not m.base_mode
                   & self.mavlink.MAV_MODE_FLAG_SAFETY_ARMED for m in msgs[reached[0]:])

    def close(self) -> None:
        self._stop = True
        with contextlib.suppress(OSError):
            self.sock.close()
        self._thread.join(2)

    def __enter__(self) -> Watch:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def lua_counts(tlog: Path) -> tuple[dict[int, int], dict[int, int]]:
    """Per vehicle: FIELD samples received, and the script's own count of those it sent
    (its last FIELD_N)."""
    received: dict[int, set[int]] = {}
    sent: dict[int, int] = {}
    for m in read_tlog(tlog):
        if m.get_type() != "NAMED_VALUE_FLOAT":
            continue
        s = m.get_srcSystem()
        if m.name == "FIELD":
            received.setdefault(s, set()).add(m.time_boot_ms)
        elif m.name == "FIELD_N":
            sent[s] = max(sent.get(s, 0), int(m.value))
    return {s: len(v) for s, v in received.items()}, sent
