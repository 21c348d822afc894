"""Is a mission file one an aircraft should fly? (``econdor import``)

:func:`check_plausible` goes past the format (:mod:`.mission_files` checks that every field
fits its message): altitudes below home, far above it or off the Earth's surface; positions
farther from home than any multicopter flies; waypoints outside the file's own geofence.
"""

from __future__ import annotations

import math

from econdor_gcs.errors import EcondorError
from econdor_gcs.files.autopilot_files import (
    FENCE_CIRCLE_IN,
    FENCE_CIRCLE_OUT,
    FENCE_VERTEX_IN,
    FENCE_VERTEX_OUT,
    RALLY_POINT,
    MissionFile,
    is_global_frame,
    is_home_item,
)
from econdor_gcs.link.codec import mavlink
from econdor_gcs.link.transfer import MissionItemSpec

__all__ = ["MAX_RANGE_M", "check_plausible"]

MAX_RANGE_M = 50_000.0
"""The farthest a mission's positions may lie from its home: beyond any multicopter's
range (30 min at 15 m/s is 27 km there and back), where a coordinate typo lands."""
_POSITIONED = frozenset(
    k for k, e in mavlink.enums["MAV_CMD"].items()
    if e.name.startswith("MAV_CMD_NAV_") and k not in (
        mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, FENCE_VERTEX_IN, FENCE_VERTEX_OUT,
        FENCE_CIRCLE_IN, FENCE_CIRCLE_OUT, RALLY_POINT)
) | {mavlink.MAV_CMD_WAYPOINT_USER_1}
"""Commands whose x / y / z are where the vehicle goes."""
_RELATIVE = frozenset({mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                       mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                       mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
                       mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT})
_AMSL = frozenset({mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT})


def _cmd_name(command: int) -> str:
    entry = mavlink.enums["MAV_CMD"].get(command)
    return entry.name.removeprefix("MAV_CMD_") if entry is not None else str(command)


def check_plausible(mfile: MissionFile, name: str) -> None:
    """Refuse (one :class:`EcondorError` line naming the item) a mission no aircraft should
    fly, though every field fits its message: an altitude below home or above
    :data:`~econdor_gcs.config.MAX_ALT_M` over it (or an AMSL one off the Earth's
    surface), a position more than :data:`MAX_RANGE_M` from home, a mission waypoint outside
    the file's own inclusion geofence or inside one of its exclusions.

    Home is the plan's ``plannedHomePosition`` (WPL: item 0, when it is a position), else
    the first position of the mission.
    """
    from shapely.geometry import Point, Polygon
    from shapely.ops import unary_union

    from econdor_gcs.config import MAX_ALT_M, MAX_AMSL_M, MIN_AMSL_M
    from econdor_gcs.core.geodesy import Origin

    items = mfile.items
    placed = [it for it in items if it.command in _POSITIONED and is_global_frame(it.frame)
              and (it.x or it.y)]
    if not placed:
        return
    home_item = items[0] if is_home_item(items) and (items[0].x or items[0].y) else placed[0]
    home_amsl = mfile.home_alt_amsl_m
    if home_amsl is None and is_home_item(items) and items[0].frame in _AMSL:
        home_amsl = items[0].z
    origin = Origin(home_item.x / 1e7, home_item.y / 1e7, home_amsl or 0.0)

    def local(it: MissionItemSpec) -> tuple[float, float]:
        x, y, _ = origin.to_local(it.x / 1e7, it.y / 1e7, 0.0)
        return x, y

    skip = id(items[0]) if is_home_item(items) else None
    placed = [it for it in placed if id(it) != skip]
    for it in placed:
        where = f"{name}: mission item {it.seq} ({_cmd_name(it.command)})"
        if it.frame in _RELATIVE:
            above = it.z
        elif home_amsl is not None:
            above = it.z - home_amsl
        else:
            above = None
        if it.frame in _AMSL and not MIN_AMSL_M <= it.z <= MAX_AMSL_M:
            raise EcondorError(f"{where}: altitude {it.z:g} m above mean sea level is off the "
                               f"Earth's surface ({MIN_AMSL_M:g}..{MAX_AMSL_M:g} m)")
        if above is not None and above < 0:
            raise EcondorError(f"{where}: altitude {above:g} m is below home")
        if above is not None and above > MAX_ALT_M:
            raise EcondorError(f"{where}: altitude {above:g} m above home is more than "
                               f"{MAX_ALT_M:g} m")
    for kind, group in (("mission item", placed), ("fence vertex", mfile.fence),
                        ("rally point", mfile.rally)):
        for it in group:
            d = math.hypot(*local(it))
            if d > MAX_RANGE_M:
                raise EcondorError(f"{name}: {kind} {it.seq} is {d / 1000:,.0f} km from home "
                                   f"(at most {MAX_RANGE_M / 1000:g} km)")
    from shapely.geometry.base import BaseGeometry

    inclusions: list[BaseGeometry] = []
    exclusions: list[BaseGeometry] = []
    k = 0
    fence = mfile.fence
    while k < len(fence):
        it = fence[k]
        if it.command in (FENCE_VERTEX_IN, FENCE_VERTEX_OUT):
            n = max(1, int(it.param1))
            poly = Polygon([local(v) for v in fence[k:k + n]])
            (inclusions if it.command == FENCE_VERTEX_IN else exclusions).append(poly)
            k += n
            continue
        if it.command in (FENCE_CIRCLE_IN, FENCE_CIRCLE_OUT):
            circle = Point(local(it)).buffer(it.param1, 64)
            (inclusions if it.command == FENCE_CIRCLE_IN else exclusions).append(circle)
        k += 1
    if not inclusions and not exclusions:
        return
    inside = unary_union(inclusions) if inclusions else None
    outside = unary_union(exclusions) if exclusions else None
    for it in placed:
        pt = Point(local(it))
        where = f"{name}: mission item {it.seq} ({_cmd_name(it.command)})"
        if inside is not None and not inside.buffer(1e-6).contains(pt):
            raise EcondorError(f"{where} is {inside.distance(pt):,.0f} m outside the file's "
                               "own inclusion geofence")
        if outside is not None and outside.contains(pt):
            raise EcondorError(f"{where} is inside the file's own exclusion geofence")
