"""Codec / Parser robustness and the tlog format."""

from __future__ import annotations

import random
import struct

from econdor_gcs.link.codec import Codec, Parser, mavlink
from econdor_gcs.link.tlog import TlogWriter, read_tlog


def heartbeat():
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC, 0, 0, 3, 3)


def test_encode_uses_gcs_identity_mavlink2_and_sequence():
    codec = Codec()
    a, b = codec.encode(heartbeat()), codec.encode(heartbeat())
    assert a[0] == 0xFD and b[0] == 0xFD  # MAVLink 2 magic
    msgs = Parser().feed(a + b)
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "HEARTBEAT"]
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in msgs} == {(255, 190)}
    assert [m.get_seq() for m in msgs] == [0, 1]


def test_parser_drops_and_counts_damage():
    codec, parser = Codec(3, 1), Parser()
    good = codec.encode(heartbeat())
    bad_crc = bytearray(codec.encode(heartbeat()))
    bad_crc[-1] ^= 0xFF
    assert parser.feed(b"\x00garbage\x01\x02") == []
    assert parser.feed(bytes(bad_crc)) == []
    assert parser.feed(good[:7]) == []  # truncated datagram
    # the fragment must not swallow the next datagram
    assert [m.get_srcSystem() for m in parser.feed(good)] == [3]
    assert parser.bad_packets == 3 and parser.packets == 1
    # garbage around a good packet in one datagram
    assert len(parser.feed(b"junk" + good + b"\xfe\x03junk")) == 1


def test_parser_counts_unknown_message_ids():
    """A well-formed packet (valid X.25 checksum over header and payload; an unknown id has
    no CRC_EXTRA) of an id outside common counts as unknown, not as damage."""
    from pymavlink.generator.mavcrc import x25crc

    parser = Parser()
    raw = bytearray(Codec(4, 1).encode(heartbeat()))
    raw[7:10] = (60123).to_bytes(3, "little")  # a message id outside common
    raw[-2:] = x25crc(bytes(raw[1:-2])).crc.to_bytes(2, "little")
    assert parser.feed(bytes(raw)) == []
    assert (parser.unknown_packets, parser.bad_packets, parser.packets) == (1, 0, 0)
    # a known id with a broken checksum is damage, not unknown
    bad = bytearray(Codec(4, 1).encode(heartbeat()))
    bad[-1] ^= 0xFF
    assert parser.feed(bytes(bad)) == []
    assert (parser.unknown_packets, parser.bad_packets, parser.packets) == (1, 1, 0)


def test_parser_never_raises_on_random_bytes():
    rng = random.Random(1234)
    parser = Parser()
    good = Codec(5, 1).encode(heartbeat())
    for _ in range(3000):
        n = rng.randrange(0, 80)
        blob = bytes(rng.randrange(256) for _ in range(n))
        if rng.random() < 0.3:  # sprinkle magic bytes so the parser tries hard
            blob = b"\xfd" + blob
        parser.feed(blob)
    assert parser.bad_packets > 0
    assert [m.get_srcSystem() for m in parser.feed(good)] == [5]


def test_tlog_round_trip_both_directions(tmp_path):
    gcs, veh = Codec(), Codec(7, 1)
    parser = Parser()
    path = tmp_path / "run" / "telemetry.tlog"
    with TlogWriter(path, flush_interval_s=10.0) as log:
        out = mavlink.MAVLink_command_long_message(7, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        log.write(gcs.encode(out), 1_700_000_000.25)
        (inc,) = parser.feed(veh.encode(heartbeat()))
        log.write(inc, 1_700_000_000.5)
        assert log.records == 2
    raw = path.read_bytes()
    assert struct.unpack(">Q", raw[:8])[0] == 1_700_000_000_250_000
    msgs = read_tlog(path)
    assert [(m.get_type(), m.get_srcSystem()) for m in msgs] == [("COMMAND_LONG", 255),
                                                              ("HEARTBEAT", 7)]
    assert abs(msgs[1]._timestamp - 1_700_000_000.5) < 1e-3


def test_tlog_flushes_without_close(tmp_path):
    path = tmp_path / "t.tlog"
    log = TlogWriter(path, flush_interval_s=0.0)
    log.write(Codec().encode(heartbeat()))
    assert len(read_tlog(path)) == 1  # readable while still open
    log.close()
    log.write(b"ignored after close")
    assert log.closed
