"""The ``econdor`` command line: a thin shell over the library.

Any :class:`~econdor_gcs.errors.EcondorError` becomes one line on stderr and exit 1;
usage errors exit 2 (argparse). No traceback for a user's mistake.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

from econdor_gcs.config import load_mission
from econdor_gcs.core.planners import PLANNER_NAMES
from econdor_gcs.errors import EcondorError

WEB_DEFAULT = "127.0.0.1:8765"


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return v


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return v


def _non_negative_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not v >= 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return v


def _sysid(text: str) -> int:
    v = _positive_int(text)
    if v > 254:
        raise argparse.ArgumentTypeError(f"system id must be within 1..254, got {v}")
    return v


def _planner_list(text: str) -> list[str]:
    """``"adaptive,lawnmower"`` -> the planners in that order; ``"all"`` -> every planner."""
    if text == "all":
        return list(PLANNER_NAMES)
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in PLANNER_NAMES]
    if unknown or not names:
        problem = f"unknown planner {unknown[0]!r}" if unknown else "no planner given"
        raise argparse.ArgumentTypeError(
            f"{problem} (choose from {', '.join(PLANNER_NAMES)}, a comma list of them, or all)")
    return list(dict.fromkeys(names))


def _probability(text: str) -> float:
    """``0.1`` or ``10%`` -> 0.1."""
    scale = 100.0 if text.endswith("%") else 1.0
    try:
        v = float(text.rstrip("%")) / scale
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a probability (0.1 or 10%), got {text!r}"
                                         ) from None
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be within 0..1 (0..100%), got {text}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="econdor", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run a mission over MAVLink (starts simulated vehicles "
                                     "unless --connect is given)")
    run.add_argument("mission", type=Path, nargs="?",
                     help="mission YAML (not with --resume: the run directory has it)")
    run.add_argument("--out", type=Path, default=None,
                     help="run directory (default runs/<name>-<time>); a non-empty one is "
                          "refused unless --force")
    run.add_argument("--force", action="store_true",
                     help="replace an earlier run in --out")
    run.add_argument("--resume", type=Path, default=None, metavar="RUN_DIR",
                     help="continue an interrupted run after its last finished flight")
    run.add_argument("--planner", choices=PLANNER_NAMES, default=None,
                     help="the planner (default: the mission's algorithm.planner)")
    run.add_argument("--vehicles", type=_positive_int, default=None,
                     help="how many vehicles (default: the mission's vehicles.count)")
    run.add_argument("--speedup", type=_positive_float, default=None,
                     help="simulated time over wall time (default: the mission's "
                          "vehicles.speedup)")
    run.add_argument("--seed", type=int, default=None,
                     help="the field's seed (default: the mission's seed)")
    run.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                     help="serve vehicles started elsewhere on this link: udpin:HOST:PORT, "
                          "udpout:HOST:PORT, tcp:HOST:PORT (e.g. ArduPilot SITL), "
                          "tcpin:HOST:PORT or a serial device DEVICE:BAUD; repeat it for "
                          "several links")
    run.add_argument("--timeout", type=_positive_float, default=None,
                     help="seconds to wait for vehicles to appear, send a position and pass "
                          "their pre-arm checks (default 60)")
    run.add_argument("--link-timeout", type=_positive_float, default=None, metavar="S",
                     help="seconds a vehicle may be silent before it is given up (default "
                          "120); a shorter drop-out of its link is waited out and its flight "
                          "picked up where it left")
    run.add_argument("--autopilot", default=None, metavar="KINDS",
                     help="the simulated vehicles this run starts: px4, ardupilot, "
                          "px4+companion or ardupilot+companion, or a comma list given to "
                          "vehicles 1, 2, ... in turn (default px4+companion: the tracer on "
                          "board); a vehicle without companion gets contours as waypoints")
    run.add_argument("--tolerance-m", type=_positive_float, default=1.0,
                     help="Douglas-Peucker tolerance of the waypoint polylines (default 1)")
    run.add_argument("--forward", default=None, metavar="udpout:HOST:PORT",
                     help="send every vehicle message to a watcher (QGroundControl, "
                          "MAVProxy --master=udpin:HOST:PORT)")
    run.add_argument("--forward-commands", action="store_true",
                     help="relay what the watcher sends to the vehicles (dropped otherwise)")
    run.add_argument("--signing-key", type=Path, default=None, metavar="FILE",
                     help="MAVLink 2 signing: 64 hex characters (the secret) or a passphrase "
                          "(hashed with SHA-256, as MAVProxy does)")
    run.add_argument("--quiet", action="store_true", help="no progress lines")
    run.add_argument("--web", nargs="?", const=WEB_DEFAULT, default=None, metavar="[HOST:]PORT",
                     help=f"serve a live page of the run (default {WEB_DEFAULT}; another "
                          "host than loopback needs the token printed at start)")

    rl = sub.add_parser("relay", help="a fault-injecting UDP relay between two loopback "
                                      "endpoints (for tests and link checks)")
    rl.add_argument("--listen", required=True, metavar="EP",
                    help="where the vehicles send, e.g. udpin:127.0.0.1:14560 (port 0: any)")
    rl.add_argument("--to", required=True, metavar="EP",
                    help="where to relay to (the GCS), e.g. udpout:127.0.0.1:14550")
    for name, what in (("drop", "lose"), ("duplicate", "deliver twice"),
                       ("reorder", "hold back behind the next one"),
                       ("corrupt", "flip one bit of")):
        rl.add_argument(f"--{name}", type=_probability, default=0.0, metavar="P",
                        help=f"probability to {what} each datagram, each way (0.1 or 10%%)")
    rl.add_argument("--seed", type=int, default=None, help="seed of the fault draws")
    rl.add_argument("--outage", action="append", default=[], metavar="START:SECONDS",
                    help="lose every datagram both ways for SECONDS, START seconds after the "
                         "first one (a radio drop-out; repeat for more)")
    rl.add_argument("--duration", type=_positive_float, default=None, metavar="S",
                    help="stop after S seconds (default: at Ctrl-C / SIGTERM)")

    st = sub.add_parser("study", help="in-process study over many seeds")
    st.add_argument("mission", type=Path, help="mission YAML")
    st.add_argument("--seeds", default="0:4", help="A:B (B excluded) or a comma list")
    st.add_argument("--planner", type=_planner_list, default=["econdor"],
                    metavar="|".join((*PLANNER_NAMES, "all")),
                    help="a planner, a comma-separated list of them, or all")
    st.add_argument("--out", type=Path, required=True,
                    help="directory for study.csv, summary.json and the figures")
    st.add_argument("--workers", type=_positive_int, default=None,
                    help="local worker processes (default: number of cores); Ctrl-C or "
                         "SIGTERM stops them, each run keeping its samples")
    st.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler")
    st.add_argument("--vehicles", type=_positive_int, default=None,
                    help="how many vehicles (default: the mission's vehicles.count)")
    st.add_argument("--no-figures", action="store_true", help="write the table only")
    st.add_argument("--quiet", action="store_true", help="no progress lines")

    rep = sub.add_parser("report", help="redraw the figures of a run directory")
    rep.add_argument("run_dir", type=Path, help="a run directory (econdor run --out)")

    vw = sub.add_parser("view", help="the web page of a finished or partial run, with an "
                                     "iteration slider")
    vw.add_argument("run_dir", type=Path, help="a run directory (econdor run --out)")
    vw.add_argument("--web", default=WEB_DEFAULT, metavar="[HOST:]PORT",
                    help=f"where to serve it (default {WEB_DEFAULT})")

    ex = sub.add_parser("export", help="missions for real aircraft from a run directory or a "
                                       "mission YAML (or a run's flown paths as GeoJSON)")
    ex.add_argument("source", type=Path, help="a run directory or a mission YAML")
    ex.add_argument("--format", choices=("wpl", "plan", "geojson", "lua"), required=True,
                    help="lua: a script for ArduPilot SITL that senses the mission's field "
                         "at the vehicle (from a mission YAML or a run directory)")
    ex.add_argument("--out", required=True,
                    help="a file, or a directory (existing or ending in /) for one file per mission")
    ex.add_argument("--style", choices=("waypoints", "trace"), default="waypoints",
                    help="contour pieces as waypoint polylines (any autopilot, the default) or "
                         "as contour items for an onboard tracer")
    ex.add_argument("--alt-m", type=_positive_float, default=None,
                    help="flight altitude above home (default: the mission's)")
    ex.add_argument("--speed-mps", type=_positive_float, default=None,
                    help="DO_CHANGE_SPEED ground speed (default: the mission's)")
    ex.add_argument("--tolerance-m", type=_positive_float, default=1.0,
                    help="Douglas-Peucker tolerance of the waypoint polylines (default 1)")
    ex.add_argument("--vehicles", type=_positive_int, default=1,
                    help="split over this many aircraft (default 1)")
    ex.add_argument("--spacing-m", type=_positive_float, default=None,
                    help="mission YAML: a north-south survey at this spacing instead of the "
                         "diagonals")
    ex.add_argument("--fence-margin-m", type=_non_negative_float, default=10.0,
                    help=".plan: geofence this far outside the area (default 10)")
    ex.add_argument("--iteration", default=None, metavar="N|all",
                    help="run directory: the missions planned for iteration N (or all) instead "
                         "of the next batch")
    ex.add_argument("--vehicle", type=int, default=None,
                    help="with --iteration: only this vehicle's mission")

    im = sub.add_parser("import", help="read a QGC WPL or .plan mission file back, check it, "
                                       "say what it holds")
    im.add_argument("path", type=Path, help="a QGC WPL (.waypoints, .txt) or .plan file")
    im.add_argument("--json", action="store_true",
                    help="print the items (mission, fence, rally) as JSON")

    up = sub.add_parser("upload", help="upload a mission file to a MAVLink autopilot, read it "
                                       "back and verify it; optionally start it")
    up.add_argument("path", type=Path, help="a QGC WPL or .plan mission file")
    up.add_argument("--connect", required=True, action="append", metavar="ENDPOINT",
                    help="the link to the vehicle: udpin:0.0.0.0:14550, udpout:HOST:PORT, "
                         "tcp:HOST:PORT, tcpin:HOST:PORT or DEVICE:BAUD (e.g. "
                         "/dev/ttyUSB0:57600)")
    up.add_argument("--sysid", type=_sysid, default=None,
                    help="the vehicle's system id (default: the first that appears)")
    up.add_argument("--start", action="store_true",
                    help="then set the mode, arm (when the pre-arm checks pass) and start it")
    up.add_argument("--timeout", type=_positive_float, default=30.0,
                    help="seconds to wait for the vehicle and each step (default 30)")
    up.add_argument("--force", action="store_true",
                    help="upload a mission the plausibility checks refuse (an altitude below "
                         "home, a waypoint outside the file's own fence, ...)")
    return p


def _cmd_study(args: argparse.Namespace) -> int:
    from econdor_lab.study import default_workers, parse_seeds, run_study

    mission = load_mission(args.mission)
    if args.vehicles:
        mission = mission.with_vehicles(count=args.vehicles)
    seeds = parse_seeds(args.seeds)
    planners = args.planner
    total = len(seeds) * len(planners)
    workers = args.workers or default_workers()
    _warm_up_tracer(args.quiet)
    if args.quiet:
        summary = run_study(mission, seeds, planners, args.out, workers, args.scheduler,
                            figures=not args.no_figures)
    else:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        console = Console(stderr=True)
        columns = (TextColumn("[bold]study[/]"), BarColumn(),
                   TextColumn("{task.completed}/{task.total} runs"), TimeElapsedColumn())
        with Progress(*columns, console=console) as prog:
            task = prog.add_task("", total=total)

            def tick(r: dict[str, Any]) -> None:
                s = r["summary"]
                prog.advance(task)
                prog.console.print(
                    f"  {s['planner']:>9} seed {s['seed']:>3}: {s['iterations']} it, "
                    f"MAE {s['final_mae_db']:.1f} dB, flown {s['flight_distance_m']:.0f} m, "
                    f"{s['wall_s']:.1f} s")

            summary = run_study(mission, seeds, planners, args.out, workers, args.scheduler,
                                progress=tick, figures=not args.no_figures)
    for planner, agg in summary["by_planner"].items():
        print(f"{planner:>9}: median final MAE {agg['median_final_mae_db']:.1f} dB over "
              f"{agg['runs']} runs, median flown {agg['median_flight_distance_m']:.0f} m "
              "(to the last estimate, without the way home)")
    print(f"wrote {args.out / 'study.csv'}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from econdor_gcs.files.figures import plot_run

    if not (args.run_dir / "metrics.csv").exists():
        raise EcondorError(f"{args.run_dir}: not a run directory (no metrics.csv)")
    for path in plot_run(args.run_dir):
        print(path)
    return 0


def _check_run_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Usage errors of ``econdor run`` (exit 2): what --resume excludes and needs."""
    if args.resume is None:
        if args.mission is None:
            parser.error("run: a MISSION.yaml is needed (or --resume RUN_DIR)")
        if args.timeout is None:
            args.timeout = 60.0
        return
    clash = [f"--{name}" for name in ("out", "planner", "vehicles", "speedup", "seed")
             if getattr(args, name) is not None] + (["--force"] if args.force else [])
    if args.mission is not None:
        clash.insert(0, "MISSION.yaml")
    if clash:
        parser.error(f"run: --resume continues the recorded run; {', '.join(clash)} cannot "
                     "change it")


def _cmd_run(args: argparse.Namespace) -> int:
    from econdor_gcs.app.run import run_mission_cli

    if not args.connect:
        # the vehicles we start load the compiled tracer from numba's cache; on a cold
        # cache compile it here first, before the station starts waiting for them
        _warm_up_tracer(args.quiet)
    return run_mission_cli(args)


WARM_UP_QUIET_S = 2.0
"""Loading the compiled tracer from numba's cache takes less; longer is a compilation."""
WARM_UP_PROGRESS_S = 10.0


def _warm_up_tracer(quiet: bool) -> None:
    """Load the compiled tracer, compiling it on a cold cache; a compilation (about 20 s
    of one core, once per installation) is announced when it starts and its progress
    printed, so a new user does not stare at a silent terminal."""
    import threading

    from sim_vehicle.tracer import warm_up

    done = threading.Event()
    failure: list[BaseException] = []

    def work() -> None:
        try:
            warm_up()
        except BaseException as exc:  # noqa: BLE001 - raised again in the main thread
            failure.append(exc)
        finally:
            done.set()

    t0 = time.monotonic()
    threading.Thread(target=work, name="econdor-warm-up", daemon=True).start()
    if not done.wait(WARM_UP_QUIET_S) and not quiet:
        print("econdor: compiling the onboard tracer (once: numba caches it for the next "
              "runs; about 20 s) ...", file=sys.stderr, flush=True)
        while not done.wait(WARM_UP_PROGRESS_S):
            print(f"econdor: ... still compiling ({time.monotonic() - t0:.0f} s)",
                  file=sys.stderr, flush=True)
        print(f"econdor: compiled in {time.monotonic() - t0:.0f} s", file=sys.stderr,
              flush=True)
    done.wait()
    if failure:
        raise failure[0]


def _cmd_view(args: argparse.Namespace) -> int:
    from econdor_gcs.app.web.replay import ReplayFeed
    from econdor_gcs.app.web.server import WebServer, parse_web_address

    host, port = parse_web_address(args.web)
    server = WebServer(ReplayFeed(args.run_dir), host, port)
    url = server.start()
    print(f"web: {url} (Ctrl-C stops)", flush=True)
    if server.exposed:
        print(f"econdor: warning: the run's page is reachable from the network on {args.web} "
              "(to whoever has the token in the address above)", file=sys.stderr, flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        return 0
    finally:
        server.stop(flush_s=0.5)


def _cmd_export(args: argparse.Namespace) -> int:
    from econdor_gcs.app.export import export_cli

    return export_cli(args)


def _cmd_import(args: argparse.Namespace) -> int:
    import dataclasses
    import json

    from econdor_gcs.files.autopilot_files import describe, read_mission_file
    from econdor_gcs.files.plausibility import check_plausible

    mfile = read_mission_file(args.path, int_frames=False)
    check_plausible(mfile, str(args.path))
    if args.json:
        doc = {name: [dataclasses.asdict(it) for it in getattr(mfile, name)]
               for name in ("items", "fence", "rally")}
        print(json.dumps(doc, indent=1, allow_nan=True))
        return 0
    print(f"{args.path}: a valid mission file")
    for line in describe(mfile):
        print(line)
    return 0


def _cmd_upload(args: argparse.Namespace) -> int:
    from econdor_gcs.app.upload import upload_cli

    return upload_cli(args)


def _cmd_relay(args: argparse.Namespace) -> int:
    import asyncio

    from econdor_gcs.link.relay import Faults, Relay, parse_outage, parse_relay_endpoint, serve

    listen, to = parse_relay_endpoint(args.listen), parse_relay_endpoint(args.to)
    relay = Relay(listen, to, Faults(args.drop, args.duplicate, args.reorder, args.corrupt),
                  seed=args.seed, outages=[parse_outage(o) for o in args.outage])

    def ready(r: Relay) -> None:
        host, port = r.listen_address
        print(f"relay: listening on udpin:{host}:{port} -> udpout:{to[0]}:{to[1]}",
              file=sys.stderr, flush=True)

    asyncio.run(serve(relay, duration_s=args.duration, ready=ready))
    print(f"relay: {relay.stats_line()}", file=sys.stderr, flush=True)
    return 0


COMMANDS = {"relay": _cmd_relay, "study": _cmd_study, "report": _cmd_report, "run": _cmd_run,
            "export": _cmd_export, "view": _cmd_view, "import": _cmd_import,
            "upload": _cmd_upload}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "run":
        _check_run_args(parser, args)
    from econdor_gcs.lifetime import sigterm_as_interrupt

    # SIGTERM stops a command as Ctrl-C does (a study's workers stop, every run closes its
    # directory), and a second stop signal does not cut that short
    with sigterm_as_interrupt():
        try:
            code = COMMANDS[args.command](args)
            sys.stdout.flush()  # (a reader gone shows here, not as Python exits)
            return code
        except BrokenPipeError:
            # the reader of the output went away (``econdor import m.waypoints | head -1``):
            # stop quietly, as a Unix tool ended by SIGPIPE does (a study stops its
            # workers on the way out, every run keeping its samples)
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 128 + signal.SIGPIPE
        except EcondorError as exc:
            print(f"econdor: error: {exc}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print("econdor: interrupted", file=sys.stderr)
            return 130


if __name__ == "__main__":
    sys.exit(main())
