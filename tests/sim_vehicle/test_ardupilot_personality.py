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
from sim_vehicle.ardupilot import NO_SPACE_AFTER_BOOT_S, ArduCopterAutopilot
from sim_vehicle.state import VehicleSettings
from tests.helpers.autopilot import command, copter_mission, download, make, rx, upload
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
