"""Waypoint routes for autopilots without the onboard tracer.

A stock autopilot can only fly waypoints, so a contour piece of the estimate becomes the
polyline of the piece itself: entered where the vehicle comes from, simplified with the
Douglas-Peucker algorithm (Douglas & Peucker 1973, via shapely/GEOS) to a tolerance in
metres, and flown as NAV_WAYPOINTs. The route is the *estimated* contour: nothing senses the
field on the way, so it is as good as the estimate.

Routes are ``(k, 2)`` arrays of local ENU metres ``(x_m, y_m)``. Which vehicle flies which
pieces, and in what order, is :func:`econdor_gcs.core.assignment.assign_jobs`' job (nearest
neighbour from where the vehicle is; each piece entered at its point nearest to it).

* :func:`piece_route`: a piece as flown from a given point: a closed piece from its point
  nearest to it, around and back to that point; an open piece from its nearer end to the other.
* :func:`simplify_route`: Douglas-Peucker; the first and last points are kept.
* :func:`task_waypoints`: a task as the waypoints a stock autopilot flies (a trace task's
  ``route_m``, simplified).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import shapely

from .geometry import FloatArray, path_length
from .tasks import Task, TraceTask, Waypoint

__all__ = ["piece_route", "route_length", "simplify_route", "task_waypoints"]


def _as_points(points_m: FloatArray | Sequence[Sequence[float]]) -> FloatArray:
    p = np.asarray(points_m, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) == 0:
        raise ValueError(f"a route needs (k, 2) points, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("a route's points must be finite")
    return p


def piece_route(points_m: FloatArray | Sequence[Sequence[float]], closed: bool,
                from_xy: tuple[float, float]) -> FloatArray:
    """The piece as flown by a vehicle coming from ``from_xy``.

    >>> sq = [(0, 0), (10, 0), (10, 10), (0, 10), (0, 0)]
    >>> piece_route(sq, True, (11, 11)).tolist()
    [[10.0, 10.0], [0.0, 10.0], [0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]
    >>> piece_route([(0, 0), (5, 0), (9, 0)], False, (10, 1)).tolist()
    [[9.0, 0.0], [5.0, 0.0], [0.0, 0.0]]
    """
    p = _as_points(points_m)
    fx, fy = from_xy
    if not closed or len(p) < 3:
        d0 = np.hypot(p[0, 0] - fx, p[0, 1] - fy)
        d1 = np.hypot(p[-1, 0] - fx, p[-1, 1] - fy)
        return p.copy() if d0 <= d1 else p[::-1].copy()
    ring = p[:-1] if np.allclose(p[0], p[-1]) else p
    i = int(np.argmin(np.hypot(ring[:, 0] - fx, ring[:, 1] - fy)))
    rotated = np.vstack([ring[i:], ring[:i]])
    return np.vstack([rotated, rotated[:1]])


def simplify_route(route_m: FloatArray, tolerance_m: float) -> FloatArray:
    """Douglas-Peucker simplification to ``tolerance_m`` (0: only repeated points go).

    Every point of the original lies within ``tolerance_m`` of the simplified polyline; the
    end points are kept (a closed route stays closed).

    >>> simplify_route(np.array([(0, 0), (5, 0.1), (10, 0)]), 0.5).tolist()
    [[0.0, 0.0], [10.0, 0.0]]
    """
    if not tolerance_m >= 0:
        raise ValueError(f"tolerance_m must be >= 0, got {tolerance_m!r}")
    p = _as_points(route_m)
    keep = np.r_[True, np.any(np.diff(p, axis=0) != 0, axis=1)]
    p = p[keep]
    if len(p) < 3 or tolerance_m == 0:
        return p
    simple = shapely.LineString(p).simplify(tolerance_m, preserve_topology=False)
    return np.asarray(simple.coords, dtype=float)


def route_length(route_m: FloatArray) -> float:
    p = _as_points(route_m)
    return path_length(p[:, 0], p[:, 1])


def task_waypoints(task: Task, tolerance_m: float) -> list[Waypoint]:
    """The waypoints that fly ``task`` without the onboard tracer.

    A :class:`Waypoint` stays itself; a :class:`TraceTask` becomes its ``route_m``
    simplified to ``tolerance_m`` (the first waypoint is the entry point, reached by transit).
    ValueError for a trace task without a route.

    >>> t = TraceTask(5.0, 0, 0, 10, 0, 1, route_m=((0, 0), (5, 0.1), (10, 0), (10, 10)))
    >>> [(w.x_m, w.y_m) for w in task_waypoints(t, 0.5)]
    [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0)]
    """
    if not isinstance(task, TraceTask):
        return [task]
    if not task.route_m:
        raise ValueError(f"piece {task.piece_id}: no route to fly as waypoints")
    route = simplify_route(np.asarray(task.route_m, dtype=float), tolerance_m)
    return [Waypoint(float(x), float(y)) for x, y in route]
