"""Mission execution of a simulated vehicle: mission items -> flight activities.

No I/O. An *activity* is a generator that advances the body by exactly one tick per step and
yields the tick's :class:`~sim_vehicle.body.Sample` (holding, climbing and descending
included); the autopilot keeps one activity running and steps it once per sim tick.
Horizontal flight is delegated to the onboard tracer's generators (``run_task``, ``fly_to``);
climbs and descents happen at :data:`CLIMB_RATE_MPS` / :data:`DESCENT_RATE_MPS` while the body
hovers. Our own payload reports only the ticks of horizontal tasks (``state.sampling``); a Lua
script on a stock ArduPilot reports every tick in the air (:meth:`Autopilot.tick
<sim_vehicle.autopilot.Autopilot.tick>`).

Mission items (see :func:`sim_vehicle.mission_server.check_item` for what is accepted):
NAV_TAKEOFF, NAV_WAYPOINT, NAV_LOITER_UNLIM / LOITER_TIME, DO_CHANGE_SPEED (from the next
item), NAV_RETURN_TO_LAUNCH, NAV_LAND, the contour item ``MAV_CMD_WAYPOINT_USER_1`` and the
sensor lag item (:data:`~econdor_gcs.core.tasks.SENSOR_LAG_COMMAND`: the tracer's
``sensor_lag_s`` and ``lag_unknown`` from then on, in later missions too, until another
says otherwise).
Progress goes out as MISSION_CURRENT and MISSION_ITEM_REACHED; the outcome of a trace item as
a ``DEBUG_FLOAT_ARRAY("TRACE")`` report just before its MISSION_ITEM_REACHED (its events and
outcome also as STATUSTEXT, for people).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Generator
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.tasks import (
    SENSOR_LAG_COMMAND,
    OutcomeStatus,
    Phase,
    TraceReport,
    TraceTask,
    Waypoint,
)

from .body import Sample
from .executor import run_task
from .mission_server import MAV_CMD_WAYPOINT_USER_1, MissionServer, StoredItem
from .state import FlightMode, VehicleState
from .telemetry import Outbox, trace_report_message
from .tracer import TracerParams, fly_to

CLIMB_RATE_MPS = 3.0
DESCENT_RATE_MPS = 1.5

Activity = Generator[Sample | None, None, Any]
"""One body tick per step; yields the tick's sample (None: no tick was taken)."""


@dataclasses.dataclass(frozen=True)
class ModeFlow:
    """The modes a personality shows while the navigator flies (None: keep the mode).

    PX4 switches sub-modes as a flight goes on (AUTO.TAKEOFF, then AUTO.LOITER; AUTO.RTL,
    then AUTO.LAND); ArduCopter stays in the mode it was put in (GUIDED, RTL, AUTO).
    """

    takeoff: FlightMode = FlightMode.TAKEOFF
    """While climbing on a takeoff command."""
    after_takeoff: FlightMode = FlightMode.HOLD
    rtl_descent: FlightMode | None = FlightMode.LAND
    """While descending at home after an RTL."""
    mission_rtl: FlightMode | None = FlightMode.RTL
    """While flying a mission's RTL item."""
    landed: FlightMode | None = FlightMode.HOLD
    """After landing and disarming."""
    mission_done: FlightMode = FlightMode.HOLD
    """After the last item, still in the air."""


class Navigator:
    """Turns mission items and flight commands into activities.

    Parameters
    ----------
    state
        The vehicle state the activities change (body, altitude, mode, mission progress).
    server
        The stored mission (items, current item, MISSION_CURRENT).
    outbox
        Where progress messages and texts go.
    tracer_params
        Base tracer tuning; the speeds come from ``state.speed_mps``, the sensor lag from
        the last sensor lag item flown (until then, this tuning's).
    flow
        The modes the personality shows on the way (:class:`ModeFlow`).
    """

    def __init__(self, state: VehicleState, server: MissionServer, outbox: Outbox,
                 tracer_params: TracerParams | None = None, flow: ModeFlow | None = None
                 ) -> None:
        self.state = state
        self.server = server
        self.outbox = outbox
        self.tracer_base = tracer_params or TracerParams()
        self.flow = flow or ModeFlow()
        self.mission_last = -1

    def tracer_params(self) -> TracerParams:
        st = self.state
        sp = min(st.speed_mps, st.settings.max_speed_mps)
        return dataclasses.replace(self.tracer_base, speed_mps=sp, transit_speed_mps=sp)

    # -- primitives ----------------------------------------------------------------------------

    def hold_forever(self) -> Activity:
        st = self.state
        st.sampling = False
        while True:
            yield st.body.hold(Phase.TRANSIT)

    def climb_to(self, target_alt_m: float) -> Activity:
        st = self.state
        st.sampling = False
        if st.alt_rel_m < target_alt_m:
            st.landed_state = mavlink.MAV_LANDED_STATE_TAKEOFF
        while abs(st.alt_rel_m - target_alt_m) > 1e-3:
            step = CLIMB_RATE_MPS * st.body.dt_s
            st.alt_rel_m += max(-step, min(step, target_alt_m - st.alt_rel_m))
            yield st.body.hold(Phase.TRANSIT)
        if st.alt_rel_m > 0.1:
            st.landed_state = mavlink.MAV_LANDED_STATE_IN_AIR

    def descend_and_disarm(self) -> Activity:
        st = self.state
        st.sampling = False
        st.landed_state = mavlink.MAV_LANDED_STATE_LANDING
        while st.alt_rel_m > 0.0:
            st.alt_rel_m = max(0.0, st.alt_rel_m - DESCENT_RATE_MPS * st.body.dt_s)
            yield st.body.hold(Phase.TRANSIT)
        st.landed_state = mavlink.MAV_LANDED_STATE_ON_GROUND
        st.armed = False
        st.mission_active = False
        if self.flow.landed is not None:
            st.mode = self.flow.landed
        self.outbox.statustext("landed, disarmed")

    def fly(self, gen: Generator[Sample, None, Any], target_alt_m: float | None) -> Activity:
        """Run a horizontal task generator, adjusting altitude on the way; report samples."""
        st = self.state
        while True:
            if target_alt_m is not None and abs(st.alt_rel_m - target_alt_m) > 1e-3:
                step = CLIMB_RATE_MPS * st.body.dt_s
                st.alt_rel_m += max(-step, min(step, target_alt_m - st.alt_rel_m))
            st.sampling = True
            try:
                sample = next(gen)
            except StopIteration as stop:
                st.sampling = False
                return stop.value
            yield sample

    def takeoff_then_hold(self, alt_m: float) -> Activity:
        self.state.mode = self.flow.takeoff
        yield from self.climb_to(alt_m)
        self.state.mode = self.flow.after_takeoff
        yield from self.hold_forever()

    def rtl(self, in_mission: bool = False) -> Activity:
        """Fly home, then land and disarm (as a command, or as a mission's RTL item)."""
        st = self.state
        mode = self.flow.mission_rtl if in_mission else FlightMode.RTL
        if mode is not None:
            st.mode = mode
        hx, hy, _ = st.home_local
        if math.hypot(st.body.x_m - hx, st.body.y_m - hy) > 1.0:
            yield from self.fly(fly_to(st.body, hx, hy, Phase.TRANSIT,
                                       speed_mps=self.tracer_params().speed_mps), None)
        if self.flow.rtl_descent is not None:
            st.mode = self.flow.rtl_descent
        yield from self.descend_and_disarm()

    def land(self) -> Activity:
        self.state.mode = FlightMode.LAND
        yield from self.descend_and_disarm()

    def ensure_airborne(self, alt_m: float) -> Activity:
        st = self.state
        if st.alt_rel_m < 0.5:
            yield from self.climb_to(alt_m if alt_m > 1.0 else st.params["ALT_M"])
        st.landed_state = mavlink.MAV_LANDED_STATE_IN_AIR

    # -- the mission ---------------------------------------------------------------------------

    def item_alt_m(self, it: StoredItem) -> float:
        """Item altitude above home (m), or 0 if it gives none."""
        if it.frame in (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT):
            return it.z - self.state.home[2]
        return it.z

    def item_xy(self, it: StoredItem) -> tuple[float, float] | None:
        if not it.is_global or (it.x == 0 and it.y == 0):
            return None
        x, y, _ = self.state.origin.to_local(it.lat_deg, it.lon_deg, 0.0)
        return x, y

    def mission(self, first: int, last: int) -> Activity:
        """Fly items ``first..last`` of the stored mission, then hold (or stay landed)."""
        st = self.state
        items = self.server.mission
        st.mission_active = True
        st.mission_complete = False
        st.mission_started = True
        self.mission_last = last
        seq = first
        while seq <= last and seq < len(items):
            it = items[seq]
            self.server.set_current(seq)
            self.outbox.put(self.server.mission_current_msg(True))
            result = yield from self.run_item(it)
            self.outbox.put(mavlink.MAVLink_mission_item_reached_message(seq))
            if result == "end":  # RTL / land: the mission ends with the vehicle down
                st.mission_active = False
                st.mission_complete = True
                return
            seq += 1
        st.mission_active = False
        st.mission_complete = True
        self.outbox.statustext("mission complete")
        st.mode = self.flow.mission_done
        self.outbox.put(self.server.mission_current_msg(False, True))
        if st.alt_rel_m > 0.0:
            yield from self.hold_forever()

    def report_trace(self, report: TraceReport) -> None:
        msg = trace_report_message(report, int(self.state.body.t_s * 1e6))
        self.outbox.archive.add_report(int(round(self.state.body.t_s * 1000.0)), msg)
        self.outbox.put(msg)

    def run_item(self, it: StoredItem) -> Generator[Sample | None, None, str]:
        """One mission item; returns ``"end"`` when it ended the flight (RTL, land)."""
        st = self.state
        cmd = it.command
        st.apply_pending_body()
        alt = self.item_alt_m(it)
        xy = self.item_xy(it)
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            yield from self.climb_to(alt if alt > 1.0 else st.params["ALT_M"])
            return "ok"
        if cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            if it.param2 > 0:
                st.speed_mps = min(float(it.param2), st.settings.max_speed_mps)
            return "ok"
        if cmd == SENSOR_LAG_COMMAND:  # the server accepts only a finite lag >= 0
            self.tracer_base = dataclasses.replace(self.tracer_base,
                                                   sensor_lag_s=float(it.param1),
                                                   lag_unknown=it.param2 == 1.0)
            return "ok"
        if cmd in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_UNLIM,
                   mavlink.MAV_CMD_NAV_LOITER_TIME):
            if xy is not None:
                near = math.hypot(xy[0] - st.body.x_m, xy[1] - st.body.y_m) < 1.0
                if not (near and st.alt_rel_m < 0.5 and cmd == mavlink.MAV_CMD_NAV_WAYPOINT):
                    yield from self.ensure_airborne(alt)
                    tgt = alt if alt > 1.0 else st.alt_rel_m
                    yield from self.fly(run_task(st.body, Waypoint(*xy), self.tracer_params()),
                                        tgt)
            if cmd == mavlink.MAV_CMD_NAV_LOITER_UNLIM:
                yield from self.ensure_airborne(alt)
                yield from self.hold_forever()
            if cmd == mavlink.MAV_CMD_NAV_LOITER_TIME:
                yield from self.ensure_airborne(alt)
                t_end = st.body.t_s + max(0.0, it.param1)
                while st.body.t_s < t_end - 1e-9:
                    yield st.body.hold(Phase.TRANSIT)
            return "ok"
        if cmd == MAV_CMD_WAYPOINT_USER_1:
            if xy is None:
                self.outbox.statustext(f"piece {int(it.param4)}: no start point",
                                       mavlink.MAV_SEVERITY_WARNING)
                self.report_trace(TraceReport(it.seq, int(it.param4), OutcomeStatus.NOT_FOUND,
                                              0.0, 0.0, float(it.param1)))
                return "ok"
            yield from self.ensure_airborne(alt)
            rad = it.param2 if it.param2 > 0 else st.params["SEARCH_RAD_M"]
            task = TraceTask(level=float(it.param1), x_m=xy[0], y_m=xy[1],
                             search_radius_m=float(rad), max_length_m=max(0.0, it.param3),
                             piece_id=int(it.param4))
            pid = task.piece_id
            outcome = yield from self.fly(
                run_task(st.body, task, self.tracer_params(),
                         on_event=lambda text: self.outbox.statustext(f"piece {pid}: {text}")),
                alt if alt > 1.0 else None)
            self.outbox.statustext(f"piece {pid}: {outcome.status} traced "
                                   f"{outcome.traced_m:.1f} m flown {outcome.flown_m:.1f} m")
            self.report_trace(TraceReport(it.seq, pid, outcome.status, outcome.traced_m,
                                          outcome.flown_m, task.level))
            return "ok"
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            yield from self.rtl(in_mission=True)
            return "end"
        if cmd == mavlink.MAV_CMD_NAV_LAND:
            if xy is not None and st.alt_rel_m > 0.5:
                yield from self.fly(run_task(st.body, Waypoint(*xy), self.tracer_params()), None)
            yield from self.land()
            return "end"
        return "ok"  # unreachable: the server rejects other commands
