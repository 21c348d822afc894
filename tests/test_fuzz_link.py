"""The station's MAVLink receive path on random and mutated frames (hypothesis).

Nothing a peer sends may crash the station: every datagram is either decoded or counted as
damage (``bad_packets``) or as an unknown message (``unknown_packets``), and no handler of
the router or the executor fails on what decodes (``handler_errors`` stays 0).
"""

from __future__ import annotations

from types import SimpleNamespace

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from econdor_gcs.config import parse_mission
from econdor_gcs.link.codec import Codec, Parser, mavlink
from econdor_gcs.link.router import Router
from econdor_gcs.station.executor import MavlinkExecutor

FUZZ = settings(max_examples=200, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])

u8, u16 = st.integers(0, 0xFF), st.integers(0, 0xFFFF)
u32, i32 = st.integers(0, 0xFFFFFFFF), st.integers(-(2**31), 2**31 - 1)
f32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
text50 = st.binary(max_size=50)

messages = st.one_of(
    st.builds(mavlink.MAVLink_heartbeat_message, u8, u8, u8, u32, u8, u8),
    st.builds(mavlink.MAVLink_global_position_int_message, u32, i32, i32, i32, i32,
              st.integers(-(2**15), 2**15 - 1), st.integers(-(2**15), 2**15 - 1),
              st.integers(-(2**15), 2**15 - 1), u16),
    st.builds(mavlink.MAVLink_named_value_float_message, u32,
              st.sampled_from([b"FIELD", b"OTHER", b"\xff\xfe"]), f32),
    st.builds(mavlink.MAVLink_statustext_message, u8, text50, u16, u8),
    st.builds(mavlink.MAVLink_mission_current_message, u16, u16, u8, u8),
    st.builds(mavlink.MAVLink_mission_item_reached_message, u16),
    st.builds(mavlink.MAVLink_command_ack_message, u16, u8, u8, i32, u8, u8),
    st.builds(mavlink.MAVLink_mission_ack_message, u8, u8, u8, u8),
    st.builds(mavlink.MAVLink_mission_request_int_message, u8, u8, u16, u8),
)


@st.composite
def frames(draw: st.DrawFn) -> tuple[bytes, bool]:
    """(datagram, intact): packed messages from systems 1..3, maybe damaged."""
    data = b"".join(Codec(draw(st.integers(1, 3)), 1).encode(draw(messages))
                    for _ in range(draw(st.integers(1, 3))))
    kind = draw(st.sampled_from(["intact", "flip", "truncate", "insert", "splice"]))
    if kind == "intact":
        return data, True
    buf = bytearray(data)
    if kind == "flip":
        bit = draw(st.integers(0, len(buf) * 8 - 1))
        buf[bit // 8] ^= 1 << (bit % 8)
    elif kind == "truncate":
        del buf[draw(st.integers(1, len(buf) - 1)):]
    elif kind == "insert":
        at = draw(st.integers(0, len(buf)))
        buf[at:at] = draw(st.binary(min_size=1, max_size=8))
    else:
        at = draw(st.integers(0, len(buf)))
        buf = buf[:at] + bytearray(draw(st.binary(min_size=1, max_size=30)))
    return bytes(buf), False


@FUZZ
@given(st.lists(st.binary(max_size=300) | frames().map(lambda f: f[0]), max_size=10))
def test_parser_never_raises_and_counts_every_datagram(datagrams: list[bytes]) -> None:
    parser = Parser()
    for data in datagrams:
        before = parser.packets + parser.bad_packets + parser.unknown_packets
        parser.feed(data)
        after = parser.packets + parser.bad_packets + parser.unknown_packets
        assert after > before or not data


@FUZZ
@given(frames())
def test_a_damaged_frame_never_passes_as_another_message(frame: tuple[bytes, bool]) -> None:
    data, intact = frame
    got = Parser().feed(data)
    if intact:
        assert len(got) >= 1
    for msg in got:  # whatever decodes is one of the messages that were packed
        assert msg.get_srcSystem() in (1, 2, 3)
        assert bytes(msg.get_msgbuf()) in data


def _station() -> tuple[Router, MavlinkExecutor]:
    router = Router("udpin:127.0.0.1:0")
    mission = parse_mission({"field": {"model": "paper"}})
    executor = MavlinkExecutor(SimpleNamespace(router=router), mission,  # type: ignore[arg-type]
                               [1, 2])
    return router, executor


@FUZZ
@given(st.lists(frames(), min_size=1, max_size=30))
def test_router_and_executor_survive_any_traffic(traffic: list[tuple[bytes, bool]]) -> None:
    router, executor = _station()
    for data, _ in traffic:
        router._on_bytes(0, data, ("127.0.0.1", 5000))
    assert router.stats["handler_errors"] == 0
    parser = router.parser
    assert router.stats["datagrams_in"] == len(traffic)
    assert parser.packets == router.stats["messages_in"] + router.stats["foreign"] + \
        router.stats["not_vehicle"]
    executor.status_rows()  # the display's view of whatever arrived
    executor.pending_samples()


@FUZZ
@given(frames())
def test_a_signing_station_refuses_every_unsigned_or_damaged_frame(
        frame: tuple[bytes, bool]) -> None:
    """With a key, nothing unsigned gets through, whatever its state; each refusal is
    counted as unsigned, as a bad signature or as damage."""
    from econdor_gcs.link.signing import SigningKey

    parser = Parser(SigningKey.from_text("fuzz"))
    data, _ = frame
    assert parser.feed(data) == []
    refused = parser.unsigned_packets + parser.bad_signature_packets + parser.bad_packets \
        + parser.unknown_packets
    assert refused >= 1
