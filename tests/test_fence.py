"""The geofence: shapes, uploads, and the flight logic's guard (in-process, no MAVLink)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.config import load_mission
from econdor_gcs.core.fields import GaussianSumField
from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.geometry import Region
from econdor_gcs.core.tasks import Phase, TraceTask, Waypoint
from econdor_gcs.link.items import MISSION_FENCE_MARGIN_M
from econdor_gcs.link.transfer import fence_items
from econdor_lab.inprocess import InProcessExecutor
from sim_vehicle.body import SimBody
from sim_vehicle.fence import (
    FENCE_HARD_MARGIN_M,
    Fence,
    check_fence,
)
from sim_vehicle.fence import (
    FENCE_MARGIN_M as STOP_MARGIN_M,
)
from sim_vehicle.kinematics import VehicleLimits
from sim_vehicle.mission_server import FENCE, MissionServer, StoredItem
from sim_vehicle.tracer import TracerParams, run_task_batch

ORIGIN = Origin(47.397742, 8.545594, 488.0)
REGION = Region(0.0, 100.0, 0.0, 100.0)
LIMITS = VehicleLimits(max_speed_mps=12.0, max_accel_mps2=5.0)

# A U open to the north: the notch 40 < x < 60, y > 30 is outside
U_SHAPE = np.array([(0, 0), (100, 0), (100, 100), (60, 100), (60, 30), (40, 30), (40, 100),
                    (0, 100)], dtype=float)


def _flat(x, y):
    return 0.0 * x


def _body(x: float, y: float, fence: Fence, region: Region = REGION) -> SimBody:
    return SimBody(_flat, region, x, y, limits=LIMITS, fence=fence)


def _distance_outside_polygon(poly: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Signed distance to the polygon boundary: > 0 outside, < 0 inside (shapely-free)."""
    fence = Fence(inclusion_polygons=(poly,))
    d = np.full(len(x), np.inf)
    for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        ex, ey = bx - ax, by - ay
        t = np.clip(((x - ax) * ex + (y - ay) * ey) / (ex * ex + ey * ey), 0.0, 1.0)
        d = np.minimum(d, np.hypot(x - ax - t * ex, y - ay - t * ey))
    inside = np.array([fence.contains(a, b) for a, b in zip(x, y, strict=True)])
    return np.where(inside, -d, d)


# ----------------------------------------------------------------------------- shapes


def test_concave_polygon_contains_and_ray_exit():
    f = Fence(inclusion_polygons=(U_SHAPE,))
    assert f.contains(20.0, 80.0) and f.contains(80.0, 80.0) and f.contains(50.0, 10.0)
    assert not f.contains(50.0, 50.0) and not f.contains(-1.0, 50.0)
    # east from the left arm: out at the notch, x = 40
    assert f.ray_exit_m(20.0, 80.0, 1.0, 0.0) == pytest.approx(20.0)
    # east along the bottom, under the notch: out at x = 100
    assert f.ray_exit_m(20.0, 10.0, 1.0, 0.0) == pytest.approx(80.0)
    assert f.ray_exit_m(50.0, 50.0, 1.0, 0.0) == 0.0  # outside already
    assert Fence().ray_exit_m(0.0, 0.0, 1.0, 0.0) == math.inf


def test_union_of_inclusion_polygons_has_no_inner_edges():
    a = np.array([(0, 0), (60, 0), (60, 40), (0, 40)], dtype=float)
    b = np.array([(40, 0), (100, 0), (100, 40), (40, 40)], dtype=float)
    f = Fence(inclusion_polygons=(a, b))
    assert f.contains(50.0, 20.0) and f.contains(90.0, 20.0)
    # from inside a, east: the edges x = 40 (b's) and x = 60 (a's) are inside the union
    assert f.ray_exit_m(10.0, 20.0, 1.0, 0.0) == pytest.approx(90.0)


def test_exclusion_shapes_cut_holes():
    hole = np.array([(40, 40), (60, 40), (60, 60), (40, 60)], dtype=float)
    f = Fence(inclusion_polygons=(U_SHAPE[[0, 1, 2, 7]],), exclusion_polygons=(hole,),
              exclusion_circles=((80.0, 80.0, 5.0),), inclusion_circles=((150.0, 50.0, 10.0),))
    assert not f.contains(50.0, 50.0) and not f.contains(80.0, 83.0)
    assert f.contains(150.0, 55.0) and not f.contains(130.0, 50.0)
    assert f.ray_exit_m(10.0, 50.0, 1.0, 0.0) == pytest.approx(30.0)  # the hole at x = 40
    assert f.ray_exit_m(80.0, 60.0, 0.0, 1.0) == pytest.approx(15.0)  # the circle at y = 75
    # only exclusions: everywhere else is allowed
    g = Fence(exclusion_circles=((0.0, 0.0, 10.0),))
    assert g.contains(50.0, 0.0) and not g.contains(1.0, 1.0)
    assert g.ray_exit_m(-50.0, 0.0, 1.0, 0.0) == pytest.approx(40.0)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="3 or more"):
        Fence(inclusion_polygons=(np.array([(0.0, 0.0), (1.0, 1.0)]),))
    with pytest.raises(ValueError, match="radius"):
        Fence(exclusion_circles=((0.0, 0.0, 0.0),))


# ----------------------------------------------------------------------------- uploads


def _item(cmd: int, x_m: float, y_m: float, p1: float,
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
            items.append(_item(cmd, x, y, float(len(poly["polygon"]))))
    for c in geofence["circles"]:
        cmd = (mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION if c["inclusion"]
               else mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION)
        x, y, _ = ORIGIN.to_local(*c["circle"]["center"])
        items.append(_item(cmd, x, y, c["circle"]["radius"]))
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


def test_a_qgc_plan_geofence_becomes_the_same_shapes():
    items = plan_geofence_items(u_shape_plan())
    assert check_fence(items) == mavlink.MAV_MISSION_ACCEPTED
    f = Fence.from_items(items, ORIGIN)
    assert len(f.inclusion_polygons) == 1 and len(f.exclusion_circles) == 1
    np.testing.assert_allclose(f.inclusion_polygons[0], U_SHAPE, atol=0.02)
    cx, cy, r = f.exclusion_circles[0]
    assert (cx, cy, r) == pytest.approx((10.0, 50.0, 4.0), abs=0.02)
    assert not f.contains(10.0, 52.0) and f.contains(10.0, 56.0)


V = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
C = mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION
R = mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT


@pytest.mark.parametrize(("items", "result"), [
    ([_item(V, 0, 0, 2), _item(V, 9, 0, 2)], mavlink.MAV_MISSION_INVALID_PARAM1),
    ([_item(V, 0, 0, 3), _item(V, 9, 0, 3)], mavlink.MAV_MISSION_INVALID_PARAM1),  # short
    ([_item(V, 0, 0, 3), _item(V, 9, 0, 4), _item(V, 9, 9, 3)],
     mavlink.MAV_MISSION_INVALID_PARAM1),  # counts differ
    ([_item(V, 0, 0, 3), _item(C, 9, 0, 5.0), _item(V, 9, 9, 3)],
     mavlink.MAV_MISSION_INVALID_PARAM1),  # a circle between the vertices
    ([_item(C, 0, 0, 0.0)], mavlink.MAV_MISSION_INVALID_PARAM1),
    ([_item(C, 0, 0, 5.0, frame=mavlink.MAV_FRAME_LOCAL_NED)],
     mavlink.MAV_MISSION_UNSUPPORTED_FRAME),
    ([_item(mavlink.MAV_CMD_NAV_WAYPOINT, 0, 0, 0.0)], mavlink.MAV_MISSION_UNSUPPORTED),
    ([_item(R, 0, 0, 0.0), _item(R, 1, 1, 0.0)], mavlink.MAV_MISSION_INVALID),
    ([_item(R, 0, 0, 0.0), _item(C, 1, 1, 3.0)], mavlink.MAV_MISSION_ACCEPTED),
])
def test_fence_upload_checks(items, result):
    assert check_fence(items) == result


def _upload(server: MissionServer, items: list[StoredItem]) -> int:
    rx = []
    msgs = [mavlink.MAVLink_mission_item_int_message(1, 1, k, it.frame, it.command, 0, 1,
                                                     it.param1, 0, 0, 0, it.x, it.y, 0.0,
                                                     FENCE) for k, it in enumerate(items)]
    for m in [mavlink.MAVLink_mission_count_message(1, 1, len(msgs), FENCE), *msgs]:
        m._header = mavlink.MAVLink_header(m.id, srcSystem=255, srcComponent=190)
        rx = server.receive(m, 0.0)
    assert rx[-1].get_type() == "MISSION_ACK"
    return int(rx[-1].type)


def test_the_vehicle_refuses_a_malformed_fence_and_keeps_the_old_one():
    s = MissionServer()
    assert _upload(s, plan_geofence_items(u_shape_plan())) == mavlink.MAV_MISSION_ACCEPTED
    stored = list(s.stores[FENCE])
    # two vertices of a "triangle", then a circle: refused at the circle, nothing changed
    bad = [_item(V, 0, 0, 3), _item(V, 9, 0, 3), _item(C, 5, 5, 2.0)]
    assert _upload(s, bad) == mavlink.MAV_MISSION_INVALID_PARAM1
    assert s.stores[FENCE] == stored


def test_the_lab_flies_inside_the_fence_the_station_uploads():
    mission = load_mission("missions/demo.yaml")
    ex = InProcessExecutor(mission, mission.build_field(1))
    station = Fence.from_items(fence_items(mission.origin, mission.region, MISSION_FENCE_MARGIN_M),
                               mission.origin)
    np.testing.assert_array_equal(ex.fence.arrays[0], station.arrays[0])
    assert all(b.fence is ex.fence for b in ex.bodies)
    r = mission.region
    # the area plus 5 m (to the centimetre the degE7 items carry)
    for x, y, inside in [(r.xmin - 4.97, 50.0, True), (r.xmin - 5.03, 50.0, False),
                         (50.0, r.ymax + 4.97, True), (50.0, r.ymax + 5.03, False)]:
        assert ex.fence.contains(x, y) is inside


# ----------------------------------------------------------------------------- the guard


def _excursion_outside(fence: Fence, rows: np.ndarray) -> float:
    """Largest distance outside the fence's single inclusion polygon (negative: inside)."""
    return float(_distance_outside_polygon(fence.inclusion_polygons[0], rows[:, 1],
                                           rows[:, 2]).max())


def test_at_full_speed_toward_the_fence_the_vehicle_stops_inside_it():
    fence = Fence.rectangle(Region(0.0, 100.0, 0.0, 100.0))
    body = _body(10.0, 50.0, fence)
    rows, outcome = run_task_batch(body, Waypoint(150.0, 50.0),
                                   TracerParams(transit_speed_mps=12.0))
    assert outcome.status == "unreachable"
    assert rows[:, 1].max() <= 100.0 - FENCE_HARD_MARGIN_M
    assert rows[:, 1].max() >= 100.0 - STOP_MARGIN_M - 0.5  # it did go for it
    speed = np.hypot(*np.diff(rows[:, 1:3], axis=0).T) / body.dt_s
    assert speed.max() > 11.0  # at full speed
    assert body.fence_attempts == 1 and body.fence_breaches == 0 and not body.fence_outside


def test_a_waypoint_behind_a_notch_is_given_up_at_the_fence():
    fence = Fence(inclusion_polygons=(U_SHAPE,))
    body = _body(20.0, 80.0, fence)
    rows, outcome = run_task_batch(body, Waypoint(80.0, 80.0))
    assert outcome.status == "unreachable"
    assert _excursion_outside(fence, rows) <= -FENCE_HARD_MARGIN_M
    assert rows[-1, 1] > 40.0 - STOP_MARGIN_M - 0.5  # stopped at the notch
    # the next waypoint, around the notch's bottom, is reached
    rows2, outcome2 = run_task_batch(body, Waypoint(20.0, 10.0))
    assert outcome2.status == "reached" and body.fence_attempts == 1


def test_passing_between_overlapping_inclusion_polygons_is_not_a_breach():
    a = np.array([(0, 0), (60, 0), (60, 40), (0, 40)], dtype=float)
    b = np.array([(40, 0), (100, 0), (100, 40), (40, 40)], dtype=float)
    body = _body(5.0, 20.0, Fence(inclusion_polygons=(a, b)), Region(0.0, 100.0, 0.0, 40.0))
    _, outcome = run_task_batch(body, Waypoint(95.0, 20.0), TracerParams(transit_speed_mps=12))
    assert outcome.status == "reached" and body.fence_attempts == 0


def test_an_exclusion_circle_on_the_way_stops_the_vehicle_before_it():
    fence = Fence(exclusion_circles=((50.0, 50.0, 10.0),))
    body = _body(10.0, 50.0, fence)
    rows, outcome = run_task_batch(body, Waypoint(90.0, 50.0))
    assert outcome.status == "unreachable"
    d = np.hypot(rows[:, 1] - 50.0, rows[:, 2] - 50.0)
    assert d.min() >= 10.0 + FENCE_HARD_MARGIN_M


def _bump(cx: float, cy: float, sigma_m: float = 15.0) -> GaussianSumField:
    return GaussianSumField(REGION, np.array([[cx, cy]]), np.array([sigma_m]), np.array([1.0]),
                            scale=100.0)


def test_a_trace_that_meets_the_fence_inside_the_area_turns_at_it():
    # the fence cuts a corner off the area; the contour (a circle of radius 20 m) runs
    # through the cut: the trace meets the fence, traces the other way, and stays inside
    fence = Fence(inclusion_polygons=(np.array([(-5, -5), (105, -5), (105, 40), (40, 105),
                                                (-5, 105)], dtype=float),))
    field = _bump(65.0, 65.0)
    level = float(field(85.0, 65.0))
    body = SimBody(field, REGION, 40.0, 40.0, limits=LIMITS, fence=fence)
    rows, outcome = run_task_batch(body, TraceTask(level, 45.0, 65.0, 10.0, 0.0, 1),
                                   TracerParams())
    assert outcome.status == "boundary" and outcome.traced_m > 60.0
    assert _excursion_outside(fence, rows) <= -FENCE_HARD_MARGIN_M
    assert body.fence_breaches == 0


# ----------------------------------------------------------------------------- the area


def _area_excursion_m(rows: np.ndarray, region: Region) -> float:
    dx = np.maximum.reduce([region.xmin - rows[:, 1], np.zeros(len(rows)),
                            rows[:, 1] - region.xmax])
    dy = np.maximum.reduce([region.ymin - rows[:, 2], np.zeros(len(rows)),
                            rows[:, 2] - region.ymax])
    return float(np.hypot(dx, dy).max())


def test_search_near_a_corner_stays_inside_the_area():
    # a level that is not there: the whole search (probe legs, descent, spiral) runs in the
    # corner; before the guard it flew up to 3 m out of the area
    field = _bump(50.0, 50.0)
    body = SimBody(field, REGION, 30.0, 30.0, limits=LIMITS,
                   fence=Fence.rectangle(REGION, 5.0))
    rows, outcome = run_task_batch(body, TraceTask(1e-6, 0.0, 0.0, 10.0, 0.0, 1))
    assert outcome.status == "not_found"
    assert (rows[:, 4] == Phase.SEARCH).sum() > 100
    assert _area_excursion_m(rows, REGION) <= 1e-3
