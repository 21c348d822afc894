"""The MAVLink commands every simulated autopilot answers: :class:`Commands`, a part of
:class:`~sim_vehicle.autopilot.Autopilot`.

COMMAND_LONG and COMMAND_INT, always answered by COMMAND_ACK: COMPONENT_ARM_DISARM (arm
only on the ground; disarm in the air only with the 21196 force code), NAV_TAKEOFF (param7
AMSL; needs armed), MISSION_START (param1/2 first/last; needs armed + a mission; DENIED,
with a STATUSTEXT "Geofence violation for waypoint N", while an item to be flown lies
outside the fence: PX4's feasibility check), NAV_RETURN_TO_LAUNCH, NAV_LAND, DO_SET_MODE,
DO_CHANGE_SPEED (from the next item), DO_SET_MISSION_CURRENT, SET_MESSAGE_INTERVAL,
REQUEST_MESSAGE, REQUEST_AUTOPILOT_CAPABILITIES, GET_HOME_POSITION; anything else ->
MAV_RESULT_UNSUPPORTED. A COMMAND_LONG resent because its ACK was lost (``confirmation``
> 0, the same sender, command and params) is answered again, not run twice. The station's
sample recovery (COMMAND_INT ``SAMPLE_COUNT``, ``SAMPLE_RESEND``, ``TRACE_RESEND``) is
answered from the payload's archive.

A personality changes a command by overriding its ``_cmd_*`` method and its entry of
``_COMMANDS`` (:class:`sim_vehicle.ardupilot.ArduPilotAutopilot`).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.tasks import (
    SAMPLE_COUNT_COMMAND,
    SAMPLE_RESEND_COMMAND,
    SAMPLE_RESEND_MAX,
    TRACE_RESEND_COMMAND,
)

from .mission_server import MissionServer
from .navigator import Activity, Navigator
from .state import VehicleState
from .telemetry import Outbox, Telemetry

__all__ = ["ACCEPTED", "DENIED", "FAILED", "FORCE_ARM", "FORCE_DISARM", "UNSUPPORTED",
           "Commands"]

FORCE_DISARM = 21196
"""COMPONENT_ARM_DISARM param2 that allows disarming in the air."""
FORCE_ARM = 2989
"""COMPONENT_ARM_DISARM param2 that skips the pre-arm checks (ArduPilot's magic number)."""

ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
DENIED = mavlink.MAV_RESULT_DENIED
FAILED = mavlink.MAV_RESULT_FAILED
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED


def _code(value: float) -> int | None:
    """A command param holding an integer code (magic numbers), or None (NaN, inf)."""
    return int(value) if math.isfinite(value) else None


class Commands:
    """The commands of one vehicle (module docstring), run on the autopilot's state.

    The autopilot provides the attributes and the four methods declared here.
    """

    state: VehicleState
    server: MissionServer
    navigator: Navigator
    outbox: Outbox
    telemetry: Telemetry
    counters: dict[str, int]
    activity: Activity | None
    _last_command: tuple[tuple[Any, ...], int] | None

    def prearm_ok(self) -> bool:
        raise NotImplementedError

    def do_set_mode(self, base_mode: float, p2: float, p3: float) -> int:
        raise NotImplementedError

    def start_mission(self, first: int, last: int) -> None:
        raise NotImplementedError

    def _fly_activity(self, activity: Activity) -> None:
        raise NotImplementedError

    # -- the command protocol ------------------------------------------------------------------

    def _on_command_long(self, msg: Any) -> None:
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6,
                  msg.param7]
        key = (msg.get_srcSystem(), msg.get_srcComponent(), msg.command,
               tuple(struct.pack("<7f", *params)))
        last = self._last_command
        if msg.confirmation > 0 and last is not None and last[0] == key:
            # a resend because our COMMAND_ACK was lost: answer again, do not run it twice
            # (a second MISSION_START would restart the mission, a second RTL after landing
            # would be refused)
            self.counters["commands_repeated"] += 1
            self.outbox.put(mavlink.MAVLink_command_ack_message(
                msg.command, last[1], 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))
            return
        result = self._command(msg, msg.command, params)
        self._last_command = (key, result)

    @property
    def answers_sample_commands(self) -> bool:
        """Whether the sample recovery commands are known here (the payload answers them)."""
        return True

    def _on_command_int(self, msg: Any) -> None:
        if msg.command in (SAMPLE_COUNT_COMMAND, SAMPLE_RESEND_COMMAND, TRACE_RESEND_COMMAND) \
                and self.answers_sample_commands:
            self._sample_command(msg)
            return
        self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                         msg.x / 1e7, msg.y / 1e7, msg.z])

    def _sample_command(self, msg: Any) -> None:
        """The station's sample recovery (COMMAND_INT, x/y = first/last time_boot_ms)."""
        self.counters["commands"] += 1
        first, last = int(msg.x) & 0xFFFFFFFF, int(msg.y) & 0xFFFFFFFF
        if msg.command == TRACE_RESEND_COMMAND:
            reports = self.outbox.archive.reports_between(first, last)
            self.outbox.put(mavlink.MAVLink_command_ack_message(
                msg.command, ACCEPTED, 0, len(reports), msg.get_srcSystem(),
                msg.get_srcComponent()))
            for report in reports:
                self.outbox.put(report)
            return
        n = self.outbox.archive.count(first, last) if first <= last else 0
        too_many = msg.command == SAMPLE_RESEND_COMMAND and n > SAMPLE_RESEND_MAX
        result = DENIED if too_many else ACCEPTED
        # the ACK first: the station learns how many follow before they arrive
        self.outbox.put(mavlink.MAVLink_command_ack_message(
            msg.command, result, 0, n, msg.get_srcSystem(), msg.get_srcComponent()))
        if msg.command == SAMPLE_RESEND_COMMAND and result == ACCEPTED and n:
            self.outbox.resend(first, last)

    def _command(self, msg: Any, cmd: int, p: list[float]) -> int:
        self.counters["commands"] += 1
        result, after = self.execute_command(cmd, p)
        self.outbox.put(mavlink.MAVLink_command_ack_message(
            cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))
        for m in after:
            self.outbox.put(m)
        return result

    # -- commands ------------------------------------------------------------------------------

    def execute_command(self, cmd: int, p: list[float]) -> tuple[int, list[Any]]:
        """Run one command; return its MAV_RESULT and the messages to send after the ACK."""
        handler = self._COMMANDS.get(cmd)
        if handler is None:
            return UNSUPPORTED, []
        return handler(self, p)

    def _cmd_arm_disarm(self, p: list[float]) -> tuple[int, list[Any]]:
        st = self.state
        if p[0] >= 0.5:
            if st.armed:
                return ACCEPTED, []
            if st.in_air:
                return DENIED, []
            return self.arm(force=_code(p[1]) == FORCE_ARM)
        if st.in_air and _code(p[1]) != FORCE_DISARM:
            return DENIED, []
        st.armed = False
        st.alt_rel_m = 0.0
        st.landed_state = mavlink.MAV_LANDED_STATE_ON_GROUND
        self.activity = None
        st.mission_active = False
        st.sampling = False
        self.outbox.statustext("disarmed")
        return ACCEPTED, [self.telemetry.heartbeat()]

    def arm(self, force: bool = False) -> tuple[int, list[Any]]:
        """Arm on the ground; ``force`` skips the pre-arm checks."""
        if not (force or self.prearm_ok()):
            self.outbox.statustext("PreArm: waiting for sensors to settle",
                                   mavlink.MAV_SEVERITY_CRITICAL)
            return FAILED, []
        if not self.state.armed:  # a new flight: the traces of the last one are not its own
            self.state.body.forget_tracks()
        self.state.armed = True
        self.outbox.statustext("armed")
        return ACCEPTED, [self.telemetry.heartbeat()]

    def _cmd_takeoff(self, p: list[float]) -> tuple[int, list[Any]]:
        st = self.state
        if not st.armed:
            return DENIED, []
        alt = p[6] - st.home[2] if math.isfinite(p[6]) else float("nan")
        if not (math.isfinite(alt) and alt > 1.0):
            alt = st.params["ALT_M"]
        self._fly_activity(self.navigator.takeoff_then_hold(alt))
        return ACCEPTED, []

    def _cmd_mission_start(self, p: list[float]) -> tuple[int, list[Any]]:
        n = len(self.server.mission)
        if n == 0 or not self.state.armed:
            return DENIED, []
        first = int(p[0]) if math.isfinite(p[0]) else 0
        last = int(p[1]) if math.isfinite(p[1]) else n - 1
        if last <= 0 or last >= n:
            last = n - 1
        if not 0 <= first <= last:
            return DENIED, []
        for it in self.server.mission[first:last + 1]:  # PX4's mission feasibility check
            xy = self.navigator.item_xy(it)
            if xy is not None and not self.state.fence.contains(*xy):
                self.outbox.statustext(f"Geofence violation for waypoint {it.seq}",
                                       mavlink.MAV_SEVERITY_CRITICAL)
                return DENIED, []
        self.start_mission(first, last)
        return ACCEPTED, []

    def _cmd_rtl(self, p: list[float]) -> tuple[int, list[Any]]:
        if not (self.state.armed and self.state.in_air):
            return DENIED, []
        self._fly_activity(self.navigator.rtl())
        return ACCEPTED, []

    def _cmd_land(self, p: list[float]) -> tuple[int, list[Any]]:
        if not self.state.in_air:
            return ACCEPTED, []
        self._fly_activity(self.navigator.land())
        return ACCEPTED, []

    def _cmd_set_mode(self, p: list[float]) -> tuple[int, list[Any]]:
        return self.do_set_mode(p[0], p[1], p[2]), []

    def _cmd_change_speed(self, p: list[float]) -> tuple[int, list[Any]]:
        if not (math.isfinite(p[1]) and p[1] > 0):
            return DENIED, []
        # takes effect from the next item (the tracer's speed is per task)
        self.state.speed_mps = min(float(p[1]), self.state.settings.max_speed_mps)
        return ACCEPTED, []

    def _cmd_set_mission_current(self, p: list[float]) -> tuple[int, list[Any]]:
        seq = _code(p[0])
        if seq is None or not 0 <= seq < len(self.server.mission):
            return DENIED, []
        self.server.set_current(seq)
        if self.state.mission_active:
            self.start_mission(seq, len(self.server.mission) - 1)
        return ACCEPTED, [self.server.mission_current_msg(self.state.mission_active)]

    def _cmd_message_interval(self, p: list[float]) -> tuple[int, list[Any]]:
        mid = _code(p[0])
        ok = mid is not None and math.isfinite(p[1]) and self.telemetry.set_interval(mid, p[1])
        return (ACCEPTED if ok else DENIED), []

    def _cmd_request_message(self, p: list[float]) -> tuple[int, list[Any]]:
        mid = _code(p[0])
        make = self.telemetry.requestable().get(mid) if mid is not None else None
        if make is None:
            return UNSUPPORTED, []
        return ACCEPTED, [make()]

    def _cmd_capabilities(self, p: list[float]) -> tuple[int, list[Any]]:
        return ACCEPTED, [self.telemetry.autopilot_version()]

    def _cmd_home(self, p: list[float]) -> tuple[int, list[Any]]:
        return ACCEPTED, [self.telemetry.home_position()]

    _COMMANDS: dict[int, Callable[[Any, list[float]], tuple[int, list[Any]]]] = {
        mavlink.MAV_CMD_COMPONENT_ARM_DISARM: _cmd_arm_disarm,
        mavlink.MAV_CMD_NAV_TAKEOFF: _cmd_takeoff,
        mavlink.MAV_CMD_MISSION_START: _cmd_mission_start,
        mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: _cmd_rtl,
        mavlink.MAV_CMD_NAV_LAND: _cmd_land,
        mavlink.MAV_CMD_DO_SET_MODE: _cmd_set_mode,
        mavlink.MAV_CMD_DO_CHANGE_SPEED: _cmd_change_speed,
        mavlink.MAV_CMD_DO_SET_MISSION_CURRENT: _cmd_set_mission_current,
        mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: _cmd_message_interval,
        mavlink.MAV_CMD_REQUEST_MESSAGE: _cmd_request_message,
        mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _cmd_capabilities,
        mavlink.MAV_CMD_GET_HOME_POSITION: _cmd_home,
    }

