"""Point-mass kinematics of a simulated multirotor in the local ENU plane.

The vehicle is a 2-D point mass that is steered by a commanded velocity. Each
:meth:`PointMass.step` moves the actual velocity toward the command while obeying
three limits (see :class:`VehicleLimits`):

* speed: ``|v| <= max_speed_mps`` (the command is clipped first);
* acceleration: ``|v_new - v_old| <= max_accel_mps2 * dt_s``;
* turn rate: while moving (``|v| >= TURN_LIMIT_MIN_SPEED_MPS``) the heading of the
  velocity changes by at most ``max_turn_rate_dps * dt_s``; a command that points
  further away than that is rotated to the limit and scaled by ``cos`` of the
  heading error, so a vehicle told to reverse brakes (and then turns freely once it is
  almost stopped) instead of accelerating sideways.

Position is integrated with the mean of the old and new velocity, so the odometer
(``sum |mean velocity| * dt``) equals the length of the polyline through the
positions after every step exactly.

The step itself is :func:`point_step`, compiled with numba (cached on disk): the
onboard tracer (:mod:`sim_vehicle.machine`) calls it for every sub-step, and
:class:`PointMass` is its Python face.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from numba import njit

TURN_LIMIT_MIN_SPEED_MPS = 0.5
"""Below this speed the vehicle is considered hovering and may turn freely."""


@dataclass(frozen=True)
class VehicleLimits:
    """Dynamic limits of a simulated vehicle.

    Parameters
    ----------
    max_speed_mps
        Maximum ground speed.
    max_accel_mps2
        Maximum magnitude of the acceleration vector (tangential and centripetal).
    max_turn_rate_dps
        Maximum rate of change of the velocity heading while moving, in degrees/s.
    """

    max_speed_mps: float = 10.0
    max_accel_mps2: float = 5.0
    max_turn_rate_dps: float = 180.0

    def __post_init__(self) -> None:
        for name in ("max_speed_mps", "max_accel_mps2", "max_turn_rate_dps"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")


@njit(cache=True)
def wrap_angle_rad(angle_rad: float) -> float:
    """Wrap an angle to ``[-pi, pi)``.

    Parameters
    ----------
    angle_rad
        Any angle in radians.

    Returns
    -------
    float
        The equivalent angle in ``[-pi, pi)``.

    Examples
    --------
    >>> round(wrap_angle_rad(3.5 * math.pi), 12) == round(-0.5 * math.pi, 12)
    True
    """
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def point_step(
    x_m: float, y_m: float, vx_mps: float, vy_mps: float, odometer_m: float,
    last_heading_rad: float, dt_s: float, vx_cmd_mps: float, vy_cmd_mps: float,
    max_speed_mps: float, max_accel_mps2: float, max_turn_rate_dps: float,
) -> tuple[float, float, float, float, float, float]:
    """One kinematic step of the point mass (the limits above); trusts its input.

    Returns
    -------
    x_m, y_m, vx_mps, vy_mps, odometer_m, last_heading_rad
        The state after ``dt_s``.
    """
    cx, cy = vx_cmd_mps, vy_cmd_mps
    cmd_speed = math.hypot(cx, cy)
    if cmd_speed > max_speed_mps:
        scale = max_speed_mps / cmd_speed
        cx, cy, cmd_speed = cx * scale, cy * scale, max_speed_mps

    vx, vy = vx_mps, vy_mps
    speed = math.hypot(vx, vy)
    if speed >= TURN_LIMIT_MIN_SPEED_MPS and cmd_speed > 0.0:
        heading = math.atan2(vy, vx)
        diff = wrap_angle_rad(math.atan2(cy, cx) - heading)
        max_turn = math.radians(max_turn_rate_dps) * dt_s
        if abs(diff) > max_turn:
            new_heading = heading + math.copysign(max_turn, diff)
            mag = cmd_speed * max(math.cos(diff), 0.0)
            cx, cy = mag * math.cos(new_heading), mag * math.sin(new_heading)

    dvx, dvy = cx - vx, cy - vy
    dv = math.hypot(dvx, dvy)
    dv_max = max_accel_mps2 * dt_s
    if dv > dv_max:
        scale = dv_max / dv
        dvx, dvy = dvx * scale, dvy * scale
    nvx, nvy = vx + dvx, vy + dvy
    if nvx != 0.0 or nvy != 0.0:
        last_heading_rad = math.atan2(nvy, nvx)
    mx, my = 0.5 * (vx + nvx), 0.5 * (vy + nvy)
    return (x_m + mx * dt_s, y_m + my * dt_s, nvx, nvy,
            odometer_m + math.hypot(mx, my) * dt_s, last_heading_rad)


def check_step(dt_s: float, vx_cmd_mps: float, vy_cmd_mps: float) -> None:
    """Raise ``ValueError`` for a non-positive step or a non-finite command."""
    if not dt_s > 0.0:
        raise ValueError(f"dt_s must be > 0, got {dt_s!r}")
    if not (math.isfinite(vx_cmd_mps) and math.isfinite(vy_cmd_mps)):
        raise ValueError(f"velocity command must be finite, got ({vx_cmd_mps}, {vy_cmd_mps})")


class PointMass:
    """A 2-D point mass steered by velocity commands.

    Parameters
    ----------
    x_m, y_m
        Initial position (local ENU metres). The vehicle starts at rest.
    limits
        Speed, acceleration and turn-rate limits.

    Attributes
    ----------
    x_m, y_m : float
        Current position.
    vx_mps, vy_mps : float
        Current velocity.
    odometer_m : float
        Distance flown since construction.
    """

    def __init__(self, x_m: float, y_m: float, limits: VehicleLimits) -> None:
        self.limits = limits
        self.x_m = float(x_m)
        self.y_m = float(y_m)
        self.vx_mps = 0.0
        self.vy_mps = 0.0
        self.odometer_m = 0.0
        self._last_heading_rad = 0.0

    @property
    def speed_mps(self) -> float:
        """Current ground speed."""
        return math.hypot(self.vx_mps, self.vy_mps)

    @property
    def heading_rad(self) -> float:
        """Direction of the velocity (ENU, radians from +x counter-clockwise).

        When at rest, the last heading flown (0 initially).
        """
        if self.vx_mps != 0.0 or self.vy_mps != 0.0:
            return math.atan2(self.vy_mps, self.vx_mps)
        return self._last_heading_rad

    def step(self, dt_s: float, vx_cmd_mps: float, vy_cmd_mps: float) -> None:
        """Advance the state by ``dt_s`` toward the commanded velocity.

        Parameters
        ----------
        dt_s
            Time step in seconds (> 0).
        vx_cmd_mps, vy_cmd_mps
            Commanded velocity; clipped to the speed limit.
        """
        check_step(dt_s, vx_cmd_mps, vy_cmd_mps)
        lim = self.limits
        (self.x_m, self.y_m, self.vx_mps, self.vy_mps, self.odometer_m,
         self._last_heading_rad) = point_step(
            self.x_m, self.y_m, self.vx_mps, self.vy_mps, self.odometer_m,
            self._last_heading_rad, float(dt_s), float(vx_cmd_mps), float(vy_cmd_mps),
            lim.max_speed_mps, lim.max_accel_mps2, lim.max_turn_rate_dps)
