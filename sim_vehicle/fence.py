"""The geofence: the shapes a vehicle may not leave, compiled tests on them, and the reports.

Shapes, in local ENU metres (uploaded as mission type FENCE, the items QGroundControl,
MAVProxy and our station send; see :func:`check_fence`):

* ``MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION`` / ``_EXCLUSION``: one item per vertex,
  ``param1`` = the polygon's vertex count (at least 3), vertices of one polygon in a row;
  polygons need not be convex (a QGC ``.plan``'s ``geoFence.polygons``);
* ``MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION`` / ``_EXCLUSION``: centre, ``param1`` = radius (m);
* ``MAV_CMD_NAV_FENCE_RETURN_POINT``: stored and reported back, not used (the vehicle
  returns home).

The allowed set is the **union** of the inclusion shapes (everywhere, if there is none)
minus every exclusion shape. That is PX4's rule; ArduPilot intersects inclusion shapes
unless its ``FENCE_OPTIONS`` asks for the union.

For the compiled flight logic (:mod:`sim_vehicle.machine`) a fence is three arrays
(:attr:`Fence.arrays`): ``verts`` ``(n, 2)`` float, every polygon's vertices in turn;
``rings`` ``(k, 3)`` int, per polygon its first vertex, vertex count and kind (+1
inclusion, -1 exclusion); ``circles`` ``(c, 4)`` float, ``cx, cy, r, kind``. An empty
fence is three empty arrays. :func:`fence_contains` and :func:`fence_ray_exit` (how far a
ray runs before it leaves the allowed set) are what the machine's guard uses.

Reports (:class:`FenceMonitor`): the machine counts *breach attempts* (episodes in which
its guard had to limit the velocity to stay inside) and breaches (being outside); the
vehicle sends them as ``FENCE_STATUS`` (machine-readable) and ``STATUSTEXT`` (for people).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numba import njit
from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.geometry import Region

INCLUSION = 1
EXCLUSION = -1

POLYGON_COMMANDS = {mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: INCLUSION,
                    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: EXCLUSION}
CIRCLE_COMMANDS = {mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION: INCLUSION,
                   mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: EXCLUSION}
FENCE_COMMANDS = frozenset({*POLYGON_COMMANDS, *CIRCLE_COMMANDS,
                            mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT})
GLOBAL_FRAMES = frozenset({mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT,
                           mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                           mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})

FENCE_MARGIN_M = 1.0
"""Where the guard plans to stop: this far inside the fence (ArduPilot's ``AVOID_MARGIN``
and ``FENCE_MARGIN`` default to 2 m)."""
FENCE_HARD_MARGIN_M = 0.25
"""The guard's guarantee: a vehicle inside the fence can always stop at least this far
inside it (see :mod:`sim_vehicle.machine`)."""


# ----------------------------------------------------------------------------- compiled


@njit(cache=True)
def _in_ring(verts: np.ndarray, first: int, count: int, x: float, y: float) -> bool:
    """Crossing-number test of ``(x, y)`` against one polygon (any shape, not self-checked)."""
    inside = False
    j = first + count - 1
    for i in range(first, first + count):
        xi, yi = verts[i, 0], verts[i, 1]
        xj, yj = verts[j, 0], verts[j, 1]
        if (yi > y) != (yj > y) and x < xi + (y - yi) * (xj - xi) / (yj - yi):
            inside = not inside
        j = i
    return inside


@njit(cache=True)
def fence_contains(verts: np.ndarray, rings: np.ndarray, circles: np.ndarray, x: float,
                   y: float) -> bool:
    """Whether ``(x, y)`` is in the allowed set (always True for an empty fence)."""
    has_inclusion = False
    included = False
    for r in range(rings.shape[0]):
        inside = _in_ring(verts, rings[r, 0], rings[r, 1], x, y)
        if rings[r, 2] > 0:
            has_inclusion = True
            included = included or inside
        elif inside:
            return False
    for c in range(circles.shape[0]):
        d2 = (x - circles[c, 0]) ** 2 + (y - circles[c, 1]) ** 2
        r2 = circles[c, 2] ** 2
        if circles[c, 3] > 0:
            has_inclusion = True
            included = included or d2 <= r2
        elif d2 < r2:
            return False
    return included or not has_inclusion


@njit(cache=True)
def _next_crossing(verts: np.ndarray, rings: np.ndarray, circles: np.ndarray, x: float,
                   y: float, ux: float, uy: float, after: float) -> float:
    """The smallest ``t > after`` at which the ray ``(x, y) + t (ux, uy)`` meets a shape's
    boundary (inf if none)."""
    best = math.inf
    for r in range(rings.shape[0]):
        first, count = rings[r, 0], rings[r, 1]
        j = first + count - 1
        for i in range(first, first + count):
            ax, ay = verts[j, 0], verts[j, 1]
            ex, ey = verts[i, 0] - ax, verts[i, 1] - ay
            j = i
            den = ux * ey - uy * ex
            if abs(den) < 1e-12:  # parallel: a ray along an edge does not cross it
                continue
            wx, wy = ax - x, ay - y
            t = (wx * ey - wy * ex) / den
            s = (wx * uy - wy * ux) / den
            if after < t < best and 0.0 <= s <= 1.0:
                best = t
    for c in range(circles.shape[0]):
        px, py = x - circles[c, 0], y - circles[c, 1]
        b = px * ux + py * uy
        disc = b * b - (px * px + py * py - circles[c, 2] ** 2)
        if disc < 0.0:
            continue
        root = math.sqrt(disc)
        for t in (-b - root, -b + root):
            if after < t < best:
                best = t
    return best


@njit(cache=True)
def fence_ray_exit(verts: np.ndarray, rings: np.ndarray, circles: np.ndarray, x: float,
                   y: float, ux: float, uy: float) -> float:
    """How far the ray from ``(x, y)`` along the unit vector ``(ux, uy)`` stays in the
    allowed set: 0 if ``(x, y)`` is outside it, inf if the ray never leaves it.

    Every boundary crossing is visited in order and the point just past it tested, so an
    edge between two overlapping inclusion polygons is not taken for the fence.
    """
    if rings.shape[0] == 0 and circles.shape[0] == 0:
        return math.inf
    if not fence_contains(verts, rings, circles, x, y):
        return 0.0
    t = 0.0
    for _ in range(verts.shape[0] + 2 * circles.shape[0] + 1):
        t = _next_crossing(verts, rings, circles, x, y, ux, uy, t + 1e-9)
        if t == math.inf:
            return t
        probe = t + 1e-6
        if not fence_contains(verts, rings, circles, x + probe * ux, y + probe * uy):
            return t
    return t


# ----------------------------------------------------------------------------- shapes


class FenceItem(Protocol):
    """What a stored FENCE item offers (:class:`sim_vehicle.mission_server.StoredItem`)."""

    @property
    def command(self) -> int: ...

    @property
    def frame(self) -> int: ...

    @property
    def param1(self) -> float: ...

    @property
    def lat_deg(self) -> float: ...

    @property
    def lon_deg(self) -> float: ...


@dataclass(frozen=True, eq=False)
class Fence:
    """A geofence in local ENU metres: inclusion and exclusion polygons and circles.

    Parameters
    ----------
    inclusion_polygons, exclusion_polygons
        Each an ``(n, 2)`` array of vertices (``n >= 3``), in either winding order.
    inclusion_circles, exclusion_circles
        Each ``(cx_m, cy_m, radius_m)``.
    return_point_m
        The uploaded return point, or None (kept, not used).

    Examples
    --------
    >>> f = Fence.rectangle(Region(0.0, 100.0, 0.0, 50.0), 5.0)
    >>> f.contains(-4.0, 20.0), f.contains(-6.0, 20.0)
    (True, False)
    >>> f.ray_exit_m(50.0, 20.0, 0.0, 1.0)  # north to y = 55
    35.0
    """

    inclusion_polygons: tuple[np.ndarray, ...] = ()
    exclusion_polygons: tuple[np.ndarray, ...] = ()
    inclusion_circles: tuple[tuple[float, float, float], ...] = ()
    exclusion_circles: tuple[tuple[float, float, float], ...] = ()
    return_point_m: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        polys = []
        for name in ("inclusion_polygons", "exclusion_polygons"):
            value = tuple(np.asarray(p, dtype=float).reshape(-1, 2) for p in getattr(self, name))
            for p in value:
                if len(p) < 3 or not np.isfinite(p).all():
                    raise ValueError(f"{name}: a polygon needs 3 or more finite vertices")
            object.__setattr__(self, name, value)
            polys.append(value)
        for name in ("inclusion_circles", "exclusion_circles"):
            circles = tuple((float(cx), float(cy), float(r))
                            for cx, cy, r in getattr(self, name))
            for _, _, r in circles:
                if not (math.isfinite(r) and r > 0.0):
                    raise ValueError(f"{name}: radius must be > 0, got {r!r}")
            object.__setattr__(self, name, circles)
        rings = [(p, INCLUSION) for p in polys[0]] + [(p, EXCLUSION) for p in polys[1]]
        verts = (np.concatenate([p for p, _ in rings]) if rings else np.zeros((0, 2)))
        firsts = np.cumsum([0] + [len(p) for p, _ in rings])
        ring_rows = np.array([(firsts[k], len(p), kind) for k, (p, kind) in enumerate(rings)],
                             dtype=np.int64).reshape(-1, 3)
        circle_rows = np.array([(*c, INCLUSION) for c in self.inclusion_circles]
                               + [(*c, EXCLUSION) for c in self.exclusion_circles],
                               dtype=float).reshape(-1, 4)
        object.__setattr__(self, "_arrays", (np.ascontiguousarray(verts, dtype=float),
                                             np.ascontiguousarray(ring_rows),
                                             np.ascontiguousarray(circle_rows)))

    @property
    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(verts, rings, circles)`` for the compiled code (see the module docstring)."""
        arrays: tuple[np.ndarray, np.ndarray, np.ndarray] = object.__getattribute__(
            self, "_arrays")
        return arrays

    @property
    def empty(self) -> bool:
        """True when nothing is fenced."""
        return not (self.inclusion_polygons or self.exclusion_polygons
                    or self.inclusion_circles or self.exclusion_circles)

    def contains(self, x_m: float, y_m: float) -> bool:
        """Whether the point is in the allowed set."""
        return bool(fence_contains(*self.arrays, float(x_m), float(y_m)))

    def ray_exit_m(self, x_m: float, y_m: float, ux: float, uy: float) -> float:
        """How far the ray along the unit vector ``(ux, uy)`` stays inside (see
        :func:`fence_ray_exit`)."""
        return float(fence_ray_exit(*self.arrays, float(x_m), float(y_m), float(ux),
                                    float(uy)))

    def describe(self) -> str:
        """``"1 inclusion polygon, 1 exclusion circle"`` (for STATUSTEXT)."""
        parts = [(len(self.inclusion_polygons), "inclusion polygon"),
                 (len(self.exclusion_polygons), "exclusion polygon"),
                 (len(self.inclusion_circles), "inclusion circle"),
                 (len(self.exclusion_circles), "exclusion circle")]
        text = ", ".join(f"{n} {what}{'s' if n > 1 else ''}" for n, what in parts if n)
        return text or "none"

    @classmethod
    def rectangle(cls, region: Region, margin_m: float = 0.0) -> Fence:
        """``region`` grown by ``margin_m`` on every side, as one inclusion polygon."""
        x0, x1 = region.xmin - margin_m, region.xmax + margin_m
        y0, y1 = region.ymin - margin_m, region.ymax + margin_m
        return cls(inclusion_polygons=(np.array([(x0, y0), (x1, y0), (x1, y1), (x0, y1)]),))

    @classmethod
    def from_items(cls, items: Sequence[FenceItem], origin: Origin) -> Fence:
        """The fence that stored FENCE items describe (check them with :func:`check_fence`
        first: a malformed list raises ``ValueError``)."""
        result = check_fence(items)
        if result != mavlink.MAV_MISSION_ACCEPTED:
            raise ValueError(f"invalid fence items: {_result_name(result)}")
        if not items:
            return cls()
        lat = np.array([it.lat_deg for it in items])
        lon = np.array([it.lon_deg for it in items])
        x_m, y_m, _ = origin.to_local_many(lat, lon, 0.0)
        xy = np.column_stack([np.asarray(x_m, dtype=float), np.asarray(y_m, dtype=float)])
        polygons: dict[int, list[np.ndarray]] = {INCLUSION: [], EXCLUSION: []}
        circles: dict[int, list[tuple[float, float, float]]] = {INCLUSION: [], EXCLUSION: []}
        ret = None
        i = 0
        while i < len(items):
            cmd = items[i].command
            if cmd in POLYGON_COMMANDS:
                n = int(items[i].param1)
                polygons[POLYGON_COMMANDS[cmd]].append(xy[i:i + n].copy())
                i += n
                continue
            if cmd in CIRCLE_COMMANDS:
                circles[CIRCLE_COMMANDS[cmd]].append((xy[i, 0], xy[i, 1], float(items[i].param1)))
            else:
                ret = (float(xy[i, 0]), float(xy[i, 1]))
            i += 1
        return cls(tuple(polygons[INCLUSION]), tuple(polygons[EXCLUSION]),
                   tuple(circles[INCLUSION]), tuple(circles[EXCLUSION]), ret)


NO_FENCE = Fence()
"""The empty fence (everything allowed)."""


# ----------------------------------------------------------------------------- uploads


def _result_name(result: int) -> str:
    entry = mavlink.enums["MAV_MISSION_RESULT"].get(result)
    return entry.name if entry is not None else str(result)


def check_fence_item(item: FenceItem) -> int:
    """``MAV_MISSION_ACCEPTED``, or the ``MAV_MISSION_RESULT`` that refuses one FENCE item:
    UNSUPPORTED (not a fence command), UNSUPPORTED_FRAME (not a global frame),
    INVALID_PARAM5_X / INVALID_PARAM6_Y (latitude / longitude), INVALID_PARAM1 (a vertex
    count that is not an integer of at least 3, a radius that is not positive)."""
    if item.command not in FENCE_COMMANDS:
        return mavlink.MAV_MISSION_UNSUPPORTED
    if item.frame not in GLOBAL_FRAMES:
        return mavlink.MAV_MISSION_UNSUPPORTED_FRAME
    if not (math.isfinite(item.lat_deg) and abs(item.lat_deg) <= 90.0):
        return mavlink.MAV_MISSION_INVALID_PARAM5_X
    if not (math.isfinite(item.lon_deg) and abs(item.lon_deg) <= 180.0):
        return mavlink.MAV_MISSION_INVALID_PARAM6_Y
    p1 = item.param1
    if item.command in POLYGON_COMMANDS and not (math.isfinite(p1) and p1 >= 3
                                                 and p1 == int(p1)):
        return mavlink.MAV_MISSION_INVALID_PARAM1
    if item.command in CIRCLE_COMMANDS and not (math.isfinite(p1) and p1 > 0):
        return mavlink.MAV_MISSION_INVALID_PARAM1
    return mavlink.MAV_MISSION_ACCEPTED


def check_fence(items: Sequence[FenceItem]) -> int:
    """``MAV_MISSION_ACCEPTED`` for a well-formed FENCE upload, else why not (the checks
    ArduPilot's fence loader makes): every item passes :func:`check_fence_item`; a
    polygon's vertices come in a row, all with its command and vertex count
    (INVALID_PARAM1 otherwise); at most one return point (MAV_MISSION_INVALID)."""
    returns = 0
    i = 0
    while i < len(items):
        result = check_fence_item(items[i])
        if result != mavlink.MAV_MISSION_ACCEPTED:
            return result
        cmd = items[i].command
        if cmd in POLYGON_COMMANDS:
            n = int(items[i].param1)
            run = items[i:i + n]
            if len(run) < n or any(it.command != cmd or it.param1 != items[i].param1
                                   for it in run):
                return mavlink.MAV_MISSION_INVALID_PARAM1
            for it in run[1:]:
                result = check_fence_item(it)
                if result != mavlink.MAV_MISSION_ACCEPTED:
                    return result
            i += n
            continue
        if cmd == mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT:
            returns += 1
            if returns > 1:
                return mavlink.MAV_MISSION_INVALID
        i += 1
    return mavlink.MAV_MISSION_ACCEPTED


# ----------------------------------------------------------------------------- reports


class FenceBody(Protocol):
    """The fence counters of a :class:`sim_vehicle.body.SimBody`."""

    @property
    def fence_attempts(self) -> int: ...

    @property
    def fence_breaches(self) -> int: ...

    @property
    def fence_outside(self) -> bool: ...

    @property
    def fence_limited(self) -> bool: ...

    @property
    def fence_event_t_s(self) -> float: ...


@dataclass
class FenceChange:
    """What changed since the last :meth:`FenceMonitor.update` (for STATUSTEXT)."""

    attempts: int = 0
    """New breach attempts (the guard braked before the fence)."""
    breached: bool = False
    """The vehicle got outside the fence."""
    returned: bool = False
    """The vehicle is back inside the fence."""

    def __bool__(self) -> bool:
        return bool(self.attempts or self.breached or self.returned)


class FenceMonitor:
    """The vehicle's fence counters, kept across body rebuilds, as ``FENCE_STATUS``.

    ``FENCE_STATUS`` fields (common dialect): ``breach_status`` 1 while the vehicle is
    outside the fence; ``breach_count`` the breach attempts and breaches so far (each
    episode of braking before the fence counts once; ArduPilot counts only breaches,
    our guard prevents those); ``breach_type`` ``FENCE_BREACH_BOUNDARY`` once there was
    one; ``breach_time`` the ``time_boot_ms`` of the latest; ``breach_mitigation``
    ``FENCE_MITIGATE_VEL_LIMIT`` while the guard is limiting the velocity, else
    ``FENCE_MITIGATE_NONE``.
    """

    def __init__(self) -> None:
        self.attempts = 0
        self.breaches = 0
        self.outside = False
        self.limiting = False
        self.last_event_ms = 0
        self._body: object | None = None
        self._seen = (0, 0)

    @property
    def count(self) -> int:
        return self.attempts + self.breaches

    def update(self, body: FenceBody) -> FenceChange:
        """Read the body's counters (a new body starts its own from zero)."""
        if body is not self._body:
            self._body, self._seen = body, (0, 0)
        attempts, breaches = body.fence_attempts, body.fence_breaches
        change = FenceChange(attempts=attempts - self._seen[0])
        if breaches > self._seen[1]:
            change.breached = True
        outside = body.fence_outside
        change.returned = self.outside and not outside
        self.attempts += change.attempts
        self.breaches += breaches - self._seen[1]
        self._seen = (attempts, breaches)
        self.outside = outside
        self.limiting = body.fence_limited
        if change.attempts or change.breached:
            self.last_event_ms = int(round(body.fence_event_t_s * 1000.0)) & 0xFFFFFFFF
        return change

    def message(self) -> Any:
        """The current ``FENCE_STATUS``."""
        return mavlink.MAVLink_fence_status_message(
            1 if self.outside else 0, min(self.count, 0xFFFF),
            mavlink.FENCE_BREACH_BOUNDARY if self.count else mavlink.FENCE_BREACH_NONE,
            self.last_event_ms,
            mavlink.FENCE_MITIGATE_VEL_LIMIT if self.limiting else mavlink.FENCE_MITIGATE_NONE)
