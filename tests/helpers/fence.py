"""Fence shapes and the FENCE items a GCS uploads for them (shared by the fence tests in-process
and over MAVLink)."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.geodesy import Origin
from sim_vehicle.fence import Fence
from sim_vehicle.mission_server import FENCE, StoredItem

ORIGIN = Origin(47.397742, 8.545594, 488.0)

# A U open to the north: the notch 40 < x < 60, y > 30 is outside
U_SHAPE = np.array([(0, 0), (100, 0), (100, 100), (60, 100), (60, 30), (40, 30), (40, 100),
                    (0, 100)], dtype=float)


def distance_outside_polygon(poly: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Signed distance to the polygon boundary: > 0 outside, < 0 inside (shapely-free)."""
    fence = Fence(inclusion_polygons=(poly,))
    d = np.full(len(x), np.inf)
    for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        ex, ey = bx - ax, by - ay
        t = np.clip(((x - ax) * ex + (y - ay) * ey) / (ex * ex + ey * ey), 0.0, 1.0)
        d = np.minimum(d, np.hypot(x - ax - t * ex, y - ay - t * ey))
    inside = np.array([fence.contains(a, b) for a, b in zip(x, y, strict=True)])
    return np.where(inside, -d, d)


def fence_item(cmd: int, x_m: float, y_m: float, p1: float,
          frame: int = mavlink.MAV_FRAME_GLOBAL) -> StoredItem:
    lat, lon, _ = ORIGIN.to_global(x_m, y_m)
    return StoredItem(0, frame, cmd, 0, 1, p1, 0.0, 0.0, 0.0, round(lat * 1e7),
                      round(lon * 1e7), 0.0, FENCE, lat, lon)


def plan_geofence_items(geofence: dict) -> list[StoredItem]:
    """The FENCE items QGroundControl uploads for a ``.plan``'s ``geoFence`` (vertices in
    ``MAV_FRAME_GLOBAL``, ``param1`` = vertex count or radius)."""
    items = []
    for poly in geofence["polygons"]:
        cmd = (mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION if poly["inclusion"]
               else mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION)
        for lat, lon in poly["polygon"]:
            x, y, _ = ORIGIN.to_local(lat, lon)
            items.append(fence_item(cmd, x, y, float(len(poly["polygon"]))))
    for c in geofence["circles"]:
        cmd = (mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION if c["inclusion"]
               else mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION)
        x, y, _ = ORIGIN.to_local(*c["circle"]["center"])
        items.append(fence_item(cmd, x, y, c["circle"]["radius"]))
    return items


def u_shape_plan() -> dict:
    """A QGroundControl ``.plan`` ``geoFence``: the U as an inclusion polygon and an
    exclusion circle in its left arm."""
    return {"version": 2,
            "polygons": [{"inclusion": True, "version": 1,
                          "polygon": [list(ORIGIN.to_global(x, y)[:2]) for x, y in U_SHAPE]}],
            "circles": [{"inclusion": False, "version": 1,
                         "circle": {"center": list(ORIGIN.to_global(10.0, 50.0)[:2]),
                                    "radius": 4.0}}]}
