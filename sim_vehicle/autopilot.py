"""The autopilot of a simulated vehicle as an I/O-free state machine, per personality.

In the style of aioquic's connection objects: the I/O loop feeds received messages with
:meth:`Autopilot.receive` (``msg, now``), steps the simulation with :meth:`Autopilot.tick`,
calls :meth:`Autopilot.poll` when :meth:`Autopilot.next_deadline` has passed (mission transfer
retries) and sends whatever the :class:`~sim_vehicle.telemetry.Outbox` holds. ``now`` is the
wall clock (protocol timeouts); the flight itself runs on the body's sim clock.

:class:`Autopilot` holds what every personality shares: arming, the mission protocol
(:class:`~sim_vehicle.mission_server.MissionServer`), parameters and the common commands.
A personality subclass says how modes are encoded and set, and adds its own habits:
:class:`sim_vehicle.px4.Px4Autopilot`.

Commands: :mod:`sim_vehicle.commands`. Uploading or clearing the mission while it runs
makes the vehicle hold.

Geofence (PX4's way): an uploaded FENCE applies at once (:mod:`sim_vehicle.fence`; the flight
logic brakes before it, whatever the vehicle is doing); MISSION_START refuses a mission
that leaves it.

Parameters (REAL32): SPEED_MPS, SAMPLE_HZ, SEARCH_RAD_M, TEL_RATE_HZ, NOISE_STD, ALT_M,
SPEEDUP, LAG_S, POS_STD_M, POS_TAU_S (:mod:`sim_vehicle.params`). SAMPLE_HZ and the sensor's
(NOISE_STD, LAG_S, POS_STD_M, POS_TAU_S: :mod:`sim_vehicle.sensor`) apply from the next
mission item (or at once when idle).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.geometry import Region
from econdor_gcs.core.tasks import Phase

from .body import Sample
from .commands import Commands
from .fence import Fence
from .mission_server import FENCE, MISSION, STOCK_COMMANDS, SUPPORTED_COMMANDS, MissionServer
from .navigator import Activity, ModeFlow, Navigator
from .params import Parameters
from .state import (
    GCS_FAILSAFE_ACTIONS,
    FlightMode,
    VehicleSettings,
    VehicleState,
)
from .telemetry import Outbox, Telemetry
from .tracer import TracerParams

MISSION_RETRY_S = 0.25
MISSION_RETRIES = 20
"""Mission upload: resend a request after MISSION_RETRY_S, fail after this many in a row
(PX4's timing: a GCS under load can answer a request seconds late)."""

class Autopilot(Commands):
    """Modes, arming, commands (:class:`~sim_vehicle.commands.Commands`), parameters and
    the mission protocol of one vehicle.

    Parameters
    ----------
    field, region, origin
        The true field ``field(x, y)``, the mission area (local ENU metres) and its origin.
    settings
        Limits, rates, defaults, system id.
    home
        ``(lat_deg, lon_deg, alt_amsl_m)``; the vehicle starts landed and disarmed there.
    tracer_params
        Base tracer tuning (speeds are overridden by SPEED_MPS).
    status_line
        The link counters as one line (answer to REQUEST_MESSAGE(STATUSTEXT)).
    now
        Wall-clock time of boot (the same clock as the ``now`` given to :meth:`receive`).
    """

    name = "generic"
    autopilot_type = mavlink.MAV_AUTOPILOT_GENERIC
    flight_sw_version = 0
    boot_mode = FlightMode.HOLD
    mode_flow = ModeFlow()
    streams_on_request = False
    """True: only HEARTBEAT until a GCS asks for streams (ArduPilot)."""
    prearm_s = 0.0
    """Default wall seconds after boot during which arming is refused."""
    lua_payload = False
    """True: without a companion the samples come from a Lua script on the autopilot
    (stamped when sent, positions only at the rate asked for; ArduPilot)."""
    no_fix_until_prearm = False
    """True: positions are latitude = longitude = 0 until the pre-arm checks pass."""

    def __init__(self, field: Callable[[float, float], float], region: Region, origin: Origin,
                 settings: VehicleSettings, home: tuple[float, float, float],
                 tracer_params: TracerParams | None = None,
                 status_line: Callable[[], str] = lambda: "", now: float = 0.0) -> None:
        self.state = VehicleState(field, region, origin, settings, home)
        self.state.mode = self.boot_mode
        self.boot_wall = now
        self.now = now
        if settings.prearm_s is not None:
            self.prearm_s = settings.prearm_s
        self.outbox = Outbox(origin, home[2])
        accepted = SUPPORTED_COMMANDS if settings.companion else STOCK_COMMANDS
        self.server = self.make_server(accepted)
        self.navigator = Navigator(self.state, self.server, self.outbox, tracer_params,
                                   self.mode_flow)
        self.telemetry = Telemetry(self.state, self.server, self.outbox, self, status_line,
                                   streams_on_request=self.streams_on_request)
        self.outbox.lua_payload = self.lua_payload and not settings.companion
        self.telemetry.no_fix_until_prearm = self.no_fix_until_prearm
        self.telemetry.positions_at_sensor_rate()
        self.activity: Activity | None = None
        self.counters: dict[str, int] = {"rx_unhandled": 0, "ticks": 0, "commands": 0,
                                         "commands_repeated": 0}
        self.gcs_heard_wall: float | None = None
        """Wall time of the last GCS HEARTBEAT (None: no GCS yet, no failsafe: ArduPilot's
        rule)."""
        self.gcs_failsafe = False
        """The GCS failsafe acted and the GCS has not been heard since."""
        self._last_command: tuple[tuple[Any, ...], int] | None = None
        """The last COMMAND_LONG run (sender, command, params) and its result: a resend of it
        (``confirmation`` > 0) is answered, not run again."""
        self.unhandled: dict[str, int] = {}
        self.params = Parameters(self.state, self.outbox, self.counters)

    # -- the personality's part ----------------------------------------------------------------

    def make_server(self, accepted_commands: frozenset[int]) -> MissionServer:
        """The mission protocol server (PX4 timing: re-request every 0.25 s)."""
        return MissionServer(timeout_s=MISSION_RETRY_S, max_retries=MISSION_RETRIES,
                             accepted_commands=accepted_commands)

    def prearm_ok(self) -> bool:
        """The pre-arm checks pass: ``prearm_s`` wall seconds have passed since boot."""
        return self.now - self.boot_wall >= self.prearm_s

    def custom_mode(self) -> int:
        """The current mode as this personality's ``custom_mode``."""
        raise NotImplementedError

    def mode_name(self) -> str:
        raise NotImplementedError

    def heartbeat_modes(self) -> tuple[int, int]:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.state.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        return base, self.custom_mode()

    def do_set_mode(self, base_mode: float, p2: float, p3: float) -> int:
        """MAV_CMD_DO_SET_MODE (params 1-3) -> MAV_RESULT."""
        raise NotImplementedError

    def on_set_mode(self, msg: Any) -> None:
        """The deprecated SET_MODE message (no answer)."""
        raise NotImplementedError

    # -- driving it ----------------------------------------------------------------------------

    @property
    def parked(self) -> bool:
        """Landed, disarmed and idle: nothing to sense or report."""
        return self.activity is None and not self.state.armed and self.state.alt_rel_m <= 0.0

    def skip_parked(self, n_ticks: int) -> None:
        """Jump ``n_ticks`` ahead while parked (one body rebuild instead of n idle ticks)."""
        st = self.state
        st.rebuild_body(st.body.t_s + n_ticks * st.body.dt_s)
        st.vel_enu_mps = (0.0, 0.0, 0.0)
        self.counters["ticks"] += n_ticks

    def tick(self) -> None:
        """One sim tick: step the activity (or hover); queue its sample if it is reported:
        our payload reports the ticks of horizontal tasks (``state.sampling``), a Lua
        script every tick in the air, hovering and climbing too (the shipped script sends
        while the autopilot is armed and likely flying)."""
        st = self.state
        self.counters["ticks"] += 1
        # the velocity an autopilot reports is good (GNSS Doppler, IMU) even where its
        # position carries the GNSS error: the true path's
        x0, y0, a0 = st.body.true_x_m, st.body.true_y_m, st.alt_rel_m
        sample: Sample | None = None
        if self.activity is not None:
            try:
                sample = next(self.activity)
            except StopIteration:
                self.activity = None
        lua_sends = self.outbox.lua_payload and st.armed and st.in_air
        if self.activity is None and sample is None:
            st.apply_pending_body()
            idle = st.body.hold(Phase.TRANSIT)
            sample = idle if lua_sends else None
        dt = st.body.dt_s
        st.vel_enu_mps = ((st.body.true_x_m - x0) / dt, (st.body.true_y_m - y0) / dt,
                          (st.alt_rel_m - a0) / dt)
        if sample is not None and (st.sampling or lua_sends):
            self.telemetry.sample(sample)
        self.telemetry.watch_fence()

    def next_deadline(self) -> float | None:
        return self.server.next_deadline()

    def poll(self, now: float) -> None:
        """Mission transfer retries / timeouts due at ``now``."""
        self.now = now
        for m in self.server.poll(now):
            self.outbox.put(m)

    def one_hz(self, now: float) -> None:
        """The 1 Hz (wall) telemetry, and the GCS failsafe's watch."""
        self.now = now
        self.check_gcs_failsafe(now)
        self.telemetry.one_hz()

    def check_gcs_failsafe(self, now: float) -> None:
        """ArduCopter's GCS failsafe (FS_GCS_ENABLE, FS_GCS_TIMEOUT; PX4: NAV_DLL_ACT,
        COM_DL_LOSS_T): flying, with no GCS HEARTBEAT for ``GCS_FS_S`` wall seconds, the
        vehicle leaves what it does for RTL (or holds where it is). Only once a GCS was
        heard, never on the ground, not again while already returning or landing. The
        timeout is wall time: it is the link's, whatever the simulation's speed-up.

        When the GCS is heard again the vehicle does not go back to its mission by itself
        (neither autopilot does): the ground station decides."""
        st = self.state
        action = st.params["GCS_FS_ACT"]
        if (action <= 0 or self.gcs_heard_wall is None or self.gcs_failsafe
                or not (st.armed and st.in_air)
                or st.mode in (FlightMode.RTL, FlightMode.LAND)
                or now - self.gcs_heard_wall < st.params["GCS_FS_S"]):
            return
        self.gcs_failsafe = True
        rtl = action >= GCS_FAILSAFE_ACTIONS["rtl"]
        self.outbox.statustext(f"Failsafe: GCS heartbeat lost for "
                               f"{now - self.gcs_heard_wall:.0f} s: "
                               f"{'RTL' if rtl else 'holding'}", mavlink.MAV_SEVERITY_CRITICAL)
        if rtl:
            self._fly_activity(self.navigator.rtl())
        else:
            self.set_hold()

    def receive(self, msg: Any, now: float) -> bool:
        """Handle one message addressed to this vehicle; False if it is not understood."""
        self.now = now
        mtype = msg.get_type()
        if mtype.startswith("MISSION_"):
            for reply in self.server.receive(msg, now):
                self.outbox.put(reply)
            self._mission_events()
            return True
        handler = self._HANDLERS.get(mtype)
        if handler is None:
            self.counters["rx_unhandled"] += 1
            self.unhandled[mtype] = self.unhandled.get(mtype, 0) + 1
            return False
        handler(self, msg)
        return True

    # -- mission events ------------------------------------------------------------------------

    def _mission_events(self) -> None:
        st = self.state
        while self.server.events:
            ev = self.server.events.pop(0)
            if ev.mission_type == FENCE:
                st.set_fence(Fence.from_items(self.server.stores[FENCE], st.origin))
                self.outbox.statustext(f"fence: {st.fence.describe()}")
                continue
            if ev.mission_type != MISSION:
                continue
            if ev.kind in ("uploaded", "cleared"):
                st.mission_complete = False
                st.mission_started = False
                # a command after a new mission is new, even if it repeats the last one (the
                # MISSION_START of the next flight, resent because the first was lost)
                self._last_command = None
            if ev.kind in ("uploaded", "cleared") and st.mission_active:
                # the mission under execution is gone: hold where we are
                self.set_hold()
            elif ev.kind == "set_current" and st.mission_active:
                self.start_mission(ev.seq, len(self.server.mission) - 1)

    def set_hold(self) -> None:
        st = self.state
        st.mission_active = False
        st.mode = FlightMode.HOLD
        self.activity = self.navigator.hold_forever() if st.alt_rel_m > 0.0 else None

    def start_mission(self, first: int, last: int) -> None:
        self.state.mode = FlightMode.MISSION
        self.activity = self.navigator.mission(first, last)

    def _fly_activity(self, activity: Activity) -> None:
        """Leave the mission (if any) for ``activity``."""
        self.state.mission_active = False
        self.activity = activity

    # -- messages ------------------------------------------------------------------------------

    def _on_heartbeat(self, msg: Any) -> None:
        if msg.type != mavlink.MAV_TYPE_GCS:
            return
        self.gcs_heard_wall = self.now
        if self.gcs_failsafe:
            self.gcs_failsafe = False
            self.outbox.statustext("GCS heartbeat back", mavlink.MAV_SEVERITY_WARNING)

    def _on_ping(self, msg: Any) -> None:
        if msg.target_system == 0:
            self.outbox.put(mavlink.MAVLink_ping_message(
                msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_timesync(self, msg: Any) -> None:
        if msg.tc1 == 0:
            self.outbox.put(mavlink.MAVLink_timesync_message(int(self.state.body.t_s * 1e9),
                                                             msg.ts1))

    def _on_set_mode(self, msg: Any) -> None:
        self.on_set_mode(msg)

    # -- messages, by type -----------------------------------------------------------------------

    _HANDLERS: dict[str, Callable[[Any, Any], None]] = {
        "HEARTBEAT": _on_heartbeat,
        "PING": _on_ping,
        "TIMESYNC": _on_timesync,
        "COMMAND_LONG": Commands._on_command_long,
        "COMMAND_INT": Commands._on_command_int,
        "SET_MODE": _on_set_mode,
        "PARAM_REQUEST_LIST": lambda self, msg: self.params.on_request_list(msg),
        "PARAM_REQUEST_READ": lambda self, msg: self.params.on_request_read(msg),
        "PARAM_SET": lambda self, msg: self.params.on_set(msg),
    }
