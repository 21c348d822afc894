"""The body's motion and the area around it, as the machine sees them (believed position).

:func:`body_move` flies one sensor period with a held command (the kinematic sub-steps of
:func:`~sim_vehicle.kinematics.point_step`); the rest measures the area's boundary and the
geofence from a point along a heading.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..fence import fence_ray_exit
from ..kinematics import point_step


@njit(cache=True)
def body_move(b, vx_cmd_mps: float, vy_cmd_mps: float) -> None:
    """Fly one sensor period (``n_sub`` kinematic sub-steps) with a held command."""
    sub_dt_s = b.dt_s / b.n_sub
    x, y, vx, vy, odo, hdg = b.x_m, b.y_m, b.vx_mps, b.vy_mps, b.odometer_m, b.last_heading_rad
    for _ in range(b.n_sub):
        x, y, vx, vy, odo, hdg = point_step(x, y, vx, vy, odo, hdg, sub_dt_s, vx_cmd_mps,
                                            vy_cmd_mps, b.max_speed_mps, b.max_accel_mps2,
                                            b.max_turn_rate_dps)
    b.x_m, b.y_m, b.vx_mps, b.vy_mps, b.odometer_m, b.last_heading_rad = x, y, vx, vy, odo, hdg
    b.ticks += 1


@njit(cache=True)
def ground_speed(b) -> float:
    """Ground speed."""
    return math.hypot(b.vx_mps, b.vy_mps)


@njit(cache=True)
def heading(b) -> float:
    """Course over ground (the last one flown when at rest)."""
    if b.vx_mps != 0.0 or b.vy_mps != 0.0:
        return math.atan2(b.vy_mps, b.vx_mps)
    return b.last_heading_rad


@njit(cache=True)
def contains(xmin: float, xmax: float, ymin: float, ymax: float, x: float, y: float) -> bool:
    return xmin <= x <= xmax and ymin <= y <= ymax


@njit(cache=True)
def shrink_m(b, margin_m: float) -> float:
    """``margin_m``, at most a quarter of the area's width and height (an inset that
    leaves room in a small area)."""
    return min(margin_m, 0.25 * (b.xmax - b.xmin), 0.25 * (b.ymax - b.ymin))


@njit(cache=True)
def ray_to_edge_m(xmin: float, xmax: float, ymin: float, ymax: float, x_m: float, y_m: float,
                  ux: float, uy: float) -> float:
    """Distance from an inside point to the region boundary along unit vector ``(ux, uy)``."""
    if not contains(xmin, xmax, ymin, ymax, x_m, y_m):
        return 0.0
    dist = math.inf
    if ux > 1e-12:
        dist = min(dist, (xmax - x_m) / ux)
    elif ux < -1e-12:
        dist = min(dist, (xmin - x_m) / ux)
    if uy > 1e-12:
        dist = min(dist, (ymax - y_m) / uy)
    elif uy < -1e-12:
        dist = min(dist, (ymin - y_m) / uy)
    return dist


@njit(cache=True)
def edge_ahead_m(b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray, x_m: float, y_m: float,
                 ux: float, uy: float) -> float:
    """Distance along ``(ux, uy)`` to the area boundary or to ``fence_margin_m`` before
    the fence, whichever comes first (0 outside the area)."""
    edge = ray_to_edge_m(b.xmin, b.xmax, b.ymin, b.ymax, x_m, y_m, ux, uy)
    if fr.shape[0] > 0 or fc.shape[0] > 0:
        edge = min(edge, fence_ray_exit(fv, fr, fc, x_m, y_m, ux, uy) - b.fence_margin_m)
    return edge
