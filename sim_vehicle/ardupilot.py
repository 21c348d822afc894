"""The ArduPilot (ArduCopter 4.5) personality of the simulated autopilot.

The habits a ground station meets, as ArduCopter has them (read in ArduPilot's
``GCS_MAVLink/MissionItemProtocol*.cpp``, ``AP_Mission`` and ``ArduCopter/mode_auto.cpp``):

* HEARTBEAT ``autopilot = MAV_AUTOPILOT_ARDUPILOTMEGA`` with ArduCopter's custom mode numbers
  (:data:`COPTER_MODES`): STABILIZE 0 (the boot mode), AUTO 3, GUIDED 4, LOITER 5, RTL 6,
  LAND 9. ``base_mode`` has CUSTOM_MODE_ENABLED and STABILIZE_ENABLED, GUIDED_ENABLED in the
  navigation modes, SAFETY_ARMED when armed. DO_SET_MODE / SET_MODE take the mode number
  (param2 / ``custom_mode``); a refused mode change is MAV_RESULT_FAILED.
* Telemetry only when asked: nothing but HEARTBEAT until REQUEST_DATA_STREAM or
  SET_MESSAGE_INTERVAL enables messages.
* Pre-arm: arming fails (MAV_RESULT_FAILED and a ``PreArm:`` STATUSTEXT) for ``prearm_s``
  wall seconds after boot, and SYS_STATUS reports the MAV_SYS_STATUS_PREARM_CHECK health bit
  clear until then; COMPONENT_ARM_DISARM param2 = 2989 forces. Arming is refused in AUTO,
  RTL and LAND ("Mode not armable").
* Missions: items are requested with MISSION_REQUEST (not ``_INT``); item 0 is home and is
  overwritten with the vehicle's home (frame MAV_FRAME_GLOBAL, altitude AMSL); downloads
  report the float frames (3 for 6, 0 for 5), altitudes in centimetres and autocontinue 1,
  and a command stored without a position (DO_CHANGE_SPEED, RTL: not in
  :data:`POSITION_COMMANDS`) comes back with frame 0 and x, y, z = 0; unknown commands are
  refused with MAV_MISSION_UNSUPPORTED (the contour item and the sensor lag item too, unless
  a companion computer runs the tracer). A mission is flown from item 1.
* The upload's clock is the vehicle's (sim) time, as ArduPilot's ``AP_HAL::millis()``: a
  missing item is requested again after 1 s, the transfer is cancelled
  (MAV_MISSION_OPERATION_CANCELLED) after 8 s without one; an item other than the one
  requested is answered MAV_MISSION_INVALID_SEQUENCE and the transfer goes on; an item with
  no transfer running is answered MAV_MISSION_ERROR. For the first
  :data:`NO_SPACE_AFTER_BOOT_S` of its time it refuses every upload with
  MAV_MISSION_NO_SPACE (its mission storage is not ready yet).
* A mission or rally upload is written into the stored items as it comes (the mission or
  rally points are truncated to the new count when the transfer begins, each item replaces
  the one stored at its place; :data:`IN_PLACE_TYPES`), so an upload that ends early (a
  refused item, the 8 s timeout) leaves the new items taken so far, then the old ones up to
  the new count (seen on SITL: a 5-item mission, then a 3-item upload given items 0 and 1
  and left, reads back as home, the new item 1, the old item 2; 3 rally points, then a
  2-point upload left after point 0, read back as the new point 0 and the old point 1). A
  fence upload replaces the fence only when it completes. A GCS's MISSION_ACK does not end a
  transfer (SITL went on requesting after MISSION_ACK(OPERATION_CANCELLED));
  MISSION_CLEAR_ALL does, and empties the mission. While a transfer of a type runs, a
  download of that type is refused with MAV_MISSION_DENIED. While the vehicle flies its
  mission (AUTO), MISSION_CLEAR_ALL is refused with MAV_MISSION_ERROR and the mission kept
  (seen on SITL in flight).
* Flying a mission: GUIDED, arm, NAV_TAKEOFF (param7 = altitude *above home*), then AUTO; or
  arm and MAV_CMD_MISSION_START with param1 = param2 = 0 (anything else is DENIED: "first-item/
  last item not supported"), which enters AUTO and resumes at the current item, or from item 1
  when the mission is complete or was never started. Entering AUTO armed on the ground needs a
  NAV_TAKEOFF as item 1. At the end of the mission the vehicle stays in AUTO, hovering; RTL
  and LAND land and disarm and keep their mode.
* Until its position estimate is ready (the pre-arm time) GLOBAL_POSITION_INT says latitude =
  longitude = 0.
* While it asks a GCS for mission items (of any type) its periodic streams go out at four times
  their interval (``GCS_MAVLINK::get_reschedule_interval_ms``; seen on SITL: positions asked
  for every 25 ms came every 100 ms during an upload). Besides, while an upload runs, for at
  most :attr:`ArduCopterAutopilot.upload_pause_s` of its time from its MISSION_COUNT, it sends
  no GLOBAL_POSITION_INT at all, while the Lua script samples on: ArduCopter SITL in the
  lossy link test went ~3 s of its time without a position while it took uploads between
  iterations, hovering (a sample in such a gap is placed only because the copter held its
  place across it: :mod:`econdor_gcs.link.pairing`). A position asked for with
  REQUEST_MESSAGE is still answered.
* Without a companion computer it is a stock autopilot whose payload is a Lua script: the
  sample commands (MAV_CMD_USER_1..3) are unknown (MAV_RESULT_UNSUPPORTED), and each sample
  is a ``FIELD`` stamped with the autopilot's clock when the script sends it
  (:data:`~sim_vehicle.telemetry.LUA_SEND_DELAY_MS` after the position it was taken at), not
  the stamp of any position; the positions go out at the rate the station asked for. The
  script samples whenever the copter is armed and in the air (hovering and climbing too), as
  the shipped one does (``arming:is_armed() and vehicle:get_likely_flying()``).

Not imitated: the RC throttle that real ArduCopter wants before AUTO takes off (``auto_armed``;
there is no pilot here), failsafes, fences, parameters other than ours; a mission flown while
an upload writes into it flies on with the items it had when it started.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from .autopilot import MISSION_RETRIES, Autopilot
from .commands import ACCEPTED, DENIED, FAILED
from .mission_server import MISSION, RALLY, MissionServer, StoredItem
from .navigator import ModeFlow
from .state import FlightMode

COPTER_STABILIZE, COPTER_AUTO, COPTER_GUIDED, COPTER_LOITER, COPTER_RTL, COPTER_LAND = (
    0, 3, 4, 5, 6, 9)
COPTER_MODES = {
    FlightMode.MANUAL: COPTER_STABILIZE,
    FlightMode.MISSION: COPTER_AUTO,
    FlightMode.GUIDED: COPTER_GUIDED,
    FlightMode.TAKEOFF: COPTER_GUIDED,  # ArduCopter takes off in GUIDED
    FlightMode.HOLD: COPTER_LOITER,
    FlightMode.RTL: COPTER_RTL,
    FlightMode.LAND: COPTER_LAND,
}
COPTER_MODE_NAMES = {COPTER_STABILIZE: "STABILIZE", COPTER_AUTO: "AUTO",
                     COPTER_GUIDED: "GUIDED", COPTER_LOITER: "LOITER", COPTER_RTL: "RTL",
                     COPTER_LAND: "LAND"}
_MODE_OF_NUMBER = {
    COPTER_STABILIZE: FlightMode.MANUAL, COPTER_AUTO: FlightMode.MISSION,
    COPTER_GUIDED: FlightMode.GUIDED, COPTER_LOITER: FlightMode.HOLD,
    COPTER_RTL: FlightMode.RTL, COPTER_LAND: FlightMode.LAND,
}
_NAV_MODES = frozenset({FlightMode.MISSION, FlightMode.GUIDED, FlightMode.TAKEOFF,
                        FlightMode.HOLD, FlightMode.RTL})
_NOT_ARMABLE = frozenset({FlightMode.MISSION, FlightMode.RTL, FlightMode.LAND})
COPTER_FLIGHT_SW_VERSION = ((4 << 24) | (5 << 16) | (7 << 8)
                            | mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL)  # "4.5.7 official"
PREARM_S = 2.0
UPLOAD_RETRY_S = 1.0
"""ArduPilot re-requests a missing item after a second of its own time ..."""
UPLOAD_TIMEOUT_S = 8.0
"""... and cancels a transfer after 8 s of its time without an item (``upload_timeout_ms``)."""
UPLOAD_STREAM_SLOWDOWN = 4.0
"""Factor on the stream intervals while it asks a GCS for mission items."""
UPLOAD_PAUSE_S = 3.0
"""Seconds of its time from an upload's MISSION_COUNT during which, while the upload runs, it
sends no GLOBAL_POSITION_INT (the gaps seen on SITL during uploads between iterations: about
3 s)."""
IN_PLACE_TYPES = frozenset({MISSION, RALLY})
"""Mission types ArduPilot writes as the items come (``MissionItemProtocol_Waypoints`` and
``_Rally``); a fence upload is kept apart and replaces the fence only when complete (seen on
SITL: a fence upload left after item 0 left the old fence whole)."""
NO_SPACE_AFTER_BOOT_S = 3.0
"""Seconds of its time after boot during which it answers every upload NO_SPACE (seen on
ArduCopter SITL: about 2.8 s)."""
POSITION_COMMANDS = frozenset({
    mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_UNLIM,
    mavlink.MAV_CMD_NAV_LOITER_TURNS, mavlink.MAV_CMD_NAV_LOITER_TIME, mavlink.MAV_CMD_NAV_LAND,
    mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_NAV_CONTINUE_AND_CHANGE_ALT,
    mavlink.MAV_CMD_NAV_LOITER_TO_ALT, mavlink.MAV_CMD_NAV_SPLINE_WAYPOINT,
    mavlink.MAV_CMD_NAV_GUIDED_ENABLE, mavlink.MAV_CMD_DO_SET_HOME, mavlink.MAV_CMD_DO_LAND_START,
    mavlink.MAV_CMD_DO_GO_AROUND, mavlink.MAV_CMD_DO_SET_ROI, mavlink.MAV_CMD_NAV_VTOL_TAKEOFF,
    mavlink.MAV_CMD_NAV_VTOL_LAND, mavlink.MAV_CMD_NAV_PAYLOAD_PLACE,
    mavlink.MAV_CMD_WAYPOINT_USER_1,
})
"""Commands ArduPilot stores with a position (``AP_Mission::stored_in_location``; the
contour item, accepted only with a companion, keeps its start point)."""

_FLOAT_FRAME = {
    mavlink.MAV_FRAME_GLOBAL_INT: mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
}


class ArduPilotMissionServer(MissionServer):
    """The mission protocol as ArduPilot speaks it (item 0 is home; float frames back; its
    own clock; see the module docstring).

    ``sim_time`` is the vehicle's time since boot (s) and ``speedup`` its speed-up: the
    server is polled with wall time, ArduPilot counts in its own.
    """

    def __init__(self, home: tuple[float, float, float], sim_time: Callable[[], float],
                 speedup: Callable[[], float],
                 mission_running: Callable[[], bool] = lambda: False, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.home = home
        self.sim_time = sim_time
        self.speedup = speedup
        self.mission_running = mission_running
        """Whether the vehicle flies its mission now (``AP_Mission``'s MISSION_RUNNING)."""
        self._last_item_wall = 0.0
        self.upload_began_s: float | None = None
        """Its time (s) when the latest upload began (None: none yet)."""

    def mission_current_msg(self, active: bool, complete: bool = False,
                            paused: bool = False) -> Any:
        """As ArduPilot sends it: ``total`` counts the items without home (item 0), as the
        MAVLink spec allows for an autopilot that stores home in the mission
        (``GCS_MAVLINK::send_mission_current``: ``num_commands() - 1``)."""
        msg = super().mission_current_msg(active, complete, paused)
        msg.total = max(len(self.mission) - 1, 0)
        return msg

    def _wall(self, sim_s: float) -> float:
        return sim_s / max(self.speedup(), 1e-9)

    def _on_count(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        up = self.upload
        if up is not None and up.mission_type == self._mtype(msg) and up.peer != peer:
            # ``MissionItemProtocol::handle_mission_count``: only the GCS uploading may
            # start its transfer again
            return [self._ack(peer, mavlink.MAV_MISSION_DENIED, self._mtype(msg))]
        if self.sim_time() < NO_SPACE_AFTER_BOOT_S and msg.count > 0:
            return [self._ack(peer, mavlink.MAV_MISSION_NO_SPACE, self._mtype(msg))]
        self.timeout_s = self._wall(UPLOAD_RETRY_S)
        self._last_item_wall = now
        replies = super()._on_count(msg, peer, now)
        if self.upload is not None:
            self.upload_began_s = self.sim_time()
            mtype = self.upload.mission_type
            if mtype in IN_PLACE_TYPES:  # truncated to the new count at once
                self.stores[mtype] = self.stores[mtype][:self.upload.count]
        return replies

    def _on_item(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        up = self.upload
        mtype = self._mtype(msg)
        if up is None or up.mission_type != mtype:
            return [self._ack(peer, mavlink.MAV_MISSION_ERROR, mtype)]
        if msg.seq != len(up.items):
            return [self._ack(peer, mavlink.MAV_MISSION_INVALID_SEQUENCE, mtype)]
        if up.peer != peer:
            return [self._ack(peer, mavlink.MAV_MISSION_DENIED, mtype)]
        self._last_item_wall = now
        self.timeout_s = self._wall(UPLOAD_RETRY_S)
        taken = len(up.items)
        replies = super()._on_item(msg, peer, now)
        if mtype in IN_PLACE_TYPES and self.upload is up and len(up.items) > taken:
            self._write_in_place(mtype, up.items[-1])
        return replies

    def _write_in_place(self, mtype: int, item: StoredItem) -> None:
        """Store one item of a running mission or rally upload at its place (ArduPilot
        writes each item as it comes; the mission's item 0 stays home)."""
        items = list(self.stores[mtype])
        if item.seq < len(items):
            items[item.seq] = item
        else:
            items.append(item)
        self.stores[mtype] = self.stored(mtype, items)

    def _on_ack(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        return []  # a GCS's MISSION_ACK does not end ArduPilot's transfer: it times out

    def _on_clear(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        mtype = self._mtype(msg)
        if mtype in (MISSION, mavlink.MAV_MISSION_TYPE_ALL) and self.mission_running():
            # ``AP_Mission::clear`` refuses while the mission runs
            return [self._ack(peer, mavlink.MAV_MISSION_ERROR, mtype)]
        return super()._on_clear(msg, peer, now)

    def _on_request_list(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        if self._receiving(self._mtype(msg)):
            return [self._ack(peer, mavlink.MAV_MISSION_DENIED, self._mtype(msg))]
        return super()._on_request_list(msg, peer, now)

    def _on_request(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        if self._receiving(self._mtype(msg)):
            return [self._ack(peer, mavlink.MAV_MISSION_DENIED, self._mtype(msg))]
        return super()._on_request(msg, peer, now)

    def _receiving(self, mtype: int) -> bool:
        return self.upload is not None and self.upload.mission_type == mtype

    def poll(self, now: float) -> list[Any]:
        up = self.upload
        if up is not None and now - self._last_item_wall > self._wall(UPLOAD_TIMEOUT_S):
            self.upload = None
            self.counters["uploads_failed"] += 1
            return [self._ack(up.peer, mavlink.MAV_MISSION_OPERATION_CANCELLED,
                              up.mission_type)]
        if up is not None:
            up.retries = 0  # it asks again until the upload times out, not a number of times
        return super().poll(now)

    def stored(self, mtype: int, items: list[StoredItem]) -> list[StoredItem]:
        if mtype != MISSION:
            return items
        lat, lon, alt_amsl = self.home
        home = StoredItem(0, mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_CMD_NAV_WAYPOINT, 0, 1,
                          0.0, 0.0, 0.0, 0.0, int(round(lat * 1e7)), int(round(lon * 1e7)),
                          round(alt_amsl, 2))
        return [home, *items[1:]]

    def reported(self, item: StoredItem) -> StoredItem:
        if item.mission_type != MISSION:
            return item
        if item.command not in POSITION_COMMANDS:
            return dataclasses.replace(item, frame=mavlink.MAV_FRAME_GLOBAL, x=0, y=0, z=0.0,
                                       xf=None, yf=None, autocontinue=1, current=0)
        return dataclasses.replace(item, frame=_FLOAT_FRAME.get(item.frame, item.frame),
                                   z=round(item.z, 2), autocontinue=1, current=0)


class ArduCopterAutopilot(Autopilot):
    """ArduCopter personality (see the module docstring)."""

    name = "ardupilot"
    autopilot_type = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    flight_sw_version = COPTER_FLIGHT_SW_VERSION
    boot_mode = FlightMode.MANUAL
    mode_flow = ModeFlow(takeoff=FlightMode.GUIDED, after_takeoff=FlightMode.GUIDED,
                         rtl_descent=None, mission_rtl=None, landed=None,
                         mission_done=FlightMode.MISSION)
    streams_on_request = True
    lua_payload = True
    no_fix_until_prearm = True
    prearm_s = PREARM_S
    upload_pause_s = UPLOAD_PAUSE_S
    """Seconds of its time from an upload's MISSION_COUNT without GLOBAL_POSITION_INT while
    the upload runs (``VehicleSettings.upload_pause_s`` overrides it; 0: none)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.state.settings.upload_pause_s is not None:
            self.upload_pause_s = self.state.settings.upload_pause_s
        self.telemetry.stream_slowdown = self._stream_slowdown
        self.telemetry.positions_paused = self._positions_paused

    def _stream_slowdown(self) -> float:
        return UPLOAD_STREAM_SLOWDOWN if self.server.upload is not None else 1.0

    def _positions_paused(self) -> bool:
        server = self.server
        if server.upload is None or not isinstance(server, ArduPilotMissionServer):
            return False
        began = server.upload_began_s
        return began is not None and self.state.body.t_s - began < self.upload_pause_s - 1e-9

    def make_server(self, accepted_commands: frozenset[int]) -> MissionServer:
        return ArduPilotMissionServer(
            self.state.home, lambda: self.state.body.t_s, lambda: self.state.params["SPEEDUP"],
            lambda: self.state.mission_active, timeout_s=UPLOAD_RETRY_S,
            max_retries=MISSION_RETRIES, request_int=False, accepted_commands=accepted_commands)

    @property
    def answers_sample_commands(self) -> bool:
        """Only a companion computer answers the sample commands; a stock ArduPilot does not
        know them (MAV_RESULT_UNSUPPORTED)."""
        return self.state.settings.companion

    def custom_mode(self) -> int:
        return COPTER_MODES[self.state.mode]

    def mode_name(self) -> str:
        return COPTER_MODE_NAMES[self.custom_mode()]

    def heartbeat_modes(self) -> tuple[int, int]:
        base, custom = super().heartbeat_modes()
        base |= mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.state.mode in _NAV_MODES:
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        return base, custom

    @property
    def has_mission(self) -> bool:
        """More than the home item."""
        return len(self.server.mission) > 1

    # -- arming and modes ----------------------------------------------------------------------

    def arm(self, force: bool = False) -> tuple[int, list[Any]]:
        if self.state.mode in _NOT_ARMABLE and not force:
            self.outbox.statustext("Arm: Mode not armable", mavlink.MAV_SEVERITY_CRITICAL)
            return FAILED, []
        return super().arm(force)

    def set_mode(self, number: int) -> int:
        """Change to ArduCopter mode ``number`` -> MAV_RESULT."""
        mode = _MODE_OF_NUMBER.get(number)
        st = self.state
        if mode is None:
            return FAILED
        if mode == FlightMode.MISSION:
            return self._enter_auto(first=None)
        if mode == FlightMode.RTL:
            if not (st.armed and st.in_air):
                return FAILED
            self._fly_activity(self.navigator.rtl())
            return ACCEPTED
        st.mode = mode
        st.mission_active = False
        if mode == FlightMode.LAND:
            self.activity = self.navigator.land() if st.in_air else None
        elif st.in_air:
            self.activity = self.navigator.hold_forever()  # GUIDED / LOITER / no pilot
        return ACCEPTED

    def _enter_auto(self, first: int | None) -> int:
        """AUTO: resume the mission (or start it at ``first``); FAILED without a mission, or
        armed on the ground without a takeoff item."""
        st = self.state
        items = self.server.mission
        if not self.has_mission:
            self.outbox.statustext("Mode change to AUTO failed: no mission",
                                   mavlink.MAV_SEVERITY_WARNING)
            return FAILED
        if st.armed and not st.in_air and items[1].command != mavlink.MAV_CMD_NAV_TAKEOFF:
            self.outbox.statustext("Auto: Missing Takeoff Cmd", mavlink.MAV_SEVERITY_WARNING)
            return FAILED
        if first is None:
            first = self.server.current_seq
            if first < 1 or st.mission_complete or first >= len(items):
                first = 1
        st.mode = FlightMode.MISSION
        if st.armed:
            self.start_mission(first, len(items) - 1)
        else:
            self.server.set_current(first)
            st.mission_active = False
            self.activity = None
        return ACCEPTED

    def do_set_mode(self, base_mode: float, p2: float, p3: float) -> int:
        if not int(base_mode) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED \
                or not math.isfinite(p2):
            return FAILED
        return self.set_mode(int(p2))

    def on_set_mode(self, msg: Any) -> None:
        if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            self.set_mode(int(msg.custom_mode))

    # -- commands ArduCopter treats its own way ------------------------------------------------

    def _cmd_takeoff(self, p: list[float]) -> tuple[int, list[Any]]:
        """GUIDED (or LOITER) takeoff to param7 metres above home."""
        st = self.state
        alt = p[6]
        if not (st.armed and not st.in_air
                and st.mode in (FlightMode.GUIDED, FlightMode.HOLD)
                and math.isfinite(alt) and alt > 0):
            return FAILED, []
        self._fly_activity(self.navigator.takeoff_then_hold(alt))
        return ACCEPTED, []

    def _cmd_mission_start(self, p: list[float]) -> tuple[int, list[Any]]:
        if p[0] != 0 or p[1] != 0:
            return DENIED, []  # ArduCopter: "first-item/last item not supported"
        return self._enter_auto(None), []

    def _on_request_data_stream(self, msg: Any) -> None:
        self.telemetry.request_data_stream(int(msg.req_stream_id), float(msg.req_message_rate),
                                           bool(msg.start_stop))

    _COMMANDS = {**Autopilot._COMMANDS,
                 mavlink.MAV_CMD_NAV_TAKEOFF: _cmd_takeoff,
                 mavlink.MAV_CMD_MISSION_START: _cmd_mission_start}
    _HANDLERS = {**Autopilot._HANDLERS, "REQUEST_DATA_STREAM": _on_request_data_stream}
