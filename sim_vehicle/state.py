"""The state of one simulated vehicle, shared by its autopilot, navigator and telemetry.

Nothing here does I/O. :class:`VehicleState` is the model; the
:class:`~sim_vehicle.autopilot.Autopilot` (modes, arming, commands) and the
:class:`~sim_vehicle.navigator.Navigator` (mission items -> flight activities) change it, the
:class:`~sim_vehicle.telemetry.Telemetry` reads it.

Positions are local ENU metres from the mission origin (the body's ``x_m``/``y_m``); the
altitude is ``alt_rel_m`` above home (the body is a 2-D point mass, climbs and descents are
handled by the navigator at fixed rates).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from enum import StrEnum

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.geometry import Region

from .body import SimBody
from .fence import NO_FENCE, Fence
from .kinematics import VehicleLimits
from .sensor import SensorModel

PARAM_NAMES = ("SPEED_MPS", "SAMPLE_HZ", "SEARCH_RAD_M", "TEL_RATE_HZ", "NOISE_STD",
               "ALT_M", "SPEEDUP", "LAG_S", "POS_STD_M", "POS_TAU_S", "GCS_FS_ACT", "GCS_FS_S")
"""The vehicle's parameters (REAL32), in PARAM_VALUE index order. ``GCS_FS_ACT`` /
``GCS_FS_S``: the GCS failsafe (:data:`GCS_FAILSAFE_ACTIONS`; ArduPilot's FS_GCS_ENABLE /
FS_GCS_TIMEOUT, PX4's NAV_DLL_ACT / COM_DL_LOSS_T)."""
GCS_FAILSAFE_ACTIONS = {"off": 0.0, "hold": 1.0, "rtl": 2.0}
"""``GCS_FS_ACT`` values: what the vehicle does on its own when the ground station's
HEARTBEAT has been missing for ``GCS_FS_S`` wall seconds while it flies."""

SENSOR_PARAMS = {"NOISE_STD": "noise_std", "LAG_S": "lag_s", "POS_STD_M": "position_std_m",
                 "POS_TAU_S": "position_tau_s"}
"""The parameters that set the sensor model (:class:`~sim_vehicle.sensor.SensorModel`),
applied from the next mission item (or at once when idle), like SAMPLE_HZ."""


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
    lag_s: float = 0.0
    position_std_m: float = 0.0
    position_tau_s: float = 10.0
    speedup: float = 50.0
    search_radius_m: float = 10.0
    tel_rate_hz: float = 10.0
    seed: int = 0
    companion: bool = False
    """A companion computer runs the tracer: contour items are accepted (else refused)."""
    prearm_s: float | None = None
    """Wall seconds after boot during which arming is refused (None: the personality's)."""
    upload_pause_s: float | None = None
    """Seconds of its time from a mission upload's start during which, while the upload runs,
    it sends no GLOBAL_POSITION_INT (None: the personality's; :mod:`sim_vehicle.ardupilot`)."""
    gcs_failsafe: str = "rtl"
    """What to do when the GCS heartbeat is lost in flight (:data:`GCS_FAILSAFE_ACTIONS`)."""
    gcs_failsafe_s: float = 5.0
    """After how many wall seconds without it (ArduPilot's FS_GCS_TIMEOUT default)."""


class FlightMode(StrEnum):
    """What the vehicle is doing, independent of how an autopilot encodes it.

    Each personality (:mod:`sim_vehicle.autopilot`) maps these to its own ``custom_mode``.
    """

    HOLD = "hold"          # hover where it is (PX4 AUTO.LOITER, ArduCopter LOITER)
    TAKEOFF = "takeoff"    # climbing to the takeoff altitude (PX4 AUTO.TAKEOFF)
    MISSION = "mission"    # executing the stored mission (PX4 AUTO.MISSION, ArduCopter AUTO)
    RTL = "rtl"            # flying home, then landing (PX4 AUTO.RTL, ArduCopter RTL)
    LAND = "land"          # descending where it is (PX4 AUTO.LAND, ArduCopter LAND)
    GUIDED = "guided"      # hover, taking commands from the GCS (ArduCopter GUIDED)
    MANUAL = "manual"      # a pilot's mode; without a pilot it hovers (ArduCopter STABILIZE)


class VehicleState:
    """Flight state of one vehicle: body, altitude, arming, mode, mission progress.

    Parameters
    ----------
    field, region, origin
        The true field ``field(x, y)``, the mission area and its geodetic origin.
    settings
        Limits, rates and defaults (:class:`VehicleSettings`).
    home
        ``(lat_deg, lon_deg, alt_amsl_m)``; the vehicle starts landed and disarmed there.
    """

    def __init__(self, field: Callable[[float, float], float], region: Region, origin: Origin,
                 settings: VehicleSettings, home: tuple[float, float, float]) -> None:
        s = settings
        self.settings = settings
        self.sysid = s.sysid
        self.field = field
        self.region = region
        self.origin = origin
        self.home = home
        hx, hy, hz = origin.to_local(home[0], home[1], home[2] - origin.alt_m)
        self.home_local = (hx, hy, hz)
        self.params: dict[str, float] = {
            "SPEED_MPS": s.speed_mps, "SAMPLE_HZ": s.sample_rate_hz,
            "SEARCH_RAD_M": s.search_radius_m, "TEL_RATE_HZ": s.tel_rate_hz,
            "NOISE_STD": s.noise_std, "ALT_M": s.altitude_m, "SPEEDUP": s.speedup,
            "LAG_S": s.lag_s, "POS_STD_M": s.position_std_m, "POS_TAU_S": s.position_tau_s,
            "GCS_FS_ACT": GCS_FAILSAFE_ACTIONS[s.gcs_failsafe], "GCS_FS_S": s.gcs_failsafe_s,
        }
        self._rng = np.random.default_rng(s.seed * 1000 + s.sysid)
        self._pos_rng = self._rng.spawn(1)[0]
        """The GNSS error's generator (its own stream: the reading noise does not change
        when a position error is added)."""
        self.fence = NO_FENCE
        """The uploaded geofence (kept when the body is rebuilt)."""
        self.body = self.make_body(hx, hy, 0.0)
        self.odo_base_m = 0.0
        self.body_dirty = False
        """SAMPLE_HZ or a sensor parameter changed: rebuild the body at the next item
        boundary."""
        self.armed = False
        self.alt_rel_m = 0.0
        self.landed_state = mavlink.MAV_LANDED_STATE_ON_GROUND
        self.mode = FlightMode.HOLD
        self.mission_active = False
        self.mission_complete = False
        self.mission_started = False
        """The stored mission was started (and has not been replaced since): left before its
        end, it is paused (MISSION_CURRENT's ``mission_state``)."""
        self.speed_mps = s.speed_mps
        self.sampling = False
        """The current tick is a sample to report (set by the navigator's activities)."""
        self.vel_enu_mps = (0.0, 0.0, 0.0)

    def make_body(self, x_m: float, y_m: float, t_s: float) -> SimBody:
        s = self.settings
        limits = VehicleLimits(max_speed_mps=s.max_speed_mps, max_accel_mps2=s.max_accel_mps2,
                               max_turn_rate_dps=s.max_turn_rate_dps)
        return SimBody(self.field, self.region, x_m, y_m, limits,
                       sample_rate_hz=self.params["SAMPLE_HZ"], rng=self._rng, t_s=t_s,
                       fence=self.fence, sensor=self.sensor_model(),
                       position_rng=self._pos_rng)

    def sensor_model(self) -> SensorModel:
        """The sensor as the parameters set it now."""
        return SensorModel(**{key: self.params[name] for name, key in SENSOR_PARAMS.items()})

    def set_fence(self, fence: Fence) -> None:
        """Fly inside ``fence`` from the next tick on."""
        self.fence = fence
        self.body.set_fence(fence)

    def rebuild_body(self, t_s: float) -> None:
        """A new body at the same place (new sample rate / sensor), the odometer, the
        sensor's state and the GNSS error carried on."""
        self.odo_base_m += self.body.odometer_m
        old = self.body
        self.body = self.make_body(old.x_m, old.y_m, t_s)
        self.body.keep_tracks_of(old)
        self.body.keep_sensor_of(old)
        self.body_dirty = False

    def apply_pending_body(self) -> None:
        if self.body_dirty:
            self.rebuild_body(self.body.t_s)

    @property
    def time_boot_ms(self) -> int:
        return int(round(self.body.t_s * 1000.0)) & 0xFFFFFFFF

    @property
    def odometer_m(self) -> float:
        return self.odo_base_m + self.body.odometer_m

    @property
    def in_air(self) -> bool:
        return self.alt_rel_m > 0.0
