"""``econdor run``: one MAVLink run into a run directory, a resumed one, and the command.

:func:`run_mission` sets up the run directory, the :class:`~.gcs.Station`, the simulated
fleet (or serves vehicles started elsewhere with ``--connect``), the live display or web
page and the :class:`~.gcs.MavlinkExecutor`, runs the :class:`~.dfc.Dfc` loop and writes the
results; a run that fails part-way still leaves a usable run directory (samples so far, tlog,
``summary.json`` with ``"error"``). :func:`resume_mission` continues an interrupted run after
its last finished flight; :func:`run_mission_cli` is the command (arguments parsed by
:mod:`econdor.cli`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from econdor_gcs.app.run_failures import checked_disk, refusals, write_partial
from econdor_gcs.config import Mission
from econdor_gcs.core.tasks import (
    SampleLog,
)
from econdor_gcs.errors import (
    EcondorError,
    RunError,
    VehicleTimeout,
)
from econdor_gcs.files.rundir import RunDir, RunDirMode, RunLog, Severity, disk_error, writing
from econdor_gcs.link.codec import MAVLinkMessage, mavlink
from econdor_gcs.link.forward import Forwarder
from econdor_gcs.link.items import MISSION_FENCE_MARGIN_M
from econdor_gcs.link.router import (
    ComponentDiscovered,
    ForeignVehicle,
    Received,
    Router,
    TwinRefused,
    VehicleDiscovered,
    VehicleLost,
    VehicleMoved,
    VehicleRecovered,
)
from econdor_gcs.link.signing import load_signing_key
from econdor_gcs.link.tlog import TlogWriter
from econdor_gcs.link.vehicles import EVENTS
from econdor_gcs.station.executor import (
    LINK_TIMEOUT_S,
    LOSS_SILENCE_S,
    MavlinkExecutor,
    Station,
    StatusAssembler,
)

if TYPE_CHECKING:
    from econdor_gcs.link.autopilots import VehicleKind

__all__ = ["resume_mission", "run_mission", "run_mission_cli"]

T = TypeVar("T")
log = logging.getLogger(__name__)


def _default_out(mission: Mission) -> Path:
    return Path("runs") / f"{mission.name}-{time.strftime('%Y%m%d-%H%M%S')}"


class _Terminated(KeyboardInterrupt):
    """SIGTERM, delivered like Ctrl-C so every ``finally`` runs."""


def _on_sigterm(signum: int, frame: Any) -> None:
    raise _Terminated()


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def run_mission(
    mission: Mission,
    out: Path,
    *,
    planner: str | None = None,
    vehicles: int | None = None,
    speedup: float | None = None,
    seed: int | None = None,
    connect: str | Sequence[str] | None = None,
    timeout_s: float = 60.0,
    link_timeout_s: float = LINK_TIMEOUT_S,
    quiet: bool = True,
    mission_path: Path | None = None,
    figures: bool = True,
    mode: RunDirMode = RunDirMode.NEW,
    signing_key_file: Path | None = None,
    web: str | None = None,
    announce: Callable[[str], None] | None = None,
    warn: Callable[[str], None] | None = None,
    autopilots: Sequence[VehicleKind] | None = None,
    tolerance_m: float = 1.0,
    forward: str | None = None,
    forward_commands: bool = False,
) -> dict[str, Any]:
    """One MAVLink run into ``out``; returns the summary (see ``summary.json``).

    ``timeout_s`` is how long vehicles may take to appear, to send a position and to pass
    their pre-arm checks; ``link_timeout_s`` how long a vehicle may be silent before it is
    given up (a shorter drop-out of its link is waited out, and the flight picks up where
    it left; at least :data:`~.losses.LOSS_SILENCE_S`).

    ``autopilots`` are the kinds of the simulated vehicles this run starts (in turn; default
    PX4 with the tracer on board); ``tolerance_m`` the Douglas-Peucker tolerance of the
    waypoint polylines for vehicles that refuse contour items. ``forward`` is a watcher's
    ``udpout:HOST:PORT`` that gets every vehicle message (:mod:`.link.forward`); what it sends
    back reaches the vehicles only with ``forward_commands``.

    ``mode`` says what to do with a non-empty ``out`` (:class:`~.rundir.RunDirMode`); to
    resume a run use :func:`resume_mission`. With ``signing_key_file`` (see
    :func:`~.signing.load_signing_key`) every message is signed, unsigned telemetry is
    dropped, and the vehicles this run starts sign too (the key is written nowhere).
    ``web`` (``[HOST:]PORT``) serves the run's page (:mod:`econdor_gcs.app.web`) with pause /
    resume / stop; ``announce`` is told its address (with the token the controls need) as
    soon as it listens, and ``warn`` that the controls are on the network when ``web`` is
    not a loopback address.

    Raises :class:`EcondorError` on failure, after writing a partial run directory
    (samples so far, tlog, ``summary.json`` with ``"error"``).
    """
    from econdor_gcs.app.fleet import DEFAULT_KIND, Fleet, kinds_for
    from econdor_gcs.dfc.loop import Dfc
    from econdor_gcs.files.plans import save_next_batch
    from econdor_gcs.files.rundir import read_checkpoint

    wall0 = time.perf_counter()
    if not link_timeout_s >= LOSS_SILENCE_S:
        raise RunError(f"--link-timeout must be at least {LOSS_SILENCE_S:g} s (vehicles "
                       f"heartbeat once a second), got {link_timeout_s:g}")
    signing = load_signing_key(signing_key_file) if signing_key_file is not None else None
    n = vehicles or mission.vehicles.count
    speed = speedup or mission.vehicles.speedup
    seed = mission.seed if seed is None else seed
    planner = planner or mission.algorithm.planner
    mission = mission.with_vehicles(count=n, speedup=speed)
    out = Path(out)
    kinds = list(autopilots or [DEFAULT_KIND])
    resume = mode == RunDirMode.RESUME
    replay = read_checkpoint(out) if resume else []
    rd = RunDir(out, mode, grid=mission.grid, received=True)
    try:
        runlog = RunLog(out / "log.jsonl")
        if not resume:
            mission_text = mission_path.read_text(encoding="utf-8") if mission_path else None
            rd.write_run_config({
                "transport": "mavlink", "mission": mission.name, "planner": planner,
                "seed": seed, "vehicles": n, "speedup": speed, "connect": connect,
                "timeout_s": timeout_s, "link_timeout_s": link_timeout_s,
                "mission_path": str(mission_path.resolve()) if mission_path else None,
                "signed": signing is not None,
                "autopilots": [str(k) for k in kinds] if connect is None else None,
                "tolerance_m": tolerance_m,
            }, mission_text)
        with writing(out / "telemetry.tlog"):
            tlog = TlogWriter(out / "telemetry.tlog", append=resume)
    except BaseException:
        rd.close()  # nothing had begun: no summary to write
        raise
    station = Station(connect or "udpin:127.0.0.1:0", tlog,
                      heartbeat_timeout_s=link_timeout_s, signing=signing)
    _log_station(station.router, runlog)
    forwarder: Forwarder | None = None
    fleet: Fleet | None = None
    executor: MavlinkExecutor | None = None
    dfc: Dfc | None = None
    live = None
    page: Any = None  # web.session.LiveWeb (aiohttp is imported only with --web)
    base: dict[str, Any] = {"transport": "mavlink", "truth_known": True,
                            "mission": mission.name, "planner": planner, "seed": seed,
                            "vehicles": n, "speedup": speed,
                            "connect": connect or None}
    timings: dict[str, float] = {}

    def fill_timings() -> None:
        timings["total_wall_s"] = time.perf_counter() - wall0
        if executor is not None:
            timings.update(executor.timings)
            timings["sim_s"] = executor.sim_s
            # how fast the vehicles' clocks ran against ours over the run (not the flights'
            # sim_s over flying time: a flight's clock starts before its upload, which a
            # lossy link makes long, so "104x" was shown for vehicles at 50x)
            timings["achieved_speedup"] = executor.clock_rate()
        if dfc is not None:
            timings["reconstruction_s"] = dfc.recon_s
        timings["requested_speedup"] = speed

    try:
        with _sigterm_as_interrupt(), _logging_to(runlog):
            if web is not None:
                from econdor_gcs.app.web.session import LiveWeb

                page = LiveWeb(web, mission=mission, planner=planner, run_dir=str(out),
                               runlog=runlog)
                url = page.start()
                runlog.add("station", f"web page at {url}")
                if announce is not None:
                    announce(url)
                if page.exposed:
                    warning = (f"the web page and its controls (pause, resume, stop) are "
                               f"reachable from the network on {web}: anyone with the "
                               "address above (its token) can stop the run")
                    runlog.add("station", warning, Severity.WARNING)
                    if warn is not None:
                        warn(warning)
            host, port = station.start()
            if forward is not None:
                forwarder = station.call(
                    Forwarder(station.router, forward, forward_commands).start())
            if connect is None:
                if mission_path is None:
                    raise RunError("run_mission: mission_path is needed to start vehicles")
                fleet = Fleet(mission_path, out / "vehicles")
                fleet.start(n, f"udpout:{host}:{port}", speedup=speed, seed=seed,
                            signing_key_file=signing_key_file, kinds=kinds)
                sysids = list(range(1, n + 1))
                try:
                    station.call(station.router.wait_for_vehicles(sysids, timeout_s))
                except VehicleTimeout as exc:
                    raise VehicleTimeout(fleet.explain(str(exc)
                                                       + refusals(station.router))) from None
            else:
                try:
                    sysids = station.call(_wait_count(station.router, n, timeout_s))
                except VehicleTimeout as exc:
                    raise VehicleTimeout(str(exc) + refusals(station.router)) from None
            # the fleet is named: any other system on these links is a stranger from now on
            station.run_sync(lambda: station.router.expect(sysids))
            t_setup = time.perf_counter() - wall0
            executor = MavlinkExecutor(station, mission, sysids, out / "missions", timeout_s,
                                       tolerance_m=tolerance_m, link_timeout_s=link_timeout_s)
            journal = executor
            executor.telemetry.on_rows = lambda v, rows: rd.journal(rows, v.index,
                                                                   journal.iteration)
            executor.wait_ready()
            truth = mission.build_field(seed)
            progress: list[Callable[[Any], None]] = [rd.progress, runlog.progress]
            on_samples: list[Callable[[SampleLog], None]] = []
            if not quiet:
                from econdor_gcs.app.live import LiveDisplay

                live = LiveDisplay(executor, planner=planner, mission=mission.name)
                live.start()
                progress.append(live.progress)
            if page is not None:
                page.attach(executor.status_rows, sysids, station.router,
                            on_stop=executor.abort_flight)
                progress.append(page.progress)
                on_samples.append(page.add_samples)
            # the run directory records each flight (samples, then its line) before the DFC
            # uses it; displays see the samples as the DFC takes them in
            dfc = Dfc(mission, executor, planner=planner, truth=truth, seed=seed,
                      progress=_all_of(progress), on_samples=_all_of(on_samples),
                      on_flight=checked_disk(rd, tlog, runlog), replay=replay,
                      checkpoint=page.checkpoint if page is not None else None)
            result = dfc.run()
            if live is not None:
                live.stop()
                live = None
            fill_timings()
            timings["setup_s"] = t_setup
            result.wall_s = time.perf_counter() - wall0
            result.sim_s = executor.sim_s
            parser = station.router.parser
            save_next_batch(out, dfc.planner, mission, result)
            started = kinds_for(n, kinds) if connect is None else None
            extra = {**base, "sysids": sysids, "timings": timings,
                     "fleet": executor.fleet_summary(started),
                     "forward": ({"to": forward, "commands": forward_commands,
                                  **forwarder.stats} if forwarder is not None else None),
                     "samples_dropped_unpaired": station.router.pairer.dropped_total,
                     "sample_pairing": station.router.pairer.counts(),
                     "link_conflicts": [c.as_dict() for c in station.router.table.conflicts],
                     "report_errors": executor.report_errors,
                     "sample_recovery": executor.sample_accounting(),
                     "lost_vehicles": executor.losses,
                     "interrupted_flights": executor.interruptions,
                     "link_timeout_s": link_timeout_s,
                     "samples_received": rd.n_received,
                     "fence": {"margin_m": MISSION_FENCE_MARGIN_M,
                               "refused_by": executor.fences_refused},
                     "link": {"bad_packets": parser.bad_packets,
                              "unknown_packets": parser.unknown_packets,
                              "unsigned_dropped": parser.unsigned_packets,
                              "bad_signature_dropped": parser.bad_signature_packets,
                              "refused_by_sysid": {str(k): v for k, v in sorted(
                                  parser.refused_by_source().items())}},
                     "signed": signing is not None}
            if resume:
                extra["resumed"] = {"flights_replayed": dfc.replayed,
                                    "samples_interrupted": rd.interrupted_samples}
            timings["rundir_s"] = rd.write_s
            rd.write_result(result, extra=extra)
            summary = {**result.summary(), **extra, "samples_recorded": rd.n_samples}
            if page is not None:
                page.close(summary)
                page = None
    except (EcondorError, KeyboardInterrupt, OSError) as exc:
        if live is not None:
            live.stop()
            live = None
        # a write the run directory does not guard (figures, a library's file): one line
        failure = disk_error(None, exc) if isinstance(exc, OSError) else exc
        msg = "interrupted" if isinstance(exc, KeyboardInterrupt) else str(failure)
        runlog.add("station", f"run failed: {msg}", Severity.ERROR)
        base["link_conflicts"] = [c.as_dict() for c in station.router.table.conflicts]
        write_partial(rd, dfc, executor, base, timings, fill_timings, msg,
                       disk=[e for e in (tlog.error and str(disk_error(tlog.path, tlog.error)),
                                         runlog.error, rd.journal_error) if e])
        if page is not None:
            page.close({**base, "error": msg})
            page = None
        if failure is not exc:
            raise failure from exc
        raise
    finally:
        if live is not None:
            live.stop()
        if page is not None:
            page.close(None)
        if forwarder is not None:
            station.loop.call_soon_threadsafe(forwarder.close)
        station.close()
        if fleet is not None:
            fleet.stop()
        tlog.close()
        rd.close()
        runlog.close()
    if figures:
        from econdor_gcs.files.figures import plot_run

        plot_run(out)
    return summary


def _all_of(callbacks: Sequence[Callable[[T], None]]) -> Callable[[T], None]:
    """One callback that calls each of ``callbacks`` in turn."""
    def call(arg: T) -> None:
        for cb in callbacks:
            cb(arg)

    return call


def _log_station(router: Router, runlog: RunLog) -> None:
    """Vehicles' STATUSTEXT (chunks joined), discoveries, losses and recoveries into the
    run's log."""

    assembler = StatusAssembler()

    def on_message(sysid: int, msg: MAVLinkMessage) -> None:
        if msg.get_type() != "STATUSTEXT":
            return
        raw = bytes(msg.text) if isinstance(msg.text, bytes | bytearray) else \
            msg.text.encode("utf-8", "replace")
        text = assembler.add(sysid, raw, getattr(msg, "id", 0), getattr(msg, "chunk_seq", 0))
        if text is None:
            return
        sev = (Severity.ERROR if msg.severity <= mavlink.MAV_SEVERITY_ERROR else
               Severity.WARNING if msg.severity == mavlink.MAV_SEVERITY_WARNING else
               Severity.INFO)
        runlog.add(f"vehicle {sysid}", text, sev)

    def on_event(event: object) -> None:
        if isinstance(event, VehicleLost):
            runlog.add(f"vehicle {event.sysid}", f"lost: no heartbeat for {event.silent_s:.0f} s",
                       Severity.ERROR)
        elif isinstance(event, VehicleRecovered):
            runlog.add(f"vehicle {event.sysid}", "heard again", Severity.WARNING)
        elif isinstance(event, VehicleDiscovered):
            runlog.add(f"vehicle {event.sysid}", f"discovered at {event.address[0]}:"
                                                 f"{event.address[1]}")
        elif isinstance(event, ComponentDiscovered):
            runlog.add(f"vehicle {event.sysid}", f"component {event.compid} (MAV_TYPE "
                                                 f"{event.mav_type}) at {event.address[0]}:"
                                                 f"{event.address[1]}")
        elif isinstance(event, TwinRefused):
            runlog.add(f"vehicle {event.sysid}", f"refused a second source of its autopilot at "
                                                 f"{event.address[0]}:{event.address[1]} (a twin: "
                                                 f"the vehicle speaks from {event.known[0]}:"
                                                 f"{event.known[1]}; first message "
                                                 f"{event.message})", Severity.ERROR)
        elif isinstance(event, ForeignVehicle):
            runlog.add(f"vehicle {event.sysid}", f"not in this run's fleet: its messages from "
                                                 f"{event.address[0]}:{event.address[1]} are "
                                                 f"dropped (first {event.message})",
                       Severity.WARNING)
        elif isinstance(event, VehicleMoved):
            runlog.add(f"vehicle {event.sysid}", f"now speaks from {event.new[0]}:{event.new[1]} "
                                                 f"(was {event.old[0]}:{event.old[1]})",
                       Severity.WARNING)

    router.subscribe(Received, lambda r: on_message(r.sysid, r.msg))
    router.subscribe(EVENTS, on_event)


class _RunLogHandler(logging.Handler):
    """Station warnings (``logging``, ``econdor_gcs.*``) into the run's log."""

    def __init__(self, runlog: RunLog) -> None:
        super().__init__(logging.WARNING)
        self.runlog = runlog

    def emit(self, record: logging.LogRecord) -> None:
        sev = Severity.ERROR if record.levelno >= logging.ERROR else Severity.WARNING
        try:
            self.runlog.add("station", record.getMessage(), sev)
        except (OSError, ValueError):  # the log file is gone or closed: say so, on stderr
            self.handleError(record)


@contextlib.contextmanager
def _logging_to(runlog: RunLog) -> Iterator[None]:
    logger = logging.getLogger("econdor_gcs")
    handler = _RunLogHandler(runlog)
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)


def resume_mission(out: Path, *, quiet: bool = True, figures: bool = True,
                   connect: str | Sequence[str] | None = None,
                   timeout_s: float | None = None,
                   link_timeout_s: float | None = None,
                   signing_key_file: Path | None = None) -> dict[str, Any]:
    """Continue the MAVLink run recorded in ``out`` after its last finished flight.

    The finished flights are replayed from ``flights.jsonl`` and ``samples.csv`` (the DFC
    plans them again from the same estimates and checks the plans match), then the vehicles
    fly on from wherever they are: started anew by this process, or the ones at
    ``connect`` (default: the run's own ``--connect``). Samples of the interrupted flight
    are kept in ``samples_interrupted.csv`` and not used.
    """
    from econdor_gcs.config import parse_mission
    from econdor_gcs.files.rundir import read_run_config
    from econdor_gcs.link.autopilots import VehicleKind

    config = read_run_config(out)
    if config.get("transport") != "mavlink":
        raise RunError(f"{out}: a {config.get('transport')} run, not a MAVLink one")
    if config.get("signed") and signing_key_file is None:
        raise RunError(f"{out}: the run was signed; resume it with --signing-key")
    copy = out / "mission.yaml"
    original = Path(config["mission_path"]) if config.get("mission_path") else None
    try:
        text = copy.read_text(encoding="utf-8")
    except OSError as exc:
        raise RunError(f"{copy}: cannot read the run's mission ({exc.strerror or exc})") from exc
    import yaml

    base_dir = original.parent if original is not None else out
    mission = parse_mission(yaml.safe_load(text), base_dir=base_dir, source=str(copy))
    mission_path = original if original is not None and original.exists() else copy
    return run_mission(
        mission, out, planner=config["planner"], vehicles=config["vehicles"],
        speedup=config["speedup"], seed=config["seed"],
        connect=connect if connect is not None else config.get("connect"),
        timeout_s=timeout_s if timeout_s is not None else config.get("timeout_s", 60.0),
        link_timeout_s=(link_timeout_s if link_timeout_s is not None
                        else config.get("link_timeout_s", LINK_TIMEOUT_S)),
        quiet=quiet, mission_path=mission_path, figures=figures, mode=RunDirMode.RESUME,
        signing_key_file=signing_key_file,
        autopilots=[VehicleKind.parse(k) for k in config.get("autopilots") or []] or None,
        tolerance_m=float(config.get("tolerance_m", 1.0)))


async def _wait_count(router: Router, n: int, timeout_s: float) -> list[int]:
    try:
        return await router.wait_for_vehicles(n, timeout_s)
    except VehicleTimeout:
        seen = sorted(router.vehicles)
        expected = list(range(1, n + 1))
        missing = [s for s in expected if s not in seen]
        if missing and all(s in expected for s in seen):
            word = "vehicle" if len(missing) == 1 else "vehicles"
            raise VehicleTimeout(
                f"{word} {', '.join(map(str, missing))} never appeared within {timeout_s:g} s "
                f"(heard from: {', '.join(map(str, seen)) or 'none'})") from None
        raise


def run_mission_cli(args: Any) -> int:
    """``econdor run`` (arguments parsed by :mod:`econdor.cli`)."""
    from econdor_gcs.app.fleet import parse_kinds
    from econdor_gcs.config import load_mission

    web = getattr(args, "web", None)
    kinds = parse_kinds(args.autopilot) if getattr(args, "autopilot", None) else None
    forward = getattr(args, "forward", None)
    forward_commands = bool(getattr(args, "forward_commands", False))
    if forward_commands and not forward:
        raise EcondorError("--forward-commands needs --forward udpout:HOST:PORT")
    if kinds is not None and args.connect:
        raise EcondorError("--autopilot chooses the vehicles econdor starts; with --connect "
                           "the vehicles are started elsewhere")
    if args.resume is not None:
        if kinds is not None:
            raise EcondorError("--autopilot: a resumed run starts the vehicles it started "
                               "before (its run.json)")
        out = args.resume
        summary = resume_mission(out, quiet=args.quiet, connect=args.connect,
                                 timeout_s=args.timeout,
                                 link_timeout_s=getattr(args, "link_timeout", None),
                                 signing_key_file=args.signing_key)
    else:
        mission = load_mission(args.mission)
        out = args.out or _default_out(mission)
        mode = RunDirMode.FORCE if args.force else RunDirMode.NEW
        summary = run_mission(mission, out, planner=args.planner, vehicles=args.vehicles,
                              speedup=args.speedup, seed=args.seed, connect=args.connect,
                              timeout_s=args.timeout,
                              link_timeout_s=getattr(args, "link_timeout", None)
                              or LINK_TIMEOUT_S, quiet=args.quiet,
                              mission_path=args.mission, mode=mode,
                              signing_key_file=args.signing_key, web=web,
                              announce=lambda url: print(f"web: {url}", flush=True),
                              warn=lambda text: print(f"econdor: warning: {text}",
                                                      file=sys.stderr, flush=True),
                              autopilots=kinds,
                              tolerance_m=getattr(args, "tolerance_m", None) or 1.0,
                              forward=forward, forward_commands=forward_commands)
    t = summary.get("timings", {})
    mae_db = summary.get("final_mae_db")
    print(f"{summary['planner']}: {summary['iterations']} iterations, final MAE "
          f"{mae_db:.1f} dB ({summary['stop_reason']}), flown "
          f"{summary['flight_distance_m']:.0f} m (contour {summary['contour_distance_m']:.0f} m), "
          f"{summary['samples']} samples, {t.get('total_wall_s', 0):.1f} s wall "
          f"({t.get('achieved_speedup', math.nan):.0f}x sim)")
    print(f"run directory: {out}")
    if web is not None:
        print(f"replay it in the browser: econdor view {out}")
    sys.stdout.flush()
    return 0
