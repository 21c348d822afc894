"""The ground station's MAVLink executor: the DFC loop flown by MAVLink vehicles.

Pieces, from the bottom up:

:class:`~.loop.Station`
    An asyncio event loop on a background thread that owns the GCS :class:`~.link.Router`
    (one UDP endpoint, vehicles routed by system id, every message to ``telemetry.tlog``).
    The synchronous world (the :class:`~.dfc.Dfc` loop in the main thread) submits
    coroutines with :meth:`Station.call`; Ctrl-C / SIGTERM interrupt that wait in the main
    thread and the ``finally`` blocks close everything. **That loop thread alone owns the
    vehicle state**: the router's callbacks update it there, the flights run there, and
    other threads (the DFC's ``positions()``, the live display's ``status_rows()``, the
    error path's ``pending_samples()``) get their answers made there
    (:meth:`Station.run_sync`). Waits wake on what the vehicles send (an event set by every
    sample, message and router event), not on polling.
:class:`MavlinkExecutor`
    The :class:`~.dfc.Executor` over MAVLink, the drop-in twin of
    :class:`econdor_lab.inprocess.InProcessExecutor`: per vehicle, a mission "item 0 home,
    takeoff, DO_CHANGE_SPEED, the tasks" is uploaded (:func:`~econdor_gcs.link.items.plan_mission`;
    a contour piece as a trace item, or as the waypoint polyline of the estimated contour for
    a vehicle that refused trace items), the vehicle started the autopilot's way
    (:func:`~.link.autopilots.start_mission`), and its samples collected until it reports
    ``MISSION_ITEM_REACHED`` for its last task item.
    The executor runs the flights (upload, start, wait, recover, rounds for the work of lost
    vehicles, the way home) with its parts, all on the station's loop thread:
    :class:`~.startup.VehicleStartup` (before the first flight: positions, stream rates,
    the geofence),
    :class:`~.telemetry.StationTelemetry` (what the vehicles send: the router's callbacks,
    sample conversion, flight reports, status rows), :class:`~.sorties.VehicleMissions`
    (each vehicle's missions planned, saved and uploaded, and its geofence),
    :class:`~.losses.VehicleLosses` (vehicles given up, item time limits, and where their
    work goes) and :class:`~.recovery.SampleRecovery` (after each flight, every sample the
    vehicles took brought in).
:mod:`econdor_gcs.app.run`
    The ``econdor run`` command on top of them: run directory, simulated fleet (or
    ``--connect``), live display, results, figures, and one-line errors that still leave a
    usable run directory.

Conventions and choices (see also DESIGN.md §4):

* **No end item.** The missions end with the last task (``plan_mission(end="none")``):
  a vehicle that completes its mission holds where it is (AUTO.LOITER), exactly like the
  in-process vehicles keep their position between iterations. A ``LOITER_UNLIM`` at the
  last task's *point* would send a tracer back to the start of its contour piece (traces
  end elsewhere), adding flight the in-process run does not have.
* **Phase of a sample**: decided once, when its flight ends
  (:func:`~.flight.decide_phases`): ``SURVEY`` in a flight the DFC flies as a survey
  (``fly(..., survey=True)``), else from the vehicle's ``NAMED_VALUE_INT("PHASE")``
  changes, looked up by the sample's ``time_boot_ms`` (:class:`~.link.reports.PhaseTrack`);
  a vehicle that reports no phases (a stock autopilot) gets the phase its mission item
  implies.
* **Distances.** ``traced_m`` and trace outcomes come from the vehicle's
  ``DEBUG_FLOAT_ARRAY("TRACE")`` reports (:class:`~.core.tasks.TraceReport`); STATUSTEXT is
  for people only (the live display shows the last one). A contour flown as waypoints is
  ``reached`` when its last waypoint is, and its traced distance is the path flown after its
  first waypoint. ``flown_m`` is the path
  length of the reported sample positions, starting at the vehicle's position when the
  flight began (the vehicle reports no odometer; samples come every sensor tick of
  horizontal motion, so this misses only the braking drift while hovering).
* **Positions.** Samples are ``GLOBAL_POSITION_INT`` + ``NAMED_VALUE_FLOAT("FIELD")``;
  latitude/longitude go back to local ENU on the origin's ellipsoid height (the vehicle
  converts its local position with up = 0) with pymap3d. Received samples are buffered raw
  per vehicle and converted in batches (one vectorised ``Origin.to_local_many`` call) when a
  report, the pending samples, a position or the live display needs them, or when the
  buffer reaches :data:`~.telemetry.SAMPLE_BATCH`.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import threading
import time
from collections.abc import Callable, Coroutine, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from econdor_gcs.config import Mission
from econdor_gcs.core.tasks import FlightReport, SampleLog, Task
from econdor_gcs.errors import ProtocolError
from econdor_gcs.link.router import AIRBORNE_ALT_M, Received, Sample, VehicleLost
from econdor_gcs.link.vehicles import EVENTS
from econdor_gcs.station.loop import Station
from econdor_gcs.station.losses import LINK_TIMEOUT_S, VehicleLosses, run_all
from econdor_gcs.station.procedures import Commands
from econdor_gcs.station.recovery import SampleRecovery
from econdor_gcs.station.sorties import VehicleMissions
from econdor_gcs.station.startup import VehicleStartup
from econdor_gcs.station.status import VehicleStatus
from econdor_gcs.station.telemetry import StationTelemetry, VehicleRow, VehicleState

if TYPE_CHECKING:
    from econdor_gcs.link.autopilots import VehicleKind

__all__ = ["MavlinkExecutor"]

T = TypeVar("T")
log = logging.getLogger(__name__)

MAX_ROUNDS = 8
"""Rounds of one iteration's flight: the plans, then the pieces left unfinished by vehicles
given up or taken off their missions by their own failsafe, flown again."""

# --------------------------------------------------------------------------------------------
# pure helpers (unit-tested in tests/station/test_gcs_unit.py)


def _merge(a: FlightReport, b: FlightReport) -> FlightReport:
    """One vehicle's report of two flights in one iteration (b after a)."""
    return FlightReport(vehicle=a.vehicle, samples=SampleLog.concat([a.samples, b.samples]),
                        flown_m=a.flown_m + b.flown_m, traced_m=a.traced_m + b.traced_m,
                        outcomes=a.outcomes + b.outcomes, end_x_m=b.end_x_m, end_y_m=b.end_y_m,
                        sim_s=a.sim_s + b.sim_s)


# --------------------------------------------------------------------------------------------
# the executor


class MavlinkExecutor:
    """Flies the DFC's per-vehicle task lists on MAVLink vehicles (the :class:`Executor`
    protocol; the drop-in twin of :class:`econdor_lab.inprocess.InProcessExecutor`).

    Parameters
    ----------
    station:
        A started :class:`Station`; the vehicles ``sysids`` must have been heard from.
    mission:
        Origin (geodesy) and altitude of the missions.
    sysids:
        System ids, in vehicle-index order.
    missions_dir:
        Every uploaded mission is saved here as ``iter{NN}_v{sysid}.json`` (and
        ``.waypoints`` when :mod:`econdor_gcs.app.export` is available).
    timeout_s:
        Per-message timeout of commands / transfers is the link layer's; this bounds a whole
        mission transfer, the wait for the first position and for the pre-arm checks.
    link_timeout_s:
        A vehicle silent this long is given up (:data:`~.losses.LINK_TIMEOUT_S`); a
        shorter silence is waited out.
    tolerance_m:
        Douglas-Peucker tolerance of the waypoint polylines given to vehicles that refuse
        contour items (stock autopilots).

    Each vehicle gets contour pieces as trace items until it refuses one with
    ``MAV_MISSION_UNSUPPORTED``; from then on (that mission included) it gets the estimated
    contour of each piece as a waypoint polyline (:attr:`VehicleState.style`).
    """

    def __init__(self, station: Station, mission: Mission, sysids: Sequence[int],
                 missions_dir: Path | None = None, timeout_s: float = 20.0,
                 tolerance_m: float = 1.0, link_timeout_s: float = LINK_TIMEOUT_S) -> None:
        self.station = station
        self.router = station.router
        self.mission = mission
        self.sysids = list(sysids)
        self.n_vehicles = len(self.sysids)
        self.missions_dir = missions_dir
        self.timeout_s = timeout_s
        self.tolerance_m = tolerance_m
        self.origin = mission.origin
        self._changed = asyncio.Event()
        """Set by every sample, message and event from the vehicles (on the loop thread, which
        owns all this state): the waits wake on it instead of polling."""
        self.altitude_m = mission.vehicles.altitude_m
        self.home = (0.0, 0.0)
        self.telemetry = StationTelemetry(self.router, self.origin, self.sysids,
                                          self._changed, self.home)
        """Each vehicle's state, kept from what it sends (the router's callbacks)."""
        self.vehicles = self.telemetry.vehicles
        self.timings = {"protocol_s": 0.0, "flight_s": 0.0, "return_s": 0.0,
                        "flight_sim_s": 0.0, "return_sim_s": 0.0}
        """Wall seconds per activity; ``flight_sim_s`` / ``return_sim_s``: the vehicles'
        own time over the same wall intervals as ``flight_s`` / ``return_s``."""
        self.iteration = 0
        self.sim_s = 0.0
        self.vehicle_losses = VehicleLosses(self.router, self.mission, self.vehicles,
                                            self.sysids, iteration=lambda: self.iteration,
                                            until=self._until, link_timeout_s=link_timeout_s)
        """Vehicles given up: silence, time limits, and where their work goes."""
        self.commands = Commands(self.router, self._until, timeout_s)
        """Arming, starting, returning: each done when acknowledged or seen done."""
        self.vehicle_missions = VehicleMissions(
            self.router, self.telemetry, self.vehicle_losses, self.mission,
            missions_dir=missions_dir, timeout_s=timeout_s, tolerance_m=tolerance_m,
            home=self.home)
        """Each vehicle's missions: planned, saved, uploaded (and the geofence)."""
        self._abort = threading.Event()
        """Set by :meth:`abort_flight` (any thread): the flight in progress ends now."""
        self._in_hand: dict[int, FlightReport] = {}
        """Reports of the flight in progress whose rounds have ended (see :meth:`_fly`)."""
        self.recovery = SampleRecovery(self.router, self.mission, self.vehicles, self.timings,
                                       self.vehicle_losses, self._until,
                                       lambda: self.aborted)
        """Every sample a vehicle took brought in after each flight (resends)."""
        self.startup = VehicleStartup(self.router, self.mission, self.sysids, self.vehicles,
                                      self.vehicle_missions, self.vehicle_losses, self._until,
                                      timeout_s)
        """The vehicles made ready: positions, streams, geofence."""
        self.router.subscribe(Sample, self.telemetry.on_sample)
        self.router.subscribe(Received, lambda r: self.telemetry.on_message(r.sysid, r.msg))
        self.router.subscribe(EVENTS, self._on_event)

    @property
    def fences_refused(self) -> list[int]:
        """Vehicles that refused the geofence upload (they fly without one)."""
        return self.vehicle_missions.fences_refused

    @property
    def losses(self) -> list[dict[str, Any]]:
        """Every vehicle given up (:attr:`.losses.VehicleLosses.records`)."""
        return self.vehicle_losses.records

    @property
    def interruptions(self) -> list[dict[str, Any]]:
        """Every flight a vehicle left on its own (its failsafe), and where its unfinished
        work went (:attr:`.losses.VehicleLosses.interruptions`)."""
        return self.vehicle_losses.interruptions

    @property
    def report_errors(self) -> int:
        """Malformed PHASE / TRACE reports received (logged, then ignored)."""
        return self.telemetry.report_errors

    # -- callbacks (on the station's loop thread) -----------------------------------------------
    def _on_event(self, event: object) -> None:
        self._changed.set()
        if isinstance(event, VehicleLost) and event.sysid in self.vehicles:
            self.vehicle_losses.mark_lost(self.vehicles[event.sysid],
                                          f"no heartbeat for {event.silent_s:.0f} s")

    # -- Executor protocol ----------------------------------------------------------------------
    def wait_ready(self) -> None:
        """Wait until every vehicle has reported a position (:class:`.startup.VehicleStartup`)."""
        self.station.call(self.startup.run())

    def clock_rate(self) -> float:
        """The vehicles' achieved speed-up (:meth:`.telemetry.StationTelemetry.clock_rate`)."""
        return self._owned(self.telemetry.clock_rate)

    def _owned(self, fn: Callable[[], T]) -> T:
        """``fn()`` on the thread that owns the vehicle state (the station's loop)."""
        run_sync = getattr(self.station, "run_sync", None)
        return run_sync(fn) if run_sync is not None else fn()

    def positions(self) -> list[tuple[float, float]]:
        return self._owned(lambda: [self.telemetry.position(s) for s in self.sysids])

    def fly(self, plans: list[list[Task]], iteration: int, *, survey: bool = False
            ) -> list[FlightReport]:
        if len(plans) != self.n_vehicles:
            raise ValueError(f"expected {self.n_vehicles} plans, got {len(plans)}")
        self.iteration = iteration
        return self.station.call(self._fly(plans, iteration, survey))

    def abort_flight(self) -> None:
        """End the flight in progress now (an operator's stop; any thread): every vehicle
        still flying its mission is sent home, its unfinished tasks stay unreported, and
        :meth:`fly` returns what was flown. Later flights are not started (:meth:`fly`
        returns at once); :meth:`finish` still brings everyone down."""
        self._abort.set()
        self.station.loop.call_soon_threadsafe(self._changed.set)

    @property
    def aborted(self) -> bool:
        """Whether :meth:`abort_flight` was called."""
        return self._abort.is_set()

    def sample_accounting(self) -> dict[str, dict[str, int | str | None]]:
        """Per vehicle: samples taken, received, recovered, duplicates, missing
        (:meth:`.recovery.SampleRecovery.sample_accounting`; for summary.json)."""
        return self.recovery.sample_accounting()

    def finish(self) -> list[FlightReport]:
        """RTL every airborne vehicle; wait until each has landed and disarmed."""
        return self.station.call(self._finish())

    # -- the flights ----------------------------------------------------------------------------
    def pending_samples(self) -> SampleLog:
        """Samples received but not yet handed to the DFC (e.g. when a flight failed): the
        flights in progress, and the rounds of the failed flight that had ended already."""
        def take() -> SampleLog:
            ended = [r.samples for r in self._in_hand.values()]
            self._in_hand = {}
            return SampleLog.concat([*ended, self.telemetry.pending_samples()])

        return self._owned(take)

    async def _disarm(self, v: VehicleState) -> None:
        await self.commands.disarm(v)

    async def _return(self, v: VehicleState) -> None:
        await self.commands.return_to_launch(v)

    async def _start(self, v: VehicleState) -> None:
        v.status = VehicleStatus.STARTING
        await self.commands.start_mission(v, 1)
        v.status = VehicleStatus.FLYING

    async def _until(self, cond: Callable[[], bool], *, tick_s: float = 0.25,
                     on_tick: Callable[[], object] | None = None,
                     deadline: float | None = None) -> bool:
        """Wait until ``cond()`` holds, waking whenever something arrives from a vehicle
        (and every ``tick_s`` for ``on_tick``, e.g. the time limits); False at ``deadline``."""
        while True:
            self._changed.clear()
            if cond():
                return True
            self.telemetry.convert_due()
            if on_tick is not None:
                on_tick()
            if deadline is not None and time.monotonic() > deadline:
                return False
            with contextlib.suppress(TimeoutError):  # a tick: look again
                await asyncio.wait_for(self._changed.wait(), tick_s)

    async def _fly(self, plans: list[list[Task]], iteration: int, survey: bool = False
                   ) -> list[FlightReport]:
        """Fly ``plans``; the plans of vehicles lost before, and the pieces a vehicle left
        unfinished (given up, or its own failsafe took it off its mission), are flown in
        further rounds, by the vehicles in service (that one too, once its link is back).
        Every round of a ``survey`` is flown as a survey."""
        self.vehicle_losses.check_lost()
        reports = {v.index: self.telemetry.end_idle(v) for v in self.vehicles.values()}
        # until they are returned, the reports of the rounds flown are what an error on the
        # way (every vehicle lost) would otherwise drop: pending_samples() takes them
        self._in_hand = reports
        plans = self.vehicle_losses.reassign([list(p) for p in plans], [], self.positions)
        for round_no in range(MAX_ROUNDS):
            if self._abort.is_set():
                break
            flown = await self._round(plans, iteration, round_no, survey)
            leftover: list[tuple[int, list[Task]]] = []
            for v in flown:
                cut = v.flight.interrupted if v.flight is not None else None
                r = self.telemetry.end(v)
                if v.lost is not None or cut is not None:
                    left = self.vehicle_losses.unfinished(r)
                    if left:
                        leftover.append((v.sysid, left))
                        if cut is not None and v.lost is None:
                            self.vehicle_losses.record_interruption(v, cut, left)
                    r.outcomes = [o for o in r.outcomes if o.task not in left]
                reports[v.index] = r if round_no == 0 else _merge(reports[v.index], r)
            if not leftover:
                break
            # the vehicles whose link is out are waited for: their failsafe flies them, the
            # station picks up where they left when they are heard again
            await run_all([self._await_link(v) for v in self.vehicles.values()
                           if v.lost is None and not self.vehicle_losses.link_back(v)])
            self.vehicle_losses.check_lost()
            plans = self.vehicle_losses.reassign([[] for _ in self.sysids], leftover,
                                                 self.positions)
        else:
            log.error("iteration %d: pieces still unfinished after %d rounds are left "
                      "unreported", iteration, MAX_ROUNDS)
        self._in_hand = {}
        out = [reports[v.index] for v in self.vehicles.values()]
        self.sim_s += max((r.sim_s for r in out), default=0.0)
        return out

    async def _await_link(self, v: VehicleState) -> None:
        await self.vehicle_losses.wait_link(v)

    async def _round(self, plans: list[list[Task]], iteration: int, round_no: int,
                     survey: bool = False) -> list[VehicleState]:
        """Upload, start and fly one set of plans; return the vehicles that flew."""
        flying: list[VehicleState] = []
        t0 = time.monotonic()
        jobs: list[Coroutine[Any, Any, None]] = []
        for sysid, tasks in zip(self.sysids, plans, strict=True):
            v = self.vehicles[sysid]
            if not tasks or v.lost is not None:
                continue
            flying.append(v)
            jobs.append(self.vehicle_losses.tolerant(v, functools.partial(
                self.vehicle_missions.plan_and_upload, v, tasks, iteration, round_no, survey)))
        # every upload first, then start everyone: streaming vehicles would slow the others'
        # transfers down (their samples share this endpoint)
        await run_all(jobs)
        await run_all([self.vehicle_losses.tolerant(v, functools.partial(self._start, v))
                       for v in flying if v.lost is None])
        t1 = time.monotonic()
        clocks = self._clocks(flying)
        for v in flying:
            v.item_since = t1
            v.item_since_ms = self.router.vehicles[v.sysid].time_boot_ms or 0
        self.timings["protocol_s"] += t1 - t0
        def tick() -> None:
            self.vehicle_losses.check_lost()
            self.vehicle_losses.check_progress(flying)

        await self._until(lambda: self._abort.is_set() or all(
            v.lost is not None or (v.flight is not None and (
                v.flight.done or v.flight.interrupted is not None)) for v in flying),
            on_tick=tick)
        if self._abort.is_set():
            busy = [v for v in flying if v.lost is None and v.flight is not None
                    and not v.flight.done]
            log.warning("operator stop: vehicles %s leave their missions and return to launch",
                        [v.sysid for v in busy])
            await run_all([self.vehicle_losses.tolerant(v, functools.partial(self._return, v))
                           for v in busy])
        self.timings["flight_s"] += time.monotonic() - t1
        self.timings["flight_sim_s"] += self._elapsed_s(clocks)
        await self.recovery.recover([v for v in flying if v.lost is None])
        return flying

    def _clocks(self, vs: list[VehicleState]) -> dict[int, int]:
        """The vehicles' own clocks now (their last position's ``time_boot_ms``)."""
        return {v.sysid: self.router.vehicles[v.sysid].time_boot_ms or 0 for v in vs}

    def _elapsed_s(self, clocks: dict[int, int]) -> float:
        """Vehicle seconds since ``clocks`` (the most any vehicle in service ran)."""
        now = self._clocks([self.vehicles[s] for s in clocks])
        return max((now[s] - t for s, t in clocks.items()
                    if self.vehicles[s].lost is None and now[s] >= t), default=0) / 1000.0

    async def _finish(self) -> list[FlightReport]:
        self.vehicle_losses.check_lost()
        t0 = time.monotonic()
        going: list[VehicleState] = []
        for v in self.vehicles.values():
            if v.lost is not None:
                continue
            link = self.router.vehicles[v.sysid]
            airborne = (link.rel_alt_m or 0.0) > AIRBORNE_ALT_M
            if not airborne:
                if link.armed:
                    with contextlib.suppress(ProtocolError):
                        await self.vehicle_losses.tolerant(
                            v, functools.partial(self._disarm, v))
                # on the ground already (an operator's stop sent it home, and it is down
                # before the run ends): landed, whatever its flight was last called
                v.status = VehicleStatus.LANDED
                continue
            self.telemetry.begin(v, [])
            going.append(v)
        for v in going:
            v.status = VehicleStatus.RETURNING
            await self.vehicle_losses.tolerant(v, functools.partial(self._return, v))
            # the way home has the time limit of an item anywhere in the area
            v.item_since = time.monotonic()
            v.item_since_ms = self.router.vehicles[v.sysid].time_boot_ms or 0
        self.timings["protocol_s"] += time.monotonic() - t0
        t1 = time.monotonic()
        clocks = self._clocks(going)

        def all_down() -> bool:
            for v in going:
                link = self.router.vehicles[v.sysid]
                f = v.flight
                if f is not None and not f.landed and not link.armed and \
                        (link.rel_alt_m or 0.0) < AIRBORNE_ALT_M and time.monotonic() - t1 > 1.5:
                    f.landed = True  # the heartbeat says so (EXTENDED_SYS_STATE may be lost)
            return all(v.flight is None or v.flight.landed or v.lost is not None
                       for v in going)

        def tick() -> None:
            self.vehicle_losses.check_lost()
            self.vehicle_losses.check_progress(going)

        await self._until(all_down, on_tick=tick)
        # the heartbeat (1 Hz) confirms the disarm; a vehicle that never says so is left be
        await self._until(lambda: not any(self.router.vehicles[v.sysid].armed
                                          for v in going if v.lost is None),
                          deadline=time.monotonic() + 2.5)
        for v in going:
            v.status = VehicleStatus.LANDED
        self.timings["return_s"] += time.monotonic() - t1
        self.timings["return_sim_s"] += self._elapsed_s(clocks)
        await self.recovery.recover(going)
        reports = [self.telemetry.end(v) if v in going else self.telemetry.end_idle(v)
                   for v in self.vehicles.values()]
        for r, v in zip(reports, self.vehicles.values(), strict=True):
            if v in going:
                r.end_x_m, r.end_y_m = self.telemetry.position(v.sysid)
        self.sim_s += max((r.sim_s for r in reports), default=0.0)
        return reports

    # -- for the live display ---------------------------------------------------------------
    def status_rows(self) -> list[VehicleRow]:
        """A snapshot of every vehicle, in vehicle-index order: the one way displays read
        vehicle state (any thread may ask; the rows are made on the thread that owns the
        state, and nothing returned is live)."""
        return self._owned(self._status_rows)

    def _status_rows(self) -> list[VehicleRow]:
        """:meth:`.telemetry.StationTelemetry.status_rows`, for :meth:`status_rows`."""
        return self.telemetry.status_rows()

    def fleet_summary(self, started: Sequence[VehicleKind] | None = None
                      ) -> list[dict[str, Any]]:
        """Per vehicle: system id, ``autopilot`` (from its HEARTBEAT), the kind this run
        started (``started_as``, None for vehicles started elsewhere), ``mode``: how it was
        given contour pieces (``trace`` items, ``waypoints`` polylines, or None if it was
        given none), and ``tasks_flown``: how many tasks it flew to an outcome each way
        (:attr:`VehicleState.tasks_flown`)."""
        return self.telemetry.fleet_summary(started)
