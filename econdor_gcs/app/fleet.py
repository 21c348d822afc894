"""Start and stop a fleet of simulated vehicles (``sim-vehicle`` processes) for ``econdor run``.

One process per vehicle, system ids 1..N, each with its log in ``LOG_DIR/v{sysid}.log``.
:meth:`Fleet.stop` always ends them: SIGTERM, wait, then SIGKILL; and each ends with the
station's process however that ends, killed outright too (``sim-vehicle --parent-pid``).
Each vehicle is a :class:`VehicleKind`: a PX4 or ArduPilot personality, with or without the
companion computer that runs the contour tracer (``econdor run --autopilot
ardupilot,px4+companion``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from econdor_gcs.errors import EcondorError
from econdor_gcs.link.autopilots import VehicleKind

DEFAULT_KIND = VehicleKind("px4", True)
"""Without ``--autopilot``: PX4 habits with the tracer on board (the simulated vehicle)."""


def parse_kinds(text: str) -> list[VehicleKind]:
    """A comma list of kinds, assigned to vehicles 1, 2, ... in turn (cycled)."""
    kinds = [VehicleKind.parse(t) for t in text.split(",") if t.strip()]
    if not kinds:
        raise EcondorError("--autopilot: empty list")
    return kinds


def kinds_for(n: int, kinds: Sequence[VehicleKind]) -> list[VehicleKind]:
    """The kind of each of ``n`` vehicles: ``kinds`` repeated in turn."""
    return [kinds[i % len(kinds)] for i in range(n)]


def sim_vehicle_command() -> list[str]:
    """``sim-vehicle`` next to this interpreter, else ``python -m sim_vehicle.cli``."""
    exe = shutil.which("sim-vehicle", path=os.path.dirname(sys.executable))
    return [exe] if exe else [sys.executable, "-m", "sim_vehicle.cli"]


class Fleet:
    """The simulated vehicles of one run."""

    def __init__(self, mission_path: str | Path, log_dir: str | Path) -> None:
        self.mission_path = Path(mission_path)
        self.log_dir = Path(log_dir)
        self.procs: dict[int, subprocess.Popen[bytes]] = {}

    def start(self, count: int, connect: str, *, speedup: float | None = None,
              seed: int | None = None, first_sysid: int = 1,
              extra: dict[int, list[str]] | None = None,
              kinds: Sequence[VehicleKind] = (DEFAULT_KIND,),
              signing_key_file: str | Path | None = None) -> None:
        """Launch ``count`` vehicles sending to ``connect`` (``udpout:HOST:PORT``), of
        ``kinds`` in turn."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        for i, sysid in enumerate(range(first_sysid, first_sysid + count)):
            cmd = [*sim_vehicle_command(), "--sysid", str(sysid), "--mission",
                   str(self.mission_path), "--connect", connect,
                   "--parent-pid", str(os.getpid()), *kinds[i % len(kinds)].args()]
            if speedup is not None:
                cmd += ["--speedup", repr(float(speedup))]
            if seed is not None:
                cmd += ["--seed", str(seed)]
            if signing_key_file is not None:  # the file's name, never the key
                cmd += ["--signing-key", str(signing_key_file)]
            cmd += (extra or {}).get(sysid, [])
            with (self.log_dir / f"v{sysid}.log").open("wb") as log:
                self.procs[sysid] = subprocess.Popen(
                    cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)

    def dead(self) -> dict[int, int]:
        """System id -> exit status of the vehicles that already exited."""
        return {s: p.returncode for s, p in self.procs.items() if p.poll() is not None}

    def explain(self, message: str) -> str:
        """``message`` plus why, if a vehicle process died (its last log line)."""
        dead = self.dead()
        if not dead:
            return message
        sysid, code = next(iter(sorted(dead.items())))
        log = self.log_dir / f"v{sysid}.log"
        last = ""
        try:
            lines = [ln for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
            last = lines[-1].strip() if lines else ""
        except OSError:
            pass
        why = f": {last}" if last else ""
        return f"vehicle {sysid} exited with status {code}{why} (log: {log})"

    def stop(self, timeout_s: float = 5.0) -> None:
        """SIGTERM everyone, wait up to ``timeout_s`` in total, SIGKILL the rest."""
        import time

        for p in self.procs.values():
            if p.poll() is None:
                p.terminate()
        deadline = time.monotonic() + timeout_s
        for p in self.procs.values():
            try:
                p.wait(max(0.05, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
