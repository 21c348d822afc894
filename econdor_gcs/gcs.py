"""The ground station: the DFC loop flown by MAVLink vehicles (``econdor run``).

Pieces, from the bottom up:

:class:`Station`
    An asyncio event loop on a background thread that owns the GCS :class:`~.link.Router`
    (one UDP endpoint, vehicles routed by system id, every message to ``telemetry.tlog``).
    The synchronous world (the :class:`~.dfc.Dfc` loop in the main thread) submits
    coroutines with :meth:`Station.call`; Ctrl-C / SIGTERM interrupt that wait in the main
    thread and the ``finally`` blocks close everything.
:class:`MavlinkExecutor`
    The :class:`~.dfc.Executor` over MAVLink, the drop-in twin of
    :class:`econdor_lab.inprocess.InProcessExecutor`: per vehicle, a mission "item 0 home,
    takeoff, DO_CHANGE_SPEED, the tasks" is uploaded (:func:`~.link.mission.plan_mission`;
    a contour piece as a trace item, or as the waypoint polyline of the estimated contour for
    a vehicle that refused trace items), the vehicle started the autopilot's way
    (:func:`~.link.autopilots.start_mission`), and its samples collected until it reports
    ``MISSION_ITEM_REACHED`` for its last task item.
:func:`run_mission_cli`
    The ``econdor run`` command: run directory, simulated fleet (or ``--connect``), live
    display, results, figures, and one-line errors that still leave a usable run directory.

Conventions and choices (see also DESIGN.md §4):

* **No end item.** The missions end with the last task (``plan_mission(end="none")``):
  a vehicle that completes its mission holds where it is (AUTO.LOITER), exactly like the
  in-process vehicles keep their position between iterations. A ``LOITER_UNLIM`` at the
  last task's *point* would send a tracer back to the start of its contour piece (traces
  end elsewhere), adding flight the in-process run does not have.
* **Phase of a sample**: from the vehicle's ``NAMED_VALUE_INT("PHASE")`` changes, looked up
  by the sample's ``time_boot_ms`` (:class:`~.link.reports.PhaseTrack`). A vehicle that
  reports no phases (a stock autopilot) gets the phase its mission item implies.
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
  buffer reaches :data:`SAMPLE_BATCH`.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Coroutine, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from .core.tasks import (
    FlightReport,
    OutcomeStatus,
    Phase,
    SampleLog,
    Task,
    TaskOutcome,
    TaskStyle,
    TraceReport,
    TraceTask,
)
from .errors import (
    EcondorError,
    LinkError,
    MissionRejected,
    ProtocolError,
    RunError,
    VehicleTimeout,
)
from .link.autopilots import AutopilotKind, start_mission
from .link.codec import MAVLinkMessage, mavlink
from .link.forward import Forwarder
from .link.mission import MAV_CMD_WAYPOINT_USER_1, MissionItemSpec, MissionPlan, plan_mission
from .link.reports import PhaseTrack, phase_change, trace_report
from .link.router import (
    Router,
    Sample,
    VehicleDiscovered,
    VehicleLost,
    VehicleRecovered,
)
from .link.tlog import TlogWriter
from .mission import Mission
from .rundir import RunLog, Severity

if TYPE_CHECKING:
    from .fleet import VehicleKind

__all__ = [
    "MavlinkExecutor",
    "Station",
    "StatusAssembler",
    "VehicleStatus",
    "build_report",
    "run_mission",
    "run_mission_cli",
]

T = TypeVar("T")

SAMPLE_BATCH = 512
"""Raw samples buffered per vehicle before they are converted to local metres anyway."""

# --------------------------------------------------------------------------------------------
# pure helpers (unit-tested in tests/test_gcs_unit.py)

log = logging.getLogger(__name__)


class StatusAssembler:
    """Joins STATUSTEXT chunks (MAVLink 2 ``id`` / ``chunk_seq``) into whole texts, for
    people (the live display); nothing the station accounts for reads them.

    A text with ``id == 0`` is complete on its own; a chunked one is complete with a chunk
    shorter than 50 bytes (or an empty terminator). Pending chunks of one id are dropped
    when a new chunk sequence for that id starts at 0.
    """

    def __init__(self) -> None:
        self._parts: dict[tuple[int, int], list[str]] = {}

    def add(self, sysid: int, text: str | bytes, text_id: int = 0, chunk_seq: int = 0,
            raw_len: int | None = None) -> str | None:
        if isinstance(text, bytes | bytearray):
            raw = bytes(text)
            text = raw.decode("utf-8", "replace")
        else:
            raw = text.encode("utf-8")
        text = text.rstrip("\x00")
        full = len(raw.rstrip(b"\x00")) >= 50 if raw_len is None else raw_len >= 50
        if text_id == 0:
            return text
        key = (sysid, text_id)
        if chunk_seq == 0:
            self._parts[key] = []
        parts = self._parts.setdefault(key, [])
        parts.append(text)
        if full:
            return None
        del self._parts[key]
        return "".join(parts)


@dataclass
class Flight:
    """What one vehicle did for one mission, as seen from the ground.

    ``task_seqs[k]`` is the ``(first, last)`` mission seq of task ``k`` (default: one item
    per task from ``first_seq``); ``style`` how its contour pieces were given (trace items,
    or waypoint polylines of the estimated contours).
    """

    index: int
    sysid: int
    tasks: list[Task]
    first_seq: int = 2              # mission seq of the first task (0 home, 1 takeoff)
    task_seqs: list[tuple[int, int]] = field(default_factory=list)
    style: TaskStyle = TaskStyle.TRACE
    start_xy: tuple[float, float] = (0.0, 0.0)
    start_ms: int | None = None
    rows: list[tuple[float, float, float, float, int]] = field(default_factory=list)
    pieces: dict[int, TraceReport] = field(default_factory=dict)
    item_flown_m: dict[int, float] = field(default_factory=dict)
    last_ms: int | None = None
    done: bool = False
    landed: bool = False

    def __post_init__(self) -> None:
        if not self.task_seqs:
            self.task_seqs = [(self.first_seq + k, self.first_seq + k)
                              for k in range(len(self.tasks))]
        if len(self.task_seqs) != len(self.tasks):
            raise ValueError(f"{len(self.tasks)} tasks but {len(self.task_seqs)} item ranges")

    @property
    def last_seq(self) -> int:
        return self.task_seqs[-1][1] if self.task_seqs else -1


def build_report(flight: Flight) -> FlightReport:
    """One :class:`FlightReport` from what was collected during ``flight``."""
    rows = flight.rows
    if rows:
        a = np.asarray(rows, dtype=float)
        log = SampleLog(a[:, 0].copy(), a[:, 1].copy(), a[:, 2].copy(), a[:, 3].copy(),
                        a[:, 4].astype(np.int8),
                        np.full(len(rows), flight.index, dtype=np.int16))
        xy = np.vstack([np.asarray(flight.start_xy)[None, :], a[:, 1:3]])
        flown = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
        end = (float(a[-1, 1]), float(a[-1, 2]))
    else:
        log = SampleLog()
        flown = 0.0
        end = flight.start_xy
    outcomes: list[TaskOutcome] = []
    flown_on = flight.item_flown_m
    for task, (first, last) in zip(flight.tasks, flight.task_seqs, strict=True):
        item_m = sum(flown_on.get(seq, 0.0) for seq in range(first, last + 1))
        if isinstance(task, TraceTask) and flight.style == TaskStyle.WAYPOINTS:
            # the estimated contour, flown as waypoints: along it from the first waypoint on
            along_m = sum(flown_on.get(seq, 0.0) for seq in range(first + 1, last + 1))
            status = OutcomeStatus.REACHED if flight.done else OutcomeStatus.UNREPORTED
            outcomes.append(TaskOutcome(task, status, item_m, along_m if flight.done else 0.0))
        elif isinstance(task, TraceTask):
            rep = flight.pieces.get(task.piece_id)
            if rep is None:
                outcomes.append(TaskOutcome(task, OutcomeStatus.UNREPORTED, item_m, 0.0))
            else:
                outcomes.append(TaskOutcome(task, rep.status, rep.flown_m, rep.traced_m))
        else:
            status = OutcomeStatus.REACHED if flight.done else OutcomeStatus.UNREPORTED
            outcomes.append(TaskOutcome(task, status, item_m))
    traced = float(sum(o.traced_m for o in outcomes))
    sim_s = 0.0
    if flight.start_ms is not None and flight.last_ms is not None:
        sim_s = max(0.0, (flight.last_ms - flight.start_ms) / 1000.0)
    return FlightReport(vehicle=flight.index, samples=log, flown_m=flown, traced_m=traced,
                        outcomes=outcomes, end_x_m=end[0], end_y_m=end[1], sim_s=sim_s)


def mission_items_json(items: Sequence[MissionItemSpec]) -> str:
    return json.dumps([dataclasses.asdict(it) for it in items], indent=1) + "\n"


# --------------------------------------------------------------------------------------------
# the asyncio loop on a thread


class Station:
    """The GCS endpoint (a :class:`Router`) served by an event loop on a background thread."""

    def __init__(self, endpoint: str, tlog: TlogWriter | None = None,
                 heartbeat_timeout_s: float = 20.0) -> None:
        self.loop = asyncio.new_event_loop()
        self.router = Router(endpoint, tlog=tlog, heartbeat_timeout_s=heartbeat_timeout_s)
        self._thread = threading.Thread(target=self._run, name="econdor-gcs", daemon=True)
        self._started = False

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.loop.run_forever()

    def start(self) -> tuple[str, int]:
        """Start the loop and bind the endpoint; return the bound ``(host, port)``."""
        self._thread.start()
        self._started = True
        self.call(self.router.start())
        return self.router.local_address

    def call(self, coro: Coroutine[Any, Any, T], timeout_s: float | None = None) -> T:
        """Run ``coro`` on the station's loop and wait for its result (from another thread).

        The wait is interruptible (Ctrl-C); the coroutine is then cancelled.
        """
        fut = asyncio.run_coroutine_threadsafe(coro, self.loop)
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        try:
            while True:
                try:
                    return fut.result(0.2)
                except TimeoutError:
                    if fut.done():
                        raise
                    if deadline is not None and time.monotonic() > deadline:
                        raise VehicleTimeout(f"no answer within {timeout_s:g} s") from None
        except BaseException:
            fut.cancel()
            raise

    def close(self) -> None:
        if not self._started:
            self.loop.close()
            return
        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(self.router.close(), self.loop).result(5.0)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(5.0)
        if not self._thread.is_alive():
            self.loop.close()
        self._started = False


# --------------------------------------------------------------------------------------------
# the executor


@dataclass
class VehicleState:
    """Ground-side bookkeeping of one vehicle across flights (for the live display too)."""

    index: int
    sysid: int
    current_seq: int | None = None
    items: list[MissionItemSpec] = field(default_factory=list)
    item_phases: dict[int, Phase] = field(default_factory=dict)
    """The phase each item of the uploaded mission implies (for vehicles that report none)."""
    item_phase: Phase = Phase.TRANSIT
    """The phase the current mission item implies."""
    style: TaskStyle | None = None
    """How this vehicle gets contour pieces: trace items until it refuses one (None: it has
    not been given any yet)."""
    phases: PhaseTrack = field(default_factory=PhaseTrack)
    last_text: str = ""
    """The vehicle's last STATUSTEXT, for people."""
    last_xy: tuple[float, float] | None = None
    flown_m: float = 0.0            # the whole run
    samples: int = 0                # the whole run
    flight: Flight | None = None
    stray: list[tuple[float, float, float, float, int]] = field(default_factory=list)
    status: str = "idle"
    raw: list[tuple[int, float, float, float, int, int]] = field(default_factory=list)
    """Samples not yet converted: (time_boot_ms, lat, lon, value, phase, mission seq or -1)."""


@dataclass(frozen=True)
class VehicleStatus:
    """One vehicle as the ground station sees it at one moment (:meth:`MavlinkExecutor.status_rows`)."""

    sysid: int
    index: int
    x_m: float | None
    """Local ENU position (m); ``None`` before the first position report."""
    y_m: float | None
    alt_rel_m: float
    heading_deg: float | None
    """Course over ground, degrees from north (``None`` until the vehicle has moved)."""
    flight_time_s: float
    """Vehicle (sim) time spent airborne over the whole run."""
    armed: bool
    lost: bool
    item: int
    """Current mission item (0 before a mission)."""
    items: int
    """Mission items after home (takeoff + tasks)."""
    phase: Phase
    flown_m: float
    samples: int
    status: str
    """The executor's word: idle, uploading, arming, flying, holding, returning, landed, ..."""
    message: str = ""
    """The vehicle's last STATUSTEXT (for people)."""


#: Wall-clock rates asked of the periodic (display) streams; samples are not affected.
STREAM_WALL_HZ = {
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 4.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 1.0,
}


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
        ``.waypoints`` when :mod:`econdor_gcs.export` is available).
    timeout_s:
        Per-message timeout of commands / transfers is the link layer's; this bounds a whole
        mission transfer and the wait for the first position.
    tolerance_m:
        Douglas-Peucker tolerance of the waypoint polylines given to vehicles that refuse
        contour items (stock autopilots).

    Each vehicle gets contour pieces as trace items until it refuses one with
    ``MAV_MISSION_UNSUPPORTED``; from then on (that mission included) it gets the estimated
    contour of each piece as a waypoint polyline (:attr:`VehicleState.style`).
    """

    def __init__(self, station: Station, mission: Mission, sysids: Sequence[int],
                 missions_dir: Path | None = None, timeout_s: float = 20.0,
                 tolerance_m: float = 1.0) -> None:
        self.station = station
        self.router = station.router
        self.mission = mission
        self.sysids = list(sysids)
        self.n_vehicles = len(self.sysids)
        self.missions_dir = missions_dir
        self.timeout_s = timeout_s
        self.tolerance_m = tolerance_m
        self.origin = mission.origin
        self._raw_lock = threading.RLock()
        self.altitude_m = mission.vehicles.altitude_m
        self.home = (0.0, 0.0)
        self.vehicles = {s: VehicleState(i, s) for i, s in enumerate(self.sysids)}
        self.assembler = StatusAssembler()
        self.timings = {"protocol_s": 0.0, "flight_s": 0.0, "return_s": 0.0}
        self.iteration = 0
        self.sim_s = 0.0
        self._lost: str | None = None
        self.report_errors = 0
        """Malformed PHASE / TRACE reports received (logged, then ignored)."""
        self.router.add_sample_handler(self._on_sample)
        self.router.add_message_handler(self._on_message)
        self.router.add_event_handler(self._on_event)

    # -- callbacks (on the station's loop thread) -----------------------------------------------
    def _on_sample(self, s: Sample) -> None:
        v = self.vehicles.get(s.sysid)
        if v is None:
            return
        seq = v.current_seq if v.current_seq is not None else -1
        with self._raw_lock:
            phase = v.phases.at(s.time_boot_ms) if v.phases.known else v.item_phase
            v.raw.append((s.time_boot_ms, s.lat_deg, s.lon_deg, float(s.value), int(phase),
                          seq))
            v.samples += 1
            f = v.flight
            if f is not None:
                if f.start_ms is None:
                    f.start_ms = s.time_boot_ms
                f.last_ms = s.time_boot_ms if f.last_ms is None else max(f.last_ms, s.time_boot_ms)
            if len(v.raw) >= SAMPLE_BATCH:
                self._convert(v)

    def _convert(self, v: VehicleState) -> None:
        """Convert ``v``'s raw samples to local rows in one vectorised pymap3d call.

        Everything that changes ``v.flight`` calls this first, so one batch always belongs
        to one flight (or to none: stray samples)."""
        with self._raw_lock:
            raw, v.raw = v.raw, []
            if not raw:
                return
            a = np.asarray(raw, dtype=float)
            x, y, _ = self.origin.to_local_many(a[:, 1], a[:, 2], 0.0)
            f = v.flight
            if v.last_xy is not None:
                steps = np.hypot(np.diff(x, prepend=v.last_xy[0]),
                                 np.diff(y, prepend=v.last_xy[1]))
            else:
                steps = np.concatenate(([0.0], np.hypot(np.diff(x), np.diff(y))))
            v.flown_m += float(steps.sum())
            if f is not None:
                seqs = a[:, 5].astype(np.int64)
                for seq in np.unique(seqs[seqs >= 0]).tolist():
                    f.item_flown_m[seq] = f.item_flown_m.get(seq, 0.0) + \
                        float(steps[seqs == seq].sum())
            v.last_xy = (float(x[-1]), float(y[-1]))
            rows = list(zip((a[:, 0] / 1000.0).tolist(), x.tolist(), y.tolist(),
                            a[:, 3].tolist(), a[:, 4].astype(np.int64).tolist(), strict=True))
            (f.rows if f is not None else v.stray).extend(rows)

    def _convert_all(self) -> None:
        for v in self.vehicles.values():
            self._convert(v)

    def _on_message(self, sysid: int, msg: MAVLinkMessage) -> None:
        v = self.vehicles.get(sysid)
        if v is None:
            return
        kind = msg.get_type()
        f = v.flight
        if kind == "MISSION_CURRENT":
            if (f is not None and f.tasks and v.status == "flying" and msg.seq == f.last_seq
                    and getattr(msg, "mission_state", 0) == mavlink.MISSION_STATE_COMPLETE):
                f.done = True  # in case the MISSION_ITEM_REACHED was lost
                v.status = "holding"
            if msg.seq != v.current_seq:
                v.current_seq = msg.seq
                v.item_phase = v.item_phases.get(msg.seq, Phase.TRANSIT)
        elif kind == "MISSION_ITEM_REACHED":
            if f is not None and f.tasks and msg.seq == f.last_seq:
                f.done = True
                v.status = "holding"
        elif kind == "NAMED_VALUE_INT":
            change = self._decode(phase_change, msg)
            if change is not None:
                with self._raw_lock:
                    v.phases.add(*change)
        elif kind == "DEBUG_FLOAT_ARRAY":
            rep = self._decode(trace_report, msg)
            if rep is not None and f is not None:
                f.pieces[rep.piece_id] = rep
        elif kind == "EXTENDED_SYS_STATE":
            if (f is not None and not f.tasks and v.status == "returning"
                    and msg.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND):
                f.landed = True
                v.status = "landed"
        elif kind == "STATUSTEXT":
            raw = bytes(msg.text) if isinstance(msg.text, bytes | bytearray) else \
                msg.text.encode("utf-8", "replace")
            text = self.assembler.add(sysid, raw, getattr(msg, "id", 0),
                                      getattr(msg, "chunk_seq", 0))
            if text is not None:
                v.last_text = text

    def _decode(self, decode: Callable[[MAVLinkMessage], T | None], msg: MAVLinkMessage
                ) -> T | None:
        """A report from ``msg``; a malformed one is logged and counted, then ignored (its
        piece shows as unreported)."""
        try:
            return decode(msg)
        except ProtocolError as exc:
            self.report_errors += 1
            log.warning("%s", exc)
            return None

    def _on_event(self, event: object) -> None:
        if isinstance(event, VehicleLost) and event.sysid in self.vehicles:
            v = self.vehicles[event.sysid]
            where = ""
            if v.flight is not None and v.current_seq is not None:
                where = f" at mission item {v.current_seq}/{len(v.items) - 1}"
            self._lost = (f"vehicle {event.sysid} lost: no heartbeat for "
                          f"{event.silent_s:.0f} s{where}")

    # -- Executor protocol ----------------------------------------------------------------------
    def wait_ready(self) -> None:
        """Wait until every vehicle has reported a position."""
        self.station.call(self._wait_positions())

    async def _wait_positions(self) -> None:
        """Ask for the streams (ArduPilot sends only heartbeats until asked; the request is
        repeated each second in case it was lost) and wait for a position from everyone."""
        deadline = time.monotonic() + self.timeout_s
        next_request = 0.0
        while True:
            missing = [s for s in self.sysids if self.router.vehicles[s].lat_deg is None]
            if not missing:
                break
            now = time.monotonic()
            if now > deadline:
                raise VehicleTimeout(f"vehicle {missing[0]} sent no position within "
                                     f"{self.timeout_s:g} s")
            if now >= next_request:
                for sysid in missing:
                    self.router.request_data_streams(sysid)
                next_request = now + 1.0
            await asyncio.sleep(0.02)
        await asyncio.gather(*(self._slow_streams(s) for s in self.sysids))

    async def _slow_streams(self, sysid: int) -> None:
        """Ask for the display-only streams at a few Hz of *wall* time.

        The samples (GLOBAL_POSITION_INT + FIELD pairs) are all the DFC needs; at high
        speed-ups the periodic streams would otherwise arrive at up to 50 Hz per message
        and vehicle, and ten vehicles then flood the endpoint while the DFC reconstructs.
        Intervals are in vehicle (sim) time, hence the speed-up factor. A vehicle that
        does not support the command keeps its default rates.
        """
        speedup = self.mission.vehicles.speedup
        for message_id, wall_hz in STREAM_WALL_HZ.items():
            with contextlib.suppress(LinkError):
                await self.router.set_message_interval(sysid, message_id, speedup / wall_hz)

    def _position(self, sysid: int) -> tuple[float, float]:
        link = self.router.vehicles.get(sysid)
        if link is None or link.lat_deg is None or link.lon_deg is None:
            return self.home
        x, y, _ = self.origin.to_local(link.lat_deg, link.lon_deg, 0.0)
        return x, y

    def positions(self) -> list[tuple[float, float]]:
        return [self._position(s) for s in self.sysids]

    def fly(self, plans: list[list[Task]], iteration: int) -> list[FlightReport]:
        if len(plans) != self.n_vehicles:
            raise ValueError(f"expected {self.n_vehicles} plans, got {len(plans)}")
        self.iteration = iteration
        return self.station.call(self._fly(plans, iteration))

    def finish(self) -> list[FlightReport]:
        """RTL every airborne vehicle; wait until each has landed and disarmed."""
        return self.station.call(self._finish())

    # -- the flights ----------------------------------------------------------------------------
    def _begin(self, v: VehicleState, tasks: list[Task], plan: MissionPlan | None = None
               ) -> Flight:
        self._convert(v)  # samples so far belong to the previous state
        link = self.router.vehicles[v.sysid]
        # where it hovers now (the in-process vehicles also start from rest after braking)
        start = self._position(v.sysid)
        f = Flight(v.index, v.sysid, list(tasks), start_xy=start, start_ms=link.time_boot_ms,
                   task_seqs=list(plan.task_seqs) if plan else [],
                   style=plan.style if plan else TaskStyle.TRACE)
        f.rows.extend(v.stray)  # nothing is ever dropped
        v.stray.clear()
        v.flight = f
        return f

    def _end(self, v: VehicleState) -> FlightReport:
        self._convert(v)
        f = v.flight
        v.flight = None
        if f is None:
            return FlightReport(v.index, SampleLog(), 0.0, 0.0, [], *self._position(v.sysid),
                                0.0)
        return build_report(f)

    def pending_samples(self) -> SampleLog:
        """Samples received but not yet handed to the DFC (e.g. when a flight failed)."""
        logs = []
        with self._raw_lock:
            self._convert_all()
            for v in self.vehicles.values():
                rows = list(v.stray) + (list(v.flight.rows) if v.flight is not None else [])
                v.stray.clear()
                if v.flight is not None:
                    v.flight.rows.clear()
                if rows:
                    a = np.asarray(rows, dtype=float)
                    logs.append(SampleLog(a[:, 0], a[:, 1], a[:, 2], a[:, 3],
                                          a[:, 4].astype(np.int8),
                                          np.full(len(rows), v.index, dtype=np.int16)))
        return SampleLog.concat(logs)

    def _save_mission(self, iteration: int, sysid: int, items: list[MissionItemSpec],
                      tasks: Sequence[Task]) -> None:
        """``iter{NN}_v{sysid}.json`` (items), ``.waypoints`` (QGC WPL) and ``.tasks.json``
        (the tasks, with the estimated contours, for ``econdor export --iteration``)."""
        if self.missions_dir is None:
            return
        from .mission_files import write_wpl
        from .plans import write_tasks

        stem = self.missions_dir / f"iter{iteration:02d}_v{sysid}"
        try:
            self.missions_dir.mkdir(parents=True, exist_ok=True)
            stem.with_suffix(".json").write_text(mission_items_json(items), encoding="utf-8")
            write_wpl(stem.with_suffix(".waypoints"), items)
            write_tasks(stem.with_suffix(".tasks.json"), tasks)
        except OSError as exc:
            raise RunError(f"{stem}: cannot save the mission ({exc.strerror or exc})") from exc

    async def _plan_and_upload(self, v: VehicleState, tasks: list[Task],
                               iteration: int) -> None:
        """Upload ``tasks`` to ``v`` as trace items, or as waypoint polylines once ``v`` has
        refused a trace item; then begin the flight."""
        style = v.style or TaskStyle.TRACE
        while True:
            plan = plan_mission(self.origin, tasks, self.altitude_m, style=style,
                                tolerance_m=self.tolerance_m, home=self.home,
                                speed_mps=self.mission.vehicles.speed_mps, end="none")
            self._save_mission(iteration, v.sysid, plan.items, tasks)
            try:
                await self._upload(v, plan.items)
            except MissionRejected as exc:
                refused_trace = (exc.result == mavlink.MAV_MISSION_UNSUPPORTED
                                 and exc.command == MAV_CMD_WAYPOINT_USER_1)
                if not (refused_trace and style == TaskStyle.TRACE):
                    raise
                log.info("vehicle %d refused a contour item: its pieces go as waypoints",
                         v.sysid)
                style = v.style = TaskStyle.WAYPOINTS
                continue
            if any(isinstance(t, TraceTask) for t in tasks):
                v.style = style
            v.item_phases = dict(plan.item_phases)
            self._begin(v, tasks, plan)
            return

    async def _upload(self, v: VehicleState, items: list[MissionItemSpec]) -> None:
        v.status = "uploading"
        try:
            await asyncio.wait_for(self.router.upload_mission(v.sysid, items), self.timeout_s)
        except TimeoutError:
            self._check_lost()  # a vehicle that went silent says so
            raise VehicleTimeout(f"vehicle {v.sysid}: mission upload did not finish within "
                                 f"{self.timeout_s:g} s") from None
        v.items = items
        v.current_seq = None
        v.status = "uploaded"

    async def _start(self, v: VehicleState) -> None:
        v.status = "starting"
        await start_mission(self.router, v.sysid, 1, self.timeout_s)
        v.status = "flying"

    @staticmethod
    async def _all(coros: list[Coroutine[Any, Any, None]]) -> None:
        """Run concurrently; on the first failure cancel the rest and raise it."""
        tasks = [asyncio.ensure_future(c) for c in coros]
        try:
            await asyncio.gather(*tasks)
        except BaseException:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            raise

    def _check_lost(self) -> None:
        if self._lost is not None:
            raise VehicleTimeout(self._lost)

    async def _fly(self, plans: list[list[Task]], iteration: int) -> list[FlightReport]:
        self._check_lost()
        flying: list[VehicleState] = []
        t0 = time.monotonic()
        jobs: list[Coroutine[Any, Any, None]] = []
        for sysid, tasks in zip(self.sysids, plans, strict=True):
            if not tasks:
                continue
            v = self.vehicles[sysid]
            flying.append(v)
            jobs.append(self._plan_and_upload(v, tasks, iteration))
        # every upload first, then start everyone: streaming vehicles would slow the others'
        # transfers down (their samples share this endpoint)
        await self._all(jobs)
        await self._all([self._start(v) for v in flying])
        t1 = time.monotonic()
        self.timings["protocol_s"] += t1 - t0
        while not all(v.flight is not None and v.flight.done for v in flying):
            self._check_lost()
            await asyncio.sleep(0.02)
        self.timings["flight_s"] += time.monotonic() - t1
        reports = [self._end(v) if v in flying else self._end_idle(v)
                   for v in self.vehicles.values()]
        self.sim_s += max((r.sim_s for r in reports), default=0.0)
        return reports

    def _end_idle(self, v: VehicleState) -> FlightReport:
        self._convert(v)
        x, y = v.last_xy if v.last_xy is not None else self._position(v.sysid)
        return FlightReport(v.index, SampleLog(), 0.0, 0.0, [], x, y, 0.0)

    async def _finish(self) -> list[FlightReport]:
        self._check_lost()
        t0 = time.monotonic()
        going: list[VehicleState] = []
        for v in self.vehicles.values():
            link = self.router.vehicles[v.sysid]
            airborne = (link.rel_alt_m or 0.0) > 0.5
            if not airborne:
                if link.armed:
                    with contextlib.suppress(ProtocolError):
                        await self.router.disarm(v.sysid)
                continue
            self._begin(v, [])
            going.append(v)
        for v in going:
            v.status = "returning"
            await self.router.return_to_launch(v.sysid)
        self.timings["protocol_s"] += time.monotonic() - t0
        t1 = time.monotonic()
        while True:
            self._check_lost()
            for v in going:
                link = self.router.vehicles[v.sysid]
                f = v.flight
                if f is not None and not f.landed and not link.armed and \
                        (link.rel_alt_m or 0.0) < 0.5 and time.monotonic() - t1 > 1.5:
                    f.landed = True  # the heartbeat says so (the STATUSTEXT may be lost)
            if all(v.flight is None or v.flight.landed for v in going):
                break
            await asyncio.sleep(0.02)
        # the heartbeat (1 Hz) confirms the disarm; a vehicle that never says so is left be
        deadline = time.monotonic() + 2.5
        while any(self.router.vehicles[v.sysid].armed for v in going):
            if time.monotonic() > deadline:
                break
            await asyncio.sleep(0.02)
        for v in going:
            v.status = "landed"
        self.timings["return_s"] += time.monotonic() - t1
        reports = [self._end(v) if v in going else self._end_idle(v)
                   for v in self.vehicles.values()]
        for r, v in zip(reports, self.vehicles.values(), strict=True):
            if v in going:
                r.end_x_m, r.end_y_m = self._position(v.sysid)
        self.sim_s += max((r.sim_s for r in reports), default=0.0)
        return reports

    # -- for the live displays (terminal, web page) ------------------------------------------
    def status_rows(self) -> list[VehicleStatus]:
        """A snapshot of every vehicle, in vehicle-index order: the one way displays read
        vehicle state (safe to call from another thread; nothing returned is live)."""
        rows = []
        self._convert_all()
        for v in self.vehicles.values():
            link = self.router.vehicles.get(v.sysid)
            x_m = y_m = None
            if link is not None and link.lat_deg is not None and link.lon_deg is not None:
                x_m, y_m, _ = self.origin.to_local(link.lat_deg, link.lon_deg, 0.0)
            rows.append(VehicleStatus(
                sysid=v.sysid,
                index=v.index,
                x_m=x_m,
                y_m=y_m,
                alt_rel_m=(link.rel_alt_m or 0.0) if link else 0.0,
                heading_deg=link.heading_deg if link else None,
                flight_time_s=link.airborne_s if link else 0.0,
                armed=bool(link.armed) if link else False,
                lost=bool(link.lost) if link else False,
                item=v.current_seq if v.current_seq is not None else 0,
                items=len(v.items) - 1 if v.items else 0,
                phase=self._phase_now(v),
                flown_m=v.flown_m,
                samples=v.samples,
                status=v.status,
                message=v.last_text,
            ))
        return rows

    def fleet_summary(self, started: Sequence[VehicleKind] | None = None
                      ) -> list[dict[str, Any]]:
        """Per vehicle: system id, autopilot (from its heartbeat), the kind this run started
        (None for vehicles started elsewhere) and how it was given contour pieces
        (``trace`` items, ``waypoints`` polylines, or None if it was given none)."""
        out = []
        for i, (sysid, v) in enumerate(self.vehicles.items()):
            link = self.router.vehicles.get(sysid)
            out.append({
                "sysid": sysid,
                "autopilot": AutopilotKind.of(link.autopilot).value if link else None,
                "started_as": str(started[i]) if started else None,
                "task_style": v.style.value if v.style else None,
            })
        return out

    @staticmethod
    def _phase_now(v: VehicleState) -> Phase:
        return v.phases.latest if v.phases.known else v.item_phase


# --------------------------------------------------------------------------------------------
# econdor run


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
    connect: str | None = None,
    timeout_s: float = 20.0,
    quiet: bool = True,
    mission_path: Path | None = None,
    figures: bool = True,
    autopilots: Sequence[VehicleKind] | None = None,
    tolerance_m: float = 1.0,
    forward: str | None = None,
    forward_commands: bool = False,
    web: str | None = None,
    announce: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """One MAVLink run into ``out``; returns the summary (see ``summary.json``).

    ``autopilots`` are the kinds of the simulated vehicles this run starts (in turn; default
    PX4 with the tracer on board); ``tolerance_m`` the Douglas-Peucker tolerance of the
    waypoint polylines for vehicles that refuse contour items. ``forward`` is a watcher's
    ``udpout:HOST:PORT`` that gets every vehicle message (:mod:`.link.forward`); what it sends
    back reaches the vehicles only with ``forward_commands``.
    ``web`` (``[HOST:]PORT``) serves the run's page (:mod:`econdor_gcs.web`) with pause /
    resume / stop; ``announce`` is told its address as soon as it listens.

    Raises :class:`EcondorError` on failure, after writing a partial run directory
    (samples so far, tlog, ``summary.json`` with ``"error"``).
    """
    from .dfc import Dfc
    from .fleet import DEFAULT_KIND, Fleet, kinds_for
    from .plans import keep_mission_file, save_next_batch
    from .rundir import RunDir

    wall0 = time.perf_counter()
    n = vehicles or mission.vehicles.count
    speed = speedup or mission.vehicles.speedup
    seed = mission.seed if seed is None else seed
    planner = planner or mission.algorithm.planner
    mission = mission.with_vehicles(count=n, speedup=speed)
    out = Path(out)
    kinds = list(autopilots or [DEFAULT_KIND])
    rd = RunDir(out, grid=mission.grid)
    if mission_path is not None:
        keep_mission_file(mission_path, out)
    runlog = RunLog(out / "log.jsonl")
    tlog = TlogWriter(out / "telemetry.tlog")
    station = Station(connect or "udpin:127.0.0.1:0", tlog, heartbeat_timeout_s=timeout_s)
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
            fw = executor.timings["flight_s"] + executor.timings["return_s"]
            timings["achieved_speedup"] = executor.sim_s / fw if fw > 0 else math.nan
        if dfc is not None:
            timings["reconstruction_s"] = dfc.recon_s
        timings["requested_speedup"] = speed

    try:
        with _sigterm_as_interrupt(), _logging_to(runlog):
            if web is not None:
                from .web.session import LiveWeb

                page = LiveWeb(web, mission=mission, planner=planner, run_dir=str(out),
                               runlog=runlog)
                url = page.start()
                runlog.add("station", f"web page at {url}")
                if announce is not None:
                    announce(url)
            host, port = station.start()
            if forward is not None:
                forwarder = station.call(
                    Forwarder(station.router, forward, forward_commands).start())
            if connect is None:
                if mission_path is None:
                    raise RunError("run_mission: mission_path is needed to start vehicles")
                fleet = Fleet(mission_path, out / "vehicles")
                fleet.start(n, f"udpout:{host}:{port}", speedup=speed, seed=seed, kinds=kinds)
                sysids = list(range(1, n + 1))
                try:
                    station.call(station.router.wait_for_vehicles(sysids, timeout_s))
                except VehicleTimeout as exc:
                    raise VehicleTimeout(fleet.explain(str(exc))) from None
            else:
                sysids = station.call(_wait_count(station.router, n, timeout_s))
            t_setup = time.perf_counter() - wall0
            executor = MavlinkExecutor(station, mission, sysids, out / "missions", timeout_s,
                                       tolerance_m=tolerance_m)
            executor.wait_ready()
            truth = mission.build_field(seed)
            progress: list[Callable[[Any], None]] = [rd.progress, runlog.progress]
            on_samples: list[Callable[[SampleLog], None]] = [rd.append_samples]
            if not quiet:
                from .live import LiveDisplay

                live = LiveDisplay(executor, planner=planner, mission=mission.name)
                live.start()
                progress.append(live.progress)
            if page is not None:
                page.attach(executor.status_rows, sysids, station.router)
                progress.append(page.progress)
                on_samples.append(page.add_samples)
            dfc = Dfc(mission, executor, planner=planner, truth=truth, seed=seed,
                      progress=_all_of(progress), on_samples=_all_of(on_samples),
                      checkpoint=page.checkpoint if page is not None else None)
            result = dfc.run()
            if live is not None:
                live.stop()
                live = None
            fill_timings()
            timings["setup_s"] = t_setup
            result.wall_s = time.perf_counter() - wall0
            result.sim_s = executor.sim_s
            save_next_batch(out, dfc.planner, mission, result)
            started = kinds_for(n, kinds) if connect is None else None
            extra = {**base, "sysids": sysids, "timings": timings,
                     "fleet": executor.fleet_summary(started),
                     "forward": ({"to": forward, "commands": forward_commands,
                                  **forwarder.stats} if forwarder is not None else None),
                     "samples_dropped_unpaired": station.router.pairer.dropped,
                     "report_errors": executor.report_errors}
            timings["rundir_s"] = rd.write_s
            rd.write_result(result, extra=extra)
            summary = {**result.summary(), **extra}
            if page is not None:
                page.close(summary)
                page = None
    except (EcondorError, KeyboardInterrupt) as exc:
        if live is not None:
            live.stop()
            live = None
        msg = "interrupted" if isinstance(exc, KeyboardInterrupt) else str(exc)
        runlog.add("station", f"run failed: {msg}", Severity.ERROR)
        _write_partial(rd, dfc, executor, base, timings, fill_timings, msg)
        if page is not None:
            page.close({**base, "error": msg})
            page = None
        raise
    finally:
        if live is not None:
            live.stop()
        if forwarder is not None:
            station.loop.call_soon_threadsafe(forwarder.close)
        if page is not None:
            page.close(None)
        station.close()
        if fleet is not None:
            fleet.stop()
        tlog.close()
        rd.close()
        runlog.close()
    if figures:
        from .figures import plot_run

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

    router.add_message_handler(on_message)
    router.add_event_handler(on_event)


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


def _write_partial(rd: Any, dfc: Any, executor: MavlinkExecutor | None,
                   base: dict[str, Any], timings: dict[str, float], fill: Any,
                   error: str) -> None:
    with contextlib.suppress(Exception):
        if executor is not None:
            pending = executor.pending_samples()
            if len(pending):
                rd.append_samples(pending)
    fill()
    records = list(dfc.records) if dfc is not None else []
    last = records[-1] if records else None
    summary = {
        **base,
        "error": error,
        "iterations": max(0, len(records) - 1),
        "final_mae": last.mae if last else None,
        "final_mae_db": last.mae_db if last else None,
        "span_ratio": last.span_ratio if last else None,
        "flight_distance_m": dfc.flight_m if dfc is not None else 0.0,
        "contour_distance_m": dfc.contour_m if dfc is not None else 0.0,
        "samples": rd.n_samples,
        "converged": False,
        "wall_s": timings.get("total_wall_s"),
        "sim_s": timings.get("sim_s", 0.0),
        "timings": timings,
    }
    with contextlib.suppress(Exception):
        rd.write_partial(records, summary)


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
    from .mission import load_mission

    mission = load_mission(args.mission)
    out = args.out or _default_out(mission)
    from .fleet import parse_kinds

    web = getattr(args, "web", None)
    kinds = parse_kinds(args.autopilot) if getattr(args, "autopilot", None) else None
    if getattr(args, "forward_commands", False) and not getattr(args, "forward", None):
        raise EcondorError("--forward-commands needs --forward udpout:HOST:PORT")
    if kinds is not None and args.connect:
        raise EcondorError("--autopilot chooses the vehicles econdor starts; with --connect "
                           "the vehicles are started elsewhere")
    summary = run_mission(mission, out, planner=args.planner, vehicles=args.vehicles,
                          speedup=args.speedup, seed=args.seed, connect=args.connect,
                          timeout_s=args.timeout, quiet=args.quiet, mission_path=args.mission,
                          autopilots=kinds,
                          tolerance_m=getattr(args, "tolerance_m", None) or 1.0,
                          forward=getattr(args, "forward", None),
                          forward_commands=bool(getattr(args, "forward_commands", False)),
                          web=web, announce=lambda url: print(f"web: {url}", flush=True))
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
