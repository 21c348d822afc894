"""The vehicle's autopilot as an I/O-free state machine: messages in, outbox out, no sockets."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.tasks import SENSOR_LAG_COMMAND
from econdor_gcs.link.transfer import MissionUploader
from sim_vehicle import navigator
from sim_vehicle.ardupilot import (
    COPTER_AUTO,
    COPTER_GUIDED,
    COPTER_STABILIZE,
    ArduCopterAutopilot,
)
from sim_vehicle.px4 import PX4_MODES, Px4Autopilot
from sim_vehicle.state import FlightMode
from tests.helpers.autopilot import (
    DECODER,
    GCS,
    MISSION,
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


def test_px4_boots_landed_in_hold_and_denies_flight_commands_until_armed():
    ap = make()
    assert ap.state.mode == FlightMode.HOLD and ap.custom_mode() == PX4_MODES[FlightMode.HOLD]
    assert ap.parked
    hb = ap.telemetry.heartbeat()
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert command(ap, mavlink.MAV_CMD_NAV_TAKEOFF)[0] == mavlink.MAV_RESULT_DENIED
    assert command(ap, mavlink.MAV_CMD_MISSION_START)[0] == mavlink.MAV_RESULT_DENIED
    result, out = command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert result == mavlink.MAV_RESULT_ACCEPTED and ap.state.armed
    # the ACK comes before the heartbeat that shows the new state
    kinds = [m.get_type() for m in out]
    assert kinds.index("COMMAND_ACK") < kinds.index("HEARTBEAT")
    assert out[kinds.index("HEARTBEAT")].base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def test_mission_flown_by_ticks_alone_reports_samples_and_progress():
    ap = make(sample_rate_hz=10.0)
    upload(ap, [item_int(0, mavlink.MAV_CMD_NAV_TAKEOFF, alt=10, current=1),
                item_int(1, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(30, 0), 10)])
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert command(ap, mavlink.MAV_CMD_MISSION_START)[0] == mavlink.MAV_RESULT_ACCEPTED
    assert ap.state.mode == FlightMode.MISSION
    msgs = run_until(ap, lambda ms: any(m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 1
                                        for m in ms))
    gpi = [m for m in msgs if m.get_type() == "GLOBAL_POSITION_INT"]
    fields = [m for m in msgs if m.get_type() == "NAMED_VALUE_FLOAT"]
    assert len(gpi) == len(fields) > 20  # only the horizontal leg is sampled, in pairs
    assert [g.time_boot_ms for g in gpi] == [f.time_boot_ms for f in fields]
    assert all(g.relative_alt == pytest.approx(10000, abs=50) for g in gpi)
    x, y, _ = MISSION.origin.to_local(gpi[-1].lat / 1e7, gpi[-1].lon / 1e7)
    assert math.hypot(x - 30, y) < 1.5
    assert ap.state.mode == FlightMode.HOLD and ap.state.mission_complete


def test_px4_do_set_mode_encoding_and_rtl_lands_and_disarms():
    ap = make()
    assert ap.do_set_mode(1, 4, 4) == mavlink.MAV_RESULT_DENIED  # AUTO.MISSION, no mission
    assert ap.do_set_mode(1, 6, 0) == mavlink.MAV_RESULT_DENIED  # OFFBOARD: not here
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ap.do_set_mode(1, 4, 2) == mavlink.MAV_RESULT_ACCEPTED  # AUTO.TAKEOFF
    run_until(ap, lambda ms: ap.state.mode == FlightMode.HOLD)
    assert ap.state.alt_rel_m == pytest.approx(MISSION.vehicles.altitude_m)
    assert ap.do_set_mode(1, 4, 5) == mavlink.MAV_RESULT_ACCEPTED  # AUTO.RTL
    msgs = run_until(ap, lambda ms: not ap.state.armed)
    assert ap.state.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
    assert any(m.get_type() == "STATUSTEXT" and m.text.startswith("landed") for m in msgs)
    assert ap.parked


def test_the_tracks_of_a_flight_are_kept_through_it_and_forgotten_at_the_next_arming():
    """A trace ends where it comes onto a track of its level flown before: in the same
    flight only (a later run of the same mission is traced afresh)."""
    import numpy as np

    ap = make()
    track = np.array([[1.0, 2.0, 0.0, 1.0, 0.0], [2.0, 2.0, 1.0, 1.0, 0.0]])
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    ap.state.body.remember_track(5.0, track)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)  # already armed: the same flight
    ap.state.rebuild_body(ap.state.body.t_s)  # a new sample rate: the same flight
    np.testing.assert_array_equal(ap.state.body.traced_track(5.0), track)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert len(ap.state.body.traced_track(5.0)) == 0


# -- the ArduCopter personality -------------------------------------------------------------


def test_ardupilot_boots_in_stabilize_and_streams_only_when_asked():
    ap = make(ArduCopterAutopilot)
    hb = ap.telemetry.heartbeat()
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.custom_mode == COPTER_STABILIZE and ap.mode_name() == "STABILIZE"
    ap.one_hz(0.0)
    ap.telemetry.periodic(0.0)
    assert [m.get_type() for m in ap.outbox.drain(0.0)] == ["HEARTBEAT"]
    ap.receive(rx(mavlink.MAVLink_request_data_stream_message(
        1, 1, mavlink.MAV_DATA_STREAM_ALL, 4, 1)), 0.0)
    ap.one_hz(1.0)
    ap.telemetry.periodic(1.0)
    kinds = {m.get_type() for m in ap.outbox.drain(1.0)}
    assert {"HEARTBEAT", "SYS_STATUS", "EXTENDED_SYS_STATE", "GLOBAL_POSITION_INT",
            "ATTITUDE"} <= kinds
    # the asked rate (4 Hz of sim time) paces the position stream
    assert ap.telemetry.intervals[mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] == 0.25


def test_ardupilot_refuses_to_arm_until_its_prearm_checks_pass():
    ap = make(ArduCopterAutopilot, now=100.0, prearm_s=2.0)
    assert not ap.telemetry.sys_status().onboard_control_sensors_health \
        & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    result, out = command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, now=101.0)
    assert result == mavlink.MAV_RESULT_FAILED and not ap.state.armed
    assert any(m.get_type() == "STATUSTEXT" and m.text.startswith("PreArm:") for m in out)
    # forcing (2989) skips the checks, as in ArduPilot
    ap2 = make(ArduCopterAutopilot, now=100.0, prearm_s=2.0)
    assert command(ap2, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, 2989, now=100.5)[0] == 0
    result, _ = command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, now=102.5)
    assert result == mavlink.MAV_RESULT_ACCEPTED and ap.state.armed
    assert ap.telemetry.sys_status().onboard_control_sensors_health \
        & mavlink.MAV_SYS_STATUS_PREARM_CHECK


def test_ardupilot_mission_protocol_habits():
    ap = make(ArduCopterAutopilot)
    trace = item_int(3, 31000, *ll(50, 50), 10, p1=42.0, p2=10, p4=7)
    # a stock ArduPilot refuses the contour item (and keeps the items before it) ...
    upload(ap, [*copter_mission(), trace], expect=mavlink.MAV_MISSION_UNSUPPORTED,
           request="MISSION_REQUEST")
    assert [it.seq for it in ap.server.mission] == [0, 1, 2]
    # ... with a companion computer it is accepted
    upload(make(ArduCopterAutopilot, companion=True), [*copter_mission(), trace],
           request="MISSION_REQUEST")
    upload(ap, copter_mission(), request="MISSION_REQUEST")
    back = download(ap)
    o = MISSION.origin
    # item 0 is home, whatever was uploaded, in the absolute frame
    assert (back[0].frame, back[0].x, back[0].y) == (
        mavlink.MAV_FRAME_GLOBAL, round(o.lat_deg * 1e7), round(o.lon_deg * 1e7))
    assert back[0].z == pytest.approx(o.alt_m)
    # the others in the float frame, altitudes in centimetres
    assert [m.frame for m in back[1:]] == [mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT] * 2
    assert back[2].z == pytest.approx(10.12, abs=1e-4)
    assert (back[2].x, back[2].y) == (copter_mission()[2].x, copter_mission()[2].y)
    legacy = download(ap, legacy=True)
    assert legacy[2].get_type() == "MISSION_ITEM" and legacy[2].frame == 3


def test_ardupilot_guided_arm_takeoff_then_auto_flies_the_mission_and_stays_in_auto():
    ap = make(ArduCopterAutopilot, prearm_s=0.0)
    upload(ap, copter_mission(), request="MISSION_REQUEST")
    assert ap.do_set_mode(1, COPTER_GUIDED, 0) == mavlink.MAV_RESULT_ACCEPTED
    assert command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)[0] == 0
    # ArduCopter: param7 is the altitude above home
    assert command(ap, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 12.0)[0] == 0
    run_until(ap, lambda ms: ap.state.alt_rel_m >= 12.0 - 1e-6)
    assert ap.custom_mode() == COPTER_GUIDED
    assert ap.do_set_mode(1, COPTER_AUTO, 0) == mavlink.MAV_RESULT_ACCEPTED
    msgs = run_until(ap, lambda ms: ap.state.mission_complete)
    reached = [m.seq for m in msgs if m.get_type() == "MISSION_ITEM_REACHED"]
    assert reached == [1, 2]  # item 0 (home) is never flown
    assert ap.custom_mode() == COPTER_AUTO and ap.state.in_air  # hovering in AUTO
    # RTL lands, disarms and stays in RTL
    assert ap.do_set_mode(1, 6, 0) == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: not ap.state.armed)
    assert ap.mode_name() == "RTL"


def test_ardupilot_arm_then_mission_start_and_its_refusals():
    ap = make(ArduCopterAutopilot, prearm_s=0.0)
    assert command(ap, mavlink.MAV_CMD_MISSION_START)[0] == mavlink.MAV_RESULT_FAILED
    upload(ap, copter_mission(), request="MISSION_REQUEST")
    assert ap.do_set_mode(1, COPTER_AUTO, 0) == mavlink.MAV_RESULT_ACCEPTED
    result, out = command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert result == mavlink.MAV_RESULT_FAILED  # not armable in AUTO
    assert any(m.get_type() == "STATUSTEXT" and "not armable" in m.text for m in out)
    assert ap.do_set_mode(1, 42, 0) == mavlink.MAV_RESULT_FAILED  # no such mode
    assert ap.do_set_mode(1, COPTER_GUIDED, 0) == 0
    assert command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)[0] == 0
    # ArduCopter (SITL): "first-item/last item not supported": only (0, 0) starts it
    assert command(ap, mavlink.MAV_CMD_MISSION_START, 1, 0)[0] == mavlink.MAV_RESULT_DENIED
    assert command(ap, mavlink.MAV_CMD_MISSION_START, 0, 0)[0] == 0
    assert ap.custom_mode() == COPTER_AUTO
    msgs = run_until(ap, lambda ms: ap.state.mission_complete)
    assert [m.seq for m in msgs if m.get_type() == "MISSION_ITEM_REACHED"] == [1, 2]


def test_nan_in_integer_params_is_answered_not_crashed():
    """MAVSDK sends NaN for unused params (arming's param2 among them)."""
    nan = float("nan")
    ap = make()
    assert command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, nan)[0] == 0
    assert command(ap, mavlink.MAV_CMD_DO_SET_MISSION_CURRENT, nan)[0] == \
        mavlink.MAV_RESULT_DENIED
    assert command(ap, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, nan, 1e5)[0] == \
        mavlink.MAV_RESULT_DENIED
    assert command(ap, mavlink.MAV_CMD_REQUEST_MESSAGE, nan)[0] == mavlink.MAV_RESULT_UNSUPPORTED


def _resend(ap, cmd, confirmation, *params):
    p = list(params) + [0.0] * (7 - len(params))
    ap.receive(rx(mavlink.MAVLink_command_long_message(1, 1, cmd, confirmation, *p)), 0.0)
    acks = [m for m in ap.outbox.drain(0.0) if m.get_type() == "COMMAND_ACK"]
    assert len(acks) == 1
    return acks[0].result


def test_a_resent_command_is_answered_not_run_again():
    """On a lossy link the ACK of MISSION_START can be lost; the station resends it with
    ``confirmation`` 1. The vehicle answers again and keeps flying where it is (running it
    again would restart the mission); after landing, a resent RTL is still ACCEPTED."""
    ap = make(sample_rate_hz=10.0)
    upload(ap, [item_int(0, mavlink.MAV_CMD_NAV_TAKEOFF, alt=10, current=1),
                item_int(1, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(60, 0), 10),
                item_int(2, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(60, 60), 10)])
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert _resend(ap, mavlink.MAV_CMD_MISSION_START, 0, 1) == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: any(m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 1
                                 for m in ms))
    assert _resend(ap, mavlink.MAV_CMD_MISSION_START, 1, 1) == mavlink.MAV_RESULT_ACCEPTED
    msgs = run_until(ap, lambda ms: any(m.get_type() == "MISSION_ITEM_REACHED" for m in ms))
    assert [m.seq for m in msgs if m.get_type() == "MISSION_ITEM_REACHED"] == [2]  # not 0, 1
    assert ap.counters["commands_repeated"] == 1
    assert _resend(ap, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0) == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: not ap.state.armed)
    assert _resend(ap, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, 1) == mavlink.MAV_RESULT_ACCEPTED
    # a new command (confirmation 0) runs: on the ground, RTL is refused
    assert _resend(ap, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0) == mavlink.MAV_RESULT_DENIED


def test_a_mission_start_resent_after_a_new_upload_runs():
    """The next flight's MISSION_START is lost and resent (``confirmation`` 1) with the same
    parameters as the last flight's: after a new mission it is a new command, not a repeat."""
    ap = make(sample_rate_hz=10.0)
    first = [item_int(0, mavlink.MAV_CMD_NAV_TAKEOFF, alt=10, current=1),
             item_int(1, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(30, 0), 10)]
    upload(ap, first)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert _resend(ap, mavlink.MAV_CMD_MISSION_START, 0, 1) == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: any(m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 1
                                 for m in ms))
    upload(ap, [first[0], item_int(1, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(30, 40), 10)])
    assert _resend(ap, mavlink.MAV_CMD_MISSION_START, 1, 1) == mavlink.MAV_RESULT_ACCEPTED
    assert ap.counters["commands_repeated"] == 0
    msgs = run_until(ap, lambda ms: any(m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 1
                                        for m in ms))
    assert msgs  # the second mission was flown to its end


def test_samples_are_archived_and_resent_on_request():
    """The recovery commands: the count of a time range, then its samples again (with the
    phase in force: the companion reports phases), as the same GLOBAL_POSITION_INT + FIELD
    pairs."""
    from econdor_gcs.core.tasks import SAMPLE_COUNT_COMMAND, SAMPLE_RESEND_COMMAND

    ap = make(sample_rate_hz=10.0, companion=True)
    upload(ap, [item_int(0, mavlink.MAV_CMD_NAV_TAKEOFF, alt=10, current=1),
                item_int(1, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(30, 0), 10)])
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    command(ap, mavlink.MAV_CMD_MISSION_START)
    msgs = run_until(ap, lambda ms: any(m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 1
                                        for m in ms))
    sent = [m for m in msgs if m.get_type() == "NAMED_VALUE_FLOAT"]
    t0, t1 = sent[3].time_boot_ms, sent[9].time_boot_ms

    def ask(cmd, first, last):
        ap.receive(rx(mavlink.MAVLink_command_int_message(1, 1, 0, cmd, 0, 0, 0, 0, 0, 0,
                                                          first, last, 0)), 0.0)
        return ap.outbox.drain(0.0)

    out = ask(SAMPLE_COUNT_COMMAND, 0, 2**31 - 1)
    assert out[0].get_type() == "COMMAND_ACK" and out[0].result_param2 == len(sent)
    assert ask(SAMPLE_COUNT_COMMAND, t0, t1)[0].result_param2 == 7
    out = ask(SAMPLE_RESEND_COMMAND, t0, t1)
    assert out[0].get_type() == "COMMAND_ACK" and out[0].result_param2 == 7
    again = [m for m in out if m.get_type() == "NAMED_VALUE_FLOAT"]
    assert [(m.time_boot_ms, m.value) for m in again] == \
        [(m.time_boot_ms, m.value) for m in sent[3:10]]
    phase = [m for m in out if m.get_type() == "NAMED_VALUE_INT"]
    assert phase and phase[0].time_boot_ms <= t0  # the phase in force at the range start
    assert ask(SAMPLE_RESEND_COMMAND, 0, 2**31 - 1)[0].result == (
        mavlink.MAV_RESULT_DENIED if len(sent) > 400 else mavlink.MAV_RESULT_ACCEPTED)


def _gcs_heartbeat(ap, now):
    ap.receive(rx(mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)), now)


def _mission_state(ap) -> int:
    return ap.telemetry.mission_current().mission_state


@pytest.mark.parametrize(("cls", "action", "mode"), [
    (Px4Autopilot, "rtl", FlightMode.RTL), (ArduCopterAutopilot, "rtl", FlightMode.RTL),
    (Px4Autopilot, "hold", FlightMode.HOLD), (ArduCopterAutopilot, "hold", FlightMode.HOLD)])
def test_gcs_failsafe_leaves_the_mission_after_5_s_without_the_gcs_heartbeat(cls, action,
                                                                            mode):
    """ArduPilot's FS_GCS_ENABLE / FS_GCS_TIMEOUT (PX4's NAV_DLL_ACT): in the air, 5 wall s
    after the last GCS HEARTBEAT, the vehicle leaves its mission (RTL, or holds); its
    MISSION_CURRENT then says PAUSED. The GCS heard again does not send it back."""
    ap = make(cls, prearm_s=0.0, gcs_failsafe=action)
    upload(ap, [item_int(0, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(0, 0), current=1),
                item_int(1, mavlink.MAV_CMD_NAV_TAKEOFF, alt=10),
                item_int(2, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(80, 80), 10)],
           request="MISSION_REQUEST_INT" if cls is Px4Autopilot else "MISSION_REQUEST")
    _gcs_heartbeat(ap, 0.0)
    if cls is ArduCopterAutopilot:
        ap.set_mode(COPTER_GUIDED)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    first = 0 if cls is ArduCopterAutopilot else 1  # ArduCopter: MISSION_START(0, 0) only
    assert command(ap, mavlink.MAV_CMD_MISSION_START, first)[0] == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: math.hypot(ap.state.body.x_m, ap.state.body.y_m) > 10.0)
    assert _mission_state(ap) == mavlink.MISSION_STATE_ACTIVE
    ap.one_hz(4.9)
    assert ap.state.mode == FlightMode.MISSION and not ap.gcs_failsafe  # not yet
    ap.one_hz(5.1)
    ap.tick()  # the new activity's first step
    assert ap.gcs_failsafe and not ap.state.mission_active
    assert ap.state.mode == mode
    assert _mission_state(ap) == mavlink.MISSION_STATE_PAUSED
    texts = [m.text for m in ap.outbox.drain(0.0) if m.get_type() == "STATUSTEXT"]
    assert any(t.startswith("Failsafe: GCS heartbeat lost") for t in texts)
    _gcs_heartbeat(ap, 7.0)
    assert not ap.gcs_failsafe and ap.state.mode == mode  # no way back on its own
    if action == "rtl":
        run_until(ap, lambda ms: not ap.state.armed)
        assert ap.state.alt_rel_m == 0.0 and _mission_state(ap) == mavlink.MISSION_STATE_PAUSED


@pytest.mark.parametrize(("kw", "heard"), [({}, False), ({"gcs_failsafe": "off"}, True)])
def test_gcs_failsafe_needs_a_gcs_heard_once_and_can_be_off(kw, heard):
    ap = make(**kw)
    if heard:
        _gcs_heartbeat(ap, 0.0)
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    command(ap, mavlink.MAV_CMD_NAV_TAKEOFF)
    run_until(ap, lambda ms: ap.state.alt_rel_m > 5.0)
    mode = ap.state.mode
    ap.one_hz(60.0)
    ap.tick()
    assert not ap.gcs_failsafe and ap.state.mode == mode


# -- the sensor lag item ----------------------------------------------------------------------


def lag_item(seq, lag_s, unknown=0.0):
    return item_int(seq, SENSOR_LAG_COMMAND, p1=lag_s, p2=unknown,
                    frame=mavlink.MAV_FRAME_MISSION)


@pytest.mark.parametrize("cls", [Px4Autopilot, ArduCopterAutopilot])
def test_only_a_companion_takes_the_sensor_lag_item(cls):
    """The sensor lag item is for the onboard tracer: refused as the contour item is by a
    stock autopilot, taken by one with a companion computer, which refuses a lag that is
    not a number >= 0."""
    request = "MISSION_REQUEST" if cls is ArduCopterAutopilot else "MISSION_REQUEST_INT"
    mission = [*copter_mission()[:2], lag_item(2, 0.75)]
    stock = make(cls)
    upload(stock, mission, expect=mavlink.MAV_MISSION_UNSUPPORTED, request=request)
    # ArduPilot keeps the items before the refused one (it writes each as it comes)
    assert len(stock.server.mission) == (2 if cls is ArduCopterAutopilot else 0)
    companion = make(cls, companion=True)
    upload(companion, mission, request=request)
    assert companion.server.mission[2].param1 == 0.75
    for bad in (-0.5, math.nan, math.inf):
        upload(make(cls, companion=True), [*copter_mission()[:2], lag_item(2, bad)],
               expect=mavlink.MAV_MISSION_INVALID_PARAM1, request=request)
    for bad in (0.5, -1.0, math.nan):  # param2: 1 for a lag of unknown size, else 0
        upload(make(cls, companion=True), [*copter_mission()[:2], lag_item(2, 0.0, bad)],
               expect=mavlink.MAV_MISSION_INVALID_PARAM2, request=request)


def test_the_tracer_traces_with_the_lag_the_item_tells_from_then_on(monkeypatch):
    """A sensor lag item sets the onboard tracer's lag for the rest of the mission and the
    missions after it (until another item says otherwise): the trace items are flown with
    it, and ``tracer_params()`` has it."""
    told = []

    def recording_run_task(body, task, params, on_event=None):
        told.append((type(task).__name__, params.sensor_lag_s, params.lag_unknown))
        return run_task(body, task, params, on_event)

    run_task = navigator.run_task
    monkeypatch.setattr(navigator, "run_task", recording_run_task)
    ap = make(sample_rate_hz=10.0, companion=True)
    assert ap.navigator.tracer_params().sensor_lag_s == 0.0
    upload(ap, [item_int(0, mavlink.MAV_CMD_NAV_TAKEOFF, alt=10, current=1), lag_item(1, 0.75),
                item_int(2, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(10, 0), 10)])
    command(ap, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert command(ap, mavlink.MAV_CMD_MISSION_START)[0] == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: ap.state.mission_complete)
    assert ap.navigator.tracer_params().sensor_lag_s == 0.75
    # the next mission has no lag item: its trace is flown with the lag told before
    trace = item_int(1, 31000, *ll(30, 0), 10, p1=5.0, p2=5.0, p3=10.0, p4=3)
    upload(ap, [item_int(0, mavlink.MAV_CMD_NAV_WAYPOINT, *ll(10, 0), 10, current=1), trace])
    assert command(ap, mavlink.MAV_CMD_MISSION_START)[0] == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: ("TraceTask", 0.75, False) in told)
    # and another item tells another lag
    upload(ap, [lag_item(0, 0.25), trace])
    assert command(ap, mavlink.MAV_CMD_MISSION_START)[0] == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: ("TraceTask", 0.25, False) in told)
    assert ap.navigator.tracer_params().sensor_lag_s == 0.25
    # a lag of unknown size (param2 = 1), and a known one after it clears it
    upload(ap, [lag_item(0, 0.0, 1.0), trace])
    assert command(ap, mavlink.MAV_CMD_MISSION_START)[0] == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: ("TraceTask", 0.0, True) in told)
    upload(ap, [lag_item(0, 0.5), trace])
    assert command(ap, mavlink.MAV_CMD_MISSION_START)[0] == mavlink.MAV_RESULT_ACCEPTED
    run_until(ap, lambda ms: ("TraceTask", 0.5, False) in told)


def _px4_count(ap, n, now=0.0, peer=(255, 190)):
    gcs = mavlink.MAVLink(None, srcSystem=peer[0], srcComponent=peer[1])
    ap.receive(DECODER.decode(bytearray(
        mavlink.MAVLink_mission_count_message(1, 1, n, 0).pack(gcs))), now)
    return ap.outbox.drain(now)


def test_px4_is_busy_with_an_upload_until_the_gcs_cancels_it():
    """PX4 (``MavlinkMissionManager``, read in its source): once it has an item of an
    upload, a new count is refused with MAV_MISSION_ERROR (it keeps asking for the next
    item), as is any other GCS's; a clear and a download are ignored as busy; the
    uploading GCS's MISSION_ACK(OPERATION_CANCELLED) ends the transfer, its old mission
    kept; then a count is taken."""
    ap = make(Px4Autopilot)
    old = copter_mission()
    upload(ap, old)
    assert [m.get_type() for m in _px4_count(ap, 3)] == ["MISSION_REQUEST_INT"]
    # a count again before any item: its request was lost, it asks for item 0 again
    [again] = _px4_count(ap, 3)
    assert (again.get_type(), again.seq) == ("MISSION_REQUEST_INT", 0)
    ap.receive(rx(old[0]), 0.0)
    ap.outbox.drain(0.0)
    for peer in ((255, 190), (255, 191)):
        [busy] = _px4_count(ap, 3, peer=peer)
        assert (busy.get_type(), busy.type) == ("MISSION_ACK", mavlink.MAV_MISSION_ERROR)
    ap.receive(rx(mavlink.MAVLink_mission_clear_all_message(1, 1, 0)), 0.0)
    ap.receive(rx(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), 0.0)
    assert [m.get_type() for m in ap.outbox.drain(0.0)] == ["STATUSTEXT", "STATUSTEXT"]
    assert ap.server.upload is not None and len(ap.server.mission) == len(old)
    ap.receive(rx(mavlink.MAVLink_mission_ack_message(
        1, 1, mavlink.MAV_MISSION_OPERATION_CANCELLED, 0)), 0.0)
    assert ap.server.upload is None and len(ap.server.mission) == len(old)
    assert [m.get_type() for m in _px4_count(ap, 3)] == ["MISSION_REQUEST_INT"]


@pytest.mark.parametrize("cancel_type", [mavlink.MAV_MISSION_TYPE_MISSION,
                                         mavlink.MAV_MISSION_TYPE_FENCE], ids=["mission", "fence"])
def test_px4_ends_an_upload_on_its_gcss_cancel_of_any_mission_type(cancel_type):
    """PX4 taking an upload ends it on the uploading GCS's MISSION_ACK(OPERATION_CANCELLED)
    whatever the ACK's mission type (``handle_mission_ack`` in GETLIST does not compare it);
    another GCS's cancel, or another result from the uploader, leaves the transfer running."""
    ap = make(Px4Autopilot)
    old = copter_mission()
    upload(ap, old)
    _px4_count(ap, 3)
    ap.receive(rx(old[0]), 0.0)
    ap.outbox.drain(0.0)
    other = mavlink.MAVLink(None, srcSystem=255, srcComponent=191)
    for msg in (mavlink.MAVLink_mission_ack_message(
                    1, 1, mavlink.MAV_MISSION_OPERATION_CANCELLED, cancel_type).pack(other),
                mavlink.MAVLink_mission_ack_message(
                    1, 1, mavlink.MAV_MISSION_ERROR, cancel_type).pack(GCS)):
        ap.receive(DECODER.decode(bytearray(msg)), 0.0)
        assert ap.server.upload is not None
    ap.receive(rx(mavlink.MAVLink_mission_ack_message(
        1, 1, mavlink.MAV_MISSION_OPERATION_CANCELLED, cancel_type)), 0.0)
    assert ap.server.upload is None and len(ap.server.mission) == len(old)
    assert [m.get_type() for m in _px4_count(ap, 3)] == ["MISSION_REQUEST_INT"]


def _station_upload(ap, specs, mission_type, t0):
    """The station's uploader against ``ap`` in simulated time (20 ms steps): its result."""
    up = MissionUploader(1, 1, specs, mission_type, timeout_s=1.5)
    for k in range(2000):
        now = t0 + 0.02 * k
        for msg in up.poll(now):
            ap.receive(rx(msg), now)
        ap.poll(now)
        for reply in ap.outbox.drain(now):
            if reply.get_type().startswith("MISSION_"):
                up.receive(rx(reply), now)
        if up.done:
            return up
    raise AssertionError("the upload never ended")


@pytest.mark.parametrize("old_type, items_taken, new_type", [
    (mavlink.MAV_MISSION_TYPE_MISSION, 0, mavlink.MAV_MISSION_TYPE_FENCE),  # CI: stuck
    (mavlink.MAV_MISSION_TYPE_MISSION, 0, mavlink.MAV_MISSION_TYPE_MISSION),
    (mavlink.MAV_MISSION_TYPE_MISSION, 2, mavlink.MAV_MISSION_TYPE_MISSION),
    (mavlink.MAV_MISSION_TYPE_MISSION, 2, mavlink.MAV_MISSION_TYPE_FENCE),
    (mavlink.MAV_MISSION_TYPE_FENCE, 2, mavlink.MAV_MISSION_TYPE_MISSION),
], ids=["mission-none-then-fence", "mission-none-then-mission", "mission-two-then-mission",
        "mission-two-then-fence", "fence-two-then-mission"])
def test_a_station_started_again_ends_px4s_transfer_of_the_one_that_died(
        old_type, items_taken, new_type):
    """A station killed part-way through an upload to PX4, started again (the same ids):
    PX4 keeps the dead transfer while it hears counts (asking for item 0 of its old type
    again, or refusing the count as busy once it has an item); the new station cancels it
    and uploads its own, whatever the two transfers' types."""
    from econdor_gcs.link.items import MissionItemSpec, fence_items

    fence = fence_items(MISSION.origin, MISSION.region, 10.0)
    mission = [MissionItemSpec.from_message(rx(it)) for it in copter_mission()]
    old = fence if old_type == mavlink.MAV_MISSION_TYPE_FENCE else mission
    ap = make(Px4Autopilot)
    # the station that died: a count and some items, then silence
    ap.receive(rx(mavlink.MAVLink_mission_count_message(1, 1, len(old), old_type)), 0.0)
    for it in old[:items_taken]:
        ap.receive(rx(it.to_message(1, 1)), 0.0)
    ap.outbox.drain(0.0)
    assert ap.server.upload is not None and ap.server.upload.mission_type == old_type
    new = fence if new_type == mavlink.MAV_MISSION_TYPE_FENCE else mission[:2]
    up = _station_upload(ap, new, new_type, 0.1)
    assert up.error is None and up.result == len(new)
    assert up.stale_transfers >= 1
    assert len(ap.server.stores[new_type]) == len(new)


def test_px4_gives_up_an_upload_with_a_statustext_and_no_ack():
    ap = make(Px4Autopilot)
    _px4_count(ap, 3)
    out = []
    for k in range(1, 40):
        ap.poll(k * 0.26)
        out += ap.outbox.drain(0.0)
    assert ap.server.upload is None
    assert [m.get_type() for m in out].count("MISSION_REQUEST_INT") == 20
    assert out[-1].get_type() == "STATUSTEXT" and "Operation timeout" in str(out[-1].text)
    assert not [m for m in out if m.get_type() == "MISSION_ACK"]
