"""The simulated ArduPilot is never kinder than ArduCopter SITL: each habit found against the
real flight code (docs/sitl.md) as a fast, I/O-free test of the personality, and the
station's answer to it where it has one."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.tasks import SAMPLE_COUNT_COMMAND
from econdor_gcs.errors import MissionRejected
from econdor_gcs.link.items import change_speed_item, rtl_item
from econdor_gcs.link.transfer import MissionUploader
from sim_vehicle.ardupilot import COPTER_GUIDED, NO_SPACE_AFTER_BOOT_S, ArduCopterAutopilot
from sim_vehicle.px4 import Px4Autopilot
from sim_vehicle.state import VehicleSettings
from tests.helpers.autopilot import (
    DECODER,
    command,
    copter_mission,
    download,
    ll,
    make,
    run_until,
    rx,
    upload,
)
from tests.helpers.vehicles import item_int


def drain(ap, now=0.0):
    return ap.outbox.drain(now)


def count(ap, n, now=0.0):
    ap.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, n, 0)), now)
    return drain(ap, now)


def test_no_upload_in_its_first_seconds():
    ap = ArduCopterAutopilot.__new__(ArduCopterAutopilot)
    from tests.helpers.autopilot import MISSION
    o = MISSION.origin
    ap.__init__(MISSION.build_field(), MISSION.region, o, VehicleSettings(sysid=1),
                (o.lat_deg, o.lon_deg, o.alt_m))
    [ack] = count(ap, 3)
    assert (ack.get_type(), ack.type) == ("MISSION_ACK", mavlink.MAV_MISSION_NO_SPACE)
    ap.skip_parked(round(NO_SPACE_AFTER_BOOT_S / ap.state.body.dt_s))
    assert count(ap, 3)[0].get_type() == "MISSION_REQUEST"


def test_commands_without_a_position_read_back_with_frame_0_and_no_position():
    ap = make(ArduCopterAutopilot)
    items = [*copter_mission(), change_speed_item(3, 8.0).to_message(1, 1),
             rtl_item(4).to_message(1, 1)]
    upload(ap, items, request="MISSION_REQUEST")
    back = download(ap)
    assert [(m.command, m.frame) for m in back[3:]] == [
        (mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_FRAME_GLOBAL),
        (mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, mavlink.MAV_FRAME_GLOBAL)]
    assert back[3].param2 == 8.0 and (back[4].x, back[4].y, back[4].z) == (0, 0, 0.0)


def test_mission_current_total_leaves_home_out():
    """ArduPilot's MISSION_CURRENT.total is its item count without home (item 0), as the
    real ArduCopter sends it (GCS_MAVLINK::send_mission_current: num_commands() - 1)."""
    ap = make(ArduCopterAutopilot)
    upload(ap, copter_mission(), request="MISSION_REQUEST")
    msg = ap.server.mission_current_msg(active=True)
    assert (msg.total, msg.mission_state) == (2, mavlink.MISSION_STATE_ACTIVE)


def test_a_stale_copy_of_an_item_gets_invalid_sequence_and_the_upload_goes_on():
    """ArduPilot requested item 1 again before our answer came; the second copy arrives
    when it waits for item 2: INVALID_SEQUENCE, and it keeps asking for item 2."""
    ap = make(ArduCopterAutopilot)
    items = copter_mission()
    count(ap, len(items))
    ap.receive(rx(items[0]), 0.0)
    drain(ap)
    ap.receive(rx(items[0]), 0.0)
    [ack] = drain(ap)
    assert ack.get_type() == "MISSION_ACK" and ack.type == mavlink.MAV_MISSION_INVALID_SEQUENCE
    assert ap.server.upload is not None
    for it in items[1:]:
        ap.receive(rx(it), 0.0)
    assert drain(ap)[-1].type == mavlink.MAV_MISSION_ACCEPTED
    # an item with no transfer running: ERROR (and no re-ACK of the finished one)
    ap.receive(rx(items[-1]), 0.0)
    assert drain(ap)[-1].type == mavlink.MAV_MISSION_ERROR


def test_the_upload_runs_on_its_own_clock():
    """Re-requests after 1 s and cancellation after 8 s *of its time*: at 10x, 0.1 s and
    0.8 s of wall time."""
    ap = make(ArduCopterAutopilot, speedup=10.0)
    count(ap, 3, now=100.0)
    ap.poll(100.05)
    assert drain(ap) == []
    ap.poll(100.11)
    assert [m.get_type() for m in drain(ap)] == ["MISSION_REQUEST"]
    ap.poll(100.81)
    [ack] = drain(ap)
    assert ack.type == mavlink.MAV_MISSION_OPERATION_CANCELLED and ap.server.upload is None


def test_station_goes_on_after_an_invalid_sequence_for_a_stale_copy():
    """The re-upload seen on SITL: our uploader took INVALID_SEQUENCE as the end."""
    ap = make(ArduCopterAutopilot)
    items = [it for it in copter_mission()]
    from econdor_gcs.link.items import MissionItemSpec

    specs = [MissionItemSpec.from_message(rx(it)) for it in items]
    up = MissionUploader(1, 1, specs, timeout_s=1.0)
    now = 0.0

    def pump(extra_copy: bool = False) -> None:
        for msg in up.poll(now):
            for _ in range(2 if extra_copy and msg.get_type() == "MISSION_ITEM_INT" else 1):
                ap.receive(rx(msg), now)
        for reply in drain(ap):
            if reply.get_type().startswith("MISSION_"):
                up.receive(rx(reply), now)

    pump()
    pump(extra_copy=True)  # item 0 twice: the vehicle answers the second INVALID_SEQUENCE
    for _ in range(5):
        pump()
    assert up.done and up.error is None and up.stale_acks == 1
    # no request after it: then it is the vehicle's verdict
    up2 = MissionUploader(1, 1, specs, timeout_s=1.0)
    up2.poll(0.0)
    up2.receive(rx(mavlink.MAVLink_mission_request_message(255, 190, 0, 0)), 0.0)
    up2.poll(0.0)
    up2.receive(rx(mavlink.MAVLink_mission_ack_message(
        255, 190, mavlink.MAV_MISSION_INVALID_SEQUENCE, 0)), 0.1)
    assert not up2.done
    up2.poll(1.5)
    assert isinstance(up2.error, MissionRejected) and \
        up2.error.result == mavlink.MAV_MISSION_INVALID_SEQUENCE


def test_mission_start_only_from_the_beginning():
    ap = make(ArduCopterAutopilot, prearm_s=0.0)
    upload(ap, copter_mission(), request="MISSION_REQUEST")
    ap.do_set_mode(1, 4, 0)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    for first, last in ((1, 0), (0, 2), (2, 2)):
        assert command(ap, mavlink.MAV_CMD_MISSION_START, first, last)[0] == \
            mavlink.MAV_RESULT_DENIED
    assert command(ap, mavlink.MAV_CMD_MISSION_START, 0, 0)[0] == mavlink.MAV_RESULT_ACCEPTED


@pytest.mark.parametrize("companion", [False, True])
def test_sample_commands_are_unknown_to_a_stock_ardupilot(companion):
    ap = make(ArduCopterAutopilot, companion=companion)
    ap.receive(rx(mavlink.MAVLink_command_int_message(
        1, 1, mavlink.MAV_FRAME_GLOBAL_INT, SAMPLE_COUNT_COMMAND, 0, 0, 0, 0, 0, 0, 0, 1000,
        0)), 0.0)
    [ack] = [m for m in drain(ap) if m.get_type() == "COMMAND_ACK"]
    want = mavlink.MAV_RESULT_ACCEPTED if companion else mavlink.MAV_RESULT_UNSUPPORTED
    assert ack.result == want


def test_positions_say_zero_until_the_estimate_is_ready():
    ap = make(ArduCopterAutopilot, now=100.0, prearm_s=2.0)
    gpi = ap.telemetry.global_position_int()
    assert (gpi.lat, gpi.lon) == (0, 0)
    ap.now = 102.5
    gpi = ap.telemetry.global_position_int()
    assert gpi.lat != 0 and gpi.lon != 0


def _fly_samples(ap, gpi_interval_s: float | None) -> list:
    from tests.helpers.autopilot import ll, run_until

    if gpi_interval_s is not None:
        command(ap, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, gpi_interval_s * 1e6)
    upload(ap, [item_int(0, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(0, 0), 0, current=1),
                item_int(1, mavlink.MAV_CMD_NAV_TAKEOFF, *ll(0, 0), 10),
                item_int(2, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(30, 0), 10)],
           request="MISSION_REQUEST")
    ap.do_set_mode(1, 4, 0)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    command(ap, mavlink.MAV_CMD_MISSION_START, 0, 0)
    return run_until(ap, lambda ms: ap.state.mission_complete)


def test_a_stock_ardupilots_samples_are_stamped_by_its_lua_script():
    """FIELD carries the autopilot's clock when the script sends it: never a position's
    stamp; positions come with the samples only when asked for at the sensor's rate."""
    ap = make(ArduCopterAutopilot, prearm_s=0.0, sample_rate_hz=10.0)
    msgs = _fly_samples(ap, gpi_interval_s=0.1)
    fields = [m.time_boot_ms for m in msgs if m.get_type() == "NAMED_VALUE_FLOAT"]
    positions = {m.time_boot_ms for m in msgs if m.get_type() == "GLOBAL_POSITION_INT"}
    assert len(fields) > 20 and not positions & set(fields)
    assert all(ms - 1 in positions for ms in fields)  # taken at a position, sent 1 ms later
    slow = make(ArduCopterAutopilot, prearm_s=0.0, sample_rate_hz=10.0)
    msgs = _fly_samples(slow, gpi_interval_s=None)  # nobody asked for positions
    assert not any(m.get_type() == "GLOBAL_POSITION_INT" for m in msgs)
    assert sum(m.get_type() == "NAMED_VALUE_FLOAT" for m in msgs) > 20


def test_with_a_companion_samples_keep_their_exact_stamps():
    ap = make(ArduCopterAutopilot, prearm_s=0.0, sample_rate_hz=10.0, companion=True)
    msgs = _fly_samples(ap, gpi_interval_s=0.1)
    fields = [m.time_boot_ms for m in msgs if m.get_type() == "NAMED_VALUE_FLOAT"]
    positions = {m.time_boot_ms for m in msgs if m.get_type() == "GLOBAL_POSITION_INT"}
    assert fields and set(fields) <= positions


VEHICLE = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)


def _from_vehicle(msg):
    """What the station would see of a vehicle's message (packed, decoded: source ids set)."""
    return DECODER.decode(bytearray(msg.pack(VEHICLE)))


class _Flight:
    """An ArduCopter driven tick by tick as the I/O loop drives it (streams included: wall
    time 0.1 s per tick, speed-up 1), every message it sends kept."""

    def __init__(self, ap) -> None:
        self.ap = ap
        self.wall = 0.0
        self.sent: list = []

    def tick(self) -> list:
        ap = self.ap
        ap.tick()
        self.wall += ap.state.body.dt_s
        out = ap.outbox.drain(self.wall)
        ap.telemetry.periodic(self.wall)
        out += ap.outbox.drain(self.wall)
        self.sent.extend(out)
        return out

    def until(self, cond, max_ticks: int = 5000) -> None:
        for _ in range(max_ticks):
            self.tick()
            if cond():
                return
        raise AssertionError("condition not reached")

    def stamps(self, kind: str, first_s: float, end_s: float) -> list[int]:
        return [m.time_boot_ms for m in self.sent if m.get_type() == kind
                and first_s * 1000 <= m.time_boot_ms < end_s * 1000]


def _hovering(gpi_interval_s: float, **settings):
    ap = make(ArduCopterAutopilot, prearm_s=0.0, sample_rate_hz=10.0, speedup=1.0, **settings)
    command(ap, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
            gpi_interval_s * 1e6)
    ap.do_set_mode(1, 4, 0)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    command(ap, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10.0)
    flight = _Flight(ap)
    flight.until(lambda: ap.state.alt_rel_m >= 10.0)
    for _ in range(10):
        flight.tick()
    return ap, flight


def test_no_positions_for_a_pause_after_an_upload_begins_while_the_lua_script_samples_on():
    """ArduCopter SITL sent no GLOBAL_POSITION_INT for ~3 s of its time after a mission
    upload began while its Lua script kept sending FIELD; while it asks for items its
    streams go four times slower (positions asked every 0.1 s came every 0.4 s)."""
    ap, flight = _hovering(gpi_interval_s=0.1)
    assert ap.upload_pause_s == 3.0
    ap.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 3, 0)), flight.wall)
    began = ap.server.upload_began_s
    assert began == pytest.approx(ap.state.body.t_s)
    flight.until(lambda: ap.state.body.t_s >= began + 5.0)  # the upload still runs
    for it in copter_mission():
        ap.receive(rx(it), flight.wall)
    assert [m.type for m in flight.tick() if m.get_type() == "MISSION_ACK"] == [
        mavlink.MAV_MISSION_ACCEPTED]
    done = ap.state.body.t_s
    flight.until(lambda: ap.state.body.t_s >= done + 2.0)

    pause = (began + 0.05, began + ap.upload_pause_s)  # the ticks after the COUNT came in
    assert flight.stamps("GLOBAL_POSITION_INT", *pause) == []
    assert len(flight.stamps("NAMED_VALUE_FLOAT", *pause)) == 29  # one per tick, at 10 Hz
    # before: one position a sample; after the pause, while it asks for items: one in four
    assert len(flight.stamps("GLOBAL_POSITION_INT", began - 1.0, began)) == 10
    assert len(flight.stamps("GLOBAL_POSITION_INT", pause[1], began + 5.0)) in (5, 6)
    assert len(flight.stamps("GLOBAL_POSITION_INT", done, done + 2.0)) >= 19
    assert len(flight.stamps("NAMED_VALUE_FLOAT", pause[1], done + 2.0)) >= 39


def test_positions_go_on_through_an_upload_on_px4_and_with_the_pause_off():
    """The pause is ArduPilot's (a parameter of the personality: 0 turns it off), not every
    autopilot's: PX4 keeps its positions coming while it takes a mission."""
    for ap in (make(ArduCopterAutopilot, prearm_s=0.0, sample_rate_hz=10.0, speedup=1.0,
                    upload_pause_s=0.0),
               make(Px4Autopilot, prearm_s=0.0, sample_rate_hz=10.0, speedup=1.0)):
        flight = _Flight(ap)
        command(ap, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 0.1e6)
        ap.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 3, 0)), flight.wall)
        t0 = ap.state.body.t_s
        flight.until(lambda ap=ap, t0=t0: ap.state.body.t_s >= t0 + 3.0)
        assert flight.stamps("GLOBAL_POSITION_INT", t0, t0 + 3.0)


@pytest.mark.parametrize("still_gap", [True, False])
def test_the_station_places_the_samples_of_the_pause_because_the_copter_held_its_place(
        monkeypatch, still_gap):
    """The station's answer to the pause: between iterations the copter hovers at the end of
    its mission while the station uploads the next one (its own uploader, answering each
    request 0.3 s of the vehicle's time later: 6 ms of wall time at 50x); every FIELD the Lua
    script sent in the pause is placed by the pairing's still-gap rule. Without that rule
    (STILL_GAP_MS 0) they are dropped: the gap is too long to interpolate across."""
    from econdor_gcs.link import pairing
    from econdor_gcs.link.items import MissionItemSpec

    if not still_gap:
        monkeypatch.setattr(pairing, "STILL_GAP_MS", 0)
    ap = make(ArduCopterAutopilot, prearm_s=0.0, sample_rate_hz=10.0, speedup=1.0)
    command(ap, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
            0.025e6)  # the station's: four positions a sample
    mission = copter_mission()
    upload(ap, mission, request="MISSION_REQUEST")
    flight = _Flight(ap)
    for _ in range(40):
        flight.tick()  # on the ground, positions streaming again after the first pause
    ap.do_set_mode(1, 4, 0)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    command(ap, mavlink.MAV_CMD_MISSION_START, 0, 0)
    flight.until(lambda: ap.state.mission_complete)
    for _ in range(20):
        flight.tick()  # hovering at the end of the mission, in AUTO
    more = [item_int(seq, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(20 + seq, 5), 10.0)
            for seq in range(3, 10)]
    uploader = MissionUploader(1, 1, [MissionItemSpec.from_message(rx(it))
                                      for it in [*mission, *more]], timeout_s=10.0)
    replies: list = []
    while not uploader.done:
        for msg in uploader.poll(flight.wall):
            ap.receive(rx(msg), flight.wall)
        for _ in range(3):  # the station's answer is 0.3 s of the vehicle's time away
            replies += [r for r in flight.tick() if r.get_type().startswith("MISSION_")]
        for reply in replies:
            uploader.receive(_from_vehicle(reply), flight.wall)
        replies.clear()
    assert uploader.error is None
    began = ap.server.upload_began_s
    flight.until(lambda: ap.state.body.t_s >= began + ap.upload_pause_s + 1.0)

    pairer = pairing.SamplePairer()
    placed = [s for m in flight.sent for s in pairer.add(1, _from_vehicle(m), flight.wall)]
    pairer.expire(flight.wall + 10.0)
    # the samples between the last position before the pause and the first after it
    in_pause = flight.stamps("NAMED_VALUE_FLOAT", began + 0.0005, began + ap.upload_pause_s)
    assert len(in_pause) == 30
    assert flight.stamps("GLOBAL_POSITION_INT", began + 0.0005, began + ap.upload_pause_s) == []
    placed_ms = {s.time_boot_ms for s in placed}
    newest_ms = max(flight.stamps("GLOBAL_POSITION_INT", 0.0, 1e9))
    sent = flight.stamps("NAMED_VALUE_FLOAT", 0.0, newest_ms / 1000)
    assert len(sent) > 100  # the climb, the mission, the hover before and after the upload
    after = {pairing.DropReason.NO_POSITION_AFTER: 1}  # the last one, sent after the newest
    if still_gap:
        assert set(sent) == placed_ms and pairer.dropped == after
    else:
        assert set(sent) - placed_ms == set(in_pause)
        assert pairer.dropped == {pairing.DropReason.GAP: len(in_pause), **after}


def _waypoints(n, y_m):
    """``n`` mission items: home, then waypoints at ``y_m`` north, 10 m apart east."""
    wp = mavlink.MAV_CMD_NAV_WAYPOINT
    return [item_int(0, wp, *ll(0.0, 0.0), 10.0),
            *[item_int(s, wp, *ll(10.0 * s, y_m), 10.0) for s in range(1, n)]]


def test_an_upload_left_part_way_leaves_the_new_items_over_the_old_ones():
    """As seen on SITL: a 5-item mission, then a 3-item upload that stops after item 1 and
    times out, reads back as home, the new item 1 and the old item 2 (ArduPilot writes each
    item as it comes, and truncates at the count)."""
    ap = make(ArduCopterAutopilot)
    old, new = _waypoints(5, 20.0), _waypoints(3, 40.0)
    upload(ap, old, request="MISSION_REQUEST")
    count(ap, 3, now=1.0)
    for it in new[:2]:
        ap.receive(rx(it), 1.0)
    drain(ap)
    ap.poll(1.0 + 8.1)
    assert drain(ap)[-1].type == mavlink.MAV_MISSION_OPERATION_CANCELLED
    back = download(ap)
    assert [(m.x, m.y) for m in back[1:]] == [(new[1].x, new[1].y), (old[2].x, old[2].y)]


def test_a_refused_item_leaves_the_items_before_it_in_the_mission():
    ap = make(ArduCopterAutopilot)
    old = _waypoints(4, 20.0)
    upload(ap, old, request="MISSION_REQUEST")
    new = _waypoints(4, 40.0)
    new[2] = item_int(2, mavlink.MAV_CMD_WAYPOINT_USER_1, *ll(20.0, 40.0), 10.0)
    count(ap, 4)
    for it in new[:3]:
        ap.receive(rx(it), 0.0)
    assert drain(ap)[-1].type == mavlink.MAV_MISSION_UNSUPPORTED and ap.server.upload is None
    back = download(ap)
    assert [(m.x, m.y) for m in back[1:]] == [(new[1].x, new[1].y), (old[2].x, old[2].y),
                                             (old[3].x, old[3].y)]


def test_a_gcs_cancel_does_not_end_the_transfer_and_downloads_are_denied_meanwhile():
    """SITL went on requesting the item after the GCS's MISSION_ACK(OPERATION_CANCELLED), and
    refused a download with MAV_MISSION_DENIED until the transfer ended."""
    ap = make(ArduCopterAutopilot, speedup=1.0)
    count(ap, 3)
    ap.receive(rx(mavlink.MAVLink_mission_ack_message(
        1, 1, mavlink.MAV_MISSION_OPERATION_CANCELLED, 0)), 0.0)
    assert ap.server.upload is not None
    ap.receive(rx(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), 0.0)
    [ack] = drain(ap)
    assert (ack.get_type(), ack.type) == ("MISSION_ACK", mavlink.MAV_MISSION_DENIED)
    ap.poll(1.1)
    assert [m.get_type() for m in drain(ap)] == ["MISSION_REQUEST"]
    # MISSION_CLEAR_ALL ends it (and empties the mission)
    ap.receive(rx(mavlink.MAVLink_mission_clear_all_message(1, 1, 0)), 2.0)
    assert drain(ap)[-1].type == mavlink.MAV_MISSION_ACCEPTED
    assert ap.server.upload is None and ap.server.mission == []


def test_rally_points_are_written_as_they_come_and_a_fence_only_when_complete():
    """As seen on SITL: 3 rally points, then a 2-point upload left after point 0, read back
    as the new point 0 and the old point 1; a fence upload left part-way leaves the old
    fence whole."""
    ap = make(ArduCopterAutopilot, speedup=1.0)
    server = ap.server

    def points(mtype, cmd, lats, n=None):  # a square's corners (a fence polygon)
        lons = [85450000, 85450000, 85470000, 85470000]
        return [mavlink.MAVLink_mission_item_int_message(
            1, 1, s, mavlink.MAV_FRAME_GLOBAL_INT, cmd, 0, 1, float(n or len(lats)), 0, 0, 0,
            lat, lons[s], 20.0, mtype) for s, lat in enumerate(lats)]

    def last_ack():
        return [m for m in drain(ap) if m.get_type() == "MISSION_ACK"][-1].type

    for mtype, cmd in ((mavlink.MAV_MISSION_TYPE_RALLY, mavlink.MAV_CMD_NAV_RALLY_POINT),
                       (mavlink.MAV_MISSION_TYPE_FENCE,
                        mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION)):
        old = points(mtype, cmd, [473970000, 473990000, 473990100, 473970100])
        ap.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, len(old), mtype)), 0.0)
        for it in old:
            ap.receive(rx(it), 0.0)
        assert last_ack() == mavlink.MAV_MISSION_ACCEPTED
        new = points(mtype, cmd, [473971000, 473991000, 473991100], n=3)
        ap.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, 3, mtype)), 1.0)
        ap.receive(rx(new[0]), 1.0)
        ap.poll(1.0 + 8.1)
        assert last_ack() == mavlink.MAV_MISSION_OPERATION_CANCELLED
        stored = [it.x for it in server.stores[mtype]]
        if mtype == mavlink.MAV_MISSION_TYPE_RALLY:
            assert stored == [new[0].x, old[1].x, old[2].x]
        else:
            assert stored == [it.x for it in old]


def test_the_mission_cannot_be_cleared_while_it_is_flown():
    """Seen on SITL: in AUTO, flying its mission, MISSION_CLEAR_ALL is answered
    MAV_MISSION_ERROR and the mission is kept; once the mission has ended it is cleared."""
    ap = make(ArduCopterAutopilot, prearm_s=0.0)
    upload(ap, [item_int(0, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(0, 0), current=1),
                item_int(1, mavlink.MAV_CMD_NAV_TAKEOFF, alt=10),
                item_int(2, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(40, 0), 10)],
           request="MISSION_REQUEST")
    ap.set_mode(COPTER_GUIDED)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert command(ap, mavlink.MAV_CMD_MISSION_START, 0)[0] == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: ap.state.alt_rel_m > 5.0)
    clear = rx(mavlink.MAVLink_mission_clear_all_message(1, 1, 0))
    ap.receive(clear, 0.0)
    [ack] = [m for m in drain(ap) if m.get_type() == "MISSION_ACK"]
    assert ack.type == mavlink.MAV_MISSION_ERROR and len(ap.server.mission) == 3
    run_until(ap, lambda ms: ap.state.mission_complete)
    ap.receive(clear, 0.0)
    [ack] = [m for m in drain(ap) if m.get_type() == "MISSION_ACK"]
    assert ack.type == mavlink.MAV_MISSION_ACCEPTED and ap.server.mission == []
