"""``econdor run``: one MAVLink run into a run directory, a resumed one, and the command.

:func:`run_mission` sets up the run directory, the :class:`~.station.loop.Station`, the simulated
fleet (or serves vehicles started elsewhere with ``--connect``), the live display or web
page and the :class:`~.station.executor.MavlinkExecutor`, runs the :class:`~.dfc.loop.Dfc` loop and writes the
results; a run that fails part-way still leaves a usable run directory (samples so far, tlog,
``summary.json`` with ``"error"``). :func:`resume_mission` continues an interrupted run after
its last finished flight; :func:`run_mission_cli` is the command (arguments parsed by
:mod:`econdor.cli`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from econdor_gcs.app.run_failures import checked_disk, refusals, write_partial
from econdor_gcs.app.run_logging import log_station, logging_to
from econdor_gcs.config import Mission
from econdor_gcs.core.tasks import (
    SampleLog,
)
from econdor_gcs.errors import (
    EcondorError,
    RunError,
    VehicleTimeout,
)
from econdor_gcs.files.layout import RunDirMode, disk_error, writing
from econdor_gcs.files.rundir import RunDir
from econdor_gcs.files.runlog import RunLog, Severity
from econdor_gcs.lifetime import sigterm_as_interrupt
from econdor_gcs.link.forward import Forwarder
from econdor_gcs.link.items import MISSION_FENCE_MARGIN_M
from econdor_gcs.link.router import (
    Router,
)
from econdor_gcs.link.signing import load_signing_key
from econdor_gcs.link.tlog import TlogWriter
from econdor_gcs.station.executor import MavlinkExecutor
from econdor_gcs.station.loop import Station
from econdor_gcs.station.losses import LINK_TIMEOUT_S, LOSS_SILENCE_S

if TYPE_CHECKING:
    from econdor_gcs.app.fleet import Fleet
    from econdor_gcs.app.live import LiveDisplay
    from econdor_gcs.app.web.session import LiveWeb
    from econdor_gcs.dfc.loop import Dfc
    from econdor_gcs.link.autopilots import VehicleKind

__all__ = ["RunOptions", "resume_mission", "run_mission", "run_mission_cli"]

T = TypeVar("T")
log = logging.getLogger(__name__)


def _default_out(mission: Mission) -> Path:
    return Path("runs") / f"{mission.name}-{time.strftime('%Y%m%d-%H%M%S')}"


@dataclass(frozen=True)
class RunOptions:
    """How :func:`run_mission` runs a mission (``econdor run``'s options); the defaults are
    the command's."""

    planner: str | None = None
    """The planner (None: the mission's ``algorithm.planner``)."""
    vehicles: int | None = None
    """How many vehicles (None: the mission's ``vehicles.count``)."""
    speedup: float | None = None
    """Simulated time over wall time (None: the mission's ``vehicles.speedup``)."""
    seed: int | None = None
    """The field's seed (None: the mission's)."""
    connect: str | Sequence[str] | None = None
    """Serve vehicles started elsewhere on these links (None: start simulated ones)."""
    timeout_s: float = 60.0
    """How long vehicles may take to appear, to send a position and to pass their pre-arm
    checks."""
    link_timeout_s: float = LINK_TIMEOUT_S
    """How long a vehicle may be silent before it is given up (a shorter drop-out of its link
    is waited out, and the flight picks up where it left; at least
    :data:`~.losses.LOSS_SILENCE_S`)."""
    quiet: bool = True
    """No live display in the terminal."""
    mission_path: Path | None = None
    """The mission's file: copied into the run directory, and what started vehicles read
    (needed without ``connect``)."""
    figures: bool = True
    """Draw the run's figures at the end."""
    mode: RunDirMode = RunDirMode.NEW
    """What to do with a non-empty run directory (:class:`~econdor_gcs.files.layout.RunDirMode`); to resume a
    run use :func:`resume_mission`."""
    signing_key_file: Path | None = None
    """MAVLink 2 signing (:func:`~.signing.load_signing_key`): every message is signed,
    unsigned telemetry is dropped, and the vehicles this run starts sign too (the key is
    written nowhere)."""
    web: str | None = None
    """``[HOST:]PORT`` of the run's page (:mod:`econdor_gcs.app.web`) with pause / resume /
    stop."""
    announce: Callable[[str], None] | None = None
    """Told the page's address (with the token the controls need) as soon as it listens."""
    warn: Callable[[str], None] | None = None
    """Told that the page's controls are on the network when ``web`` is not a loopback
    address."""
    autopilots: Sequence[VehicleKind] | None = None
    """The kinds of the simulated vehicles this run starts, in turn (None: PX4 with the
    tracer on board)."""
    tolerance_m: float = 1.0
    """Douglas-Peucker tolerance of the waypoint polylines for vehicles that refuse contour
    items."""
    forward: str | None = None
    """A watcher's ``udpout:HOST:PORT`` that gets every vehicle message
    (:mod:`.link.forward`)."""
    forward_commands: bool = False
    """What the watcher sends reaches the vehicles (else it is dropped)."""


def run_mission(mission: Mission, out: Path, options: RunOptions | None = None,
                **fields: Any) -> dict[str, Any]:
    """One MAVLink run into ``out`` with ``options`` (any of their ``fields`` may be given
    as keywords instead); returns the summary (see ``summary.json``).

    Raises :class:`EcondorError` on failure, after writing a partial run directory
    (samples so far, tlog, ``summary.json`` with ``"error"``).
    """
    opts = dataclasses.replace(options or RunOptions(), **fields)
    summary = _MavlinkRun(mission, Path(out), opts).run()
    if opts.figures:
        from econdor_gcs.files.figures import plot_run

        plot_run(out)
    return summary


class _MavlinkRun:
    """One run of :func:`run_mission`: what it holds open, set up and given back in order
    by one :class:`contextlib.ExitStack` (run directory, log, tlog, station, fleet, forward,
    web page, live display), so a failure at any step closes exactly what was opened."""

    def __init__(self, mission: Mission, out: Path, opts: RunOptions) -> None:
        from econdor_gcs.app.fleet import DEFAULT_KIND

        self.wall0 = time.perf_counter()
        if not opts.link_timeout_s >= LOSS_SILENCE_S:
            raise RunError(f"--link-timeout must be at least {LOSS_SILENCE_S:g} s (vehicles "
                           f"heartbeat once a second), got {opts.link_timeout_s:g}")
        self.opts = opts
        self.signing = (load_signing_key(opts.signing_key_file)
                        if opts.signing_key_file is not None else None)
        self.n = opts.vehicles or mission.vehicles.count
        self.speed = opts.speedup or mission.vehicles.speedup
        self.seed = mission.seed if opts.seed is None else opts.seed
        self.planner = opts.planner or mission.algorithm.planner
        self.mission = mission.with_vehicles(count=self.n, speedup=self.speed)
        self.out = out
        self.kinds = list(opts.autopilots or [DEFAULT_KIND])
        self.resume = opts.mode == RunDirMode.RESUME
        self.fleet: Fleet | None = None
        self.forwarder: Forwarder | None = None
        self.executor: MavlinkExecutor | None = None
        self.dfc: Dfc | None = None
        self.live: LiveDisplay | None = None
        self.page: LiveWeb | None = None
        self.base: dict[str, Any] = {
            "transport": "mavlink", "truth_known": True, "mission": mission.name,
            "planner": self.planner, "seed": self.seed, "vehicles": self.n,
            "speedup": self.speed, "connect": opts.connect or None}
        self.timings: dict[str, float] = {}

    def run(self) -> dict[str, Any]:
        from econdor_gcs.files.checkpoint import read_checkpoint

        o = self.opts
        replay = read_checkpoint(self.out) if self.resume else []
        # the stop signals' scope holds the clean-up too: a second Ctrl-C must not cut it
        with sigterm_as_interrupt(), contextlib.ExitStack() as stack:
            self.rd = RunDir(self.out, o.mode, grid=self.mission.grid, received=True)
            stack.callback(self.rd.close)
            self.runlog = RunLog(self.out / "log.jsonl")
            stack.callback(self.runlog.close)
            if not self.resume:
                self._write_config()
            with writing(self.out / "telemetry.tlog"):
                self.tlog = TlogWriter(self.out / "telemetry.tlog", append=self.resume)
            stack.callback(self.tlog.close)
            # the station closes before the fleet stops: what the vehicles say while they
            # shut down is not the run's
            stack.callback(self._stop_fleet)
            self.station = Station(o.connect or "udpin:127.0.0.1:0", self.tlog,
                                   heartbeat_timeout_s=o.link_timeout_s, signing=self.signing)
            stack.callback(self.station.close)
            stack.callback(self._close_outputs)
            log_station(self.station.router, self.runlog)
            try:
                with logging_to(self.runlog):
                    return self._fly(replay)
            except (EcondorError, KeyboardInterrupt, OSError) as exc:
                failure = self._fail(exc)
                if failure is not exc:
                    raise failure from exc
                raise
        raise AssertionError("unreachable")  # pragma: no cover - the with returns or raises

    def _write_config(self) -> None:
        o = self.opts
        path = o.mission_path
        self.rd.write_run_config({
            "transport": "mavlink", "mission": self.mission.name, "planner": self.planner,
            "seed": self.seed, "vehicles": self.n, "speedup": self.speed,
            "connect": o.connect, "timeout_s": o.timeout_s,
            "link_timeout_s": o.link_timeout_s,
            "mission_path": str(path.resolve()) if path else None,
            "signed": self.signing is not None,
            "autopilots": [str(k) for k in self.kinds] if o.connect is None else None,
            "tolerance_m": o.tolerance_m,
        }, path.read_text(encoding="utf-8") if path else None)

    def _fill_timings(self) -> None:
        t = self.timings
        t["total_wall_s"] = time.perf_counter() - self.wall0
        if self.executor is not None:
            t.update(self.executor.timings)
            t["sim_s"] = self.executor.sim_s
            # how fast the vehicles' clocks ran against ours over the run, not the flights'
            # sim_s over flying time: a flight's clock starts before its upload, which a
            # lossy link makes long
            t["achieved_speedup"] = self.executor.clock_rate()
        if self.dfc is not None:
            t["reconstruction_s"] = self.dfc.recon_s
        t["requested_speedup"] = self.speed

    def _start_web(self) -> None:
        from econdor_gcs.app.web.session import LiveWeb

        o = self.opts
        assert o.web is not None
        self.page = LiveWeb(o.web, mission=self.mission, planner=self.planner,
                            run_dir=str(self.out), runlog=self.runlog)
        url = self.page.start()
        self.runlog.add("station", f"web page at {url}")
        if o.announce is not None:
            o.announce(url)
        if self.page.exposed:
            warning = (f"the web page and its controls (pause, resume, stop) are "
                       f"reachable from the network on {o.web}: anyone with the "
                       "address above (its token) can stop the run")
            self.runlog.add("station", warning, Severity.WARNING)
            if o.warn is not None:
                o.warn(warning)

    def _vehicles(self, host: str, port: int) -> list[int]:
        """The fleet's system ids: the vehicles this run starts, or the first ``n`` that
        appear on the links."""
        from econdor_gcs.app.fleet import Fleet

        o, station = self.opts, self.station
        if o.connect is not None:
            try:
                return station.call(_wait_count(station.router, self.n, o.timeout_s))
            except VehicleTimeout as exc:
                raise VehicleTimeout(str(exc) + refusals(station.router)) from None
        if o.mission_path is None:
            raise RunError("run_mission: mission_path is needed to start vehicles")
        self.fleet = Fleet(o.mission_path, self.out / "vehicles")
        self.fleet.start(self.n, f"udpout:{host}:{port}", speedup=self.speed, seed=self.seed,
                         signing_key_file=o.signing_key_file, kinds=self.kinds)
        sysids = list(range(1, self.n + 1))
        try:
            station.call(station.router.wait_for_vehicles(sysids, o.timeout_s))
        except VehicleTimeout as exc:
            raise VehicleTimeout(self.fleet.explain(str(exc)
                                                    + refusals(station.router))) from None
        return sysids

    def _fly(self, replay: list[Any]) -> dict[str, Any]:
        from econdor_gcs.dfc.loop import Dfc
        from econdor_gcs.files.plans import save_next_batch

        o, station, rd, mission = self.opts, self.station, self.rd, self.mission
        if o.web is not None:
            self._start_web()
        host, port = station.start()
        if o.forward is not None:
            self.forwarder = station.call(
                Forwarder(station.router, o.forward, o.forward_commands).start())
        sysids = self._vehicles(host, port)
        # the fleet is named: any other system on these links is a stranger from now on
        station.run_sync(lambda: station.router.expect(sysids))
        t_setup = time.perf_counter() - self.wall0
        executor = self.executor = MavlinkExecutor(
            station, mission, sysids, self.out / "missions", o.timeout_s,
            tolerance_m=o.tolerance_m, link_timeout_s=o.link_timeout_s)
        executor.telemetry.on_rows = lambda v, rows: rd.journal(rows, v.index,
                                                               executor.iteration)
        executor.wait_ready()
        truth = mission.build_field(self.seed)
        progress: list[Callable[[Any], None]] = [rd.progress, self.runlog.progress]
        on_samples: list[Callable[[SampleLog], None]] = []
        if not o.quiet:
            from econdor_gcs.app.live import LiveDisplay

            self.live = LiveDisplay(executor, planner=self.planner, mission=mission.name)
            self.live.start()
            progress.append(self.live.progress)
        page = self.page
        if page is not None:
            page.attach(executor.status_rows, sysids, station.router,
                        on_stop=executor.abort_flight)
            progress.append(page.progress)
            on_samples.append(page.add_samples)
        # the run directory records each flight (samples, then its line) before the DFC
        # uses it; displays see the samples as the DFC takes them in
        dfc = self.dfc = Dfc(mission, executor, planner=self.planner, truth=truth,
                             seed=self.seed, progress=_all_of(progress),
                             on_samples=_all_of(on_samples),
                             on_flight=checked_disk(rd, self.tlog, self.runlog),
                             replay=replay,
                             checkpoint=page.checkpoint if page is not None else None)
        result = dfc.run()
        self._stop_live()
        self._fill_timings()
        self.timings["setup_s"] = t_setup
        result.wall_s = time.perf_counter() - self.wall0
        result.sim_s = executor.sim_s
        save_next_batch(self.out, dfc.planner, mission, result)
        extra = self._summary_extra(sysids)
        if self.resume:
            extra["resumed"] = {"flights_replayed": dfc.replayed,
                                "samples_interrupted": rd.interrupted_samples}
        self.timings["rundir_s"] = rd.write_s
        rd.write_result(result, extra=extra)
        summary = {**result.summary(), **extra, "samples_recorded": rd.n_samples}
        if page is not None:
            page.close(summary)
            self.page = None
        return summary

    def _summary_extra(self, sysids: list[int]) -> dict[str, Any]:
        """What ``summary.json`` holds beside the DFC's result: the fleet, the link and the
        accounting of samples and losses."""
        from econdor_gcs.app.fleet import kinds_for

        o, router, executor = self.opts, self.station.router, self.executor
        assert executor is not None
        parser = router.parser
        started = kinds_for(self.n, self.kinds) if o.connect is None else None
        forwarder = self.forwarder
        return {**self.base, "sysids": sysids, "timings": self.timings,
                "fleet": executor.fleet_summary(started),
                "forward": ({"to": o.forward, "commands": o.forward_commands,
                             **forwarder.stats} if forwarder is not None else None),
                "samples_dropped_unpaired": router.pairer.dropped_total,
                "sample_pairing": router.pairer.counts(),
                "link_conflicts": [c.as_dict() for c in router.table.conflicts],
                "report_errors": executor.report_errors,
                "sample_recovery": executor.sample_accounting(),
                "lost_vehicles": executor.losses,
                "interrupted_flights": executor.interruptions,
                "link_timeout_s": o.link_timeout_s,
                "samples_received": self.rd.n_received,
                "fence": {"margin_m": MISSION_FENCE_MARGIN_M,
                          "refused_by": executor.fences_refused},
                "link": {"bad_packets": parser.bad_packets,
                         "unknown_packets": parser.unknown_packets,
                         "unsigned_dropped": parser.unsigned_packets,
                         "bad_signature_dropped": parser.bad_signature_packets,
                         "refused_by_sysid": {str(k): v for k, v in sorted(
                             parser.refused_by_source().items())}},
                "signed": self.signing is not None}

    def _fail(self, exc: BaseException) -> BaseException:
        """Leave a usable run directory after ``exc``; the error to raise (a write the run
        directory does not guard, such as figures or a library's file, as one line)."""
        self._stop_live()
        failure = disk_error(None, exc) if isinstance(exc, OSError) else exc
        msg = "interrupted" if isinstance(exc, KeyboardInterrupt) else str(failure)
        self.runlog.add("station", f"run failed: {msg}", Severity.ERROR)
        self.base["link_conflicts"] = [c.as_dict()
                                       for c in self.station.router.table.conflicts]
        tlog = self.tlog
        write_partial(self.rd, self.dfc, self.executor, self.base, self.timings,
                      self._fill_timings, msg,
                      disk=[e for e in (tlog.error and str(disk_error(tlog.path, tlog.error)),
                                        self.runlog.error, self.rd.journal_error) if e])
        if self.page is not None:
            self.page.close({**self.base, "error": msg})
            self.page = None
        return failure

    def _stop_live(self) -> None:
        if self.live is not None:
            self.live.stop()
            self.live = None

    def _close_outputs(self) -> None:
        """The live display, the web page (without a summary: the run did not get to one)
        and the forward to a watcher."""
        self._stop_live()
        if self.page is not None:
            self.page.close(None)
        if self.forwarder is not None:
            self.station.loop.call_soon_threadsafe(self.forwarder.close)

    def _stop_fleet(self) -> None:
        if self.fleet is not None:
            self.fleet.stop()


def _all_of(callbacks: Sequence[Callable[[T], None]]) -> Callable[[T], None]:
    """One callback that calls each of ``callbacks`` in turn."""
    def call(arg: T) -> None:
        for cb in callbacks:
            cb(arg)

    return call


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
    return run_mission(mission, out, RunOptions(
        planner=config["planner"], vehicles=config["vehicles"], speedup=config["speedup"],
        seed=config["seed"],
        connect=connect if connect is not None else config.get("connect"),
        timeout_s=timeout_s if timeout_s is not None else config.get("timeout_s", 60.0),
        link_timeout_s=(link_timeout_s if link_timeout_s is not None
                        else config.get("link_timeout_s", LINK_TIMEOUT_S)),
        quiet=quiet, mission_path=mission_path, figures=figures, mode=RunDirMode.RESUME,
        signing_key_file=signing_key_file,
        autopilots=[VehicleKind.parse(k) for k in config.get("autopilots") or []] or None,
        tolerance_m=float(config.get("tolerance_m", 1.0))))


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
        summary = run_mission(mission, out, RunOptions(
            planner=args.planner, vehicles=args.vehicles, speedup=args.speedup,
            seed=args.seed, connect=args.connect, timeout_s=args.timeout,
            link_timeout_s=getattr(args, "link_timeout", None) or LINK_TIMEOUT_S,
            quiet=args.quiet, mission_path=args.mission, mode=mode,
            signing_key_file=args.signing_key, web=web,
            announce=lambda url: print(f"web: {url}", flush=True),
            warn=lambda text: print(f"econdor: warning: {text}", file=sys.stderr,
                                    flush=True),
            autopilots=kinds, tolerance_m=getattr(args, "tolerance_m", None) or 1.0,
            forward=forward, forward_commands=forward_commands))
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
