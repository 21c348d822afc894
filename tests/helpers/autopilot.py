"""The autopilot personalities driven I/O-free: a GCS's messages in, the outbox drained (shared by
the autopilot and ArduPilot-personality tests)."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.config import load_mission
from sim_vehicle.ardupilot import NO_SPACE_AFTER_BOOT_S, ArduCopterAutopilot
from sim_vehicle.px4 import Px4Autopilot
from sim_vehicle.state import VehicleSettings
from tests.helpers.vehicles import DEMO, item_int

GCS = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
DECODER = mavlink.MAVLink(None)
MISSION = load_mission(DEMO)


def rx(msg):
    """What the vehicle would see: msg packed by the GCS and decoded (sets src ids)."""
    return DECODER.decode(bytearray(msg.pack(GCS)))


def make(cls=Px4Autopilot, now=0.0, **kw):
    settings = VehicleSettings(sysid=1, **kw)
    o = MISSION.origin
    ap = cls(MISSION.build_field(), MISSION.region, o, settings,
             (o.lat_deg, o.lon_deg, o.alt_m), now=now)
    if cls is ArduCopterAutopilot:  # it takes uploads 3 s (of its time) after boot
        ap.skip_parked(round(NO_SPACE_AFTER_BOOT_S / ap.state.body.dt_s))
    return ap


def command(ap, cmd, *params, now=0.0):
    p = list(params) + [0.0] * (7 - len(params))
    ap.receive(rx(mavlink.MAVLink_command_long_message(1, 1, cmd, 0, *p)), now)
    out = ap.outbox.drain(0.0)
    acks = [m for m in out if m.get_type() == "COMMAND_ACK"]
    assert len(acks) == 1 and acks[0].command == cmd
    return acks[0].result, out


def upload(ap, items, expect=mavlink.MAV_MISSION_ACCEPTED, request="MISSION_REQUEST_INT"):
    ap.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, len(items), 0)), 0.0)
    for it in items:
        out = ap.outbox.drain(0.0)
        if out and out[-1].get_type() == "MISSION_ACK":
            break
        assert out[-1].get_type() == request and out[-1].seq == it.seq
        ap.receive(rx(it), 0.0)
    out = ap.outbox.drain(0.0)
    assert out[-1].get_type() == "MISSION_ACK" and out[-1].type == expect


def download(ap, legacy=False):
    ap.receive(rx(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), 0.0)
    n = ap.outbox.drain(0.0)[-1].count
    req = mavlink.MAVLink_mission_request_message if legacy else \
        mavlink.MAVLink_mission_request_int_message
    items = []
    for seq in range(n):
        ap.receive(rx(req(1, 1, seq, 0)), 0.0)
        items.append(ap.outbox.drain(0.0)[-1])
    return items


def run_until(ap, cond, max_ticks=20000):
    msgs = []
    for _ in range(max_ticks):
        ap.tick()
        msgs.extend(ap.outbox.drain(0.0))
        if cond(msgs):
            return msgs
    raise AssertionError("condition not reached")


def ll(x, y):
    lat, lon, _ = MISSION.origin.to_global(x, y)
    return lat, lon


def copter_mission():
    return [item_int(0, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(5, 5), 0, current=1),
            item_int(1, mavlink.MAV_CMD_NAV_TAKEOFF, *ll(0, 0), 10.123),
            item_int(2, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(20, 0), 10.123)]
