"""A ``sim-vehicle`` process keeps inside an uploaded fence (MAVLink, as a GCS sees it)."""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sim_vehicle.fence import FENCE_HARD_MARGIN_M, FENCE_MARGIN_M
from tests.helpers.fence import (
    ORIGIN,
    U_SHAPE,
    distance_outside_polygon,
    plan_geofence_items,
    u_shape_plan,
)
from tests.helpers.vehicles import GcsLink, VehicleProcess, item_int

FENCE = mavlink.MAV_MISSION_TYPE_FENCE
GEODESY_M = 0.02
"""Positions travel as degE7 integers (about a centimetre)."""


def _ll(x_m: float, y_m: float) -> tuple[float, float]:
    lat, lon, _ = ORIGIN.to_global(x_m, y_m)
    return lat, lon


def _waypoints(*points: tuple[float, float], alt_m: float = 20.0) -> list:
    items = [item_int(0, mavlink.MAV_CMD_NAV_TAKEOFF, alt=alt_m, current=1)]
    items += [item_int(k, mavlink.MAV_CMD_NAV_WAYPOINT, *_ll(*p), alt_m)
              for k, p in enumerate(points, start=1)]
    return items


def _fly_until(gcs: GcsLink, done, timeout_s: float = 30.0) -> list:
    """Every message until ``done(msg)``."""
    seen = []
    while True:
        m = gcs.recv_match(("GLOBAL_POSITION_INT", "FENCE_STATUS", "STATUSTEXT",
                            "MISSION_ITEM_REACHED", "EXTENDED_SYS_STATE"), timeout=timeout_s)
        seen.append(m)
        if done(m):
            return seen


def _positions(msgs: list) -> np.ndarray:
    gpi = [m for m in msgs if m.get_type() == "GLOBAL_POSITION_INT"]
    x, y, _ = ORIGIN.to_local_many(np.array([m.lat for m in gpi]) / 1e7,
                                   np.array([m.lon for m in gpi]) / 1e7)
    return np.column_stack([x, y])


def _texts(msgs: list) -> list[str]:
    return [m.text for m in msgs if m.get_type() == "STATUSTEXT"]


def test_a_vehicle_told_to_fly_through_the_fence_stops_inside_it():
    home = ",".join(str(v) for v in (*_ll(20.0, 15.0), ORIGIN.alt_m))
    with VehicleProcess("--speedup", "50", "--home", home, connect="udpin:127.0.0.1:0") as proc, \
            GcsLink.to("127.0.0.1", proc.port) as gcs:
        gcs.send(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))
        gcs.recv_match("HEARTBEAT", timeout=10)
        # the fence of a QGroundControl .plan: a U (the notch 40 < x < 60, y > 30 is
        # outside) and an exclusion circle in its left arm
        fence = [item_int(k, it.command, it.lat_deg, it.lon_deg, p1=it.param1,
                          frame=it.frame) for k, it in enumerate(plan_geofence_items(
                              u_shape_plan()))]
        for it in fence:
            it.mission_type = FENCE
        assert gcs.upload(1, fence, mission_type=FENCE) == mavlink.MAV_MISSION_ACCEPTED
        gcs.recv_match("STATUSTEXT", lambda m: m.text.startswith("fence: 1 inclusion"))
        assert len(gcs.download(1, mission_type=FENCE)) == len(fence)

        # PX4's feasibility check: a waypoint inside the notch refuses the mission start
        assert gcs.upload(1, _waypoints((20.0, 40.0), (50.0, 60.0))) == 0
        assert gcs.command_long(1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        gcs.keep = True  # the STATUSTEXT comes before the COMMAND_ACK
        ack = gcs.command_long(1, mavlink.MAV_CMD_MISSION_START)
        assert ack.result == mavlink.MAV_RESULT_DENIED
        assert "Geofence violation for waypoint 2" in _texts(gcs.received)
        gcs.keep = False

        # waypoints inside, but the leg 1 -> 2 crosses the notch: the vehicle brakes at the
        # fence, gives the waypoint up and flies on around the notch
        mission = _waypoints((20.0, 85.0), (80.0, 85.0), (20.0, 15.0), (80.0, 15.0),
                             (80.0, 85.0))
        assert gcs.upload(1, mission) == mavlink.MAV_MISSION_ACCEPTED
        gcs.flush()
        assert gcs.command_long(1, mavlink.MAV_CMD_MISSION_START).result == 0
        msgs = _fly_until(gcs, lambda m: m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 5)
        xy = _positions(msgs)
        outside = distance_outside_polygon(U_SHAPE, xy[:, 0], xy[:, 1])
        assert outside.max() <= -FENCE_HARD_MARGIN_M + GEODESY_M
        left_arm = xy[(xy[:, 1] > 40.0) & (xy[:, 0] < 50.0)]
        assert left_arm[:, 0].max() > 40.0 - FENCE_MARGIN_M - 0.5  # it went for the notch
        assert math.dist(xy[-1], (80.0, 85.0)) < 2.0  # and on around it to the last one
        status = [m for m in msgs if m.get_type() == "FENCE_STATUS"]
        assert status and status[-1].breach_count == 1 and status[-1].breach_status == 0
        assert status[-1].breach_type == mavlink.FENCE_BREACH_BOUNDARY
        assert any(m.breach_mitigation == mavlink.FENCE_MITIGATE_VEL_LIMIT for m in status)
        assert any(t.startswith("fence: braking before the fence") for t in _texts(msgs))

        # RTL: home (20, 15) is behind the notch too; the vehicle stops at it and lands
        gcs.flush()
        assert gcs.command_long(1, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH).result == 0
        msgs = _fly_until(gcs, lambda m: m.get_type() == "EXTENDED_SYS_STATE"
                          and m.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND)
        xy = _positions(msgs)
        assert distance_outside_polygon(U_SHAPE, xy[:, 0], xy[:, 1]).max() \
            <= -FENCE_HARD_MARGIN_M + GEODESY_M
        assert 60.0 < xy[-1, 0] < 60.0 + FENCE_MARGIN_M + 0.5  # at the notch's east edge
        gcs.send(mavlink.MAVLink_command_long_message(
            1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, mavlink.MAVLINK_MSG_ID_FENCE_STATUS,
            0, 0, 0, 0, 0, 0))
        assert gcs.recv_match("FENCE_STATUS", timeout=5).breach_count == 2
