"""What a simulated vehicle tells the world: message builders, stream rates, the outbox.

No I/O: everything to send goes into an :class:`Outbox`, which the vehicle's I/O loop drains.

Time: all MAVLink timestamps (``time_boot_ms``, ``time_usec``) are sim time since boot.
HEARTBEAT, SYS_STATUS, EXTENDED_SYS_STATE (and MISSION_CURRENT while a mission is stored) go
out at 1 Hz of wall time; GLOBAL_POSITION_INT, LOCAL_POSITION_NED and ATTITUDE at
``TEL_RATE_HZ`` of sim time (or the interval a GCS set with SET_MESSAGE_INTERVAL) but never
more than :data:`MAX_STREAM_WALL_HZ` per wall second. A personality that streams only when
asked (ArduPilot) sends nothing but HEARTBEAT until a GCS enables messages with
REQUEST_DATA_STREAM (:data:`DATA_STREAMS`; the rate in Hz of sim time) or
SET_MESSAGE_INTERVAL.

Samples: every sensor reading taken while the vehicle executes a horizontal motion task goes
out as ``GLOBAL_POSITION_INT`` immediately followed by ``NAMED_VALUE_FLOAT("FIELD")`` with the
same ``time_boot_ms``, regardless of the stream rates. A stock ArduPilot's Lua payload instead
samples every tick in the air, stamps ``FIELD`` when it sends it, and its positions come at
the rate asked for (with the samples when that is at least the sensor's) and pause as the
personality says (:attr:`Telemetry.stream_slowdown`, :attr:`Telemetry.positions_paused`).
Samples wait in the outbox as local positions; :meth:`Outbox.drain` converts all of them to
latitude/longitude in one vectorised pymap3d call and keeps the order of everything queued.
With the companion computer (the tracer on board), whenever the phase of the sampled ticks
changes (transit, search, trace), ``NAMED_VALUE_INT("PHASE")`` goes out just before the first
sample of the new phase, with that sample's ``time_boot_ms`` (a stock autopilot's payload knows
no phases); the end of a trace item is a ``DEBUG_FLOAT_ARRAY("TRACE")``
(:func:`trace_report_message`). Both are defined in :mod:`econdor_gcs.core.tasks`; STATUSTEXT
is for people only.

Geofence: with a fence loaded, ``FENCE_STATUS`` (:class:`~sim_vehicle.fence.FenceMonitor`) goes
out at 1 Hz and at once whenever the vehicle braked before the fence or got outside it (with
a STATUSTEXT for people), and SYS_STATUS shows the GEOFENCE sensor (unhealthy while outside).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.tasks import PHASE_NAME, TRACE_REPORT_NAME, TraceReport

from .body import Sample
from .fence import FenceMonitor
from .mission_server import MissionServer
from .state import VehicleState

MAX_STREAM_WALL_HZ = 50.0
"""Periodic streams never go out more often than this per wall second."""

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
DATA_STREAMS: dict[int, tuple[int, ...]] = {
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: (mavlink.MAVLINK_MSG_ID_SYS_STATUS,
                                              mavlink.MAVLINK_MSG_ID_MISSION_CURRENT,
                                              mavlink.MAVLINK_MSG_ID_FENCE_STATUS),
    mavlink.MAV_DATA_STREAM_POSITION: (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                                       mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    mavlink.MAV_DATA_STREAM_EXTRA1: (mavlink.MAVLINK_MSG_ID_ATTITUDE,),
    mavlink.MAV_DATA_STREAM_EXTRA3: (mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,),
}
"""REQUEST_DATA_STREAM groups -> the messages they enable (ArduCopter's grouping, for ours)."""
DATA_STREAMS[mavlink.MAV_DATA_STREAM_ALL] = tuple(
    m for group in list(DATA_STREAMS.values()) for m in group)
STATUSTEXT_CHUNK = 50
"""Bytes of text in one STATUSTEXT; longer texts are sent in chunks with a common id."""
LUA_SEND_DELAY_MS = 1
"""A Lua payload's sample is stamped when the script sends it, this long after the position
it read (so no stamp is a position's)."""


class _QueuedSample(NamedTuple):
    time_boot_ms: int
    x_m: float
    y_m: float
    alt_rel_m: float
    vel_enu_mps: tuple[float, float, float]
    value: float
    with_position: bool = True
    """Its GLOBAL_POSITION_INT goes out with it (decided when it is taken)."""


def gpi_message(home_alt_amsl_m: float, ms: int, lat_deg: float, lon_deg: float,
                alt_rel_m: float, vel_enu_mps: tuple[float, float, float]) -> Any:
    """GLOBAL_POSITION_INT at ``alt_rel_m`` above a home at ``home_alt_amsl_m``."""
    ve, vn, vu = vel_enu_mps
    hdg = int(round(math.degrees(math.atan2(ve, vn)) % 360 * 100)) \
        if ve * ve + vn * vn > 0.01 else 65535
    return mavlink.MAVLink_global_position_int_message(
        ms, int(round(lat_deg * 1e7)), int(round(lon_deg * 1e7)),
        int(round((home_alt_amsl_m + alt_rel_m) * 1000)), int(round(alt_rel_m * 1000)),
        int(round(vn * 100)), int(round(ve * 100)), int(round(-vu * 100)), hdg)


DEBUG_FLOAT_ARRAY_LEN = 58


def trace_report_message(report: TraceReport, time_usec: int) -> Any:
    """The ``DEBUG_FLOAT_ARRAY("TRACE")`` that carries ``report`` (array_id = item seq)."""
    data = report.to_array()
    data += [0.0] * (DEBUG_FLOAT_ARRAY_LEN - len(data))
    return mavlink.MAVLink_debug_float_array_message(
        time_usec, TRACE_REPORT_NAME.encode(), report.seq, data)


def phase_message(time_boot_ms: int, phase: int) -> Any:
    """``NAMED_VALUE_INT("PHASE")``: samples from ``time_boot_ms`` on are in ``phase``."""
    return mavlink.MAVLink_named_value_int_message(time_boot_ms, PHASE_NAME.encode(),
                                                   int(phase))


class SampleArchive:
    """Every sample the vehicle took since boot, and its phase changes, kept for the station's
    recovery requests (:data:`~econdor_gcs.core.tasks.SAMPLE_COUNT_COMMAND`,
    :data:`~econdor_gcs.core.tasks.SAMPLE_RESEND_COMMAND`). Times only grow.

    >>> a = SampleArchive()
    >>> for ms in (100, 200, 300):
    ...     a.add(_QueuedSample(ms, 0.0, 0.0, 30.0, (0.0, 0.0, 0.0), 1.0))
    >>> a.count(150, 300), a.count(0, 99), len(a)
    (2, 0, 3)
    """

    def __init__(self) -> None:
        self._ms: list[int] = []
        self._samples: list[_QueuedSample] = []
        self._phase_ms: list[int] = []
        self._phases: list[int] = []
        self._report_ms: list[int] = []
        self._reports: list[Any] = []

    def __len__(self) -> int:
        return len(self._ms)

    def add(self, sample: _QueuedSample) -> None:
        self._ms.append(sample.time_boot_ms)
        self._samples.append(sample)

    def add_phase(self, time_boot_ms: int, phase: int) -> None:
        self._phase_ms.append(time_boot_ms)
        self._phases.append(phase)

    def add_report(self, time_boot_ms: int, msg: Any) -> None:
        """A TRACE report (its message), kept to be sent again on request."""
        self._report_ms.append(time_boot_ms)
        self._reports.append(msg)

    def reports_between(self, first_ms: int, last_ms: int) -> list[Any]:
        lo = bisect.bisect_left(self._report_ms, first_ms)
        return self._reports[lo:bisect.bisect_right(self._report_ms, last_ms)]

    def count(self, first_ms: int, last_ms: int) -> int:
        """Samples taken at ``first_ms <= time_boot_ms <= last_ms``."""
        return bisect.bisect_right(self._ms, last_ms) - bisect.bisect_left(self._ms, first_ms)

    def between(self, first_ms: int, last_ms: int) -> list[_QueuedSample]:
        lo, hi = bisect.bisect_left(self._ms, first_ms), bisect.bisect_right(self._ms, last_ms)
        return self._samples[lo:hi]

    def phases_between(self, first_ms: int, last_ms: int) -> list[tuple[int, int]]:
        """The phase changes in the range, and the one in force at its start."""
        lo = bisect.bisect_right(self._phase_ms, first_ms) - 1
        hi = bisect.bisect_right(self._phase_ms, last_ms)
        return list(zip(self._phase_ms[max(lo, 0):hi], self._phases[max(lo, 0):hi],
                        strict=True))


class Outbox:
    """Everything the vehicle wants to send, in order, until the I/O loop drains it.

    Parameters
    ----------
    origin
        Converts the samples' local positions to latitude/longitude.
    home_alt_amsl_m
        Home altitude, for the AMSL altitude of the sample positions.
    """

    def __init__(self, origin: Origin, home_alt_amsl_m: float) -> None:
        self.origin = origin
        self.home_alt_amsl_m = home_alt_amsl_m
        self._queue: list[Any] = []
        self._n_samples = 0
        self._status_id = 0
        self.archive = SampleArchive()
        self.samples_resent = 0
        self.samples_sent = 0
        self.last_sample_wall = -1.0
        """Wall time of the last drain that carried samples."""
        self.lua_payload = False
        """The samples are a Lua script's (a stock ArduPilot): ``FIELD`` stamped
        :data:`LUA_SEND_DELAY_MS` after the position it was taken at."""
        self.positions_with_samples = True
        """A Lua payload's vehicle: whether the station asked for positions at least at the
        sensor's rate (then each sample tick's position goes out, unless the telemetry says
        otherwise: :meth:`Telemetry.sample`)."""

    def put(self, msg: Any) -> None:
        self._queue.append(msg)

    def put_sample(self, sample: Sample, x_m: float, y_m: float, alt_rel_m: float,
                   vel_enu_mps: tuple[float, float, float], with_position: bool = True) -> None:
        """Queue one sample taken at ``(x_m, y_m, alt_rel_m)``, after its position
        (GLOBAL_POSITION_INT with its stamp) if ``with_position``."""
        ms = int(round(sample.t_s * 1000.0)) & 0xFFFFFFFF
        queued = _QueuedSample(ms, x_m, y_m, alt_rel_m, vel_enu_mps, float(sample.value),
                               with_position)
        self.archive.add(queued)
        self._queue.append(queued)
        self._n_samples += 1

    def resend(self, first_ms: int, last_ms: int) -> int:
        """Queue the archived samples of a range again, after its phase changes; return how
        many."""
        for ms, phase in self.archive.phases_between(first_ms, last_ms):
            self._queue.append(phase_message(ms, phase))
        # a resend answers the station's recovery: each sample with its position
        again = [q._replace(with_position=True) for q in self.archive.between(first_ms, last_ms)]
        self._queue.extend(again)
        self._n_samples += len(again)
        self.samples_resent += len(again)
        return len(again)

    def statustext(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        """Queue a STATUSTEXT; texts longer than 50 bytes go in chunks (MAVLink 2 id/chunk_seq)."""
        raw = text.encode("utf-8", "replace")
        if len(raw) <= STATUSTEXT_CHUNK:
            self.put(mavlink.MAVLink_statustext_message(severity, raw, 0, 0))
            return
        self._status_id = self._status_id % 65535 + 1
        chunks = [raw[i:i + STATUSTEXT_CHUNK] for i in range(0, len(raw), STATUSTEXT_CHUNK)]
        for n, chunk in enumerate(chunks):
            self.put(mavlink.MAVLink_statustext_message(severity, chunk, self._status_id, n))
        if len(chunks[-1]) == STATUSTEXT_CHUNK:  # terminate explicitly
            self.put(mavlink.MAVLink_statustext_message(severity, b"", self._status_id,
                                                        len(chunks)))

    @property
    def has_samples(self) -> bool:
        return self._n_samples > 0

    def __len__(self) -> int:
        return len(self._queue)

    def drain(self, wall: float) -> list[Any]:
        """Everything queued, as messages, in order; samples become GLOBAL_POSITION_INT +
        NAMED_VALUE_FLOAT("FIELD") pairs (one vectorised geodetic conversion for all)."""
        queue, self._queue = self._queue, []
        if not self._n_samples:
            return queue
        n = self._n_samples
        self._n_samples = 0
        samples = [q for q in queue if isinstance(q, _QueuedSample)]
        xy = np.asarray([(q.x_m, q.y_m) for q in samples], dtype=float)
        lat, lon, _ = self.origin.to_global_many(xy[:, 0], xy[:, 1], 0.0)
        places = iter(zip(lat.tolist(), lon.tolist(), strict=True))
        out: list[Any] = []
        for q in queue:
            if not isinstance(q, _QueuedSample):
                out.append(q)
                continue
            la, lo = next(places)
            if q.with_position:
                out.append(gpi_message(self.home_alt_amsl_m, q.time_boot_ms, la, lo,
                                       q.alt_rel_m, q.vel_enu_mps))
            ms = q.time_boot_ms
            if self.lua_payload:
                ms = (ms + LUA_SEND_DELAY_MS) & 0xFFFFFFFF
            out.append(mavlink.MAVLink_named_value_float_message(ms, b"FIELD", q.value))
        self.samples_sent += n  # resent ones included
        self.last_sample_wall = wall
        return out


class ModeEncoder(Protocol):
    """How an autopilot personality shows itself in HEARTBEAT and AUTOPILOT_VERSION."""

    autopilot_type: int
    flight_sw_version: int

    def heartbeat_modes(self) -> tuple[int, int]:
        """``(base_mode, custom_mode)`` of the current state."""
        ...

    def prearm_ok(self) -> bool:
        """The pre-arm checks pass (SYS_STATUS health bit MAV_SYS_STATUS_PREARM_CHECK)."""
        ...


class Telemetry:
    """Message builders and stream scheduling for one vehicle.

    Parameters
    ----------
    state
        What to report.
    server
        The mission store (MISSION_CURRENT).
    outbox
        Where the streams go.
    modes
        The personality's mode encoding (HEARTBEAT).
    status_line
        Text of the STATUSTEXT a GCS gets for REQUEST_MESSAGE(STATUSTEXT): the link counters.
    """

    STREAMS = (
        ("GLOBAL_POSITION_INT", mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT),
        ("LOCAL_POSITION_NED", mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
        ("ATTITUDE", mavlink.MAVLINK_MSG_ID_ATTITUDE),
    )
    """The periodic streams (name, message id), at ``TEL_RATE_HZ`` of sim time by default."""

    def __init__(self, state: VehicleState, server: MissionServer, outbox: Outbox,
                 modes: ModeEncoder, status_line: Callable[[], str],
                 streams_on_request: bool = False) -> None:
        self.state = state
        self.server = server
        self.outbox = outbox
        self.modes = modes
        self.status_line = status_line
        self.streams_on_request = streams_on_request
        self.enabled: set[int] = set()
        """With ``streams_on_request``: the message ids a GCS has asked for."""
        self.intervals: dict[int, float] = {}
        """Message id -> interval override in seconds of sim time; < 0 = stream off."""
        self._last_sent_wall: dict[str, float] = {}
        self._last_sent_sim: dict[str, float] = {}
        self.phase: int | None = None
        """Phase of the last sample sent (None before the first)."""
        self.no_fix_until_prearm = False
        """Positions say latitude = longitude = 0 until the pre-arm checks pass."""
        self.stream_slowdown: Callable[[], float] = lambda: 1.0
        """The factor on the periodic streams' intervals now (a personality's: ArduPilot
        sends its streams four times slower while it asks a GCS for mission items)."""
        self.positions_paused: Callable[[], bool] = lambda: False
        """Whether no GLOBAL_POSITION_INT goes out now, neither on its stream nor with a
        sample (a personality's: :mod:`sim_vehicle.ardupilot`, after an upload begins)."""
        self.fence = FenceMonitor()
        self._builders: dict[str, Callable[[], Any]] = {
            "GLOBAL_POSITION_INT": self.global_position_int,
            "LOCAL_POSITION_NED": self.local_position_ned,
            "ATTITUDE": self.attitude,
        }

    # -- builders ------------------------------------------------------------------------------

    def heartbeat(self) -> Any:
        base, custom = self.modes.heartbeat_modes()
        status = mavlink.MAV_STATE_ACTIVE if self.state.armed else mavlink.MAV_STATE_STANDBY
        return mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, self.modes.autopilot_type, base, custom, status, 3)

    def sys_status(self) -> Any:
        present = healthy = SENSORS
        if not self.modes.prearm_ok():
            healthy &= ~mavlink.MAV_SYS_STATUS_PREARM_CHECK
        if not self.state.fence.empty:
            present |= mavlink.MAV_SYS_STATUS_GEOFENCE
            if not self.fence.outside:
                healthy |= mavlink.MAV_SYS_STATUS_GEOFENCE
        return mavlink.MAVLink_sys_status_message(
            present, present, healthy, 100, 16000, 1000, 90, 0, 0, 0, 0, 0, 0)

    def fence_status(self) -> Any:
        return self.fence.message()

    def extended_sys_state(self) -> Any:
        return mavlink.MAVLink_extended_sys_state_message(
            mavlink.MAV_VTOL_STATE_UNDEFINED, self.state.landed_state)

    def autopilot_version(self) -> Any:
        return mavlink.MAVLink_autopilot_version_message(
            CAPABILITIES, self.modes.flight_sw_version, 0, 0, 1, [0] * 8, [0] * 8, [0] * 8, 0,
            0, self.state.sysid, [0] * 18)

    def home_position(self) -> Any:
        st = self.state
        lat, lon, alt = st.home
        hx, hy, _ = st.home_local
        return mavlink.MAVLink_home_position_message(
            int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
            hy, hx, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(st.body.t_s * 1e6))

    def global_position_int(self) -> Any:
        st = self.state
        if self.no_fix_until_prearm and not self.modes.prearm_ok():
            lat = lon = 0.0  # ArduPilot: no position estimate yet
        else:
            lat, lon, _ = st.origin.to_global(st.body.x_m, st.body.y_m, 0.0)
        return gpi_message(st.home[2], st.time_boot_ms, lat, lon, st.alt_rel_m, st.vel_enu_mps)

    def local_position_ned(self) -> Any:
        st = self.state
        ve, vn, vu = st.vel_enu_mps
        return mavlink.MAVLink_local_position_ned_message(
            st.time_boot_ms, st.body.y_m - st.home_local[1], st.body.x_m - st.home_local[0],
            -st.alt_rel_m, vn, ve, -vu)

    def attitude(self) -> Any:
        ve, vn, _ = self.state.vel_enu_mps
        yaw = math.atan2(ve, vn) if ve * ve + vn * vn > 0.01 else 0.0
        return mavlink.MAVLink_attitude_message(self.state.time_boot_ms, 0.0, 0.0, yaw, 0.0,
                                                0.0, 0.0)

    def mission_current(self) -> Any:
        st = self.state
        return self.server.mission_current_msg(st.mission_active, st.mission_complete,
                                               st.mission_started)

    def counters_text(self) -> Any:
        return mavlink.MAVLink_statustext_message(
            mavlink.MAV_SEVERITY_INFO, self.status_line().encode()[:STATUSTEXT_CHUNK], 0, 0)

    def requestable(self) -> dict[int, Callable[[], Any]]:
        """Message id -> builder, for REQUEST_MESSAGE and SET_MESSAGE_INTERVAL."""
        return {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: self.heartbeat,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self.sys_status,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self.attitude,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.local_position_ned,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.global_position_int,
            mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: self.mission_current,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.autopilot_version,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self.home_position,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.extended_sys_state,
            mavlink.MAVLINK_MSG_ID_STATUSTEXT: self.counters_text,
            mavlink.MAVLINK_MSG_ID_FENCE_STATUS: self.fence_status,
        }

    # -- rates ---------------------------------------------------------------------------------

    def set_interval(self, message_id: int, interval_us: float) -> bool:
        """SET_MESSAGE_INTERVAL: 0 = default rate, < 0 = off. False for unknown messages."""
        if message_id not in self.requestable():
            return False
        if interval_us == 0:
            self.intervals.pop(message_id, None)
        else:
            self.intervals[message_id] = -1.0 if interval_us < 0 else interval_us / 1e6
        if interval_us >= 0:
            self.enabled.add(message_id)
        self.positions_at_sensor_rate()
        return True

    def request_data_stream(self, stream_id: int, rate_hz: float, start: bool) -> bool:
        """REQUEST_DATA_STREAM: enable (``start``) or stop a group at ``rate_hz`` of sim time
        (1 Hz messages keep their wall rate). False for an unknown group."""
        group = DATA_STREAMS.get(stream_id)
        if group is None:
            return False
        periodic = {mid for _, mid in self.STREAMS}
        for mid in group:
            if not start:
                self.enabled.discard(mid)
                continue
            self.enabled.add(mid)
            if mid in periodic and rate_hz > 0:
                self.intervals[mid] = 1.0 / rate_hz
        self.positions_at_sensor_rate()
        return True

    def positions_at_sensor_rate(self, slowdown: float = 1.0) -> bool:
        """Whether the positions are asked for at least at the sensor's rate (their interval
        times ``slowdown``); a Lua payload's vehicle then sends them with the samples (else at
        the rate asked, as the periodic stream). The unslowed answer is kept in
        :attr:`Outbox.positions_with_samples`."""
        gpi = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
        rate = self.state.params["TEL_RATE_HZ"]
        period = self.intervals.get(gpi, 1.0 / rate if rate > 0 else -1.0)
        sample_hz = self.state.params["SAMPLE_HZ"]
        fast = self.streaming(gpi) and 0 < period * slowdown <= 1.0 / sample_hz + 1e-9
        if slowdown == 1.0:
            self.outbox.positions_with_samples = fast
        return fast

    def streaming(self, message_id: int) -> bool:
        """Whether ``message_id`` goes out on its own (not only on request)."""
        if self.intervals.get(message_id, 0.0) < 0:
            return False
        return not self.streams_on_request or message_id in self.enabled

    def one_hz(self) -> None:
        """The 1 Hz (wall) messages: HEARTBEAT, SYS_STATUS, EXTENDED_SYS_STATE, MISSION_CURRENT."""
        self.outbox.put(self.heartbeat())
        for mid, make in ((mavlink.MAVLINK_MSG_ID_SYS_STATUS, self.sys_status),
                          (mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, self.extended_sys_state)):
            if self.streaming(mid):
                self.outbox.put(make())
        if self.server.mission and self.streaming(mavlink.MAVLINK_MSG_ID_MISSION_CURRENT):
            self.outbox.put(self.mission_current())
        if not self.state.fence.empty and self.streaming(mavlink.MAVLINK_MSG_ID_FENCE_STATUS):
            self.outbox.put(self.fence_status())

    def watch_fence(self) -> None:
        """After a tick: FENCE_STATUS and a STATUSTEXT when the guard braked before the
        fence or the vehicle got outside it (or back inside)."""
        change = self.fence.update(self.state.body)
        if not change:
            return
        body = self.state.body
        where = f"at ({body.x_m:.1f}, {body.y_m:.1f}) m"
        if change.breached:
            self.outbox.statustext(f"fence: outside the fence {where}",
                                   mavlink.MAV_SEVERITY_CRITICAL)
        elif change.attempts:
            self.outbox.statustext(f"fence: braking before the fence {where}",
                                   mavlink.MAV_SEVERITY_WARNING)
        if change.returned:
            self.outbox.statustext(f"fence: back inside {where}", mavlink.MAV_SEVERITY_INFO)
        self.outbox.put(self.fence_status())

    def periodic(self, wall: float) -> None:
        """Queue the periodic streams that are due at sim time now and wall time ``wall``."""
        sim = self.state.body.t_s
        rate = self.state.params["TEL_RATE_HZ"]
        slowdown = self.stream_slowdown()
        for name, mid in self.STREAMS:
            period = self.intervals.get(mid, 1.0 / rate if rate > 0 else -1.0)
            if period < 0 or not self.streaming(mid):
                continue
            if sim - self._last_sent_sim.get(name, -1e9) < period * slowdown - 1e-9:
                continue
            if wall - self._last_sent_wall.get(name, -1e9) < 1.0 / MAX_STREAM_WALL_HZ:
                continue
            if name == "GLOBAL_POSITION_INT":
                if self.positions_paused():
                    continue
                if self._positions_with_samples(slowdown) and \
                        wall - self.outbox.last_sample_wall < 0.5 / MAX_STREAM_WALL_HZ:
                    continue  # sample pairs are flowing; they carry the position already
            self.outbox.put(self._builders[name]())
            self._last_sent_sim[name] = sim
            self._last_sent_wall[name] = wall

    def _positions_with_samples(self, slowdown: float) -> bool:
        """Each sample's position goes out with it: always for our own payload (the exact
        stamps of :mod:`sim_vehicle`), for a Lua payload only while the positions, slowed
        down by ``slowdown``, still come at least at the sensor's rate (else the position
        stream, at its own rate, carries them)."""
        out = self.outbox
        if not out.lua_payload:
            return True
        return out.positions_with_samples if slowdown == 1.0 else \
            self.positions_at_sensor_rate(slowdown)

    def sample(self, sample: Sample) -> None:
        """Queue one sample at the vehicle's current position and velocity (after a PHASE
        message when its phase differs from the previous sample's)."""
        st = self.state
        if sample.phase != self.phase and st.settings.companion:
            self.phase = sample.phase
            ms = int(round(sample.t_s * 1000.0)) & 0xFFFFFFFF
            self.outbox.archive.add_phase(ms, sample.phase)
            self.outbox.put(phase_message(ms, sample.phase))
        with_position = (self._positions_with_samples(self.stream_slowdown())
                         and not self.positions_paused())
        self.outbox.put_sample(sample, st.body.x_m, st.body.y_m, st.alt_rel_m, st.vel_enu_mps,
                               with_position)
