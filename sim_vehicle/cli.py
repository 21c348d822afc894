"""``sim-vehicle``: run simulated MAVLink vehicles.

    sim-vehicle --sysid N --mission MISSION.yaml --connect udpout:127.0.0.1:14550
                [--autopilot px4|ardupilot] [--companion] [--prearm-s S]
                [--gcs-failsafe rtl|hold|off] [--gcs-failsafe-s S]
                [--speedup X] [--home LAT,LON,ALT] [--seed S] [--count N --sysid-base B]
                [--parent-pid PID]

``--autopilot`` picks the personality (PX4 or ArduCopter habits, see
:mod:`sim_vehicle.px4` and :mod:`sim_vehicle.ardupilot`); without ``--companion`` the vehicle
is a stock autopilot and refuses contour items and sensor lag items (MAV_MISSION_UNSUPPORTED),
with it a companion computer runs the onboard tracer.

One process per vehicle. With ``--count N`` this process launches N child ``sim-vehicle``
processes (system ids B..B+N-1, B defaults to ``--sysid``) and waits for them; for ``udpin``
and ``tcpin`` endpoints vehicle i listens on PORT+i (PORT 0: each picks an ephemeral port).
SIGTERM / SIGINT stop the vehicle(s) cleanly with exit status 0. With ``--parent-pid`` (the
ground station that starts it: ``econdor run``) a vehicle gets that SIGTERM when the parent
ends, however it ends (Linux), and does not start if it has ended already; the children of
``--count`` end with their launcher the same way.

At start each vehicle prints one line on stderr:
``sim-vehicle SYSID: ready on KIND:HOST:PORT`` (the actually bound local address for
``udpin``/``tcpin``) followed by the personality, e.g. ``(ardupilot, companion)``; at exit one
line with the achieved speedup and the link counters.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import time
from typing import Any

from econdor_gcs.errors import EcondorError
from econdor_gcs.lifetime import die_with_parent


def _home(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected LAT,LON,ALT, got {text!r}")
    try:
        lat, lon, alt = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three numbers LAT,LON,ALT, got {text!r}"
                                         ) from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise argparse.ArgumentTypeError(f"home out of range: {text!r}")
    return lat, lon, alt


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not v > 0 or v != v or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return v


def _non_negative(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not v >= 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return v


def _sysid(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 1 <= v <= 254:
        raise argparse.ArgumentTypeError(f"system id must be within 1..254, got {v}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="sim-vehicle",
        description="Simulated multicopter(s) speaking MAVLink 2 like PX4 or ArduCopter, "
                    "for econdor.")
    p.add_argument("--sysid", type=_sysid, default=1, help="MAVLink system id (default 1)")
    p.add_argument("--mission", required=True, help="mission YAML (field, area, origin)")
    p.add_argument("--connect", default="udpout:127.0.0.1:14550",
                   help="udpout:HOST:PORT (default udpout:127.0.0.1:14550), udpin:HOST:PORT "
                        "or tcpin:HOST:PORT")
    p.add_argument("--speedup", type=_positive, default=None,
                   help="sim time / wall time (default: the mission's vehicles.speedup)")
    p.add_argument("--home", type=_home, default=None,
                   help="home LAT,LON,ALT (AMSL); default the mission origin")
    p.add_argument("--seed", type=int, default=None, help="field seed (default mission seed)")
    p.add_argument("--count", type=int, default=1, help="launch this many vehicles")
    p.add_argument("--sysid-base", type=_sysid, default=None,
                   help="first system id with --count (default --sysid)")
    p.add_argument("--tel-rate", type=_positive, default=None,
                   help="position telemetry rate, Hz of sim time (default min(10, sample rate))")
    p.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4",
                   help="whose habits to imitate (default px4)")
    p.add_argument("--companion", action="store_true",
                   help="a companion computer runs the contour tracer: accept contour items "
                        "(MAV_CMD_WAYPOINT_USER_1) and sensor lag items (MAV_CMD_USER_4); "
                        "without it they are refused")
    p.add_argument("--prearm-s", type=_non_negative, default=None,
                   help="wall seconds after boot during which arming fails (default: 2 for "
                        "ardupilot, 0 for px4)")
    p.add_argument("--gcs-failsafe", choices=("rtl", "hold", "off"), default="rtl",
                   help="flying with no GCS heartbeat for --gcs-failsafe-s seconds: return to "
                        "launch (default), hold where it is, or go on (ArduPilot's "
                        "FS_GCS_ENABLE, PX4's NAV_DLL_ACT)")
    p.add_argument("--gcs-failsafe-s", type=_positive, default=5.0, metavar="S",
                   help="wall seconds without a GCS heartbeat before the failsafe acts "
                        "(default 5, ArduPilot's FS_GCS_TIMEOUT)")
    p.add_argument("--signing-key", default=None, metavar="FILE",
                   help="MAVLink 2 signing: 64 hex characters (the secret) or a passphrase "
                        "(SHA-256, as MAVProxy does); unsigned messages are then ignored")
    p.add_argument("--parent-pid", type=int, default=None, metavar="PID",
                   help="end with process PID (the ground station that started this "
                        "vehicle), however it ends; Linux")
    p.add_argument("--reject-command", type=int, action="append", default=[],
                   metavar="CMD", help="(testing) refuse mission items with this MAV_CMD")
    return p


def _run_one(args: argparse.Namespace) -> int:
    from econdor_gcs.config import load_mission
    from econdor_gcs.link.signing import load_signing_key

    from .mavlink_vehicle import AUTOPILOTS, MavlinkVehicle
    from .tracer import warm_up
    from .transport import parse_endpoint

    if args.parent_pid is not None and not die_with_parent(args.parent_pid):
        raise EcondorError(f"--parent-pid {args.parent_pid}: that process has ended")
    mission = load_mission(args.mission)
    ep = parse_endpoint(args.connect)
    if args.seed is not None and args.seed < 0:
        raise EcondorError(f"--seed must be >= 0, got {args.seed}")
    signing = load_signing_key(args.signing_key) if args.signing_key is not None else None
    overrides: dict[str, Any] = {"companion": args.companion, "prearm_s": args.prearm_s,
                                 "gcs_failsafe": args.gcs_failsafe,
                                 "gcs_failsafe_s": args.gcs_failsafe_s}
    if args.tel_rate is not None:
        overrides["tel_rate_hz"] = args.tel_rate
    warm_up()  # load (or compile) the tracer before the vehicle shows itself
    try:
        vehicle = MavlinkVehicle.from_mission(mission, sysid=args.sysid, connect=ep,
                                              speedup=args.speedup, seed=args.seed,
                                              home=args.home, signing=signing,
                                              autopilot=AUTOPILOTS[args.autopilot], **overrides)
    except OSError as exc:
        raise EcondorError(f"cannot open {args.connect}: {exc.strerror or exc}") from exc

    vehicle.server.reject_commands.update(args.reject_command)

    def on_signal(signum: int, frame: Any) -> None:
        vehicle.request_stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    host, port = vehicle.local_address
    where = args.connect if ep.kind == "udpout" else f"{ep.kind}:{host}:{port}"
    kind = "companion" if args.companion else "no companion"
    print(f"sim-vehicle {args.sysid}: ready on {where} ({args.autopilot}, {kind})",
          file=sys.stderr, flush=True)
    t0 = time.monotonic()
    vehicle.run()
    wall = time.monotonic() - t0
    print(f"sim-vehicle {args.sysid}: stopped after {wall:.1f} s wall, {vehicle.sim_time_s:.1f} s"
          f" sim (achieved {vehicle.achieved_speedup():.1f}x of "
          f"{vehicle.params['SPEEDUP']:g}x); samples {vehicle.counters['samples']}; "
          f"{vehicle.counters_line()}", file=sys.stderr, flush=True)
    return 0


def _run_many(args: argparse.Namespace) -> int:
    from econdor_gcs.config import load_mission

    from .transport import parse_endpoint

    if args.parent_pid is not None and not die_with_parent(args.parent_pid):
        raise EcondorError(f"--parent-pid {args.parent_pid}: that process has ended")
    load_mission(args.mission)  # fail fast, once, with one line
    ep = parse_endpoint(args.connect)
    base = args.sysid_base if args.sysid_base is not None else args.sysid
    if base + args.count - 1 > 254:
        raise EcondorError(f"system ids {base}..{base + args.count - 1} exceed 254")
    from .tracer import warm_up

    warm_up()  # compile once here on a cold cache; the children then load it
    children: list[subprocess.Popen[bytes]] = []
    stopping = False

    def on_signal(signum: int, frame: Any) -> None:
        nonlocal stopping
        stopping = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    for i in range(args.count):
        port = ep.port if ep.kind == "udpout" or ep.port == 0 else ep.port + i
        cmd = [sys.executable, "-m", "sim_vehicle.cli", "--sysid", str(base + i),
               "--mission", args.mission, "--connect", f"{ep.kind}:{ep.host}:{port}",
               "--parent-pid", str(os.getpid())]
        if args.speedup is not None:
            cmd += ["--speedup", repr(args.speedup)]
        if args.home is not None:
            cmd += ["--home", ",".join(repr(v) for v in args.home)]
        if args.seed is not None:
            cmd += ["--seed", str(args.seed)]
        if args.tel_rate is not None:
            cmd += ["--tel-rate", repr(args.tel_rate)]
        cmd += ["--autopilot", args.autopilot]
        if args.companion:
            cmd.append("--companion")
        if args.prearm_s is not None:
            cmd += ["--prearm-s", repr(args.prearm_s)]
        cmd += ["--gcs-failsafe", args.gcs_failsafe, "--gcs-failsafe-s",
                repr(args.gcs_failsafe_s)]
        for c in args.reject_command:
            cmd += ["--reject-command", str(c)]
        if args.signing_key is not None:
            cmd += ["--signing-key", args.signing_key]
        children.append(subprocess.Popen(cmd))
    status = 0
    try:
        while not stopping and any(c.poll() is None for c in children):
            time.sleep(0.1)
    finally:
        for c in children:
            if c.poll() is None:
                c.terminate()
        deadline = time.monotonic() + 5.0
        for c in children:
            try:
                c.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                c.kill()
                c.wait()
            if c.returncode not in (0, -signal.SIGTERM):
                status = 1
    return status


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.count < 1:
            raise EcondorError(f"--count must be >= 1, got {args.count}")
        return _run_many(args) if args.count > 1 else _run_one(args)
    except (EcondorError, ValueError) as exc:
        print(f"sim-vehicle: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 0


if __name__ == "__main__":
    with contextlib.suppress(BrokenPipeError):
        sys.exit(main())
