"""The pure mission / command state machines against an in-memory fake vehicle.

Messages really go through bytes (our Codec -> Parser both ways), time is simulated, and loss is
simulated by dropping packets on either side.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import pytest

from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.tasks import SENSOR_LAG_COMMAND, Phase, TaskStyle, TraceTask, Waypoint
from econdor_gcs.errors import MissionRejected, ProtocolError, VehicleTimeout
from econdor_gcs.link.codec import Codec, Parser, mavlink
from econdor_gcs.link.items import (
    MissionItemSpec,
    build_mission,
    plan_mission,
    sensor_lag_item,
    trace_item,
    waypoint_item,
)
from econdor_gcs.link.transfer import (
    CommandSender,
    MissionClear,
    MissionDownloader,
    MissionUploader,
)

ORIGIN = Origin(47.397742, 8.545594, 488.0)
SYSID = 2


class FakeVehicle:
    """A minimal mission server + command handler (the vehicle side), no retries of its own."""

    def __init__(self, sysid: int = SYSID, *, legacy_requests: bool = False,
                 reject_item: tuple[int, int] | None = None,
                 command_results: list[int] | None = None,
                 mission: list[MissionItemSpec] | None = None) -> None:
        self.sysid = sysid
        self.codec = Codec(sysid, 1)
        self.parser = Parser()
        self.legacy_requests = legacy_requests
        self.reject_item = reject_item  # (seq, MAV_MISSION_RESULT)
        self.command_results = list(command_results or [mavlink.MAV_RESULT_ACCEPTED])
        self.mission: list[MissionItemSpec] = list(mission or [])
        self.incoming: list[MissionItemSpec] = []
        self.expected_count: int | None = None
        self.received: list = []

    def _request(self, seq: int):
        if self.legacy_requests:
            return mavlink.MAVLink_mission_request_message(255, 190, seq, 0)
        return mavlink.MAVLink_mission_request_int_message(255, 190, seq, 0)

    def _ack(self, result: int):
        return mavlink.MAVLink_mission_ack_message(255, 190, result, 0)

    def handle(self, msg) -> list:
        self.received.append(msg)
        kind = msg.get_type()
        assert msg.get_srcSystem() == 255 and msg.get_srcComponent() == 190
        if kind == "MISSION_COUNT":
            self.expected_count, self.incoming = msg.count, []
            if msg.count == 0:
                self.mission = []
                return [self._ack(mavlink.MAV_MISSION_ACCEPTED)]
            return [self._request(0)]
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            if self.expected_count is None:
                return []
            if msg.seq == len(self.incoming):
                if self.reject_item and msg.seq == self.reject_item[0]:
                    self.expected_count = None
                    return [self._ack(self.reject_item[1])]
                self.incoming.append(MissionItemSpec.from_message(msg))
            if len(self.incoming) == self.expected_count:
                self.mission = list(self.incoming)
                return [self._ack(mavlink.MAV_MISSION_ACCEPTED)]
            return [self._request(len(self.incoming))]
        if kind == "MISSION_REQUEST_LIST":
            return [mavlink.MAVLink_mission_count_message(255, 190, len(self.mission), 0)]
        if kind == "MISSION_REQUEST_INT":
            return [self.mission[msg.seq].to_message(255, 190)]
        if kind == "MISSION_CLEAR_ALL":
            self.mission = []
            return [self._ack(mavlink.MAV_MISSION_ACCEPTED)]
        if kind == "COMMAND_LONG":
            result = self.command_results.pop(0) if len(self.command_results) > 1 \
                else self.command_results[0]
            if result is None:  # scripted silence
                return []
            return [mavlink.MAVLink_command_ack_message(msg.command, result, 50, 0, 255, 190)]
        return []


Drop = Callable[[int, str], bool]


def never(_i: int, _kind: str) -> bool:
    return False


def drive(machine, vehicle: FakeVehicle | None, *, drop_up: Drop = never,
          drop_down: Drop = never, max_steps: int = 10_000) -> float:
    """Run ``machine`` to completion against ``vehicle`` in simulated time; return the end time."""
    gcs_codec, gcs_parser = Codec(), Parser()
    now, up, down = 100.0, 0, 0
    for _ in range(max_steps):
        out = machine.poll(now)
        for msg in out:
            data = gcs_codec.encode(msg)
            up += 1
            if vehicle is None or drop_up(up, msg.get_type()):
                continue
            for decoded in vehicle.parser.feed(data):
                for reply in vehicle.handle(decoded):
                    raw = vehicle.codec.encode(reply)
                    down += 1
                    if drop_down(down, reply.get_type()):
                        continue
                    for back in gcs_parser.feed(raw):
                        assert back.get_srcSystem() == vehicle.sysid
                        machine.receive(back, now)
        if not out:
            if machine.done:  # the outbox was flushed by this poll
                return now
            deadline = machine.next_deadline()
            assert deadline is not None
            now = max(now, deadline)
    raise AssertionError("machine never finished")


def sample_items() -> list[MissionItemSpec]:
    tasks = [TraceTask(42.5, 30.0, 40.0, 15.0, 0.0, 7), Waypoint(80.0, 10.0),
             TraceTask(61.25, 55.0, 60.0, 10.0, 250.0, 8)]
    return build_mission(ORIGIN, tasks, altitude_m=20.0, home=(5.0, 5.0), end="rtl")


def test_upload_succeeds_and_stores_items_verbatim():
    items = sample_items()
    vehicle = FakeVehicle()
    up = MissionUploader(SYSID, 1, items)
    drive(up, vehicle)
    assert up.done and up.error is None and up.result == len(items)
    assert vehicle.mission == items
    kinds = [m.get_type() for m in vehicle.received]
    assert kinds == ["MISSION_COUNT"] + ["MISSION_ITEM_INT"] * len(items)
    assert all(m.frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT for m in vehicle.received[1:])
    assert up.retries_used == 0


def test_upload_survives_lost_requests_and_items():
    items = sample_items()
    vehicle = FakeVehicle()
    up = MissionUploader(SYSID, 1, items, timeout_s=1.0, retries=3)
    # lose every 3rd packet towards the vehicle and every 2nd MISSION_REQUEST_INT back
    end = drive(up, vehicle, drop_up=lambda i, k: i % 3 == 0,
                drop_down=lambda i, k: k == "MISSION_REQUEST_INT" and i % 2 == 0)
    assert up.error is None, up.error
    assert vehicle.mission == items
    assert up.retries_used > 0
    assert end > 100.0  # some timeouts really happened


def test_upload_survives_lost_final_ack():
    items = sample_items()[:3]
    vehicle = FakeVehicle()
    up = MissionUploader(SYSID, 1, items, timeout_s=1.0, retries=2)
    drive(up, vehicle, drop_down=lambda i, k: k == "MISSION_ACK" and i == 3)
    assert up.error is None and up.result == 3
    assert vehicle.mission == items


def test_upload_times_out_when_retries_exhausted():
    up = MissionUploader(SYSID, 1, sample_items(), timeout_s=0.5, retries=3)
    sent: list[str] = []

    def lose_every_message(i: int, kind: str) -> bool:
        sent.append(kind)
        return True

    vehicle = FakeVehicle()
    end = drive(up, vehicle, drop_up=lose_every_message)
    assert isinstance(up.error, VehicleTimeout)
    assert "vehicle 2" in str(up.error) and "mission upload" in str(up.error)
    assert sent == ["MISSION_COUNT"] * 4  # first send + 3 retries
    assert end == pytest.approx(100.0 + 4 * 0.5)
    assert up.next_deadline() is None and up.poll(end + 10) == []


def test_upload_rejection_names_the_enum_and_item():
    vehicle = FakeVehicle(reject_item=(3, mavlink.MAV_MISSION_UNSUPPORTED_FRAME))
    up = MissionUploader(SYSID, 1, sample_items())
    drive(up, vehicle)
    assert isinstance(up.error, ProtocolError)
    assert str(up.error) == "vehicle 2 rejected mission item 3: MAV_MISSION_UNSUPPORTED_FRAME"


def test_upload_rejection_of_count():
    class NoSpace(FakeVehicle):
        def handle(self, msg):
            return [self._ack(mavlink.MAV_MISSION_NO_SPACE)]

    up = MissionUploader(SYSID, 1, sample_items())
    drive(up, NoSpace())
    assert isinstance(up.error, ProtocolError)
    assert "MAV_MISSION_NO_SPACE" in str(up.error)


@pytest.mark.parametrize("legacy_items", [False, True])
def test_upload_to_a_legacy_requester(legacy_items):
    items = sample_items()
    vehicle = FakeVehicle(legacy_requests=True)
    up = MissionUploader(SYSID, 1, items, legacy_items=legacy_items)
    drive(up, vehicle)
    assert up.error is None
    expected = "MISSION_ITEM" if legacy_items else "MISSION_ITEM_INT"
    assert {m.get_type() for m in vehicle.received[1:]} == {expected}
    if legacy_items:
        # float frames, float degrees: float32 degrees, ~4e-6 deg (~0.4 m) at 47 deg
        assert vehicle.received[1].frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
        for got, want in zip(vehicle.mission, items, strict=True):
            assert (got.command, got.frame, got.seq) == (want.command, want.frame, want.seq)
            assert abs(got.x - want.x) <= 40 and abs(got.y - want.y) <= 40
    else:
        assert vehicle.mission == items


def test_upload_empty_mission():
    vehicle = FakeVehicle(mission=sample_items())
    up = MissionUploader(SYSID, 1, [])
    drive(up, vehicle)
    assert up.error is None and up.result == 0 and vehicle.mission == []


def test_uploader_ignores_a_stale_accept_and_cancels_a_transfer_of_another_type():
    """Before item 0 is asked for, an ACCEPTED is a stale answer; a request of another
    mission type (or for another item) is the vehicle's earlier transfer with this station:
    cancelled (in its type), then the count again, once per count sent."""
    up = MissionUploader(SYSID, 1, sample_items(), timeout_s=1.0)
    assert [m.get_type() for m in up.poll(0.0)] == ["MISSION_COUNT"]
    up.receive(mavlink.MAVLink_mission_ack_message(255, 190, 0, 0), 0.1)
    assert not up.done and up.poll(0.1) == []
    fence = mavlink.MAV_MISSION_TYPE_FENCE
    up.receive(mavlink.MAVLink_mission_request_int_message(255, 190, 0, fence), 0.1)
    cancel, count = up.poll(0.1)
    assert (cancel.get_type(), cancel.type, cancel.mission_type) == (
        "MISSION_ACK", mavlink.MAV_MISSION_OPERATION_CANCELLED, fence)
    assert (count.get_type(), count.mission_type) == ("MISSION_COUNT", 0)
    up.receive(mavlink.MAVLink_mission_request_int_message(255, 190, 3, 0), 0.15)  # in flight
    assert not up.done and up.poll(0.2) == [] and up.stale_transfers == 1
    # no answer to that count: the count again, after which a stale request is cancelled again
    assert [m.get_type() for m in up.poll(1.2)] == ["MISSION_COUNT"]
    up.receive(mavlink.MAVLink_mission_request_int_message(255, 190, 3, 0), 1.3)
    assert [m.get_type() for m in up.poll(1.3)] == ["MISSION_ACK", "MISSION_COUNT"]
    for seq in range(len(up.items)):
        up.receive(mavlink.MAVLink_mission_request_int_message(255, 190, seq, 0), 1.4)
    up.receive(mavlink.MAVLink_mission_ack_message(255, 190, 0, 0), 1.5)
    assert up.done and up.error is None and up.stale_transfers == 2


def test_an_old_transfer_that_took_our_items_is_started_again():
    """PX4 asked for item 0 of its old transfer (same type, another count) and took ours:
    a request beyond our count, or an ACCEPTED before our last item was asked for, starts
    ours again (its cancel, then the count); a vehicle that keeps doing so is an error
    once the retries are spent."""
    items = sample_items()
    n = len(items)
    longer = MissionUploader(SYSID, 1, items, timeout_s=1.0, retries=1)
    longer.poll(0.0)
    for seq in range(n + 1):  # the old transfer had one more item
        longer.receive(mavlink.MAVLink_mission_request_int_message(255, 190, seq, 0), 0.1)
    cancel, count = longer.poll(0.1)[-2:]
    assert (cancel.type, count.get_type()) == (mavlink.MAV_MISSION_OPERATION_CANCELLED,
                                               "MISSION_COUNT")
    assert not longer.done and not longer.requested
    for seq in range(n + 1):
        longer.receive(mavlink.MAVLink_mission_request_int_message(255, 190, seq, 0), 0.2)
    assert isinstance(longer.error, ProtocolError) and f"item {n} of a {n}-item" in str(
        longer.error)
    shorter = MissionUploader(SYSID, 1, items, timeout_s=1.0)
    shorter.poll(0.0)
    for seq in range(n - 1):  # the old transfer had one item fewer
        shorter.receive(mavlink.MAVLink_mission_request_int_message(255, 190, seq, 0), 0.1)
    shorter.receive(mavlink.MAVLink_mission_ack_message(255, 190, 0, 0), 0.1)
    assert [m.get_type() for m in shorter.poll(0.1)][-2:] == ["MISSION_ACK", "MISSION_COUNT"]
    for seq in range(n):
        shorter.receive(mavlink.MAVLink_mission_request_int_message(255, 190, seq, 0), 0.2)
    shorter.receive(mavlink.MAVLink_mission_ack_message(255, 190, 0, 0), 0.3)
    assert shorter.done and shorter.error is None and shorter.result == n


@pytest.mark.parametrize("result", [mavlink.MAV_MISSION_ERROR,
                                    mavlink.MAV_MISSION_OPERATION_CANCELLED,
                                    mavlink.MAV_MISSION_INVALID_SEQUENCE])
def test_an_answer_to_the_attempt_before_does_not_end_the_upload_running(result):
    """An upload started again (ArduPilot cancelled the one before, its 8 s being 40 ms of
    wall time at 200x): the vehicle's answer to the last item of the attempt before (ERROR:
    no transfer running) arrives after the new MISSION_COUNT. The vehicle then requests item
    0 of the new transfer: the upload goes on and completes. The same answer with no request
    after it is the vehicle's verdict, at the timeout."""
    items = sample_items()
    up = MissionUploader(SYSID, 1, items, timeout_s=1.0)
    assert [m.get_type() for m in up.poll(0.0)] == ["MISSION_COUNT"]
    up.receive(mavlink.MAVLink_mission_ack_message(255, 190, result, 0), 0.05)
    assert not up.done
    for seq in range(len(items)):
        up.receive(mavlink.MAVLink_mission_request_int_message(255, 190, seq, 0), 0.1)
    up.receive(mavlink.MAVLink_mission_ack_message(255, 190, mavlink.MAV_MISSION_ACCEPTED, 0),
               0.2)
    assert up.done and up.error is None and up.result == len(items) and up.stale_acks == 1
    alone = MissionUploader(SYSID, 1, items, timeout_s=1.0)
    alone.poll(0.0)
    alone.receive(mavlink.MAVLink_mission_ack_message(255, 190, result, 0), 0.05)
    assert not alone.done
    alone.poll(1.5)
    assert alone.done and isinstance(alone.error, MissionRejected)
    assert alone.error.result == result


def test_uploader_rejects_misnumbered_items():
    items = sample_items()
    with pytest.raises(ValueError, match="seq"):
        MissionUploader(SYSID, 1, items[1:])


def test_download_round_trips_items_despite_loss():
    items = sample_items()
    vehicle = FakeVehicle(mission=items)
    down = MissionDownloader(SYSID, 1, timeout_s=1.0, retries=3)
    drive(down, vehicle, drop_up=lambda i, k: i % 4 == 2 and k != "MISSION_ACK",
          drop_down=lambda i, k: i % 5 == 1)
    assert down.error is None, down.error
    assert down.result == items
    assert down.retries_used > 0
    assert vehicle.received[-1].get_type() == "MISSION_ACK"
    assert vehicle.received[-1].type == mavlink.MAV_MISSION_ACCEPTED


def test_download_empty_and_timeout():
    down = MissionDownloader(SYSID, 1)
    drive(down, FakeVehicle(mission=[]))
    assert down.result == [] and down.error is None

    down = MissionDownloader(SYSID, 1, timeout_s=0.2, retries=1)
    drive(down, None)
    assert isinstance(down.error, VehicleTimeout)
    assert "MISSION_COUNT" in str(down.error)


def test_clear():
    vehicle = FakeVehicle(mission=sample_items())
    clear = MissionClear(SYSID, 1, timeout_s=0.5)
    drive(clear, vehicle, drop_up=lambda i, k: i == 1)
    assert clear.result is True and clear.error is None and vehicle.mission == []
    assert clear.retries_used == 1

    class Refuses(FakeVehicle):
        def handle(self, msg):
            return [self._ack(mavlink.MAV_MISSION_DENIED)]

    clear = MissionClear(SYSID, 1)
    drive(clear, Refuses())
    assert isinstance(clear.error, ProtocolError)
    assert "MAV_MISSION_DENIED" in str(clear.error)


ARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM


def test_command_accepted():
    vehicle = FakeVehicle()
    cmd = CommandSender(SYSID, 1, ARM, [1])
    drive(cmd, vehicle)
    assert cmd.error is None and cmd.result.result == mavlink.MAV_RESULT_ACCEPTED
    sent = vehicle.received[0]
    assert (sent.command, sent.param1, sent.confirmation) == (ARM, 1.0, 0)


def test_command_retry_increments_confirmation():
    vehicle = FakeVehicle()
    cmd = CommandSender(SYSID, 1, ARM, [1], timeout_s=0.5, retries=3)
    drive(cmd, vehicle, drop_up=lambda i, k: i <= 2)
    assert cmd.error is None
    assert [m.confirmation for m in vehicle.received] == [2]  # the first two were lost
    assert cmd.confirmation == 2


def test_command_in_progress_keeps_waiting_without_resending():
    cmd = CommandSender(SYSID, 1, mavlink.MAV_CMD_NAV_TAKEOFF, timeout_s=1.0, retries=1)
    assert len(cmd.poll(0.0)) == 1
    ack = mavlink.MAVLink_command_ack_message
    for t in (0.8, 1.6, 2.4):  # each IN_PROGRESS pushes the deadline out
        cmd.receive(ack(mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_RESULT_IN_PROGRESS, 40,
                        0, 255, 190), t)
        assert cmd.poll(t + 0.5) == []
    assert cmd.progress == 40 and not cmd.done
    cmd.receive(ack(mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 255, 190), 3.0)
    assert cmd.done and cmd.error is None


def test_command_denied_names_command_and_result():
    cmd = CommandSender(SYSID, 1, ARM, [1])
    drive(cmd, FakeVehicle(command_results=[mavlink.MAV_RESULT_DENIED]))
    assert isinstance(cmd.error, ProtocolError)
    assert str(cmd.error) == \
        "vehicle 2 answered MAV_CMD_COMPONENT_ARM_DISARM with MAV_RESULT_DENIED"


def test_command_ignores_acks_of_other_commands_and_times_out():
    cmd = CommandSender(SYSID, 1, ARM, [1], timeout_s=0.25, retries=2)
    drive(cmd, FakeVehicle(command_results=[None]))
    assert isinstance(cmd.error, VehicleTimeout)
    assert "MAV_CMD_COMPONENT_ARM_DISARM" in str(cmd.error)
    cmd = CommandSender(SYSID, 1, ARM, [1], timeout_s=0.25, retries=0)
    cmd.poll(0.0)
    cmd.receive(mavlink.MAVLink_command_ack_message(
        mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_RESULT_DENIED, 0, 0, 255, 190), 0.1)
    assert not cmd.done


# -- mission building ---------------------------------------------------------------------------


def test_build_mission_layout():
    items = sample_items()
    cmds = [it.command for it in items]
    assert cmds == [mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_TAKEOFF, 31000,
                    mavlink.MAV_CMD_NAV_WAYPOINT, 31000, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH]
    assert [it.seq for it in items] == list(range(len(items)))
    assert [it.current for it in items] == [1] + [0] * (len(items) - 1)
    assert {it.frame for it in items} == {mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
    assert {it.mission_type for it in items} == {0}
    trace = items[2]
    assert (trace.param1, trace.param2, trace.param3, trace.param4) == (42.5, 15.0, 0.0, 7.0)
    assert trace.z == 20.0
    x, y, _ = ORIGIN.to_local(trace.lat_deg, trace.lon_deg)
    assert x == pytest.approx(30.0, abs=0.02) and y == pytest.approx(40.0, abs=0.02)
    hx, hy, _ = ORIGIN.to_local(items[0].lat_deg, items[0].lon_deg)
    assert hx == pytest.approx(5.0, abs=0.02) and hy == pytest.approx(5.0, abs=0.02)
    assert items[0].z == 0.0 and items[1].z == 20.0


def test_build_mission_end_options():
    tasks = [Waypoint(10.0, 20.0)]
    loiter = build_mission(ORIGIN, tasks, 15.0, end="loiter")
    assert loiter[-1].command == mavlink.MAV_CMD_NAV_LOITER_UNLIM
    assert (loiter[-1].x, loiter[-1].y, loiter[-1].z) == (loiter[-2].x, loiter[-2].y, 15.0)
    none = build_mission(ORIGIN, tasks, 15.0, end="none")
    assert len(none) == 3 and none[-1].command == mavlink.MAV_CMD_NAV_WAYPOINT
    with pytest.raises(ValueError, match="end"):
        build_mission(ORIGIN, tasks, 15.0, end="land")
    with pytest.raises(ValueError, match="altitude"):
        build_mission(ORIGIN, tasks, 0.0)


def test_item_helpers_and_message_round_trip():
    item = trace_item(4, 47.4, 8.5, 25.0, 12.5, 20.0, 300.0, 11)
    assert item.command == 31000 and item.x == 474000000 and item.y == 85000000
    msg = item.to_message(SYSID, 1)
    assert msg.get_type() == "MISSION_ITEM_INT" and msg.target_system == SYSID
    assert MissionItemSpec.from_message(msg) == item
    wp = waypoint_item(1, 47.4, 8.5, 10.0)
    assert MissionItemSpec.from_message(wp.to_legacy_message(SYSID, 1)) == wp


def _told(level: float, piece: int, lag_s: float | None) -> TraceTask:
    return TraceTask(level, 30.0, 40.0, 15.0, 0.0, piece, route_m=((30.0, 40.0), (50.0, 40.0)),
                     sensor_lag_s=lag_s)


def test_the_sensor_lag_item_goes_before_a_trace_item_once_and_again_on_change():
    tasks = [Waypoint(80.0, 10.0), _told(1.0, 1, 0.75), _told(2.0, 2, 0.75), Waypoint(5.0, 5.0),
             _told(3.0, 3, None), _told(4.0, 4, 1.25), _told(5.0, 5, 0.75)]
    plan = plan_mission(ORIGIN, tasks, 20.0, speed_mps=6.0, end="none")
    cmds = [it.command for it in plan.items]
    user_1, lag, wp = 31000, SENSOR_LAG_COMMAND, mavlink.MAV_CMD_NAV_WAYPOINT
    assert cmds == [wp, mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_DO_CHANGE_SPEED, wp,
                    lag, user_1, user_1, wp, user_1, lag, user_1, lag, user_1]
    assert [plan.items[s].param1 for s in (4, 9, 11)] == [0.75, 1.25, 0.75]
    assert plan.items[4] == sensor_lag_item(4, 0.75)
    # the lag items belong to no task: the tasks' items, phases and last seq are the trace
    # items', numbered on past them
    assert plan.task_seqs == [(3, 3), (5, 5), (6, 6), (7, 7), (8, 8), (10, 10), (12, 12)]
    assert plan.last_task_seq == 12 and 4 not in plan.item_phases
    assert {plan.item_phases[s] for s in (5, 6, 8, 10, 12)} == {Phase.SEARCH}
    assert [it.seq for it in plan.items] == list(range(len(plan.items)))
    # no lag told, no item: the mission is what it was
    untold = [dataclasses.replace(t, sensor_lag_s=None) if isinstance(t, TraceTask) else t
              for t in tasks]
    assert SENSOR_LAG_COMMAND not in [it.command for it in
                                      plan_mission(ORIGIN, untold, 20.0, end="none").items]
    # each mission tells the lag afresh (a vehicle may be new to this one)
    again = plan_mission(ORIGIN, tasks[2:3], 20.0, end="none")
    assert [it.command for it in again.items][2:] == [lag, user_1]
    # a lag of unknown size is told apart from a zero one (param2 = 1), and when it
    # becomes known the lag is told again
    unknown = dataclasses.replace(_told(1.0, 1, 0.0), lag_unknown=True)
    plan = plan_mission(ORIGIN, [unknown, unknown, _told(2.0, 2, 0.0), _told(3.0, 3, 0.9)],
                        20.0, end="none")
    told = [(it.param1, it.param2) for it in plan.items if it.command == lag]
    assert told == [(0.0, 1.0), (0.0, 0.0), (0.9, 0.0)]


def test_a_waypoint_mission_has_no_sensor_lag_item():
    plan = plan_mission(ORIGIN, [_told(1.0, 1, 0.75)], 20.0, style=TaskStyle.WAYPOINTS,
                        end="none")
    assert SENSOR_LAG_COMMAND not in [it.command for it in plan.items]


def test_the_sensor_lag_item_has_no_position_and_survives_the_wire():
    item = sensor_lag_item(3, 0.8125)
    assert (item.frame, item.command, item.param1) == (mavlink.MAV_FRAME_MISSION, 31013, 0.8125)
    assert (item.x, item.y, item.z) == (0, 0, 0.0)
    assert MissionItemSpec.from_message(item.to_message(SYSID, 1)) == item
    assert MissionItemSpec.from_message(item.to_legacy_message(SYSID, 1)) == item


def test_a_clear_is_not_answered_by_the_end_of_an_upload_given_up():
    """ArduPilot's OPERATION_CANCELLED for an upload the station left (its 8 s over) can
    arrive while a clear is on its way: the clear's own answer is the one that counts."""
    clear = MissionClear(SYSID, 1, mavlink.MAV_MISSION_TYPE_RALLY)
    assert [m.get_type() for m in clear.poll(0.0)] == ["MISSION_CLEAR_ALL"]
    clear.receive(mavlink.MAVLink_mission_ack_message(
        255, 190, mavlink.MAV_MISSION_OPERATION_CANCELLED, mavlink.MAV_MISSION_TYPE_RALLY), 0.1)
    assert not clear.done
    clear.receive(mavlink.MAVLink_mission_ack_message(
        255, 190, mavlink.MAV_MISSION_ACCEPTED, mavlink.MAV_MISSION_TYPE_RALLY), 0.2)
    assert clear.done and clear.error is None and clear.result is True
    refused = MissionClear(SYSID, 1)
    refused.poll(0.0)
    refused.receive(mavlink.MAVLink_mission_ack_message(255, 190, mavlink.MAV_MISSION_DENIED,
                                                        0), 0.1)
    assert isinstance(refused.error, ProtocolError)
