"""The simulated vehicle's MAVLink receive path on random and mutated frames (hypothesis).

Frames go through the vehicle's own parsing and dispatch (``MavlinkVehicle._receive`` with a
transport that hands over the test's datagrams), then the autopilot flies a few hundred ticks
on whatever it accepted. Nothing may raise, no handler may fail (a failure would be logged
and counted as bad), and every datagram is accounted for.
"""

from __future__ import annotations

import logging

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink
from vehicle_helpers import DEMO

from econdor_gcs.config import load_mission
from econdor_gcs.core.tasks import (
    SAMPLE_COUNT_COMMAND,
    SAMPLE_RESEND_COMMAND,
    TRACE_RESEND_COMMAND,
)
from econdor_gcs.link.codec import Codec
from sim_vehicle.autopilot import Autopilot
from sim_vehicle.mavlink_vehicle import MavlinkVehicle

FUZZ = settings(max_examples=150, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
MISSION = load_mission(DEMO)

u8, u16 = st.integers(0, 0xFF), st.integers(0, 0xFFFF)
i32 = st.integers(-(2**31), 2**31 - 1)
f32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
lat = st.integers(-900_000_000, 900_000_000) | i32
commands = st.sampled_from([*Autopilot._COMMANDS, SAMPLE_COUNT_COMMAND, SAMPLE_RESEND_COMMAND,
                            TRACE_RESEND_COMMAND, 31000, 0, 65535])
nav = st.sampled_from([16, 17, 19, 20, 21, 22, 31000, 178, 0, 999])
frames = st.sampled_from([0, 3, 5, 6, 2, 11, 255])
target = st.sampled_from([0, 1, 1, 1, 7])
mtype = st.sampled_from([0, 0, 1, 2, 255, 9])

messages = st.one_of(
    st.builds(mavlink.MAVLink_command_long_message, target, u8, commands, u8,
              f32, f32, f32, f32, f32, f32, f32),
    st.builds(mavlink.MAVLink_command_int_message, target, u8, frames, commands, u8, u8,
              f32, f32, f32, f32, i32, i32, f32),
    st.builds(mavlink.MAVLink_mission_count_message, target, u8, u16, mtype),
    st.builds(mavlink.MAVLink_mission_item_int_message, target, u8, st.integers(0, 5), frames,
              nav, u8, u8, f32, f32, f32, f32, lat, lat, f32, mtype),
    st.builds(mavlink.MAVLink_mission_item_message, target, u8, st.integers(0, 5), frames, nav,
              u8, u8, f32, f32, f32, f32, f32, f32, f32, mtype),
    st.builds(mavlink.MAVLink_mission_request_list_message, target, u8, mtype),
    st.builds(mavlink.MAVLink_mission_request_int_message, target, u8, u16, mtype),
    st.builds(mavlink.MAVLink_mission_request_message, target, u8, u16, mtype),
    st.builds(mavlink.MAVLink_mission_clear_all_message, target, u8, mtype),
    st.builds(mavlink.MAVLink_mission_set_current_message, target, u8, u16),
    st.builds(mavlink.MAVLink_mission_ack_message, target, u8, u8, mtype),
    st.builds(mavlink.MAVLink_param_set_message, target, u8,
              st.sampled_from([b"SPEED_MPS", b"SAMPLE_HZ", b"SPEEDUP", b"NOISE_STD", b"ALT_M",
                               b"X", b"\xff"]), f32, u8),
    st.builds(mavlink.MAVLink_param_request_read_message, target, u8, st.binary(max_size=16),
              st.integers(-32768, 32767)),
    st.builds(mavlink.MAVLink_set_mode_message, target, u8, i32.map(lambda v: v & 0xFFFFFFFF)),
    st.builds(mavlink.MAVLink_heartbeat_message, u8, u8, u8, i32.map(lambda v: v & 0xFFFFFFFF),
              u8, u8),
)


@st.composite
def datagrams(draw: st.DrawFn) -> bytes:
    codec = Codec(255, 190)
    data = b"".join(codec.encode(draw(messages)) for _ in range(draw(st.integers(1, 3))))
    kind = draw(st.sampled_from(["intact", "intact", "flip", "truncate", "garbage"]))
    buf = bytearray(data)
    if kind == "flip":
        bit = draw(st.integers(0, len(buf) * 8 - 1))
        buf[bit // 8] ^= 1 << (bit % 8)
    elif kind == "truncate":
        del buf[draw(st.integers(1, len(buf) - 1)):]
    elif kind == "garbage":
        buf = bytearray(draw(st.binary(min_size=1, max_size=120)))
    return bytes(buf)


@pytest.fixture(scope="module")
def vehicle():
    v = MavlinkVehicle.from_mission(MISSION, sysid=1, connect="udpin:127.0.0.1:0")
    yield v
    v.close()


@FUZZ
@given(st.lists(datagrams(), min_size=1, max_size=12))
def test_vehicle_survives_any_frames(vehicle, caplog, traffic: list[bytes]) -> None:
    arm = Codec(255, 190).encode(mavlink.MAVLink_command_long_message(
        1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
    feed = [arm, *traffic]
    vehicle.transport.recv_all = lambda max_chunks: [(("127.0.0.1", 5000), d) for d in feed]
    before = dict(vehicle.io_counters)
    with caplog.at_level(logging.ERROR, logger="sim_vehicle"):
        vehicle._receive()
        for _ in range(300):  # fly on whatever was accepted
            vehicle.autopilot.tick()
        vehicle.autopilot.outbox.drain(0.0)
    assert "error handling" not in caplog.text, caplog.text
    got = {k: vehicle.io_counters[k] - before[k] for k in before}
    assert got["rx_packets"] + got["rx_bad"] >= 1  # every datagram is seen, as a message or bad
