"""A simulated multicopter that speaks MAVLink 2 (common dialect) like a PX4 autopilot.

One :class:`MavlinkVehicle` = one system id, component 1. It owns a :class:`SimBody`, runs
the mission items with the onboard tracer, and serves the GCS over one transport
(``udpout:``, ``udpin:`` or ``tcpin:``, see :mod:`sim_vehicle.transport`). pymavlink is used
only as a codec; the loop is a plain ``select`` loop, so a vehicle can run in its own process
(``sim-vehicle``) or in-process on a thread (:meth:`MavlinkVehicle.start`).

Time: sim time runs ``speedup`` times faster than wall time. All MAVLink timestamps
(``time_boot_ms``, ``time_usec``) are sim time since the vehicle booted. One sim tick =
one ``SimBody`` sensor period. HEARTBEAT, SYS_STATUS and EXTENDED_SYS_STATE go out at
1 Hz of wall time; GLOBAL_POSITION_INT, LOCAL_POSITION_NED and ATTITUDE at ``TEL_RATE_HZ``
of sim time but never more than :data:`MAX_STREAM_WALL_HZ` per wall second.

Samples: every sensor reading taken while the vehicle executes a horizontal motion task
(waypoint / trace item, RTL or land leg) is sent as ``GLOBAL_POSITION_INT`` immediately
followed by ``NAMED_VALUE_FLOAT("FIELD")`` with the same ``time_boot_ms`` -- regardless of
the telemetry rate cap. Ticks spent holding, climbing, descending or on the ground are not
reported as samples.

Flight modes use PX4's encoding: ``custom_mode = main_mode << 16 | sub_mode << 24``
(see :data:`MODES`): AUTO.LOITER (hold; the boot mode), AUTO.MISSION, AUTO.RTL, AUTO.LAND,
AUTO.TAKEOFF. ``base_mode`` always has CUSTOM_MODE_ENABLED, plus SAFETY_ARMED when armed
and AUTO|GUIDED|STABILIZE (all modes here are auto modes).

Commands (COMMAND_LONG and COMMAND_INT, always answered by COMMAND_ACK): COMPONENT_ARM_DISARM
(arm only on the ground; disarm in the air only with the 21196 force code), NAV_TAKEOFF
(param7 AMSL; needs armed), MISSION_START (param1/2 first/last; needs armed + a mission),
NAV_RETURN_TO_LAUNCH, NAV_LAND, DO_SET_MODE (PX4 main 4 = AUTO, sub 2/3/4/5/6), DO_CHANGE_SPEED
(from the next item), DO_SET_MISSION_CURRENT, SET_MESSAGE_INTERVAL, REQUEST_MESSAGE,
REQUEST_AUTOPILOT_CAPABILITIES, GET_HOME_POSITION; anything else -> MAV_RESULT_UNSUPPORTED.
Arming in AUTO.MISSION starts the mission (PX4 habit). Uploading or clearing the mission
while it runs makes the vehicle hold.

Parameters (REAL32): SPEED_MPS, SAMPLE_HZ, SEARCH_RAD_M, TEL_RATE_HZ, NOISE_STD, ALT_M,
SPEEDUP. SAMPLE_HZ / NOISE_STD apply from the next mission item (or at once when idle).

Robustness: garbage, bad-CRC and truncated packets, messages for other systems/components,
and more than :data:`RX_BUDGET_PER_S` messages per second from one peer are dropped and
counted in :attr:`MavlinkVehicle.counters`; REQUEST_MESSAGE(STATUSTEXT=253) answers with a
one-line summary, and ``sim-vehicle`` prints it at exit.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import select
import socket
import threading
import time
from collections.abc import Callable, Generator
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.tasks import Phase, TraceTask, Waypoint

from .body import Sample, SimBody
from .executor import run_task
from .kinematics import VehicleLimits
from .mission_server import (
    MAV_CMD_WAYPOINT_USER_1,
    MISSION,
    MissionServer,
    StoredItem,
)
from .tracer import TracerParams, fly_to
from .transport import Endpoint, Transport, open_transport, parse_endpoint

log = logging.getLogger("sim_vehicle")

COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1
MAX_STREAM_WALL_HZ = 50.0
CLIMB_RATE_MPS = 3.0
DESCENT_RATE_MPS = 1.5
RX_BUDGET_PER_S = 5000
TICK_BATCH_WALL_S = 0.01
MISSION_RETRY_S = 0.25
MISSION_RETRIES = 20
"""Mission upload: resend a request after MISSION_RETRY_S, fail after this many in a row."""
"""Messages per wall second accepted from one peer; the rest is dropped as a flood."""

# PX4 main modes and AUTO sub modes
PX4_MAIN_AUTO = 4
PX4_SUB_TAKEOFF, PX4_SUB_LOITER, PX4_SUB_MISSION, PX4_SUB_RTL, PX4_SUB_LAND = 2, 3, 4, 5, 6


def px4_mode(main: int, sub: int = 0) -> int:
    return (main << 16) | (sub << 24)


MODES = {
    "AUTO.TAKEOFF": px4_mode(PX4_MAIN_AUTO, PX4_SUB_TAKEOFF),
    "AUTO.LOITER": px4_mode(PX4_MAIN_AUTO, PX4_SUB_LOITER),
    "AUTO.MISSION": px4_mode(PX4_MAIN_AUTO, PX4_SUB_MISSION),
    "AUTO.RTL": px4_mode(PX4_MAIN_AUTO, PX4_SUB_RTL),
    "AUTO.LAND": px4_mode(PX4_MAIN_AUTO, PX4_SUB_LAND),
}
MODE_NAMES = {v: k for k, v in MODES.items()}

SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mavlink.MAV_SYS_STATUS_AHRS
    | mavlink.MAV_SYS_STATUS_PREARM_CHECK
)
CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
)
FLIGHT_SW_VERSION = (1 << 24) | (14 << 16) | (0 << 8) | 255  # "1.14.0 release", PX4 style

# Parameters: name -> (default from the mission, lower bound, upper bound)
PARAM_NAMES = ("SPEED_MPS", "SAMPLE_HZ", "SEARCH_RAD_M", "TEL_RATE_HZ", "NOISE_STD",
               "ALT_M", "SPEEDUP")


def _reset_parser(parser: mavlink.MAVLink) -> None:
    parser.buf = bytearray()
    parser.buf_index = 0
    parser.expected_length = mavlink.HEADER_LEN_V1 + 2


class _Sink:
    """File-like shim: pymavlink's MAVLink.send() writes here, we forward to the transport."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.chunks.append(bytes(data))


@dataclasses.dataclass
class VehicleSettings:
    """Everything a vehicle needs besides the mission file's field and geometry."""

    sysid: int = 1
    speed_mps: float = 8.0
    max_speed_mps: float = 12.0
    max_accel_mps2: float = 5.0
    max_turn_rate_dps: float = 180.0
    sample_rate_hz: float = 10.0
    altitude_m: float = 30.0
    noise_std: float = 0.0
    speedup: float = 50.0
    search_radius_m: float = 10.0
    tel_rate_hz: float = 10.0
    seed: int = 0


class MavlinkVehicle:
    """One simulated PX4-like vehicle on one MAVLink transport.

    Parameters
    ----------
    field, region, origin
        The true field ``field(x, y)``, the mission area (local ENU metres) and its origin.
    settings
        :class:`VehicleSettings` (sysid, speeds, rates, speedup, ...).
    connect
        Endpoint string or :class:`~sim_vehicle.transport.Endpoint`; port 0 with ``udpin``
        or ``tcpin`` binds an ephemeral port (read :attr:`local_address`).
    home
        ``(lat, lon, alt_amsl)``; default the mission origin. The vehicle starts landed
        and disarmed at home.
    tracer_params
        Base :class:`TracerParams` (speeds are overridden by SPEED_MPS).
    """

    def __init__(
        self,
        field: Callable[[float, float], float],
        region: Any,
        origin: Origin,
        settings: VehicleSettings | None = None,
        connect: str | Endpoint = "udpout:127.0.0.1:14550",
        home: tuple[float, float, float] | None = None,
        tracer_params: TracerParams | None = None,
    ) -> None:
        self.settings = s = settings or VehicleSettings()
        self.sysid = s.sysid
        self.field = field
        self.region = region
        self.origin = origin
        self.home = home or (origin.lat_deg, origin.lon_deg, origin.alt_m)
        hx, hy, hz = origin.to_local(self.home[0], self.home[1], self.home[2] - origin.alt_m)
        self.home_local = (hx, hy, hz)
        self.endpoint = parse_endpoint(connect) if isinstance(connect, str) else connect
        self.transport: Transport = open_transport(self.endpoint)
        self.mav = mavlink.MAVLink(_Sink(), srcSystem=self.sysid, srcComponent=COMPONENT_ID)
        self.mav.robust_parsing = True
        self.tracer_base = tracer_params or TracerParams()
        self.params: dict[str, float] = {
            "SPEED_MPS": s.speed_mps, "SAMPLE_HZ": s.sample_rate_hz,
            "SEARCH_RAD_M": s.search_radius_m, "TEL_RATE_HZ": s.tel_rate_hz,
            "NOISE_STD": s.noise_std, "ALT_M": s.altitude_m, "SPEEDUP": s.speedup,
        }
        self._rng = np.random.default_rng(s.seed * 1000 + s.sysid)
        self.body = self._make_body(hx, hy, 0.0)
        self._odo_base = 0.0
        self._body_dirty = False
        # PX4's mission protocol timing: re-request every 0.25 s, give up after 5 s without
        # progress (a GCS under load can answer a request seconds late)
        self.server = MissionServer(timeout_s=MISSION_RETRY_S, max_retries=MISSION_RETRIES)
        # flight state
        self.armed = False
        self.alt_m = 0.0  # above home
        self.landed_state = mavlink.MAV_LANDED_STATE_ON_GROUND
        self.custom_mode = MODES["AUTO.LOITER"]
        self.activity: Generator[Sample | None, None, Any] | None = None
        self.sampling = False  # the current tick is a sample to report
        self.mission_active = False
        self.mission_complete = False
        self.mission_last = -1
        self.speed_mps = s.speed_mps
        self._prev_xy = (self.body.x_m, self.body.y_m)
        self._vel = (0.0, 0.0, 0.0)  # east, north, up
        # I/O state
        self.counters: dict[str, int] = {
            "rx_packets": 0, "rx_bad": 0, "rx_other_target": 0, "rx_flood": 0,
            "rx_unhandled": 0, "tx_packets": 0, "samples": 0, "ticks": 0, "commands": 0,
        }
        self._parsers: dict[object, mavlink.MAVLink] = {}
        self._unhandled: dict[str, int] = {}
        self._rx_window: dict[object, list[float]] = {}
        self._intervals: dict[int, float] = {}  # msg id -> interval override (s), <0 = off
        self._last_sent_wall: dict[str, float] = {}
        self._last_sent_sim: dict[str, float] = {}
        self._last_sample_wall = -1.0
        # samples of the current loop iteration, converted to lat/lon in one vectorised
        # pymap3d call and sent before anything else goes out (see _flush_samples)
        self._pending: list[tuple[int, float, float, float, float, float, float, float]] = []
        self._status_id = 0
        self._stop = threading.Event()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._thread: threading.Thread | None = None
        self._wall0 = 0.0
        self._sim_ref = 0.0
        self._wall_ref = 0.0
        self.started_wall = 0.0
        self.behind_events = 0
        self.tx_filter: Callable[[Any], bool] | None = None
        """Test hook: called with each outgoing message; return False to drop it."""

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_mission(cls, mission: Any, sysid: int = 1, connect: str | Endpoint = "",
                     speedup: float | None = None, seed: int | None = None,
                     home: tuple[float, float, float] | None = None,
                     **overrides: Any) -> MavlinkVehicle:
        """Build a vehicle from a loaded :class:`econdor_gcs.mission.Mission`."""
        v = mission.vehicles
        settings = VehicleSettings(
            sysid=sysid, speed_mps=v.speed_mps, max_speed_mps=v.max_speed_mps,
            max_accel_mps2=v.max_accel_mps2, max_turn_rate_dps=v.max_turn_rate_dps,
            sample_rate_hz=v.sample_rate_hz, altitude_m=v.altitude_m, noise_std=v.noise_std,
            speedup=v.speedup if speedup is None else speedup,
            search_radius_m=mission.algorithm.search_radius_m,
            tel_rate_hz=min(10.0, v.sample_rate_hz),
            seed=mission.seed if seed is None else seed,
        )
        for k, val in overrides.items():
            setattr(settings, k, val)
        field = mission.build_field(settings.seed)
        return cls(field, mission.region, mission.origin, settings,
                   connect or "udpout:127.0.0.1:14550", home=home)

    def _make_body(self, x: float, y: float, t_s: float) -> SimBody:
        s = self.settings
        limits = VehicleLimits(max_speed_mps=s.max_speed_mps, max_accel_mps2=s.max_accel_mps2,
                               max_turn_rate_dps=s.max_turn_rate_dps)
        return SimBody(self.field, self.region, x, y, limits,
                       sample_rate_hz=self.params["SAMPLE_HZ"],
                       noise_std=self.params["NOISE_STD"], rng=self._rng, t_s=t_s)

    @property
    def local_address(self) -> tuple[str, int]:
        return self.transport.local_address

    @property
    def sim_time_s(self) -> float:
        return self.body.t_s

    @property
    def time_boot_ms(self) -> int:
        return int(round(self.body.t_s * 1000.0)) & 0xFFFFFFFF

    @property
    def odometer_m(self) -> float:
        return self._odo_base + self.body.odometer_m

    @property
    def mode_name(self) -> str:
        return MODE_NAMES.get(self.custom_mode, f"0x{self.custom_mode:08x}")

    # ------------------------------------------------------------------ running

    def start(self) -> MavlinkVehicle:
        """Run the loop on a daemon thread (in-process use)."""
        self._thread = threading.Thread(target=self.run, name=f"sim-vehicle-{self.sysid}",
                                        daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the loop (from any thread) and wait for it; closes the sockets."""
        self._stop.set()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)
            self._thread = None

    def request_stop(self) -> None:
        """Signal-handler-safe stop request."""
        self._stop.set()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")

    def run(self) -> None:
        """The main loop; returns after :meth:`stop` / :meth:`request_stop`."""
        now = time.monotonic()
        self._wall0 = self._wall_ref = self.started_wall = now
        self._sim_ref = self.body.t_s
        next_hb = now
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if now >= next_hb:
                    self._send_1hz()
                    next_hb += 1.0
                    if next_hb < now:
                        next_hb = now + 1.0
                self._advance(now)
                self._periodic_streams(time.monotonic())
                dl = self.server.next_deadline()
                if dl is not None and time.monotonic() >= dl:
                    # a transfer deadline passed while we were busy: the awaited item may
                    # be sitting in the socket, so read before declaring a timeout
                    self._receive()
                for m in self.server.poll(time.monotonic()):
                    self._send(m)
                self.transport.flush()
                timeout = self._next_timeout(next_hb)
                rlist = [*self.transport.fileno_list(), self._wake_r]
                wlist = self.transport.want_write()
                try:
                    readable, _, _ = select.select(rlist, wlist, [], timeout)
                except (InterruptedError, ValueError):
                    continue
                if self._wake_r in readable:
                    with contextlib.suppress(OSError):
                        self._wake_r.recv(64)
                if readable:
                    self._receive()
        finally:
            self.close()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.transport.close()
        for s in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                s.close()

    def _next_timeout(self, next_hb: float) -> float:
        now = time.monotonic()
        t = next_hb
        speedup = self.params["SPEEDUP"]
        t_tick = self._wall_ref + (self.body.t_s + self.body.dt_s - self._sim_ref) / speedup
        # wake for ticks at most every TICK_BATCH_WALL_S: the ticks due by then run in one
        # go, so their samples share one vectorised geodetic conversion (I/O still wakes us)
        t = min(t, max(t_tick, now + TICK_BATCH_WALL_S))
        dl = self.server.next_deadline()
        if dl is not None:
            t = min(t, dl)
        return max(0.0, min(t - now, 0.1))

    def achieved_speedup(self) -> float:
        wall = time.monotonic() - self._wall0
        return self.body.t_s / wall if wall > 0 else 0.0

    # ------------------------------------------------------------------ receiving

    def _receive(self) -> None:
        now = time.monotonic()
        for peer, data in self.transport.recv_all(256):
            parser = self._parsers.get(peer)
            if parser is None:
                if len(self._parsers) > 32:
                    self._parsers.clear()
                parser = mavlink.MAVLink(None)
                parser.robust_parsing = True
                self._parsers[peer] = parser
            if not self.transport.stream and parser.buf_len() > 0:
                # a datagram is self-contained: leftovers of the previous one are garbage
                self.counters["rx_bad"] += 1
                _reset_parser(parser)
            try:
                msgs = parser.parse_buffer(data) or []
            except Exception:  # noqa: BLE001 - never let a peer's bytes kill the vehicle
                self.counters["rx_bad"] += 1
                _reset_parser(parser)
                continue
            for msg in msgs:
                if isinstance(msg, mavlink.MAVLink_bad_data):
                    self.counters["rx_bad"] += 1
                    continue
                if not self._budget_ok(peer, now):
                    self.counters["rx_flood"] += 1
                    continue
                self.counters["rx_packets"] += 1
                try:
                    self._dispatch(msg, now)
                except Exception:  # noqa: BLE001
                    log.exception("sysid %d: error handling %s", self.sysid, msg.get_type())
                    self.counters["rx_bad"] += 1

    def _budget_ok(self, peer: object, now: float) -> bool:
        w = self._rx_window.get(peer)
        if w is None or now - w[0] >= 1.0:
            self._rx_window[peer] = [now, 1]
            if len(self._rx_window) > 64:
                self._rx_window = {peer: [now, 1]}
            return True
        w[1] += 1
        return w[1] <= RX_BUDGET_PER_S

    def _dispatch(self, msg: Any, now: float) -> None:
        ts = getattr(msg, "target_system", None)
        if ts is not None and ts not in (0, self.sysid):
            self.counters["rx_other_target"] += 1
            return
        tc = getattr(msg, "target_component", None)
        if tc is not None and tc not in (0, COMPONENT_ID) and msg.get_type() != "MISSION_ACK":
            self.counters["rx_other_target"] += 1
            return
        mtype = msg.get_type()
        if mtype.startswith("MISSION_"):
            for reply in self.server.receive(msg, now):
                self._send(reply)
            self._mission_events()
            return
        handler = getattr(self, "_on_" + mtype.lower(), None)
        if handler is None:
            self.counters["rx_unhandled"] += 1
            self._unhandled[mtype] = self._unhandled.get(mtype, 0) + 1
            return
        handler(msg)

    # ------------------------------------------------------------------ sending

    def _send(self, msg: Any) -> None:
        if self._pending:
            self._flush_samples()  # keep the send order of the ticks
        self._send_now(msg)

    def _send_now(self, msg: Any) -> None:
        if self.tx_filter is not None and not self.tx_filter(msg):
            return
        sink: _Sink = self.mav.file
        self.mav.send(msg)
        for chunk in sink.chunks:
            self.transport.send(chunk)
        sink.chunks.clear()
        self.counters["tx_packets"] += 1

    def statustext(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        raw = text.encode("utf-8", "replace")
        if len(raw) <= 50:
            self._send(mavlink.MAVLink_statustext_message(severity, raw, 0, 0))
            return
        self._status_id = self._status_id % 65535 + 1
        chunks = [raw[i:i + 50] for i in range(0, len(raw), 50)]
        for n, chunk in enumerate(chunks):
            self._send(mavlink.MAVLink_statustext_message(severity, chunk, self._status_id, n))
        if len(chunks[-1]) == 50:  # terminate explicitly
            self._send(mavlink.MAVLink_statustext_message(severity, b"", self._status_id,
                                                          len(chunks)))

    def _heartbeat(self) -> Any:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
            mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
            | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED)
        if self.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        status = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        return mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, self.custom_mode,
            status, 3)

    def _sys_status(self) -> Any:
        return mavlink.MAVLink_sys_status_message(
            SENSORS, SENSORS, SENSORS, 100, 16000, 1000, 90, 0, 0, 0, 0, 0, 0)

    def _ext_state(self) -> Any:
        return mavlink.MAVLink_extended_sys_state_message(
            mavlink.MAV_VTOL_STATE_UNDEFINED, self.landed_state)

    def _autopilot_version(self) -> Any:
        return mavlink.MAVLink_autopilot_version_message(
            CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 1, [0] * 8, [0] * 8, [0] * 8, 0, 0,
            self.sysid, [0] * 18)

    def _home_position(self) -> Any:
        lat, lon, alt = self.home
        hx, hy, _ = self.home_local
        return mavlink.MAVLink_home_position_message(
            int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
            hy, hx, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(self.body.t_s * 1e6))

    def _gpi(self) -> Any:
        lat, lon, _ = self.origin.to_global(self.body.x_m, self.body.y_m, 0.0)
        ve, vn, vu = self._vel
        return self._gpi_msg(self.time_boot_ms, lat, lon, self.alt_m, ve, vn, vu)

    def _gpi_msg(self, ms: int, lat: float, lon: float, alt: float, ve: float, vn: float,
                 vu: float) -> Any:
        hdg = int(round(math.degrees(math.atan2(ve, vn)) % 360 * 100)) \
            if ve * ve + vn * vn > 0.01 else 65535
        return mavlink.MAVLink_global_position_int_message(
            ms, int(round(lat * 1e7)), int(round(lon * 1e7)),
            int(round((self.home[2] + alt) * 1000)), int(round(alt * 1000)),
            int(round(vn * 100)), int(round(ve * 100)), int(round(-vu * 100)), hdg)

    def _local_ned(self) -> Any:
        ve, vn, vu = self._vel
        return mavlink.MAVLink_local_position_ned_message(
            self.time_boot_ms, self.body.y_m - self.home_local[1],
            self.body.x_m - self.home_local[0], -self.alt_m, vn, ve, -vu)

    def _attitude(self) -> Any:
        ve, vn, _ = self._vel
        yaw = math.atan2(ve, vn) if ve * ve + vn * vn > 0.01 else 0.0
        return mavlink.MAVLink_attitude_message(self.time_boot_ms, 0.0, 0.0, yaw, 0.0, 0.0, 0.0)

    def _send_1hz(self) -> None:
        self._send(self._heartbeat())
        for mid, make in ((mavlink.MAVLINK_MSG_ID_SYS_STATUS, self._sys_status),
                          (mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, self._ext_state)):
            if self._intervals.get(mid, 1.0) >= 0:
                self._send(make())
        if self.server.mission:
            self._send(self.server.mission_current_msg(self.mission_active,
                                                        self.mission_complete))

    _STREAMS = (
        ("GLOBAL_POSITION_INT", mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, "_gpi"),
        ("LOCAL_POSITION_NED", mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, "_local_ned"),
        ("ATTITUDE", mavlink.MAVLINK_MSG_ID_ATTITUDE, "_attitude"),
    )

    def _periodic_streams(self, wall: float) -> None:
        sim = self.body.t_s
        rate = self.params["TEL_RATE_HZ"]
        for name, mid, maker in self._STREAMS:
            period = self._intervals.get(mid, 1.0 / rate if rate > 0 else -1.0)
            if period < 0:
                continue
            if sim - self._last_sent_sim.get(name, -1e9) < period - 1e-9:
                continue
            if wall - self._last_sent_wall.get(name, -1e9) < 1.0 / MAX_STREAM_WALL_HZ:
                continue
            if name == "GLOBAL_POSITION_INT" and wall - self._last_sample_wall < 0.5 / \
                    MAX_STREAM_WALL_HZ:
                continue  # sample pairs are flowing; they carry the position already
            self._send(getattr(self, maker)())
            self._last_sent_sim[name] = sim
            self._last_sent_wall[name] = wall

    def _send_sample(self, sample: Sample) -> None:
        """Queue one sample; :meth:`_flush_samples` sends it (before any other message)."""
        ms = int(round(sample.t_s * 1000.0)) & 0xFFFFFFFF
        ve, vn, vu = self._vel
        self._pending.append((ms, self.body.x_m, self.body.y_m, self.alt_m, ve, vn, vu,
                              float(sample.value)))

    def _flush_samples(self) -> None:
        """Send the queued samples, in order, as GLOBAL_POSITION_INT + NAMED_VALUE_FLOAT
        pairs; their positions go to lat/lon in one vectorised pymap3d call."""
        pending = self._pending
        if not pending:
            return
        self._pending = []
        a = np.asarray([p[1:3] for p in pending], dtype=float)
        lat, lon, _ = self.origin.to_global_many(a[:, 0], a[:, 1], 0.0)
        for (ms, _x, _y, alt, ve, vn, vu, value), la, lo in zip(
                pending, lat.tolist(), lon.tolist(), strict=True):
            self._send_now(self._gpi_msg(ms, la, lo, alt, ve, vn, vu))
            self._send_now(mavlink.MAVLink_named_value_float_message(ms, b"FIELD", value))
            self.counters["samples"] += 1
        self._last_sample_wall = time.monotonic()

    # ------------------------------------------------------------------ simulation

    def _advance(self, wall: float) -> None:
        speedup = self.params["SPEEDUP"]
        target = self._sim_ref + (wall - self._wall_ref) * speedup
        dt = self.body.dt_s
        if self.activity is None and not self.armed and self.alt_m <= 0.0:
            # parked: nothing to sense or report, so skip the idle ticks in one jump
            n = int((target - self.body.t_s) / dt + 1e-9)
            if n > 0:
                self._odo_base += self.body.odometer_m
                self.body = self._make_body(self.body.x_m, self.body.y_m,
                                            self.body.t_s + n * dt)
                self._body_dirty = False
                self._vel = (0.0, 0.0, 0.0)
                self.counters["ticks"] += n
            return
        budget_end = wall + 0.02  # keep serving I/O at least every 20 ms of wall time
        while self.body.t_s + dt <= target + 1e-9:
            self._tick()
            if time.monotonic() > budget_end:
                break
        self._flush_samples()
        # fallen behind by more than half a second of wall time: stop trying to catch up
        if target - self.body.t_s > 0.5 * speedup:
            self.behind_events += 1
            self._sim_ref = self.body.t_s
            self._wall_ref = time.monotonic()

    def _tick(self) -> None:
        self.counters["ticks"] += 1
        x0, y0, a0 = self.body.x_m, self.body.y_m, self.alt_m
        sample: Sample | None = None
        if self.activity is not None:
            try:
                sample = next(self.activity)
            except StopIteration:
                self.activity = None
        if self.activity is None and sample is None:
            self._apply_pending_body()
            self.body.hold(Phase.TRANSIT)
        dt = self.body.dt_s
        self._vel = ((self.body.x_m - x0) / dt, (self.body.y_m - y0) / dt,
                     (self.alt_m - a0) / dt)
        if sample is not None and self.sampling:
            self._send_sample(sample)

    def _apply_pending_body(self) -> None:
        if self._body_dirty:
            self._odo_base += self.body.odometer_m
            self.body = self._make_body(self.body.x_m, self.body.y_m, self.body.t_s)
            self._body_dirty = False

    def _tracer_params(self) -> TracerParams:
        sp = min(self.speed_mps, self.settings.max_speed_mps)
        return dataclasses.replace(self.tracer_base, speed_mps=sp, transit_speed_mps=sp)

    # activities: generators doing exactly one body tick per step -----------------------

    def _hold_forever(self) -> Generator[Sample | None, None, None]:
        self.sampling = False
        while True:
            self.body.hold(Phase.TRANSIT)
            yield None

    def _climb_to(self, target_alt: float) -> Generator[Sample | None, None, None]:
        self.sampling = False
        if self.alt_m < target_alt:
            self.landed_state = mavlink.MAV_LANDED_STATE_TAKEOFF
        while abs(self.alt_m - target_alt) > 1e-3:
            step = CLIMB_RATE_MPS * self.body.dt_s
            self.alt_m += max(-step, min(step, target_alt - self.alt_m))
            self.body.hold(Phase.TRANSIT)
            yield None
        if self.alt_m > 0.1:
            self.landed_state = mavlink.MAV_LANDED_STATE_IN_AIR

    def _descend_and_disarm(self) -> Generator[Sample | None, None, None]:
        self.sampling = False
        self.landed_state = mavlink.MAV_LANDED_STATE_LANDING
        while self.alt_m > 0.0:
            self.alt_m = max(0.0, self.alt_m - DESCENT_RATE_MPS * self.body.dt_s)
            self.body.hold(Phase.TRANSIT)
            yield None
        self.landed_state = mavlink.MAV_LANDED_STATE_ON_GROUND
        self.armed = False
        self.mission_active = False
        self.custom_mode = MODES["AUTO.LOITER"]
        self.statustext("landed, disarmed")

    def _fly(self, gen: Generator[Sample, None, Any], target_alt: float | None
             ) -> Generator[Sample | None, None, Any]:
        """Run a horizontal task generator, adjusting altitude on the way; report samples."""
        while True:
            if target_alt is not None and abs(self.alt_m - target_alt) > 1e-3:
                step = CLIMB_RATE_MPS * self.body.dt_s
                self.alt_m += max(-step, min(step, target_alt - self.alt_m))
            self.sampling = True
            try:
                sample = next(gen)
            except StopIteration as stop:
                self.sampling = False
                return stop.value
            yield sample

    def _takeoff_then_hold(self, alt: float) -> Generator[Sample | None, None, None]:
        self.custom_mode = MODES["AUTO.TAKEOFF"]
        yield from self._climb_to(alt)
        self.custom_mode = MODES["AUTO.LOITER"]
        yield from self._hold_forever()

    def _rtl(self) -> Generator[Sample | None, None, None]:
        self.custom_mode = MODES["AUTO.RTL"]
        hx, hy, _ = self.home_local
        if math.hypot(self.body.x_m - hx, self.body.y_m - hy) > 1.0:
            yield from self._fly(fly_to(self.body, hx, hy, Phase.TRANSIT,
                                        speed_mps=self._tracer_params().speed_mps), None)
        self.custom_mode = MODES["AUTO.LAND"]
        yield from self._descend_and_disarm()

    def _land(self) -> Generator[Sample | None, None, None]:
        self.custom_mode = MODES["AUTO.LAND"]
        yield from self._descend_and_disarm()

    # mission execution -------------------------------------------------------------------

    def _item_alt(self, it: StoredItem) -> float:
        """Item altitude above home (m), or 0 if it gives none."""
        if it.frame in (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT):
            return it.z - self.home[2]
        return it.z

    def _item_xy(self, it: StoredItem) -> tuple[float, float] | None:
        if not it.is_global or (it.x == 0 and it.y == 0):
            return None
        x, y, _ = self.origin.to_local(it.lat_deg, it.lon_deg, 0.0)
        return x, y

    def _mission(self, first: int, last: int) -> Generator[Sample | None, None, None]:
        items = self.server.mission
        self.mission_active = True
        self.mission_complete = False
        self.mission_last = last
        seq = first
        while seq <= last and seq < len(items):
            it = items[seq]
            self.server.set_current(seq)
            self._send(self.server.mission_current_msg(True))
            result = yield from self._run_item(it)
            self._send(mavlink.MAVLink_mission_item_reached_message(seq))
            if result == "end":  # RTL / land: the mission ends with the vehicle down
                self.mission_active = False
                self.mission_complete = True
                return
            seq += 1
        self.mission_active = False
        self.mission_complete = True
        self.statustext("mission complete")
        self.custom_mode = MODES["AUTO.LOITER"]
        self._send(self.server.mission_current_msg(False, True))
        if self.alt_m > 0.0:
            yield from self._hold_forever()

    def _ensure_airborne(self, alt: float) -> Generator[Sample | None, None, None]:
        if self.alt_m < 0.5:
            yield from self._climb_to(alt if alt > 1.0 else self.params["ALT_M"])
        self.landed_state = mavlink.MAV_LANDED_STATE_IN_AIR

    def _run_item(self, it: StoredItem) -> Generator[Sample | None, None, str]:
        cmd = it.command
        self._apply_pending_body()
        alt = self._item_alt(it)
        xy = self._item_xy(it)
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            yield from self._climb_to(alt if alt > 1.0 else self.params["ALT_M"])
            return "ok"
        if cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            if it.param2 > 0:
                self.speed_mps = min(float(it.param2), self.settings.max_speed_mps)
            return "ok"
        if cmd in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_UNLIM,
                   mavlink.MAV_CMD_NAV_LOITER_TIME):
            if xy is not None:
                near = math.hypot(xy[0] - self.body.x_m, xy[1] - self.body.y_m) < 1.0
                if not (near and self.alt_m < 0.5 and cmd == mavlink.MAV_CMD_NAV_WAYPOINT):
                    yield from self._ensure_airborne(alt)
                    tgt = alt if alt > 1.0 else self.alt_m
                    yield from self._fly(run_task(self.body, Waypoint(*xy),
                                                  self._tracer_params()), tgt)
            if cmd == mavlink.MAV_CMD_NAV_LOITER_UNLIM:
                yield from self._ensure_airborne(alt)
                yield from self._hold_forever()
            if cmd == mavlink.MAV_CMD_NAV_LOITER_TIME:
                yield from self._ensure_airborne(alt)
                t_end = self.body.t_s + max(0.0, it.param1)
                while self.body.t_s < t_end - 1e-9:
                    self.body.hold(Phase.TRANSIT)
                    yield None
            return "ok"
        if cmd == MAV_CMD_WAYPOINT_USER_1:
            if xy is None:
                self.statustext(f"piece {int(it.param4)}: no start point", 4)
                return "ok"
            yield from self._ensure_airborne(alt)
            rad = it.param2 if it.param2 > 0 else self.params["SEARCH_RAD_M"]
            task = TraceTask(level=float(it.param1), x_m=xy[0], y_m=xy[1],
                             search_radius_m=float(rad), max_length_m=max(0.0, it.param3),
                             piece_id=int(it.param4))
            pid = task.piece_id
            outcome = yield from self._fly(
                run_task(self.body, task, self._tracer_params(),
                         on_event=lambda text: self.statustext(f"piece {pid}: {text}")),
                alt if alt > 1.0 else None)
            if outcome is not None:
                self.statustext(f"piece {pid}: {outcome.status} traced {outcome.traced_m:.1f} m"
                                f" flown {outcome.flown_m:.1f} m")
            return "ok"
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            yield from self._rtl()
            return "end"
        if cmd == mavlink.MAV_CMD_NAV_LAND:
            if xy is not None and self.alt_m > 0.5:
                yield from self._fly(run_task(self.body, Waypoint(*xy),
                                              self._tracer_params()), None)
            yield from self._land()
            return "end"
        return "ok"  # unreachable: the server rejects other commands

    def _mission_events(self) -> None:
        while self.server.events:
            ev = self.server.events.pop(0)
            if ev.mission_type != MISSION:
                continue
            if ev.kind in ("uploaded", "cleared"):
                self.mission_complete = False
            if ev.kind in ("uploaded", "cleared") and self.mission_active:
                # the mission under execution is gone: hold where we are
                self._set_hold()
            elif ev.kind == "set_current" and self.mission_active:
                self._start_mission(ev.seq, len(self.server.mission) - 1)

    def _set_hold(self) -> None:
        self.mission_active = False
        self.custom_mode = MODES["AUTO.LOITER"]
        self.activity = self._hold_forever() if self.alt_m > 0.0 else None

    def _start_mission(self, first: int, last: int) -> None:
        self.custom_mode = MODES["AUTO.MISSION"]
        self.activity = self._mission(first, last)

    # ------------------------------------------------------------------ commands

    def _on_heartbeat(self, msg: Any) -> None:
        pass

    def _on_ping(self, msg: Any) -> None:
        if msg.target_system == 0:
            self._send(mavlink.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(),
                                                    msg.get_srcComponent()))

    def _on_timesync(self, msg: Any) -> None:
        if msg.tc1 == 0:
            self._send(mavlink.MAVLink_timesync_message(int(self.body.t_s * 1e9), msg.ts1))

    def _on_command_long(self, msg: Any) -> None:
        self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                         msg.param5, msg.param6, msg.param7])

    def _on_command_int(self, msg: Any) -> None:
        self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                         msg.x / 1e7, msg.y / 1e7, msg.z])

    def _on_set_mode(self, msg: Any) -> None:
        self._do_set_mode(float(msg.base_mode), float((msg.custom_mode >> 16) & 0xFF),
                          float((msg.custom_mode >> 24) & 0xFF))

    def _command(self, msg: Any, cmd: int, p: list[float]) -> None:
        self.counters["commands"] += 1
        result, after = self._execute_command(cmd, p)
        self._send(mavlink.MAVLink_command_ack_message(
            cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))
        for m in after:
            self._send(m)

    def _execute_command(self, cmd: int, p: list[float]) -> tuple[int, list[Any]]:
        ok, denied = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
        in_air = self.alt_m > 0.0
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] >= 0.5:
                if self.armed:
                    return ok, []
                if in_air:
                    return denied, []
                self.armed = True
                self.statustext("armed")
                if self.custom_mode == MODES["AUTO.MISSION"] and self.server.mission:
                    self._start_mission(self.server.current_seq, len(self.server.mission) - 1)
                return ok, [self._heartbeat()]
            if in_air and int(p[1]) != 21196:
                return denied, []
            self.armed = False
            self.alt_m = 0.0
            self.landed_state = mavlink.MAV_LANDED_STATE_ON_GROUND
            self.activity = None
            self.mission_active = False
            self.sampling = False
            self.statustext("disarmed")
            return ok, [self._heartbeat()]
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            if not self.armed:
                return denied, []
            alt = p[6] - self.home[2] if math.isfinite(p[6]) else float("nan")
            if not (math.isfinite(alt) and alt > 1.0):
                alt = self.params["ALT_M"]
            self.mission_active = False
            self.activity = self._takeoff_then_hold(alt)
            return ok, []
        if cmd == mavlink.MAV_CMD_MISSION_START:
            n = len(self.server.mission)
            if n == 0 or not self.armed:
                return denied, []
            first = int(p[0]) if math.isfinite(p[0]) else 0
            last = int(p[1]) if math.isfinite(p[1]) else n - 1
            if last <= 0 or last >= n:
                last = n - 1
            if not 0 <= first <= last:
                return denied, []
            self._start_mission(first, last)
            return ok, []
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            if not (self.armed and in_air):
                return denied, []
            self.mission_active = False
            self.activity = self._rtl()
            return ok, []
        if cmd == mavlink.MAV_CMD_NAV_LAND:
            if not in_air:
                return ok, []
            self.mission_active = False
            self.activity = self._land()
            return ok, []
        if cmd == mavlink.MAV_CMD_DO_SET_MODE:
            return self._do_set_mode(p[0], p[1], p[2]), []
        if cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            if not (math.isfinite(p[1]) and p[1] > 0):
                return denied, []
            self.speed_mps = min(float(p[1]), self.settings.max_speed_mps)
            if self.activity is not None and self.mission_active:
                pass  # takes effect from the next item (the tracer's speed is per task)
            return ok, []
        if cmd == mavlink.MAV_CMD_DO_SET_MISSION_CURRENT:
            seq = int(p[0])
            if not 0 <= seq < len(self.server.mission):
                return denied, []
            self.server.set_current(seq)
            if self.mission_active:
                self._start_mission(seq, len(self.server.mission) - 1)
            return ok, [self.server.mission_current_msg(self.mission_active)]
        if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            mid, us = int(p[0]), p[1]
            if mid not in self._requestable():
                return denied, []
            if us == 0:
                self._intervals.pop(mid, None)
            else:
                self._intervals[mid] = -1.0 if us < 0 else us / 1e6
            return ok, []
        if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
            mid = int(p[0])
            make = self._requestable().get(mid)
            if make is None:
                return mavlink.MAV_RESULT_UNSUPPORTED, []
            return ok, [make()]
        if cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return ok, [self._autopilot_version()]
        if cmd == mavlink.MAV_CMD_GET_HOME_POSITION:
            return ok, [self._home_position()]
        return mavlink.MAV_RESULT_UNSUPPORTED, []

    def _requestable(self) -> dict[int, Callable[[], Any]]:
        return {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: self._heartbeat,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self._sys_status,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self._attitude,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._local_ned,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._gpi,
            mavlink.MAVLINK_MSG_ID_MISSION_CURRENT:
                lambda: self.server.mission_current_msg(self.mission_active),
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._autopilot_version,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._home_position,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._ext_state,
            mavlink.MAVLINK_MSG_ID_STATUSTEXT: self._counters_text,
        }

    def counters_line(self) -> str:
        c = self.counters
        return (f"rx {c['rx_packets']} bad {c['rx_bad']} other {c['rx_other_target']} "
                f"flood {c['rx_flood']} tx {c['tx_packets']} drop {self.transport.tx_dropped}")

    def _counters_text(self) -> Any:
        return mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO,
                                                  self.counters_line().encode()[:50], 0, 0)

    def _do_set_mode(self, base: float, main: float, sub: float) -> int:
        if not int(base) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED or int(main) != 4:
            return mavlink.MAV_RESULT_DENIED
        sub_i = int(sub)
        in_air = self.alt_m > 0.0
        if sub_i == PX4_SUB_MISSION:
            if not self.server.mission:
                return mavlink.MAV_RESULT_DENIED
            if self.custom_mode == MODES["AUTO.MISSION"] and self.mission_active:
                return mavlink.MAV_RESULT_ACCEPTED
            self.custom_mode = MODES["AUTO.MISSION"]
            if self.armed:
                cur = self.server.current_seq
                if cur >= len(self.server.mission):
                    cur = 0
                self._start_mission(cur, len(self.server.mission) - 1)
            return mavlink.MAV_RESULT_ACCEPTED
        if sub_i in (PX4_SUB_LOITER, 0, 1):
            self.custom_mode = MODES["AUTO.LOITER"]
            self.mission_active = False
            if in_air:
                self.activity = self._hold_forever()
            return mavlink.MAV_RESULT_ACCEPTED
        if sub_i == PX4_SUB_RTL:
            if not (self.armed and in_air):
                return mavlink.MAV_RESULT_DENIED
            self.mission_active = False
            self.activity = self._rtl()
            return mavlink.MAV_RESULT_ACCEPTED
        if sub_i == PX4_SUB_LAND:
            self.mission_active = False
            if in_air:
                self.activity = self._land()
            return mavlink.MAV_RESULT_ACCEPTED
        if sub_i == PX4_SUB_TAKEOFF:
            if not self.armed:
                return mavlink.MAV_RESULT_DENIED
            self.mission_active = False
            self.activity = self._takeoff_then_hold(self.params["ALT_M"])
            return mavlink.MAV_RESULT_ACCEPTED
        return mavlink.MAV_RESULT_DENIED

    # ------------------------------------------------------------------ parameters

    def _param_msg(self, name: str) -> Any:
        return mavlink.MAVLink_param_value_message(
            name.encode(), float(self.params[name]), mavlink.MAV_PARAM_TYPE_REAL32,
            len(PARAM_NAMES), PARAM_NAMES.index(name))

    def _on_param_request_list(self, msg: Any) -> None:
        for name in PARAM_NAMES:
            self._send(self._param_msg(name))

    @staticmethod
    def _param_id(msg: Any) -> str:
        pid = msg.param_id
        if isinstance(pid, bytes):
            pid = pid.decode("ascii", "replace")
        return pid.rstrip("\x00")

    def _on_param_request_read(self, msg: Any) -> None:
        if 0 <= msg.param_index < len(PARAM_NAMES):
            self._send(self._param_msg(PARAM_NAMES[msg.param_index]))
            return
        name = self._param_id(msg)
        if name in self.params:
            self._send(self._param_msg(name))
        else:
            self.counters["rx_unhandled"] += 1

    def _on_param_set(self, msg: Any) -> None:
        name = self._param_id(msg)
        if name not in self.params:
            self.statustext(f"unknown parameter {name}", mavlink.MAV_SEVERITY_WARNING)
            return
        value = float(msg.param_value)
        ok = math.isfinite(value) and (value >= 0 if name == "NOISE_STD" else value > 0)
        if name == "SPEED_MPS":
            ok = ok and value <= self.settings.max_speed_mps
        if name == "SAMPLE_HZ":
            ok = ok and value <= 1000.0
        if ok:
            self._set_param(name, value)
        else:
            self.statustext(f"{name}: rejected {value:g}", mavlink.MAV_SEVERITY_WARNING)
        self._send(self._param_msg(name))

    def _set_param(self, name: str, value: float) -> None:
        self.params[name] = value
        if name == "SPEED_MPS":
            self.speed_mps = value
        elif name in ("SAMPLE_HZ", "NOISE_STD"):
            self._body_dirty = True  # applied at the next item boundary / idle tick
        elif name == "SPEEDUP":
            self._sim_ref = self.body.t_s
            self._wall_ref = time.monotonic()
        elif name == "SEARCH_RAD_M":
            self.settings.search_radius_m = value
        elif name == "ALT_M":
            self.settings.altitude_m = value
