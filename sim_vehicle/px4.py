"""The PX4 personality of the simulated autopilot (PX4 v1.14 habits).

``custom_mode = main_mode << 16 | sub_mode << 24`` (see :data:`PX4_MODES`): AUTO.LOITER (hold;
the boot mode), AUTO.MISSION, AUTO.RTL, AUTO.LAND, AUTO.TAKEOFF. ``base_mode`` always has
CUSTOM_MODE_ENABLED, plus SAFETY_ARMED when armed and AUTO|GUIDED|STABILIZE (all modes here
are auto modes). DO_SET_MODE takes param2 = main mode (AUTO = 4), param3 = AUTO sub mode.
Arming in AUTO.MISSION starts the mission. Telemetry streams from boot.

Its mission protocol (``MavlinkMissionManager`` in ``src/modules/mavlink/mavlink_mission.cpp``,
:class:`Px4MissionServer`): an upload goes to the storage not in use and becomes the mission
only when complete, so one that ends early leaves the mission as it was. While it takes an
upload it refuses a new MISSION_COUNT with MAV_MISSION_ERROR ("busy") once it has an item
(before that it asks for item 0 again), from any other GCS at once; it ends the transfer on
the uploading GCS's MISSION_ACK(OPERATION_CANCELLED) of any mission type (no other ACK), ignores
MISSION_CLEAR_ALL and download requests ("busy"), asks again for the missing item every
0.25 s and gives up 5 s after it last heard from the GCS, with a STATUSTEXT and no
MISSION_ACK.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from .autopilot import MISSION_RETRIES, MISSION_RETRY_S, Autopilot
from .commands import ACCEPTED, DENIED
from .mission_server import MissionServer
from .state import FlightMode

# PX4 main modes and AUTO sub modes
PX4_MAIN_AUTO = 4
PX4_SUB_TAKEOFF, PX4_SUB_LOITER, PX4_SUB_MISSION, PX4_SUB_RTL, PX4_SUB_LAND = 2, 3, 4, 5, 6


def px4_mode(main: int, sub: int = 0) -> int:
    return (main << 16) | (sub << 24)


PX4_MODES = {
    FlightMode.TAKEOFF: px4_mode(PX4_MAIN_AUTO, PX4_SUB_TAKEOFF),
    FlightMode.HOLD: px4_mode(PX4_MAIN_AUTO, PX4_SUB_LOITER),
    FlightMode.MISSION: px4_mode(PX4_MAIN_AUTO, PX4_SUB_MISSION),
    FlightMode.RTL: px4_mode(PX4_MAIN_AUTO, PX4_SUB_RTL),
    FlightMode.LAND: px4_mode(PX4_MAIN_AUTO, PX4_SUB_LAND),
}
PX4_MODE_NAMES = {
    FlightMode.TAKEOFF: "AUTO.TAKEOFF", FlightMode.HOLD: "AUTO.LOITER",
    FlightMode.MISSION: "AUTO.MISSION", FlightMode.RTL: "AUTO.RTL", FlightMode.LAND: "AUTO.LAND",
}
PX4_FLIGHT_SW_VERSION = (1 << 24) | (14 << 16) | (0 << 8) | 255  # "1.14.0 release"


def _busy(text: str) -> Any:
    return mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_CRITICAL, text.encode(), 0, 0)


class Px4MissionServer(MissionServer):
    """The mission protocol as PX4 speaks it while an upload runs (the module docstring);
    its retry timing is the base server's (a request again every 0.25 s, for 5 s)."""

    def _on_count(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        up = self.upload
        if up is None:
            return super()._on_count(msg, peer, now)
        up.retries = 0  # any COUNT counts as hearing from the GCS: the transfer goes on
        if peer != up.peer or up.items:
            return [self._ack(peer, mavlink.MAV_MISSION_ERROR, self._mtype(msg))]
        up.deadline = now + self.timeout_s  # its request was lost: again, from item 0
        return [self._request(up)]

    def _on_ack(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        up = self.upload
        if (up is not None and up.peer == peer
                and msg.type == mavlink.MAV_MISSION_OPERATION_CANCELLED):
            self.upload = None  # whatever the cancel's mission type, as PX4 does
            self.counters["uploads_failed"] += 1
        return []

    def _on_clear(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        if self.upload is not None:
            return [_busy("WPM: IGN CLEAR CMD: Busy")]
        return super()._on_clear(msg, peer, now)

    def _on_request_list(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        if self.upload is not None:
            return [_busy("Mission download request ignored, already active")]
        return super()._on_request_list(msg, peer, now)

    def _on_item(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        up = self.upload
        if up is not None and up.peer == peer and msg.seq != len(up.items):
            return []  # an item it did not ask for is ignored; its own request repeats
        return super()._on_item(msg, peer, now)

    def poll(self, now: float) -> list[Any]:
        up = self.upload
        if up is not None and now >= up.deadline and up.retries >= self.max_retries:
            self.upload = None
            self.counters["uploads_failed"] += 1
            return [_busy("Operation timeout")]  # and no MISSION_ACK
        return super().poll(now)


class Px4Autopilot(Autopilot):
    """PX4 personality (v1.14 habits; see the module docstring)."""

    name = "px4"
    autopilot_type = mavlink.MAV_AUTOPILOT_PX4
    flight_sw_version = PX4_FLIGHT_SW_VERSION
    boot_mode = FlightMode.HOLD

    def make_server(self, accepted_commands: frozenset[int]) -> MissionServer:
        return Px4MissionServer(timeout_s=MISSION_RETRY_S, max_retries=MISSION_RETRIES,
                                accepted_commands=accepted_commands)

    def custom_mode(self) -> int:
        return PX4_MODES[self.state.mode]

    def mode_name(self) -> str:
        return PX4_MODE_NAMES[self.state.mode]

    def heartbeat_modes(self) -> tuple[int, int]:
        base, custom = super().heartbeat_modes()
        # every PX4 mode here is an auto mode
        base |= (mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
                 | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED)
        return base, custom

    def arm(self, force: bool = False) -> tuple[int, list[Any]]:
        result = super().arm(force)
        if result[0] == ACCEPTED and self.state.mode == FlightMode.MISSION and self.server.mission:
            # PX4: arming in AUTO.MISSION starts the mission
            self.start_mission(self.server.current_seq, len(self.server.mission) - 1)
        return result

    def on_set_mode(self, msg: Any) -> None:
        self.do_set_mode(float(msg.base_mode), float((msg.custom_mode >> 16) & 0xFF),
                         float((msg.custom_mode >> 24) & 0xFF))

    def do_set_mode(self, base_mode: float, p2: float, p3: float) -> int:
        """PX4: param2 = main mode (only AUTO = 4 here), param3 = AUTO sub mode."""
        if not int(base_mode) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED \
                or int(p2) != PX4_MAIN_AUTO:
            return DENIED
        sub = int(p3)
        st = self.state
        if sub == PX4_SUB_MISSION:
            if not self.server.mission:
                return DENIED
            if st.mode == FlightMode.MISSION and st.mission_active:
                return ACCEPTED
            st.mode = FlightMode.MISSION
            if st.armed:
                cur = self.server.current_seq
                if cur >= len(self.server.mission):
                    cur = 0
                self.start_mission(cur, len(self.server.mission) - 1)
            return ACCEPTED
        if sub in (PX4_SUB_LOITER, 0, 1):
            st.mode = FlightMode.HOLD
            st.mission_active = False
            if st.in_air:
                self.activity = self.navigator.hold_forever()
            return ACCEPTED
        if sub == PX4_SUB_RTL:
            if not (st.armed and st.in_air):
                return DENIED
            self._fly_activity(self.navigator.rtl())
            return ACCEPTED
        if sub == PX4_SUB_LAND:
            st.mission_active = False
            if st.in_air:
                self.activity = self.navigator.land()
            return ACCEPTED
        if sub == PX4_SUB_TAKEOFF:
            if not st.armed:
                return DENIED
            self._fly_activity(self.navigator.takeoff_then_hold(st.params["ALT_M"]))
            return ACCEPTED
        return DENIED
