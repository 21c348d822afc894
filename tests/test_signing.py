"""MAVLink 2 signing on the station side: keys, signed sending, unsigned telemetry dropped."""

from __future__ import annotations

import asyncio
import hashlib
import re
from pathlib import Path

import pytest

from econdor_gcs.errors import EcondorError
from econdor_gcs.link.codec import Codec, Parser, mavlink
from econdor_gcs.link.router import Router
from econdor_gcs.link.signing import SigningKey, load_signing_key
from econdor_gcs.link.tlog import TlogWriter, read_tlog

HEX = "0123456789abcdef" * 4
KEY = SigningKey(bytes.fromhex(HEX))
OTHER = SigningKey.from_text("another passphrase")


def heartbeat(kind: int = mavlink.MAV_TYPE_QUADROTOR) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_heartbeat_message(kind, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 3, 3)


# -- key files ------------------------------------------------------------------------------


def _key_file(path: Path, text: str) -> Path:
    """A key file as it should be: readable by its owner alone."""
    path.write_text(text)
    path.chmod(0o600)
    return path


def test_a_key_file_of_64_hex_characters_is_the_secret(tmp_path: Path) -> None:
    path = _key_file(tmp_path / "key", HEX.upper() + "\n")
    assert load_signing_key(path).secret == bytes.fromhex(HEX)


@pytest.mark.parametrize("text", ["correct horse battery staple\n", HEX[:-1], HEX + "0",
                                  "zz" * 32])
def test_anything_else_is_a_passphrase_hashed_as_mavproxy_does(tmp_path: Path,
                                                               text: str) -> None:
    path = _key_file(tmp_path / "key", text)
    # MAVProxy's `signing setup PASSPHRASE`: hashlib.sha256(passphrase.encode()).digest()
    assert load_signing_key(path).secret == hashlib.sha256(text.strip().encode()).digest()


def test_unusable_key_files_name_the_file_never_the_key(tmp_path: Path) -> None:
    empty = _key_file(tmp_path / "empty", "  \n")
    with pytest.raises(EcondorError, match=r"empty: an empty signing key"):
        load_signing_key(empty)
    with pytest.raises(EcondorError, match=r"nope: no such signing key file"):
        load_signing_key(tmp_path / "nope")
    binary = tmp_path / "binary"
    binary.write_bytes(b"\xff\xfe s3cret")
    binary.chmod(0o600)
    with pytest.raises(EcondorError, match="binary: the signing key file is not UTF-8") as exc:
        load_signing_key(binary)
    assert "s3cret" not in str(exc.value)
    passphrase = _key_file(tmp_path / "pass", "s3cret")
    key = load_signing_key(passphrase)
    assert "s3cret" not in repr(key) and key.secret.hex() not in repr(key)


# -- codec and parser -----------------------------------------------------------------------


def test_parser_takes_signed_and_drops_unsigned_wrong_and_replayed_packets() -> None:
    parser = Parser(KEY)
    signed = Codec(1, 1, KEY).encode(heartbeat())
    got = parser.feed(signed)
    assert len(got) == 1 and got[0].get_signed()
    assert parser.feed(Codec(2, 1).encode(heartbeat())) == []
    assert parser.unsigned_packets == 1
    assert parser.feed(Codec(3, 1, OTHER).encode(heartbeat())) == []
    assert parser.bad_signature_packets == 1
    assert parser.feed(signed) == []  # a replay: its timestamp is not newer
    assert parser.bad_signature_packets == 2
    assert (parser.packets, parser.bad_packets) == (1, 0)
    # damage is still damage, not a signature problem
    broken = bytearray(Codec(1, 1, KEY).encode(heartbeat()))
    broken[12] ^= 0x01
    assert parser.feed(bytes(broken)) == []
    assert (parser.bad_packets, parser.unsigned_packets, parser.bad_signature_packets) == \
        (1, 1, 2)


def is_signed(msg: mavlink.MAVLink_message) -> bool:
    """The packet carries a signature (incompat flag), whoever decoded it."""
    return bool(msg.get_msgbuf()[2] & mavlink.MAVLINK_IFLAG_SIGNED)


def test_a_forged_packet_does_not_cut_the_signed_link() -> None:
    """A packet signed with the wrong key but a later timestamp, claiming the same sender,
    must not make the genuine packets after it look like replays (pymavlink 2.4 records the
    timestamp before it checks the signature; we check first)."""
    genuine = Codec(1, 1, KEY)
    forger = Codec(1, 1, OTHER)
    forger.mav.signing.timestamp = genuine.mav.signing.timestamp + 10**9
    parser = Parser(KEY)
    assert len(parser.feed(genuine.encode(heartbeat()))) == 1
    assert parser.feed(forger.encode(heartbeat())) == []
    assert len(parser.feed(genuine.encode(heartbeat()))) == 1
    assert (parser.packets, parser.bad_signature_packets) == (2, 1)


def test_an_unsigned_parser_reads_signed_packets() -> None:
    """Signing adds a signature; peers that do not check it still read the messages."""
    got = Parser().feed(Codec(1, 1, KEY).encode(heartbeat()))
    assert len(got) == 1 and is_signed(got[0]) and not got[0].get_signed()


# -- the router -----------------------------------------------------------------------------


class Peer(asyncio.DatagramProtocol):
    def __init__(self, codec: Codec, parser: Parser) -> None:
        self.codec, self.parser, self.got = codec, parser, []
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr) -> None:
        self.got.extend(self.parser.feed(data))

    def send(self, msg) -> None:
        assert self.transport is not None
        self.transport.sendto(self.codec.encode(msg))


async def peer(address, sysid: int, key: SigningKey | None, check: SigningKey | None) -> Peer:
    loop = asyncio.get_running_loop()
    _, p = await loop.create_datagram_endpoint(lambda: Peer(Codec(sysid, 1, key), Parser(check)),
                                               remote_addr=address)
    return p


def test_signed_router_hears_only_signed_vehicles_and_signs_what_it_sends(
        tmp_path: Path) -> None:
    tlog_path = tmp_path / "telemetry.tlog"

    async def main() -> tuple[Router, Peer, Peer, Peer]:
        with TlogWriter(tlog_path) as tlog:
            async with Router("udpin:127.0.0.1:0", signing=KEY, tlog=tlog,
                              gcs_heartbeat_s=0.05) as router:
                good = await peer(router.local_address, 1, KEY, KEY)
                plain = await peer(router.local_address, 2, None, None)
                wrong = await peer(router.local_address, 3, OTHER, OTHER)
                for _ in range(5):
                    for p in (good, plain, wrong):
                        p.send(heartbeat())
                    await asyncio.sleep(0.05)
                await router.wait_for_vehicles([1], 3.0)
                async with asyncio.timeout(3.0):
                    while not good.got:
                        await asyncio.sleep(0.02)
                for p in (good, plain, wrong):
                    assert p.transport is not None
                    p.transport.close()
                return router, good, plain, wrong

    router, good, plain, wrong = asyncio.run(main())
    assert sorted(router.vehicles) == [1]
    assert router.parser.unsigned_packets == 5 and router.parser.bad_signature_packets == 5
    assert router.parser.bad_packets == 0
    # the station signs: the vehicle with the key accepts, the one with another refuses
    assert good.got and all(m.get_signed() for m in good.got)
    assert wrong.got == [] and wrong.parser.bad_signature_packets == 0  # never sent to it
    # the tlog holds signed packets, never the key
    data = tlog_path.read_bytes()
    assert KEY.secret not in data and HEX.encode() not in data
    logged = read_tlog(tlog_path)
    assert logged and all(is_signed(m) for m in logged)
    assert {m.get_srcSystem() for m in logged} == {1, 255}  # what was dropped is not logged


# -- the vehicle ----------------------------------------------------------------------------


def _signed_link(key: SigningKey):
    from vehicle_helpers import GcsLink

    link = GcsLink.listen()
    key.apply(link.mav)
    key.apply(link.parser, sign_outgoing=False)
    return link


def test_an_unsigned_client_cannot_change_a_signed_vehicles_mission(tmp_path: Path) -> None:
    """sim-vehicle --signing-key: the signed station uploads; a plain pymavlink client (and
    one with the wrong key) then tries to upload, clear and arm: nothing is answered,
    nothing changes, and the vehicle counts what it ignored."""
    from vehicle_helpers import GcsLink, VehicleProcess, item_int

    key_file = _key_file(tmp_path / "key", "correct horse battery staple\n")
    key = load_signing_key(key_file)
    mission = [item_int(0, mavlink.MAV_CMD_NAV_WAYPOINT, 47.3977, 8.5456, 0, current=1),
               item_int(1, mavlink.MAV_CMD_NAV_TAKEOFF, 47.3977, 8.5456, 20),
               item_int(2, mavlink.MAV_CMD_NAV_WAYPOINT, 47.3979, 8.5458, 20)]
    with _signed_link(key) as station, VehicleProcess(
            "--signing-key", str(key_file), "--speedup", "10",
            connect=f"udpout:127.0.0.1:{station.port}") as proc:
        hb = station.recv_match("HEARTBEAT", timeout=10)
        assert hb.get_signed()  # the vehicle signs, with the same key
        assert station.upload(1, mission) == mavlink.MAV_MISSION_ACCEPTED
        assert station.remote is not None
        for intruder_key in (None, OTHER):
            with GcsLink.to(*station.remote) as intruder:
                if intruder_key is not None:
                    intruder_key.apply(intruder.mav)
                other = [item_int(0, mavlink.MAV_CMD_NAV_WAYPOINT, 10.0, 10.0, 0, current=1)]
                with pytest.raises(TimeoutError):
                    intruder.upload(1, other, timeout=2.0)
                intruder.send(mavlink.MAVLink_mission_clear_all_message(1, 1, 0))
                with pytest.raises(TimeoutError):
                    intruder.command_long(1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1,
                                          timeout=1.0)
        station.flush()
        kept = station.download(1)
        assert [(m.seq, m.command, m.x, m.y) for m in kept] == \
            [(m.seq, m.command, m.x, m.y) for m in mission]
        hb = station.recv_match("HEARTBEAT", timeout=5)
        assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        assert proc.stop() == 0
        line = proc.output()
    # unsigned: count, clear, arm (+ retries); wrongly signed: the same
    import re

    m = re.search(r"unsigned (\d+) badsig (\d+)", line)
    assert m and int(m[1]) >= 3 and int(m[2]) >= 3, line
    assert key.secret.hex() not in line and "correct horse" not in line


# -- issue 34, point 5 ----------------------------------------------------------------------


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o620])
def test_a_key_file_others_may_read_or_write_is_refused(tmp_path: Path, mode: int) -> None:
    """As OpenSSH refuses a private key others can read: a key others can read signs for
    them, one they can write becomes theirs. One line, with the fix; never the key."""
    path = _key_file(tmp_path / "key", "s3cret passphrase")
    path.chmod(mode)
    with pytest.raises(EcondorError, match=rf"key: the signing key file may be read or "
                                           rf"written by others \(mode 0{mode:o}\); make it "
                                           rf"yours alone: chmod 600 .*key$") as exc:
        load_signing_key(path)
    assert "s3cret" not in str(exc.value)
    path.chmod(0o600)
    assert load_signing_key(path).secret == hashlib.sha256(b"s3cret passphrase").digest()


def test_a_world_readable_key_stops_run_and_sim_vehicle_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import subprocess
    import sys

    from vehicle_helpers import DEMO, REPO

    from econdor import cli

    path = tmp_path / "key"
    path.write_text("s3cret passphrase")
    path.chmod(0o644)
    assert cli.main(["run", str(DEMO), "--out", str(tmp_path / "run"), "--quiet",
                     "--signing-key", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "chmod 600" in err and "s3cret" not in err
    proc = subprocess.run([sys.executable, "-m", "sim_vehicle.cli", "--mission", str(DEMO),
                           "--signing-key", str(path)], capture_output=True, text=True,
                          cwd=REPO, timeout=60)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "chmod 600" in proc.stderr


def test_a_signed_arm_replayed_to_a_restarted_vehicle_is_refused(tmp_path: Path) -> None:
    """Issue 34: a captured signed ARM replayed to the vehicle after its restart armed it
    (its stream timestamps were forgotten, and the packet was within the guide's one
    minute for new streams). The vehicle keeps them on disk per key: refused."""
    from vehicle_helpers import inproc_vehicle, wait_for

    with _signed_link(KEY) as station:
        with inproc_vehicle(connect=f"udpout:127.0.0.1:{station.port}", signing=KEY) as v:
            station.recv_match("HEARTBEAT", timeout=10)
            arm = station.pack(mavlink.MAVLink_command_long_message(
                1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
            station.send_raw(arm)  # the captured packet, as a listener kept it
            wait_for(lambda: v.armed, 10, "armed")
            assert station.command_long(1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0).result == 0
            wait_for(lambda: not v.armed, 10, "disarmed")
        with inproc_vehicle(connect=f"udpout:127.0.0.1:{station.port}", signing=KEY) as v:
            station.flush()
            station.remote = None
            station.recv_match("HEARTBEAT", timeout=10)  # the new vehicle's address
            before = v.io_counters["rx_bad_signature"]
            station.send_raw(arm)  # the replay
            wait_for(lambda: v.io_counters["rx_bad_signature"] > before, 10, "the refusal")
            assert not v.armed
            # a fresh command with the key still works
            assert station.command_long(1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
            wait_for(lambda: v.armed, 10, "armed")


def test_without_the_stored_timestamps_the_replay_would_have_armed_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The premise of the test above: a vehicle that forgot its timestamps (a fresh state
    folder) takes the replayed ARM, as the issue reported."""
    from vehicle_helpers import inproc_vehicle, wait_for

    from econdor_gcs.link.signing import STATE_DIR_ENV

    with _signed_link(KEY) as station:
        monkeypatch.setenv(STATE_DIR_ENV, str(tmp_path / "first"))
        with inproc_vehicle(connect=f"udpout:127.0.0.1:{station.port}", signing=KEY) as v:
            station.recv_match("HEARTBEAT", timeout=10)
            arm = station.pack(mavlink.MAVLink_command_long_message(
                1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
            station.send_raw(arm)
            wait_for(lambda: v.armed, 10, "armed")
        monkeypatch.setenv(STATE_DIR_ENV, str(tmp_path / "forgotten"))
        with inproc_vehicle(connect=f"udpout:127.0.0.1:{station.port}", signing=KEY) as v:
            station.flush()
            station.remote = None
            station.recv_match("HEARTBEAT", timeout=10)
            station.send_raw(arm)
            wait_for(lambda: v.armed, 10, "armed by the replay")


def test_a_replay_to_a_restarted_station_is_refused() -> None:
    """The station keeps its timestamps too (per key, as system 255): a vehicle's signed
    packet captured before the station restarted is refused after it."""
    from econdor_gcs.station.executor import Station

    vehicle = Codec(1, 1, KEY)
    captured = vehicle.encode(heartbeat())
    first = Station("udpin:127.0.0.1:0", signing=KEY)
    assert len(first.router.parser.feed(captured)) == 1
    first.start()
    first.close()  # its timestamps go to disk
    second = Station("udpin:127.0.0.1:0", signing=KEY)
    assert second.router.parser.feed(captured) == []
    assert second.router.parser.refused_by_source() == {1: {"replayed": 1}}
    assert len(second.router.parser.feed(vehicle.encode(heartbeat()))) == 1  # a new one
    second.close()


def test_a_vehicle_with_another_key_is_named(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 34: a wrongly keyed vehicle showed up only as "vehicles 2, 3 never appeared"."""
    from vehicle_helpers import DEMO, free_port, inproc_vehicle

    from econdor import cli

    key_file = _key_file(tmp_path / "key", HEX)
    port = free_port()
    with inproc_vehicle(connect=f"udpout:127.0.0.1:{port}", signing=OTHER):
        code = cli.main(["run", str(DEMO), "--connect", f"udpin:127.0.0.1:{port}",
                         "--vehicles", "1", "--out", str(tmp_path / "run"), "--quiet",
                         "--signing-key", str(key_file), "--timeout", "3"])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1, err
    assert "vehicle 1 never appeared" in err
    assert re.search(r"vehicle 1: its packets are signed with another key \(\d+ refused\)",
                     err), err
