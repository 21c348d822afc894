"""sim-vehicle: the pure mission server, then the vehicle over real loopback sockets."""

from __future__ import annotations

import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink
from vehicle_helpers import (
    DEMO,
    GcsLink,
    VehicleProcess,
    inproc_vehicle,
    item_int,
    sim_vehicle_cmd,
    wait_for,
)

from econdor_gcs.config import load_mission
from econdor_gcs.core.tasks import Phase
from econdor_gcs.link.reports import trace_report
from sim_vehicle.mission_server import MissionServer
from sim_vehicle.state import PARAM_NAMES

GCS = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
DECODER = mavlink.MAVLink(None)
MISSION = load_mission(DEMO)
ORIGIN = MISSION.origin


def rx(msg):
    """What the vehicle would see: msg packed by the GCS and decoded (sets src ids)."""
    return DECODER.decode(bytearray(msg.pack(GCS)))


def ll(x, y):
    lat, lon, _ = ORIGIN.to_global(x, y)
    return lat, lon


def three_items():
    return [
        item_int(0, mavlink.MAV_CMD_NAV_TAKEOFF, alt=20, current=1),
        item_int(1, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(30, 40), 20, p4=float("nan")),
        item_int(2, 31000, *ll(50, 50), 25, p1=42.5, p2=8, p3=100, p4=7),
    ]


def upload(server, items, now=0.0):
    replies = server.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, len(items), 0)), now)
    for it in items:
        assert replies[-1].get_type() == "MISSION_REQUEST_INT"
        assert replies[-1].seq == it.seq
        replies = server.receive(rx(it), now)
    return replies


def fields(m):
    d = m.to_dict()
    for k in ("mavpackettype", "target_system", "target_component"):
        d.pop(k, None)
    return d


# ------------------------------------------------------------------ pure state machine


def test_upload_then_download_identical():
    s = MissionServer()
    items = three_items()
    replies = upload(s, items)
    assert [r.get_type() for r in replies] == ["MISSION_ACK"]
    assert replies[0].type == mavlink.MAV_MISSION_ACCEPTED
    assert replies[0].target_system == 255 and replies[0].target_component == 190
    assert [e.kind for e in s.events] == ["uploaded"]
    count = s.receive(rx(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), 1.0)
    assert count[0].get_type() == "MISSION_COUNT" and count[0].count == 3
    for it in items:
        got = s.receive(rx(mavlink.MAVLink_mission_request_int_message(1, 1, it.seq, 0)), 1.0)
        a, b = fields(rx(got[0])), fields(rx(it))
        if math.isnan(b["param4"]):
            assert math.isnan(a.pop("param4")) and b.pop("param4") is not None
        assert a == b
    # legacy MISSION_REQUEST gets a float MISSION_ITEM
    got = s.receive(rx(mavlink.MAVLink_mission_request_message(1, 1, 2, 0)), 1.0)[0]
    assert got.get_type() == "MISSION_ITEM"
    assert got.x == pytest.approx(items[2].x / 1e7, abs=1e-5)
    assert got.param1 == pytest.approx(42.5) and got.command == 31000


def test_legacy_item_upload_round_trips_floats_and_types_are_separate():
    s = MissionServer()
    s.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 1, 0)), 0.0)
    legacy = mavlink.MAVLink_mission_item_message(1, 1, 0, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                                                  16, 1, 1, 0, 0, 0, 0, 47.3981, 8.5461, 30, 0)
    ack = s.receive(rx(legacy), 0.1)
    assert ack[0].type == mavlink.MAV_MISSION_ACCEPTED
    back = s.receive(rx(mavlink.MAVLink_mission_request_message(1, 1, 0, 0)), 0.2)[0]
    assert (back.x, back.y, back.frame) == (rx(legacy).x, rx(legacy).y, legacy.frame)
    # a fence upload (a triangle) does not touch the mission
    fence = [item_int(k, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, lat, lon, p1=3,
                      frame=mavlink.MAV_FRAME_GLOBAL_INT)
             for k, (lat, lon) in enumerate([(47.39, 8.54), (47.40, 8.54), (47.40, 8.55)])]
    s.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 3, 1)), 1.0)
    for it in fence:
        it.mission_type = mavlink.MAV_MISSION_TYPE_FENCE
        replies = s.receive(rx(it), 1.0)
    assert replies[0].type == mavlink.MAV_MISSION_ACCEPTED
    assert len(s.mission) == 1 and len(s.stores[1]) == 3


def test_clear_all_and_count_zero():
    s = MissionServer()
    upload(s, three_items())
    r = s.receive(rx(mavlink.MAVLink_mission_clear_all_message(1, 1, 0)), 1.0)
    assert r[0].get_type() == "MISSION_ACK" and r[0].type == 0
    assert s.mission == []
    upload(s, three_items())
    r = s.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 0, 0)), 2.0)
    assert r[0].type == 0 and s.mission == []


def test_set_current():
    s = MissionServer()
    upload(s, three_items())
    s.events.clear()
    r = s.receive(rx(mavlink.MAVLink_mission_set_current_message(1, 1, 2)), 1.0)
    assert r[0].get_type() == "MISSION_CURRENT" and r[0].seq == 2 and r[0].total == 3
    assert s.current_seq == 2 and s.events[0].kind == "set_current"
    r = s.receive(rx(mavlink.MAVLink_mission_set_current_message(1, 1, 9)), 1.0)
    assert r[0].get_type() == "STATUSTEXT" and s.current_seq == 2


def test_timeout_resends_request_then_gives_up():
    s = MissionServer(timeout_s=0.25, max_retries=5)
    r = s.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 2, 0)), 10.0)
    assert r[0].seq == 0 and s.next_deadline() == pytest.approx(10.25)
    assert s.poll(10.2) == []
    r = s.poll(10.26)
    assert r[0].get_type() == "MISSION_REQUEST_INT" and r[0].seq == 0
    # an item resets the retry counter; the next one is then requested
    r = s.receive(rx(three_items()[0]), 10.3)
    assert r[0].seq == 1
    now = 10.3
    for _ in range(5):
        now += 0.3
        assert s.poll(now)[0].seq == 1
    now += 0.3
    r = s.poll(now)
    assert r[0].get_type() == "MISSION_ACK" and r[0].type == mavlink.MAV_MISSION_ERROR
    assert s.upload is None and s.next_deadline() is None and s.mission == []


def test_out_of_sequence_item_rerequests_expected():
    s = MissionServer()
    items = three_items()
    s.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 3, 0)), 0.0)
    s.receive(rx(items[0]), 0.0)
    r = s.receive(rx(items[2]), 0.1)  # skipped seq 1
    assert r[0].get_type() == "MISSION_REQUEST_INT" and r[0].seq == 1
    r = s.receive(rx(items[0]), 0.1)  # duplicate
    assert r[0].seq == 1
    s.receive(rx(items[1]), 0.2)
    assert s.receive(rx(items[2]), 0.2)[0].type == mavlink.MAV_MISSION_ACCEPTED
    # an item with no transfer going on
    stray = s.receive(rx(items[1]), 5.0)
    assert stray[0].type == mavlink.MAV_MISSION_INVALID_SEQUENCE


def test_lost_final_ack_is_repeated():
    s = MissionServer()
    items = three_items()
    upload(s, items)
    r = s.receive(rx(items[2]), 1.0)  # the GCS did not get our ACK and resends
    assert r[0].get_type() == "MISSION_ACK" and r[0].type == mavlink.MAV_MISSION_ACCEPTED


@pytest.mark.parametrize("frame,command,result", [
    (mavlink.MAV_FRAME_LOCAL_NED, 16, mavlink.MAV_MISSION_UNSUPPORTED_FRAME),
    (mavlink.MAV_FRAME_MISSION, 16, mavlink.MAV_MISSION_UNSUPPORTED_FRAME),
    (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink.MAV_CMD_DO_JUMP,
     mavlink.MAV_MISSION_UNSUPPORTED),
    (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 31001, mavlink.MAV_MISSION_UNSUPPORTED),
])
def test_rejected_items(frame, command, result):
    s = MissionServer()
    upload(s, three_items())
    s.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 2, 0)), 0.0)
    bad = item_int(0, command, 47.39, 8.54, 10, frame=frame)
    r = s.receive(rx(bad), 0.1)
    assert r[0].get_type() == "MISSION_ACK" and r[0].type == result
    assert s.upload is None and len(s.mission) == 3  # old mission kept


@pytest.mark.parametrize("clear_type", [mavlink.MAV_MISSION_TYPE_MISSION,
                                        mavlink.MAV_MISSION_TYPE_ALL])
def test_clear_all_cancels_an_upload_in_progress(clear_type):
    """MISSION_CLEAR_ALL of the upload's type, or of type ALL, ends the transfer: no more
    requests, no retries, and the items that follow are refused."""
    s = MissionServer()
    items = three_items()
    s.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 3, 0)), 0.0)
    s.receive(rx(items[0]), 0.0)
    r = s.receive(rx(mavlink.MAVLink_mission_clear_all_message(1, 1, clear_type)), 0.1)
    assert r[0].get_type() == "MISSION_ACK" and r[0].type == mavlink.MAV_MISSION_ACCEPTED
    assert s.upload is None and s.next_deadline() is None and s.poll(5.0) == []
    r = s.receive(rx(items[1]), 0.2)
    assert r[0].get_type() == "MISSION_ACK" and r[0].type == mavlink.MAV_MISSION_INVALID_SEQUENCE
    assert s.mission == []


def test_clearing_another_type_leaves_the_upload_running():
    s = MissionServer()
    items = three_items()
    s.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 3, 0)), 0.0)
    s.receive(rx(mavlink.MAVLink_mission_clear_all_message(1, 1, mavlink.MAV_MISSION_TYPE_FENCE)),
              0.1)
    assert s.upload is not None
    for it in items:
        r = s.receive(rx(it), 0.2)
    assert r[0].type == mavlink.MAV_MISSION_ACCEPTED and len(s.mission) == 3


def test_new_count_or_gcs_ack_cancels_transfer():
    s = MissionServer()
    items = three_items()
    s.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 3, 0)), 0.0)
    s.receive(rx(items[0]), 0.0)
    r = s.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 2, 0)), 0.1)
    assert r[0].seq == 0 and s.upload.count == 2  # restarted from scratch
    s.receive(rx(mavlink.MAVLink_mission_ack_message(1, 1, mavlink.MAV_MISSION_OPERATION_CANCELLED,
                                                     0)), 0.2)
    assert s.upload is None and s.poll(5.0) == [] and s.mission == []


def test_origin_to_global_many_matches_scalar():
    from econdor_gcs.core.geodesy import Origin

    pts = np.array([(0, 0, 0), (100, 100, 30), (-4000, 2500, 10), (2500, -4900, 120)], float)
    for lat0, lon0 in ((47.397742, 8.545594), (-33.9, 151.2), (0.0, -70.0), (78.2, 15.6)):
        o = Origin(lat0, lon0, 488.0)
        lat, lon, h = o.to_global_many(pts[:, 0], pts[:, 1], pts[:, 2])
        for k, (e, n, u) in enumerate(pts):
            slat, slon, sh = o.to_global(e, n, u)
            assert abs(lat[k] - slat) < 1e-10 and abs(lon[k] - slon) < 1e-10
            assert abs(h[k] - sh) < 1e-4
        x, y, _ = o.to_local_many(lat, lon, h)
        assert np.allclose(x, pts[:, 0], atol=1e-6) and np.allclose(y, pts[:, 1], atol=1e-6)


# ------------------------------------------------------------------ vehicle over sockets


@pytest.fixture
def vehicle():
    with inproc_vehicle(speedup=100.0) as v:
        yield v


@pytest.fixture
def gcs(vehicle):
    host, port = vehicle.local_address
    with GcsLink.to("127.0.0.1", port) as g:
        g.send(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))
        g.recv_match("HEARTBEAT", timeout=5)
        yield g


def test_heartbeat_and_version(vehicle, gcs):
    hb = gcs.recv_match("HEARTBEAT", timeout=3)
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
    assert hb.type == mavlink.MAV_TYPE_QUADROTOR and hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.custom_mode == (4 << 16) | (3 << 24)  # AUTO.LOITER
    assert hb.system_status == mavlink.MAV_STATE_STANDBY
    ack = gcs.command_long(1, mavlink.MAV_CMD_REQUEST_MESSAGE,
                           mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    av = gcs.recv_match("AUTOPILOT_VERSION")
    need = (mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
    assert av.capabilities & need == need
    gcs.command_long(1, mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1)
    gcs.recv_match("AUTOPILOT_VERSION")
    gcs.command_long(1, mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION)
    home = gcs.recv_match("HOME_POSITION")
    assert home.latitude == round(ORIGIN.lat_deg * 1e7)
    ext = gcs.recv_match("EXTENDED_SYS_STATE", timeout=3)
    assert ext.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND


def test_params_list_read_set(vehicle, gcs):
    gcs.send(mavlink.MAVLink_param_request_list_message(1, 1))
    names = set()
    while len(names) < len(PARAM_NAMES):
        pv = gcs.recv_match("PARAM_VALUE")
        assert pv.param_type == mavlink.MAV_PARAM_TYPE_REAL32 and pv.param_count == len(PARAM_NAMES)
        names.add(pv.param_id)
    assert {"SPEED_MPS", "SAMPLE_HZ", "SEARCH_RAD_M", "TEL_RATE_HZ", "NOISE_STD", "LAG_S",
            "POS_STD_M", "POS_TAU_S"} <= names
    gcs.send(mavlink.MAVLink_param_request_read_message(1, 1, b"SPEED_MPS", -1))
    assert gcs.recv_match("PARAM_VALUE").param_value == pytest.approx(8.0)
    gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"SPEED_MPS", 4.0, 9))
    pv = gcs.recv_match("PARAM_VALUE", lambda m: m.param_id == "SPEED_MPS")
    assert pv.param_value == pytest.approx(4.0) and vehicle.speed_mps == 4.0
    gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"SPEED_MPS", -3.0, 9))  # rejected
    pv = gcs.recv_match("PARAM_VALUE", lambda m: m.param_id == "SPEED_MPS")
    assert pv.param_value == pytest.approx(4.0)
    # the new speed takes effect: fly a waypoint and watch the ground speed
    gcs.upload(1, [item_int(0, 16, *ll(60, 0), 10)])
    assert gcs.command_long(1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert gcs.command_long(1, mavlink.MAV_CMD_MISSION_START).result == 0
    speeds = []
    while True:
        m = gcs.recv_match(("GLOBAL_POSITION_INT", "MISSION_ITEM_REACHED"), timeout=10)
        if m.get_type() == "MISSION_ITEM_REACHED":
            break
        speeds.append(math.hypot(m.vx, m.vy) / 100)
    assert 3.5 < max(speeds) <= 4.3


def test_two_waypoint_mission_runs_to_the_end(vehicle, gcs):
    items = [item_int(0, mavlink.MAV_CMD_NAV_TAKEOFF, alt=15, current=1),
             item_int(1, 16, *ll(40, 30), 15), item_int(2, 16, *ll(70, 60), 15)]
    assert gcs.upload(1, items) == mavlink.MAV_MISSION_ACCEPTED
    # not armed: takeoff / mission start are denied, not ignored
    assert gcs.command_long(1, mavlink.MAV_CMD_NAV_TAKEOFF).result == mavlink.MAV_RESULT_DENIED
    assert gcs.command_long(1, mavlink.MAV_CMD_MISSION_START).result == mavlink.MAV_RESULT_DENIED
    assert gcs.command_long(1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    hb = gcs.recv_match("HEARTBEAT", lambda m: m.base_mode & 128)
    assert hb.system_status == mavlink.MAV_STATE_ACTIVE
    assert gcs.command_long(1, mavlink.MAV_CMD_MISSION_START, 0, 2).result == 0
    seen = []
    while True:
        m = gcs.recv_match(("MISSION_ITEM_REACHED", "MISSION_CURRENT"), timeout=15)
        if m.get_type() == "MISSION_CURRENT" and (not seen or seen[-1] != ("cur", m.seq)):
            seen.append(("cur", m.seq))
        if m.get_type() == "MISSION_ITEM_REACHED":
            seen.append(("reached", m.seq))
            if m.seq == 2:
                break
    assert ("reached", 0) in seen and ("reached", 1) in seen and ("cur", 2) in seen
    gpi = gcs.recv_match("GLOBAL_POSITION_INT", timeout=3)
    x, y, _ = ORIGIN.to_local(gpi.lat / 1e7, gpi.lon / 1e7)
    assert math.hypot(x - 70, y - 60) < 2.0 and gpi.relative_alt == pytest.approx(15000, abs=200)
    hb = gcs.recv_match("HEARTBEAT", timeout=3)
    assert hb.custom_mode == (4 << 16) | (3 << 24) and hb.base_mode & 128  # hovering, armed
    # RTL brings it home and disarms it
    assert gcs.command_long(1, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH).result == 0
    gcs.recv_match("EXTENDED_SYS_STATE",
                   lambda m: m.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND, timeout=20)
    assert not vehicle.armed and math.hypot(vehicle.body.x_m, vehicle.body.y_m) < 2.0


def test_trace_item_samples_are_paired_and_events_reported(vehicle, gcs):
    field = MISSION.build_field()
    level = float(field(50.0, 50.0)) + 0.5
    items = [item_int(0, mavlink.MAV_CMD_NAV_TAKEOFF, alt=20, current=1),
             item_int(1, 31000, *ll(50, 50), 20, p1=level, p2=10, p3=60, p4=3)]
    assert gcs.upload(1, items) == 0
    gcs.keep = True
    gcs.received.clear()
    gcs.command_long(1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    gcs.command_long(1, mavlink.MAV_CMD_MISSION_START)
    gcs.recv_match("MISSION_ITEM_REACHED", lambda m: m.seq == 1, timeout=30)
    msgs = list(gcs.received)
    pairs = 0
    for i, m in enumerate(msgs):
        if m.get_type() == "NAMED_VALUE_FLOAT" and m.name == "FIELD":
            prev = msgs[i - 1]
            assert prev.get_type() == "GLOBAL_POSITION_INT"
            assert prev.time_boot_ms == m.time_boot_ms
            x, y, _ = ORIGIN.to_local(prev.lat / 1e7, prev.lon / 1e7)
            assert m.value == pytest.approx(float(field(x, y)), abs=0.05)
            pairs += 1
    assert pairs > 50
    # machine-readable: a PHASE change before the first sample of each phase ...
    phases = [(i, m) for i, m in enumerate(msgs)
              if m.get_type() == "NAMED_VALUE_INT" and m.name == "PHASE"]
    assert [m.value for _, m in phases][:3] == [Phase.TRANSIT, Phase.SEARCH, Phase.TRACE]
    for i, m in phases:
        nxt = next(s for s in msgs[i:] if s.get_type() == "GLOBAL_POSITION_INT")
        assert nxt.time_boot_ms == m.time_boot_ms
    # ... and the outcome as a TRACE report just before the item is reached
    k = next(i for i, m in enumerate(msgs)
             if m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 1)
    report = trace_report(msgs[k - 1])
    assert report is not None and (report.seq, report.piece_id) == (1, 3)
    assert report.status in {"closed", "length_limit", "boundary"}
    assert 0 < report.traced_m <= report.flown_m
    assert report.level == pytest.approx(level)
    # STATUSTEXT says the same for people
    texts = [m.text for m in msgs if m.get_type() == "STATUSTEXT"]
    assert any(t.startswith("piece 3: contour found") for t in texts), texts
    assert any(t.startswith(f"piece 3: {report.status.value} traced") for t in texts), texts
    times = [m.time_boot_ms for m in msgs if m.get_type() == "NAMED_VALUE_FLOAT"]
    assert times == sorted(times) and len(set(times)) == len(times)


def test_commands_unknown_and_invalid(vehicle, gcs):
    assert gcs.command_long(1, 31999).result == mavlink.MAV_RESULT_UNSUPPORTED
    assert gcs.command_long(1, mavlink.MAV_CMD_MISSION_START).result == mavlink.MAV_RESULT_DENIED
    ack = gcs.command_long(1, mavlink.MAV_CMD_REQUEST_MESSAGE, 9999)
    assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED
    # COMMAND_INT path, and DO_SET_MODE in PX4 encoding
    gcs.send(mavlink.MAVLink_command_int_message(1, 1, 0, mavlink.MAV_CMD_DO_SET_MODE, 0, 0,
                                                 1, 4, 3, 0, 0, 0, 0))
    assert gcs.recv_match("COMMAND_ACK").result == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.command_long(1, mavlink.MAV_CMD_DO_SET_MODE, 1, 4, 4).result == \
        mavlink.MAV_RESULT_DENIED  # AUTO.MISSION without a mission
    assert gcs.command_long(1, mavlink.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == \
        mavlink.MAV_RESULT_DENIED  # OFFBOARD is not supported
    assert gcs.command_long(1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                            mavlink.MAVLINK_MSG_ID_ATTITUDE, 100000).result == 0


def test_garbage_corruption_and_wrong_target_do_not_stop_it(vehicle, gcs):
    import random

    rnd = random.Random(4)
    before = dict(vehicle.counters)
    good = gcs.pack(mavlink.MAVLink_command_long_message(1, 1, 31999, 0, 0, 0, 0, 0, 0, 0, 0))
    for _ in range(50):
        gcs.send_raw(bytes(rnd.randrange(256) for _ in range(rnd.randrange(1, 300))))
        corrupt = bytearray(good)
        corrupt[rnd.randrange(10, len(corrupt))] ^= 0xFF
        gcs.send_raw(bytes(corrupt))
        gcs.send_raw(good[: rnd.randrange(1, len(good))])
        gcs.send(mavlink.MAVLink_command_long_message(7, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    wait_for(lambda: vehicle.counters["rx_other_target"] - before["rx_other_target"] >= 50, 5,
             "wrong-target messages counted")
    assert vehicle.counters["rx_bad"] > before["rx_bad"]
    assert not vehicle.armed  # the commands for system 7 were not obeyed
    gcs.flush()
    assert gcs.command_long(1, 31999).result == mavlink.MAV_RESULT_UNSUPPORTED
    gcs.command_long(1, mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_STATUSTEXT)
    assert gcs.recv_match("STATUSTEXT", lambda m: m.text.startswith("rx ")).text


def test_flood_is_dropped_and_counted(vehicle, gcs):
    hb = gcs.pack(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))
    t0 = time.monotonic()
    while vehicle.counters["rx_flood"] == 0 and time.monotonic() - t0 < 10:
        for _ in range(2000):
            gcs.send_raw(hb)
    assert vehicle.counters["rx_flood"] > 0

    def answers():  # within the flood's budget window a command is dropped too; retry
        gcs.flush()
        try:
            return gcs.command_long(1, 31999, timeout=0.3).result
        except TimeoutError:
            return None

    assert wait_for(answers, 5, "an answer after the flood") == mavlink.MAV_RESULT_UNSUPPORTED


def test_upload_survives_packet_loss(vehicle, gcs):
    items = [item_int(i, 16, *ll(10 + i, 20), 10, current=int(i == 0)) for i in range(12)]
    sent = {"n": 0}

    def drop_every_third_item(msg):
        if msg.get_type() != "MISSION_ITEM_INT":
            return False
        sent["n"] += 1
        return sent["n"] % 3 == 0

    gcs.drop_tx = drop_every_third_item
    req = {"n": 0}

    def vehicle_drops_every_fourth_request(msg):
        if msg.get_type() != "MISSION_REQUEST_INT":
            return True
        req["n"] += 1
        return req["n"] % 4 != 0

    vehicle.tx_filter = vehicle_drops_every_fourth_request
    assert gcs.upload(1, items, timeout=20) == mavlink.MAV_MISSION_ACCEPTED
    vehicle.tx_filter = None
    gcs.drop_tx = None
    assert vehicle.server.counters["resends"] >= 4
    back = gcs.download(1)
    assert [(m.seq, m.x, m.y, m.current) for m in back] == [(m.seq, m.x, m.y, m.current)
                                                            for m in items]


# ------------------------------------------------------------------ the process / CLI


def test_cli_errors_are_one_line(tmp_path):
    r = subprocess.run([*sim_vehicle_cmd(), "--mission", str(tmp_path / "nope.yaml")],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text("field: {model: paper}\nvehicles: {speed_mps: -1}\n")
    r = subprocess.run([*sim_vehicle_cmd(), "--mission", str(bad)],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and "vehicles.speed_mps" in r.stderr and r.stderr.count("\n") == 1
    r = subprocess.run([*sim_vehicle_cmd(), "--mission", str(DEMO), "--connect", "udp:x"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and "bad endpoint" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([*sim_vehicle_cmd(), "--mission", str(DEMO), "--speedup", "fast"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_process_udpout_count_and_sigterm():
    with GcsLink.listen() as gcs, VehicleProcess(
            "--count", "2", "--sysid-base", "5", "--speedup", "20",
            connect=f"udpout:127.0.0.1:{gcs.port}") as proc:
        seen = set()
        deadline = time.monotonic() + 10
        while seen != {5, 6} and time.monotonic() < deadline:
            for m in gcs.poll():
                if m.get_type() == "HEARTBEAT":
                    seen.add(m.get_srcSystem())
        assert seen == {5, 6}
        # the GCS can talk back through the udpout vehicle's source address
        gcs.remote = None
        gcs.recv_match("HEARTBEAT", lambda m: m.get_srcSystem() == 5)
        gcs.flush()
        t0 = time.monotonic()
        gpi0 = gcs.recv_match("GLOBAL_POSITION_INT", lambda m: m.get_srcSystem() == 6)
        gpi1 = gcs.recv_match("GLOBAL_POSITION_INT",
                              lambda m: m.get_srcSystem() == 6 and m.time_boot_ms
                              > gpi0.time_boot_ms + 20000, timeout=10)
        rate = (gpi1.time_boot_ms - gpi0.time_boot_ms) / 1000 / (time.monotonic() - t0)
        assert 10 < rate < 30  # sim time runs ~20x wall time
        assert proc.stop() == 0
        # each child's exit line (speed-up and counters; the log is gone after the block)
        assert proc.output().count("stopped after") == 2, proc.output()


def test_process_sigint_exit_zero():
    with GcsLink.listen() as gcs:
        p = VehicleProcess(connect=f"udpout:127.0.0.1:{gcs.port}").start()
        gcs.recv_match("HEARTBEAT", timeout=10)
        assert p.proc is not None
        p.proc.send_signal(signal.SIGINT)
        assert p.proc.wait(10) == 0
        assert "Traceback" not in p.output() and "stopped after" in p.output()
        p.stop()
    Path(p.log.name).unlink(missing_ok=True)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
