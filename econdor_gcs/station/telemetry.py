"""What the ground station knows of each vehicle, from what the vehicle sends.

Parts of :class:`~.executor.MavlinkExecutor`:

:class:`StationTelemetry`
    The router's sample and message callbacks, on the station's loop thread (which alone
    owns the vehicle state): samples buffered raw per vehicle and converted to local metres
    in batches of :data:`SAMPLE_BATCH`, mission progress, phases, trace reports and texts,
    and each flight's samples settled into a :class:`~.core.tasks.FlightReport`.
:class:`VehicleState`
    One vehicle's bookkeeping across flights: what is the station's own (its samples, its
    flights and their mission progress, whether it was given up). What the link knows of
    a vehicle (heartbeats and modes, components, positions, its clock, the state of its
    mission) is the link's vehicle table's (:class:`~.link.vehicles.VehicleLink`), read
    there; the item time limits' view of its link is :class:`~.losses.LinkWatch`.
:class:`VehicleRow`
    One vehicle as the live display sees it at one moment; its ``status`` is a
    :class:`~.status.VehicleStatus`.

:class:`~.flight.Flight`, :func:`~.flight.build_report` and
:class:`~.flight.StatusAssembler` (a flight, its report, STATUSTEXT texts) live in
:mod:`.flight`.
"""

from __future__ import annotations

import asyncio
import bisect
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.tasks import (
    FlightReport,
    OutcomeStatus,
    Phase,
    SampleLog,
    Task,
    TaskStyle,
    TraceTask,
)
from econdor_gcs.errors import ProtocolError
from econdor_gcs.link.autopilots import AutopilotKind, FlightMode, flight_mode
from econdor_gcs.link.codec import MAVLinkMessage, mavlink
from econdor_gcs.link.items import MissionItemSpec, MissionPlan
from econdor_gcs.link.reports import PhaseTrack, phase_change, trace_report
from econdor_gcs.link.router import Router, Sample
from econdor_gcs.station.flight import (
    LATE,
    Flight,
    StatusAssembler,
    build_report,
    settle,
    settled_samples,
)
from econdor_gcs.station.status import VehicleStatus

if TYPE_CHECKING:
    from econdor_gcs.link.autopilots import VehicleKind

__all__ = [
    "StationTelemetry",
    "VehicleState",
    "VehicleRow",
]

T = TypeVar("T")
log = logging.getLogger(__name__)

SAMPLE_BATCH = 512
"""Raw samples buffered per vehicle before they are converted to local metres anyway."""
SAMPLE_BATCH_S = 1.0
"""... or the wall time the oldest of them may wait: converted batches go to the run
directory as they are made (:attr:`StationTelemetry.on_rows`), so a station that dies
loses at most this much of what it had received."""
RUNNING_STATES = frozenset({mavlink.MISSION_STATE_ACTIVE, mavlink.MISSION_STATE_PAUSED,
                            mavlink.MISSION_STATE_COMPLETE})
"""``mission_state``s of a mission that was started."""

# --------------------------------------------------------------------------------------------
# pure helpers (unit-tested in tests/station/test_gcs_unit.py)


# --------------------------------------------------------------------------------------------
# per-vehicle state


def _counts_ours(msg: MAVLinkMessage, items: Sequence[object], unknown: bool = False) -> bool:
    """Whether a MISSION_CURRENT's ``total`` is the mission we sent: its item count, or one
    less where the autopilot keeps home as item 0 and leaves it out of the total (ArduPilot;
    the MAVLink spec allows both). ``unknown``: a total the autopilot does not state
    (0 or UINT16_MAX) counts as ours too."""
    total = int(getattr(msg, "total", 0) or 0)
    if total in (0, 0xFFFF):
        return unknown
    return total in (len(items), len(items) - 1)


@dataclass
class VehicleState:
    """The station's own bookkeeping of one vehicle across flights (for the live display
    too); what the link knows of it is its :class:`~.link.vehicles.VehicleLink`."""

    index: int
    sysid: int
    current_seq: int | None = None
    items: list[MissionItemSpec] = field(default_factory=list)
    item_phase: Phase = Phase.TRANSIT
    """The phase the current mission item implies (the live display's, for a vehicle that
    reports none)."""
    style: TaskStyle | None = None
    """How this vehicle gets contour pieces: trace items until it refuses one (None: it has
    not been given any yet)."""
    tasks_flown: dict[str, int] = field(
        default_factory=lambda: {"trace": 0, "waypoints": 0, "legs": 0})
    """Tasks flown to an outcome (since this station started): contour pieces as ``trace``
    items or as ``waypoints`` polylines, and plain waypoint ``legs`` (initiation, survey)."""
    phases: PhaseTrack = field(default_factory=PhaseTrack)
    last_text: str = ""
    """The vehicle's last STATUSTEXT, for people."""
    last_xy: tuple[float, float] | None = None
    flown_m: float = 0.0            # the whole run
    samples: int = 0                # the whole run
    flight: Flight | None = None
    stray: list[np.ndarray] = field(default_factory=list)
    """Batches of samples received outside a flight (:data:`.flight.RECEIVED_COLUMNS`; the
    next flight takes them)."""
    status: VehicleStatus = VehicleStatus.IDLE
    raw: list[tuple[int, float, float, float, int]] = field(default_factory=list)
    """Samples not yet converted: (time_boot_ms, lat, lon, value, mission seq or -1)."""
    raw_since: float = 0.0
    """Wall time the oldest of ``raw`` arrived."""
    seen_ms: list[int] = field(default_factory=list)
    """Sorted times of every sample received (a resent one that is already here is a
    duplicate); with ``_seen`` for the lookups."""
    _seen: set[int] = field(default_factory=set)
    newest_ms: int = -1
    synced_ms: int = -1
    """Every sample up to this time is here (the vehicle's count says so)."""
    duplicates: int = 0
    recovered: int = 0
    """Samples that came only after a resend request."""
    recovering: bool = False
    lost: str | None = None
    """Why the vehicle was given up (None while it serves)."""
    item_since: float = 0.0
    """Wall time the current mission item began (for the item time limit)."""
    item_since_ms: int = 0
    """The vehicle's own (sim) time when the current mission item began."""
    vehicle_samples: int | None = None
    """How many samples the vehicle says it took (its count at the last recovery)."""
    missing: int | None = 0
    """Samples the vehicle took that never arrived, despite the recovery (0 = none lost;
    None: unknown, the vehicle was given up before it could be asked)."""
    no_recovery: str | None = None
    """Why this vehicle's samples cannot be recovered (its payload does not answer the
    sample count: a stock autopilot's Lua script); None while recovery works."""
    mission_news_at: float = 0.0
    """Monotonic time of the last sign that the uploaded mission runs or ran: a
    MISSION_CURRENT of it ACTIVE, PAUSED or COMPLETE, or a MISSION_ITEM_REACHED (a short
    mission can be over before a once-a-second MISSION_CURRENT says ACTIVE)."""

    def count_seen(self, first_ms: int, last_ms: int) -> int:
        return bisect.bisect_right(self.seen_ms, last_ms) - \
            bisect.bisect_left(self.seen_ms, first_ms)


@dataclass(frozen=True)
class VehicleRow:
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
    status: VehicleStatus
    """What the executor says the vehicle is doing."""
    message: str = ""
    """The vehicle's last STATUSTEXT (for people)."""


# --------------------------------------------------------------------------------------------
# what the vehicles send


class StationTelemetry:
    """Keeps every vehicle's :class:`VehicleState` from what it sends: the router's sample
    and message callbacks, the conversion of samples to local metres, and the per-flight
    bookkeeping that ends in a :class:`~.core.tasks.FlightReport` (a part of
    :class:`~.executor.MavlinkExecutor`).

    Everything here runs on the station's loop thread, which alone owns the vehicle state;
    the executor hands other threads' questions to that thread.

    Parameters
    ----------
    router:
        The station's router: its per-vehicle links give positions and vehicle times.
    origin:
        The mission's origin; samples and positions are local ENU metres of it.
    sysids:
        System ids, in vehicle-index order.
    changed:
        Set by every sample and message from a vehicle: the executor's waits wake on it.
    home:
        The position of a vehicle that has reported none.
    """

    def __init__(self, router: Router, origin: Origin, sysids: Sequence[int],
                 changed: asyncio.Event, home: tuple[float, float] = (0.0, 0.0)) -> None:
        self.router = router
        self.origin = origin
        self.changed = changed
        self.home = home
        self.vehicles = {s: VehicleState(i, s) for i, s in enumerate(sysids)}
        self.on_rows: Callable[[VehicleState, list[tuple[float, float, float, float, int]]],
                               None] | None = None
        """Told every batch of samples as it is converted (``(t_s, x_m, y_m, value,
        phase)`` rows, in arrival order): the run directory's journal of everything
        received. Its phase is the live display's (:meth:`live_phases`), not the
        sample's, which is decided when its flight ends."""
        self.assembler = StatusAssembler()
        self.report_errors = 0
        """Malformed PHASE / TRACE reports received (logged, then ignored)."""

    # -- callbacks (the router's, on the station's loop thread) ---------------------------------
    def on_sample(self, s: Sample) -> None:
        v = self.vehicles.get(s.sysid)
        if v is None:
            return
        seq = v.current_seq if v.current_seq is not None else -1
        self.changed.set()
        t = s.time_boot_ms
        if t in v._seen:
            v.duplicates += 1  # a resend of a sample that had arrived
            return
        v._seen.add(t)
        if t > v.newest_ms:
            v.newest_ms = t
            v.seen_ms.append(t)
        else:  # a resent sample: its item and phase are settled at the end, by time
            bisect.insort(v.seen_ms, t)
            seq = LATE
        if v.recovering:
            v.recovered += 1
        now = time.monotonic()
        if not v.raw:
            v.raw_since = now
        v.raw.append((s.time_boot_ms, s.lat_deg, s.lon_deg, float(s.value), seq))
        v.samples += 1
        f = v.flight
        if f is not None:
            if f.start_ms is None:
                f.start_ms = s.time_boot_ms
            f.last_ms = s.time_boot_ms if f.last_ms is None else max(f.last_ms, s.time_boot_ms)
        if len(v.raw) >= SAMPLE_BATCH or now - v.raw_since >= SAMPLE_BATCH_S:
            self._convert(v)

    def _convert(self, v: VehicleState) -> None:
        """Convert ``v``'s raw samples to local rows in one vectorised pymap3d call.

        Everything that changes ``v.flight`` calls this first, so one batch always belongs
        to one flight (or to none: stray samples)."""
        raw, v.raw = v.raw, []
        if not raw:
            return
        a = np.asarray(raw, dtype=float)
        x, y, _ = self.origin.to_local_many(a[:, 1], a[:, 2], 0.0)
        f = v.flight
        seqs = a[:, 4].astype(np.int64)
        live = seqs != LATE  # the live display's odometer follows the samples in order
        if live.any():
            xs, ys = x[live], y[live]
            start = v.last_xy if v.last_xy is not None else (float(xs[0]), float(ys[0]))
            v.flown_m += float(np.sum(np.hypot(np.diff(xs, prepend=start[0]),
                                               np.diff(ys, prepend=start[1]))))
            v.last_xy = (float(xs[-1]), float(ys[-1]))
        batch = np.column_stack([a[:, 0], x, y, a[:, 3], a[:, 4]])
        if self.on_rows is not None:
            self.on_rows(v, list(zip((a[:, 0] / 1000.0).tolist(), x.tolist(), y.tolist(),
                                     a[:, 3].tolist(), self.live_phases(v, a[:, 0], seqs),
                                     strict=True)))
        (f.received if f is not None else v.stray).append(batch)

    @staticmethod
    def live_phases(v: VehicleState, t_ms: np.ndarray, seqs: np.ndarray) -> list[int]:
        """The phases the live display would show for samples arriving now: the vehicle's
        phase at their time as reported so far, else their mission item's. A sample's own
        phase is decided when its flight ends (:func:`~.flight.decide_phases`)."""
        if v.phases.known:
            return [int(v.phases.at(int(t))) for t in t_ms]
        items = v.flight.item_phases if v.flight is not None else {}
        return [int(items.get(int(s), v.item_phase) if s >= 0 else v.item_phase)
                for s in seqs]

    def _convert_all(self) -> None:
        for v in self.vehicles.values():
            self._convert(v)

    def convert_due(self) -> None:
        """Convert the batches that waited :data:`SAMPLE_BATCH_S` (samples that stopped
        coming, e.g. in a link outage, still reach the run directory)."""
        now = time.monotonic()
        for v in self.vehicles.values():
            if v.raw and now - v.raw_since >= SAMPLE_BATCH_S:
                self._convert(v)

    def on_message(self, sysid: int, msg: MAVLinkMessage) -> None:
        v = self.vehicles.get(sysid)
        if v is None:
            return
        self.changed.set()
        kind = msg.get_type()
        f = v.flight
        link = self.router.vehicles[sysid]  # the link's table has taken the message in
        if kind == "MISSION_CURRENT":
            if link.mission_state in RUNNING_STATES and _counts_ours(msg, v.items):
                v.mission_news_at = link.mission_state_at
            if msg.seq != v.current_seq:
                v.current_seq = msg.seq
                v.item_since = time.monotonic()
                v.item_since_ms = link.time_boot_ms or 0
                v.item_phase = f.item_phases.get(msg.seq, Phase.TRANSIT) if f is not None \
                    else Phase.TRANSIT
            self._judge(v, msg)
        elif kind == "HEARTBEAT":
            self._judge(v, msg)
        elif kind == "MISSION_ITEM_REACHED":
            v.mission_news_at = time.monotonic()
            if f is not None:
                f.reached.add(msg.seq)
            if f is not None and f.tasks and msg.seq == f.last_seq and f.interrupted is None:
                f.done = True
                v.status = VehicleStatus.HOLDING
        elif kind == "NAMED_VALUE_INT":
            change = self._decode(phase_change, msg)
            if change is not None:
                v.phases.add(*change)
        elif kind == "DEBUG_FLOAT_ARRAY":
            rep = self._decode(trace_report, msg)
            if rep is not None and f is not None:
                f.pieces[rep.piece_id] = rep
        elif kind == "EXTENDED_SYS_STATE":
            if (f is not None and not f.tasks and v.status == VehicleStatus.RETURNING
                    and msg.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND):
                f.landed = True
                v.status = VehicleStatus.LANDED
        elif kind == "STATUSTEXT":
            raw = bytes(msg.text) if isinstance(msg.text, bytes | bytearray) else \
                msg.text.encode("utf-8", "replace")
            text = self.assembler.add(sysid, raw, getattr(msg, "id", 0),
                                      getattr(msg, "chunk_seq", 0))
            if text is not None:
                v.last_text = text

    def _judge(self, v: VehicleState, msg: MAVLinkMessage) -> None:
        """Whether the flight in progress ended, from the vehicle's HEARTBEAT and
        MISSION_CURRENT, whatever acknowledgement or progress message was lost on the way.

        Done: MISSION_CURRENT says COMPLETE at the last item (in case its last
        MISSION_ITEM_REACHED was lost); for an autopilot that states no ``mission_state``,
        its HEARTBEAT shows HOLD (PX4's AUTO.LOITER after a mission) at the last item.
        Left before its end on its own (a failsafe): once it has shown that it flies this
        mission, its HEARTBEAT shows RTL or LAND, or disarmed, or its MISSION_CURRENT says
        PAUSED (or, without a ``mission_state``, HOLD before the last item)."""
        f = v.flight
        if f is None or not f.tasks or f.done or f.interrupted is not None \
                or v.status != VehicleStatus.FLYING:
            return
        link = self.router.vehicles[v.sysid]
        if msg.get_type() == "MISSION_CURRENT":
            state = link.mission_state
            if not _counts_ours(msg, v.items, unknown=True):  # not an old mission's
                return
            if state == mavlink.MISSION_STATE_ACTIVE:
                f.in_mission = True
            elif state == mavlink.MISSION_STATE_COMPLETE and msg.seq == f.last_seq:
                f.done = True
                v.status = VehicleStatus.HOLDING
            elif state == mavlink.MISSION_STATE_PAUSED and f.in_mission:
                f.interrupted = f"it left its mission at item {msg.seq} (MISSION_CURRENT: " \
                                "paused)"
        else:
            mode = flight_mode(AutopilotKind.of(link.autopilot), link.custom_mode)
            if mode == FlightMode.MISSION and link.armed:
                f.in_mission = True
            elif not f.in_mission:
                return
            elif not link.armed:
                f.interrupted = "it landed and disarmed"
            elif mode in (FlightMode.RTL, FlightMode.LAND):
                f.interrupted = f"it switched to {mode.value.upper()}"
            elif mode == FlightMode.HOLD and link.mission_state == mavlink.MISSION_STATE_UNKNOWN:
                if v.current_seq == f.last_seq:
                    f.done = True
                    v.status = VehicleStatus.HOLDING
                else:
                    f.interrupted = f"it holds at item {v.current_seq}"
        if f.interrupted is not None:
            v.status = VehicleStatus.INTERRUPTED
            log.warning("vehicle %d left its mission before the end on its own: %s",
                        v.sysid, f.interrupted)

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

    # -- positions and flights ------------------------------------------------------------------
    def position(self, sysid: int) -> tuple[float, float]:
        link = self.router.vehicles.get(sysid)
        if link is None or link.lat_deg is None or link.lon_deg is None:
            return self.home
        x, y, _ = self.origin.to_local(link.lat_deg, link.lon_deg, 0.0)
        return x, y

    def begin(self, v: VehicleState, tasks: list[Task], plan: MissionPlan | None = None,
              survey: bool = False) -> Flight:
        """A new flight of ``v`` (``survey``: the station flies it as a survey, its samples
        are ``Phase.SURVEY``)."""
        self._convert(v)  # samples so far belong to the previous state
        link = self.router.vehicles[v.sysid]
        # where it hovers now (the in-process vehicles also start from rest after braking)
        start = self.position(v.sysid)
        f = Flight(v.index, v.sysid, list(tasks), start_xy=start, start_ms=link.time_boot_ms,
                   task_seqs=list(plan.task_seqs) if plan else [],
                   style=plan.style if plan else TaskStyle.TRACE,
                   item_phases=dict(plan.item_phases) if plan else {}, survey=survey)
        old = v.flight  # a flight begun again (its upload was cut short by the link)
        for batch in [*v.stray, *(old.received if old is not None else [])]:
            carried = batch.copy()  # nothing is ever dropped; attributed by time at the end
            carried[:, 4] = LATE
            f.received.append(carried)
        v.stray.clear()
        v.flight = f
        return f

    def end(self, v: VehicleState) -> FlightReport:
        self._convert(v)
        f = v.flight
        v.flight = None
        if f is None:
            return FlightReport(v.index, SampleLog(), 0.0, 0.0, [], *self.position(v.sysid),
                                0.0)
        settle(f, v.phases)
        report = build_report(f)
        for o in report.outcomes:
            if o.status != OutcomeStatus.UNREPORTED:
                way = f.style.value if isinstance(o.task, TraceTask) else "legs"
                v.tasks_flown[way] += 1
        return report

    def end_idle(self, v: VehicleState) -> FlightReport:
        self._convert(v)
        x, y = v.last_xy if v.last_xy is not None else self.position(v.sysid)
        return FlightReport(v.index, SampleLog(), 0.0, 0.0, [], x, y, 0.0)

    def pending_samples(self) -> SampleLog:
        """Take out every sample received but not yet in a report (the stray ones and the
        rows of the flights in progress): :meth:`~.executor.MavlinkExecutor.pending_samples`."""
        logs = []
        self._convert_all()
        for v in self.vehicles.values():
            f = v.flight
            batches = [*v.stray, *(f.received if f is not None else [])]
            v.stray.clear()
            if f is not None:
                f.received.clear()
            if batches:  # their phases decided now, with what the vehicle said so far
                log, _ = settled_samples(batches, v.index, v.phases,
                                         f.item_phases if f is not None else {},
                                         f is not None and f.survey)
                logs.append(log)
        return SampleLog.concat(logs)

    # -- snapshots for the displays and the summary -------------------------------------------
    def status_rows(self) -> list[VehicleRow]:
        """The rows of :meth:`~.executor.MavlinkExecutor.status_rows` (made here, on the
        station's loop thread)."""
        rows = []
        self._convert_all()
        for v in self.vehicles.values():
            link = self.router.vehicles.get(v.sysid)
            x_m = y_m = None
            if link is not None and link.lat_deg is not None and link.lon_deg is not None:
                x_m, y_m, _ = self.origin.to_local(link.lat_deg, link.lon_deg, 0.0)
            rows.append(VehicleRow(
                sysid=v.sysid,
                index=v.index,
                x_m=x_m,
                y_m=y_m,
                alt_rel_m=(link.rel_alt_m or 0.0) if link else 0.0,
                heading_deg=link.heading_deg if link else None,
                flight_time_s=link.airborne_s if link else 0.0,
                armed=bool(link.armed) if link else False,
                lost=v.lost is not None or (bool(link.lost) if link else False),
                item=v.current_seq if v.current_seq is not None else 0,
                items=len(v.items) - 1 if v.items else 0,
                phase=self._phase_now(v),
                flown_m=v.flown_m,
                samples=v.samples,
                status=v.status,
                message=v.last_text,
            ))
        return rows

    def clock_rate(self) -> float:
        """The vehicles' sim-time speed-up as achieved: the median of the clock rates
        (:attr:`~.link.vehicles.VehicleLink.clock_rate`) of the vehicles in service (NaN:
        none known yet)."""
        rates = sorted(
            rate for v in self.vehicles.values()
            if v.lost is None and (link := self.router.vehicles.get(v.sysid)) is not None
            and (rate := link.clock_rate) is not None)
        if not rates:
            return float("nan")
        mid = len(rates) // 2
        return rates[mid] if len(rates) % 2 else (rates[mid - 1] + rates[mid]) / 2

    def fleet_summary(self, started: Sequence[VehicleKind] | None = None
                      ) -> list[dict[str, Any]]:
        """The rows of :meth:`~.executor.MavlinkExecutor.fleet_summary`."""
        out = []
        for i, (sysid, v) in enumerate(self.vehicles.items()):
            link = self.router.vehicles.get(sysid)
            out.append({
                "sysid": sysid,
                "autopilot": AutopilotKind.of(link.autopilot).value if link else None,
                "started_as": str(started[i]) if started else None,
                "mode": v.style.value if v.style else None,
                "tasks_flown": dict(v.tasks_flown),
            })
        return out

    @staticmethod
    def _phase_now(v: VehicleState) -> Phase:
        return v.phases.latest if v.phases.known else v.item_phase
