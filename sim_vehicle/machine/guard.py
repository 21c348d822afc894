"""The guard: every velocity command is limited so the vehicle can always stop inside the
geofence and, during a trace task, inside the mission area (see :func:`guard`)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..fence import FENCE_HARD_MARGIN_M, fence_contains, fence_ray_exit
from ..kinematics import point_step
from .vehicle import contains, ground_speed, ray_to_edge_m

GUARD_SOFT_ACCEL_FRACTION = 0.7
"""The guard's soft limit slows a command so that the vehicle could stop before the
boundary ahead with this fraction of its acceleration limit (the fly-to brakes with 0.6,
so a fly-to to a point inside is never slowed by it)."""
AREA_HARD_MARGIN_M = 1e-3
"""A trace task can always stop at least this far inside the mission area."""
FENCE_EPISODE_GAP_S = 1.0
"""Fence limiting after this long without any counts as a new breach attempt."""


@njit(cache=True)
def _predict(b, vx_cmd_mps: float, vy_cmd_mps: float) -> tuple[float, float, float, float]:
    """Position and velocity after one tick with the command (:func:`body_move` without
    moving)."""
    sub_dt_s = b.dt_s / b.n_sub
    x, y, vx, vy, odo, hdg = b.x_m, b.y_m, b.vx_mps, b.vy_mps, 0.0, b.last_heading_rad
    for _ in range(b.n_sub):
        x, y, vx, vy, odo, hdg = point_step(x, y, vx, vy, odo, hdg, sub_dt_s, vx_cmd_mps,
                                            vy_cmd_mps, b.max_speed_mps, b.max_accel_mps2,
                                            b.max_turn_rate_dps)
    return x, y, vx, vy


@njit(cache=True)
def _stops_in_area(b, x: float, y: float, vx: float, vy: float) -> bool:
    """Braking from ``(x, y)`` at ``(vx, vy)`` stops inside the area (a zero command brakes
    along a straight line with the full acceleration limit)."""
    if not contains(b.xmin, b.xmax, b.ymin, b.ymax, x, y):
        return False
    v = math.hypot(vx, vy)
    if v < 1e-9:
        return True
    return (ray_to_edge_m(b.xmin, b.xmax, b.ymin, b.ymax, x, y, vx / v, vy / v)
            >= v * v / (2.0 * b.max_accel_mps2) + AREA_HARD_MARGIN_M)


@njit(cache=True)
def _stops_in_fence(b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray, x: float, y: float,
                    vx: float, vy: float) -> bool:
    """Braking from ``(x, y)`` at ``(vx, vy)`` stops ``FENCE_HARD_MARGIN_M`` inside the
    fence."""
    v = math.hypot(vx, vy)
    if v < 1e-9:
        return fence_contains(fv, fr, fc, x, y)
    return (fence_ray_exit(fv, fr, fc, x, y, vx / v, vy / v)
            >= v * v / (2.0 * b.max_accel_mps2) + FENCE_HARD_MARGIN_M)


@njit(cache=True)
def guard(ctl, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray) -> None:
    """Change the command in ``ctl`` so the vehicle stays inside the fence (always) and the
    mission area (during a trace task, while it is inside it).

    Two stages, for each boundary the vehicle is inside of:

    * soft (in the spirit of ArduPilot's AC_Avoid): the command's speed is limited to
      ``sqrt(2 a d)`` with ``a`` = ``GUARD_SOFT_ACCEL_FRACTION`` of the acceleration limit
      and ``d`` the distance along the command to the area boundary or to
      ``fence_margin_m`` before the fence, so the vehicle slows down smoothly;
    * hard: one tick with the (limited) command is predicted with the kinematics
      themselves; if braking from there (a zero command: a straight line at the full
      acceleration limit) would not stop inside (``AREA_HARD_MARGIN_M`` /
      ``FENCE_HARD_MARGIN_M``), the vehicle brakes now instead. Braking from a state that
      passed this check passes it again, so a vehicle that starts a task able to stop
      inside never leaves.

    Outside a boundary nothing is limited (so a vehicle can fly back in; AC_Avoid does the
    same). Fence limiting is counted (``fence_attempts``, one per episode), so is being
    outside (``fence_breaches``); ``fence_stuck`` counts the ticks the fence has held a
    vehicle still.
    """
    vx, vy = ctl.cmd_vx, ctl.cmd_vy
    x, y = b.x_m, b.y_m
    area_on = ctl.area_guard != 0 and contains(b.xmin, b.xmax, b.ymin, b.ymax, x, y)
    fence_on = False
    if fr.shape[0] > 0 or fc.shape[0] > 0:
        fence_on = fence_contains(fv, fr, fc, x, y)
        if not fence_on and b.fence_outside == 0:
            b.fence_breaches += 1
            b.fence_event_tick = b.ticks
        b.fence_outside = 0 if fence_on else 1
    fence_limited = False
    if area_on or fence_on:
        speed = math.hypot(vx, vy)
        if speed > 0.0:
            ux, uy = vx / speed, vy / speed
            a_soft = GUARD_SOFT_ACCEL_FRACTION * b.max_accel_mps2
            v_max = speed
            if area_on:
                d = ray_to_edge_m(b.xmin, b.xmax, b.ymin, b.ymax, x, y, ux, uy)
                v_max = min(v_max, math.sqrt(2.0 * a_soft * d))
            if fence_on:
                d = fence_ray_exit(fv, fr, fc, x, y, ux, uy) - b.fence_margin_m
                v_fence = math.sqrt(2.0 * a_soft * max(d, 0.0))
                if v_fence < speed - 1e-6:
                    fence_limited = True
                v_max = min(v_max, v_fence)
            if v_max < speed:
                vx, vy = vx * (v_max / speed), vy * (v_max / speed)
        px, py, pvx, pvy = _predict(b, vx, vy)
        brake = area_on and not _stops_in_area(b, px, py, pvx, pvy)
        if fence_on and not _stops_in_fence(b, fv, fr, fc, px, py, pvx, pvy):
            brake = True
            fence_limited = True
        if brake:
            vx = vy = 0.0
            b.guard_brakes += 1
    if fence_limited:
        if (b.ticks - b.fence_last_tick) * b.dt_s > FENCE_EPISODE_GAP_S:
            b.fence_attempts += 1
            b.fence_event_tick = b.ticks
        b.fence_last_tick = b.ticks
        if math.hypot(vx, vy) < 0.1 and ground_speed(b) < 0.2:
            b.fence_stuck += 1
        else:
            b.fence_stuck = 0
    else:
        b.fence_stuck = 0
    b.fence_limited = 1 if fence_limited else 0
    ctl.cmd_vx, ctl.cmd_vy = vx, vy
