"""The UDP router against fake vehicles on real loopback sockets (port 0 everywhere)."""

from __future__ import annotations

import asyncio
import socket

import pytest

from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.tasks import TraceTask
from econdor_gcs.errors import LinkError, ProtocolError, VehicleTimeout
from econdor_gcs.link.codec import Codec, Parser, mavlink
from econdor_gcs.link.items import build_mission
from econdor_gcs.link.pairing import STILL_GAP_MS, DropReason, Placement
from econdor_gcs.link.router import (
    MissionItemReached,
    Received,
    Router,
    Sample,
    SamplePairer,
    StatusText,
    VehicleDiscovered,
    VehicleLost,
    VehicleRecovered,
    parse_endpoint,
)
from econdor_gcs.link.tlog import TlogWriter, read_tlog
from econdor_gcs.link.transfer import CommandSender
from econdor_gcs.link.transports import EndpointKind
from econdor_gcs.link.vehicles import EVENTS
from tests.helpers.router import ENDPOINT, FakeUdpVehicle, next_event, run

ORIGIN = Origin(47.397742, 8.545594, 488.0)


def test_parse_endpoint():
    ep = parse_endpoint("udpin:127.0.0.1:14550")
    assert (ep.kind, ep.host, ep.port) == (EndpointKind.UDPIN, "127.0.0.1", 14550)
    assert parse_endpoint("udp:0.0.0.0:14551").kind == EndpointKind.UDPIN
    assert parse_endpoint("tcp:1.2.3.4:5").kind == EndpointKind.TCP
    assert parse_endpoint("tcpin:0.0.0.0:5760").kind == EndpointKind.TCPIN
    assert parse_endpoint("udpout:10.0.0.2:14550").kind == EndpointKind.UDPOUT
    serial = parse_endpoint("/dev/ttyUSB0:57600")
    assert (serial.kind, serial.host, serial.port) == (EndpointKind.SERIAL, "/dev/ttyUSB0",
                                                       57600)
    assert parse_endpoint("serial:/dev/ttyS1,115200").port == 115200
    for bad in ("udpin:host", "udpin:h:port", "udpin:h:70000", "14550", "tcp:h:0",
                "udpout:h:0", "ftp:h:21", "/dev/ttyUSB0:fast"):
        with pytest.raises(LinkError):
            parse_endpoint(bad)


def test_two_vehicles_discovered_and_routed_by_sysid():
    async def main():
        async with Router(ENDPOINT, gcs_heartbeat_s=0.1) as router:
            events = router.queue(EVENTS)
            v1 = await FakeUdpVehicle(1).start(router.local_address)
            v2 = await FakeUdpVehicle(2).start(router.local_address)
            v1.heartbeat()
            v2.heartbeat()
            assert await router.wait_for_vehicles([1, 2], timeout_s=3.0) == [1, 2]
            assert router.vehicles[1].address == v1.address
            assert router.vehicles[2].address == v2.address
            seen = {(await next_event(events, VehicleDiscovered)).sysid for _ in range(2)}
            assert seen == {1, 2}

            router.send(1, mavlink.MAVLink_statustext_message(6, b"for one"))
            router.send(2, mavlink.MAVLink_statustext_message(6, b"for two"))
            assert (await v1.wait_for("STATUSTEXT")).text == "for one"
            assert (await v2.wait_for("STATUSTEXT")).text == "for two"
            texts = [m.text for m in v1.got if m.get_type() == "STATUSTEXT"]
            assert texts == ["for one"]

            # the GCS heartbeat reaches every known vehicle, as 255/190, MAV_TYPE_GCS
            hb = await v2.wait_for("HEARTBEAT")
            assert (hb.type, hb.autopilot) == (mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID)
            assert (hb.get_srcSystem(), hb.get_srcComponent()) == (255, 190)

            for v in (v1, v2):
                v.close()

            with pytest.raises(LinkError, match="vehicle 9"):
                router.send(9, mavlink.MAVLink_statustext_message(6, b"nobody"))

    run(main())


def test_wait_for_vehicles_names_the_missing_ones():
    async def main():
        async with Router(ENDPOINT) as router:
            v1 = await FakeUdpVehicle(1).start(router.local_address)
            v1.heartbeat()
            with pytest.raises(VehicleTimeout, match=r"^vehicle 3 never appeared within 0.3 s$"):
                await router.wait_for_vehicles([1, 3], timeout_s=0.3)
            with pytest.raises(VehicleTimeout, match="only 1 of 2 vehicles"):
                await router.wait_for_vehicles(2, timeout_s=0.2)
            assert await router.wait_for_vehicles(1, timeout_s=1.0) == [1]
            v1.close()

    run(main())


def test_silent_vehicle_is_lost_then_recovered():
    async def main():
        async with Router(ENDPOINT, heartbeat_timeout_s=0.3) as router:
            events = router.queue(EVENTS)
            v = await FakeUdpVehicle(4).start(router.local_address)
            v.heartbeat()
            await next_event(events, VehicleDiscovered)
            lost = await next_event(events, VehicleLost, timeout_s=3.0)
            assert lost.sysid == 4 and lost.silent_s > 0.3
            assert router.vehicles[4].lost
            v.heartbeat()
            assert (await next_event(events, VehicleRecovered)).sysid == 4
            assert not router.vehicles[4].lost
            v.close()

    run(main())


def test_garbage_datagrams_are_counted_and_harmless():
    async def main():
        async with Router(ENDPOINT) as router:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            codec = Codec(6, 1)
            good = codec.encode(mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC, 0, 0, 3, 3))
            bad_crc = bytearray(good)
            bad_crc[-2] ^= 0x55
            for junk in (b"\x00" * 50, b"\xfd\xff" + b"x" * 20, bytes(bad_crc), good[:9], b""):
                sock.sendto(junk, router.local_address)
            sock.sendto(good, router.local_address)
            await router.wait_for_vehicles([6], timeout_s=3.0)
            assert router.bad_packets >= 4
            assert router.stats["datagrams_in"] == 6
            sock.close()

    run(main())


def test_mission_transfer_and_commands_over_udp_with_loss():
    items = build_mission(ORIGIN, [TraceTask(50.0, 20.0, 30.0, 10.0, 0.0, 1),
                                   TraceTask(70.0, 60.0, 20.0, 10.0, 100.0, 2)], 25.0)

    async def main():
        async with Router(ENDPOINT) as router:
            v1 = await FakeUdpVehicle(1).start(router.local_address)
            v2 = await FakeUdpVehicle(2, deny={mavlink.MAV_CMD_MISSION_START}).start(
                router.local_address)
            v1.heartbeat()
            v2.heartbeat()
            await router.wait_for_vehicles(2, timeout_s=3.0)

            # lose every 3rd datagram the router sends (simulated loss by patching sendto)
            transport = router.links[0]._transport
            real_sendto = transport.sendto
            counter = {"n": 0, "dropped": 0}

            def lossy_sendto(data, addr=None):
                counter["n"] += 1
                if counter["n"] % 3 == 0:
                    counter["dropped"] += 1
                    return
                real_sendto(data, addr)

            transport.sendto = lossy_sendto
            n1, n2 = await asyncio.gather(
                router.upload_mission(1, items, timeout_s=0.15, retries=5),
                router.upload_mission(2, items[:3], timeout_s=0.15, retries=5))
            assert (n1, n2) == (len(items), 3)
            assert v1.mission == items and v2.mission == items[:3]
            assert await router.download_mission(1, timeout_s=0.15) == items
            transport.sendto = real_sendto
            assert counter["dropped"] > 0

            await router.arm(1)
            await router.start_mission(1)
            with pytest.raises(ProtocolError, match="MAV_CMD_MISSION_START.*MAV_RESULT_DENIED"):
                await router.start_mission(2)
            await router.clear_mission(2, timeout_s=0.2)
            assert v2.mission == []
            # wait for the armed heartbeat to be processed
            async with asyncio.timeout(3.0):
                while not router.vehicles[1].armed:
                    v1.heartbeat()
                    await asyncio.sleep(0.02)
            v1.close()
            v2.close()

    run(main())


class _StallingVehicle(FakeUdpVehicle):
    """Takes items 0 and 1 of an upload and then stops asking; ``autopilot`` in its
    HEARTBEAT."""

    def __init__(self, sysid: int, autopilot: int) -> None:
        super().__init__(sysid)
        self.autopilot = autopilot

    def heartbeat(self) -> None:
        self.send(mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, self.autopilot, 0, 4, mavlink.MAV_STATE_ACTIVE, 3))

    def handle(self, msg) -> list:
        if msg.get_type() == "MISSION_ITEM_INT" and msg.seq >= 1:
            return []
        return super().handle(msg)


@pytest.mark.parametrize("autopilot", [mavlink.MAV_AUTOPILOT_PX4,
                                       mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA])
def test_an_upload_left_part_way_is_cancelled_and_an_ardupilots_partial_mission_cleared(
        autopilot):
    """The mission protocol's cancel (MISSION_ACK OPERATION_CANCELLED) goes out when the
    station gives up on an upload the vehicle began to take; an ArduPilot, which keeps the
    items it took and ignores that cancel, is noted as holding a partial mission until it is
    cleared."""
    async def main():
        async with Router(ENDPOINT) as router:
            v = await _StallingVehicle(1, autopilot).start(router.local_address)
            v.heartbeat()
            await router.wait_for_vehicles([1], timeout_s=3.0)
            items = build_mission(ORIGIN, [TraceTask(50.0, 20.0, 30.0, 10.0, 0.0, 1)], 25.0)
            with pytest.raises(VehicleTimeout, match="no request after item 1"):
                await router.upload_mission(1, items, timeout_s=0.05, retries=2)
            cancel = await v.wait_for("MISSION_ACK")
            assert cancel.type == mavlink.MAV_MISSION_OPERATION_CANCELLED
            ardupilot = autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
            assert router.vehicles[1].partial_missions == ({0} if ardupilot else set())
            assert await router.clear_partial_missions(1, timeout_s=0.2) == ([0] if ardupilot else [])
            assert [m.get_type() for m in v.got].count("MISSION_CLEAR_ALL") == ardupilot
            assert router.vehicles[1].partial_missions == set()
            v.close()

    run(main())


def test_run_protocol_times_out_against_a_mute_vehicle():
    async def main():
        async with Router(ENDPOINT) as router:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            sock.sendto(Codec(8, 1).encode(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 3, 3)),
                        router.local_address)
            await router.wait_for_vehicles([8], timeout_s=3.0)
            with pytest.raises(VehicleTimeout, match="vehicle 8.*mission clear"):
                await router.clear_mission(8, timeout_s=0.05, retries=2)
            with pytest.raises(VehicleTimeout, match="within 0.1 s"):
                await router.run_protocol(8, CommandSender(8, 1, 400, [1], timeout_s=1.0),
                                          timeout_s=0.1)
            sock.close()

    run(main())


def test_telemetry_events_samples_and_tlog(tmp_path):
    path = tmp_path / "telemetry.tlog"

    async def main():
        tlog = TlogWriter(path)
        async with Router(ENDPOINT, tlog=tlog) as router:
            events = router.queue(EVENTS)
            samples = router.queue(Sample)
            seen_msgs: list[tuple[int, str]] = []

            def broken(received):
                raise RuntimeError("a buggy consumer")

            router.subscribe(Received, broken)  # must not starve the others
            router.subscribe(Received,
                             lambda r: seen_msgs.append((r.sysid, r.msg.get_type())))
            v1 = await FakeUdpVehicle(1).start(router.local_address)
            v2 = await FakeUdpVehicle(2).start(router.local_address)
            v1.heartbeat()
            v2.heartbeat()
            await router.wait_for_vehicles(2, timeout_s=3.0)

            def pos(t, lat, lon):
                return mavlink.MAVLink_global_position_int_message(
                    t, int(lat * 1e7), int(lon * 1e7), 510_000, 22_000, 0, 0, 0, 0)

            def value(t, val):
                return mavlink.MAVLink_named_value_float_message(t, b"FIELD", val)

            v1.send(pos(1000, 47.1, 8.1))
            v1.send(value(1000, 12.5))
            v2.send(value(1000, 99.0))  # same time, other vehicle: must not pair with v1's
            v2.send(pos(1000, 47.2, 8.2))
            got = {}
            for _ in range(2):
                async with asyncio.timeout(3.0):
                    s = await samples.get()
                got[s.sysid] = s
            assert got[1] == Sample(1, 1000, 47.1, 8.1, 22.0, 12.5)
            assert got[2].value == 99.0 and got[2].lat_deg == pytest.approx(47.2)

            v1.send(mavlink.MAVLink_mission_current_message(3))
            v1.send(mavlink.MAVLink_mission_item_reached_message(3))
            v2.send(mavlink.MAVLink_statustext_message(4, b"trace done"))
            assert await next_event(events, MissionItemReached) == MissionItemReached(1, 3)
            assert await next_event(events, StatusText) == StatusText(2, 4, "trace done")
            link = router.vehicles[1]
            assert link.mission_current == 3 and link.mission_reached == 3
            assert link.rel_alt_m == pytest.approx(22.0) and link.lat_deg == pytest.approx(47.1)
            assert router.vehicles[2].statustexts[-1][1:] == (4, "trace done")
            assert (1, "MISSION_ITEM_REACHED") in seen_msgs
            await router.command(2, mavlink.MAV_CMD_DO_SET_MODE, 1, 4)
            assert router.stats["handler_errors"] >= len(seen_msgs) > 0
            v1.close()
            v2.close()
        tlog.close()

    run(main())
    msgs = read_tlog(path)
    sources = {m.get_srcSystem() for m in msgs}
    assert {1, 2, 255} <= sources
    kinds_out = {m.get_type() for m in msgs if m.get_srcSystem() == 255}
    assert "COMMAND_LONG" in kinds_out
    kinds_in = {m.get_type() for m in msgs if m.get_srcSystem() == 2}
    assert {"HEARTBEAT", "NAMED_VALUE_FLOAT", "STATUSTEXT", "COMMAND_ACK"} <= kinds_in


def test_port_in_use_is_a_link_error():
    async def main():
        async with Router(ENDPOINT) as first:
            host, port = first.local_address
            with pytest.raises(LinkError, match="cannot listen"):
                await Router(f"udpin:{host}:{port}").start()

    run(main())


# -- SamplePairer without sockets -----------------------------------------------------------


def _rx(msg, sysid: int = 1, compid: int = 1):
    """``msg`` as it arrives from (sysid, compid): encoded, then parsed."""
    [got] = Parser().feed(Codec(sysid, compid).encode(msg))
    return got


def _pos(t, lat=47.0, lon=8.0, rel_mm=15_000):
    return _rx(mavlink.MAVLink_global_position_int_message(t, int(lat * 1e7), int(lon * 1e7),
                                                          0, rel_mm, 0, 0, 0, 0))


def _val(t, v, name=b"FIELD"):
    return _rx(mavlink.MAVLink_named_value_float_message(t, name, v))


def test_pairer_pairs_exact_stamps_in_either_order():
    p = SamplePairer(hold_s=2.0)
    assert p.add(1, _val(10, 3.0), 0.0) == []  # no position yet: it waits
    assert p.add(1, _pos(10, 47.5, 8.5), 0.1) == [Sample(1, 10, 47.5, 8.5, 15.0, 3.0)]
    assert p.add(1, _pos(20), 0.1) == []
    assert p.add(1, _val(20, 4.0), 0.2) == [Sample(1, 20, 47.0, 8.0, 15.0, 4.0)]
    assert p.pending == 0 and p.exact == 2 and p.interpolated == 0 and p.dropped_total == 0


def test_pairer_ignores_other_names_and_keeps_vehicles_apart():
    p = SamplePairer()
    assert p.add(1, _val(10, 1.0, b"OTHER"), 0.0) == []
    assert p.add(1, _pos(10), 0.0) == []
    assert p.add(2, _val(10, 2.0), 0.0) == []  # same time_boot_ms, other vehicle
    assert p.add(1, mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 3, 3), 0.0) == []
    assert p.pending == 1
    assert p.add(2, _pos(10), 0.1)[0].sysid == 2


def test_pairer_interpolates_between_positions_in_time():
    """A Lua script's stamp falls between two positions: the sample goes where the vehicle
    was at that moment, linearly between them."""
    p = SamplePairer(max_gap_ms=500)
    p.add(1, _pos(1000, 47.0, 8.0, 10_000), 0.0)
    assert p.add(1, _val(1050, 7.0), 0.0) == []  # after the newest position: it waits
    [s] = p.add(1, _pos(1200, 47.0, 8.004, 20_000), 0.1)
    assert s.placement == Placement.INTERPOLATED and s.time_boot_ms == 1050
    assert s.lon_deg == pytest.approx(8.001) and s.rel_alt_m == pytest.approx(12.5)
    [s2] = p.add(1, _val(1100, 8.0), 0.2)  # between two known positions: placed at once
    assert s2.lon_deg == pytest.approx(8.002)
    assert (p.exact, p.interpolated) == (0, 2)


def test_pairer_drops_what_it_cannot_place_with_a_reason():
    p = SamplePairer(max_gap_ms=500, hold_s=1.0)
    p.add(1, _val(500, 1.0), 0.0)               # before any position
    p.add(1, _pos(1000), 0.0)
    p.add(1, _pos(1800, lon=8.0001), 0.0)       # 7.6 m on
    p.add(1, _val(1500, 2.0), 0.1)              # between positions 0.8 s apart: a gap
    p.add(1, _val(2500, 3.0), 0.2)              # after the newest, and none comes
    assert p.pending == 3 and p.expire(0.9) == 0
    # a late position fills the gap before the hold ends: placed after all
    assert [s.value for s in p.add(1, _pos(1400), 0.95)] == [2.0]
    assert p.expire(5.0) == 2 and p.pending == 0
    assert p.dropped == {DropReason.NO_POSITION_BEFORE: 1, DropReason.NO_POSITION_AFTER: 1}


def test_pairer_bridges_a_gap_the_vehicle_held_its_place_across():
    """ArduCopter pauses its positions for seconds while it takes a mission upload,
    hovering, and its Lua script samples on: a gap of up to STILL_GAP_MS whose two ends are
    within STILL_M of each other places its samples; one the vehicle moved across does not."""
    p = SamplePairer(max_gap_ms=500, hold_s=1.0)
    p.add(1, _pos(1000), 0.0)
    p.add(1, _pos(4000, lat=47.000005), 0.0)     # 3 s later, 0.56 m away: hovering
    [s] = p.add(1, _val(2500, 1.0), 0.1)
    assert s.placement == Placement.INTERPOLATED and s.lat_deg == pytest.approx(47.0000025)
    p.add(1, _pos(6000, lat=47.0001), 0.2)       # 2 s later, 10.5 m away: it flew
    assert p.add(1, _val(5000, 2.0), 0.3) == []
    p.add(1, _pos(6000 + STILL_GAP_MS + 1, lat=47.0001), 0.4)  # still, but too long
    assert p.add(1, _val(10_000, 3.0), 0.5) == []
    assert p.expire(5.0) == 2 and p.dropped == {DropReason.GAP: 2}


def test_position_track_restarts_with_a_rebooted_autopilot():
    p = SamplePairer()
    p.add(1, _pos(500_000), 0.0)
    p.add(1, _pos(1_000), 0.0)  # its clock started again
    assert len(p.track(1)) == 1 and p.track(1).newest_ms == 1_000


async def _with_sim_vehicle(body) -> None:
    """Run ``body(router, vehicle)`` against the simulated PX4 vehicle (in-process, 20x)."""
    from tests.helpers.vehicles import inproc_vehicle

    async with Router(ENDPOINT) as router:
        host, port = router.local_address
        with inproc_vehicle(connect=f"udpout:{host}:{port}", speedup=20.0) as vehicle:
            await router.wait_for_vehicles([1], 10.0)
            async with asyncio.timeout(10.0):
                while router.vehicles[1].alt_m is None:
                    await asyncio.sleep(0.02)
            await body(router, vehicle)


async def _until(cond, timeout_s: float = 10.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not cond():
            await asyncio.sleep(0.02)


def test_set_mode_sends_main_and_sub_mode_as_px4_reads_them():
    """DO_SET_MODE carries PX4's main and sub mode in param2/3, not the packed HEARTBEAT
    value: the simulated PX4 vehicle takes off, then returns, by mode changes alone."""
    from sim_vehicle.px4 import PX4_MAIN_AUTO, PX4_SUB_RTL, PX4_SUB_TAKEOFF
    from sim_vehicle.state import FlightMode

    async def body(router: Router, vehicle) -> None:
        await router.arm(1)
        await router.set_mode(1, PX4_MAIN_AUTO, PX4_SUB_TAKEOFF)
        await _until(lambda: vehicle.state.alt_rel_m > 5.0)
        await router.set_mode(1, PX4_MAIN_AUTO, PX4_SUB_RTL)
        await _until(lambda: vehicle.state.mode in (FlightMode.RTL, FlightMode.LAND))

    run(_with_sim_vehicle(body))


def test_takeoff_altitude_is_above_home_as_documented():
    """NAV_TAKEOFF's param7 is AMSL for PX4: ``takeoff(sysid, 12)`` holds at 12 m above
    home (not at the vehicle's default 30 m, which a bare 12 m AMSL below home gives)."""

    async def body(router: Router, vehicle) -> None:
        await router.arm(1)
        await router.takeoff(1, 12.0)
        await _until(lambda: vehicle.state.alt_rel_m > 11.99)
        t0 = vehicle.sim_time_s
        await _until(lambda: vehicle.sim_time_s > t0 + 6.0)  # it holds there
        assert vehicle.state.alt_rel_m == pytest.approx(12.0, abs=1e-3)

    run(_with_sim_vehicle(body))


def test_takeoff_needs_a_home_altitude():
    async def main() -> None:
        async with Router(ENDPOINT) as router:
            v = await FakeUdpVehicle(7).start(router.local_address)
            v.heartbeat()
            await router.wait_for_vehicles([7], 3.0)
            with pytest.raises(LinkError, match="vehicle 7: no position yet"):
                await router.takeoff(7, 10.0)
            v.close()

    run(main())


def test_heading_and_airborne_time_from_positions():
    """GLOBAL_POSITION_INT: the last known heading, and vehicle time between airborne fixes."""

    async def main():
        async with Router(ENDPOINT) as router:
            v = await FakeUdpVehicle(1).start(router.local_address)
            v.heartbeat()
            await router.wait_for_vehicles(1, timeout_s=3.0)

            def pos(t_ms, rel_alt_mm, hdg_cdeg):
                return mavlink.MAVLink_global_position_int_message(
                    t_ms, 473977420, 85455940, 518_000, rel_alt_mm, 0, 0, 0, hdg_cdeg)

            for msg in (pos(1000, 0, 65535),        # on the ground, heading unknown
                        pos(2000, 10_000, 9000),    # took off: 90 degrees
                        pos(4000, 10_000, 65535),   # still flying, heading unknown: keep 90
                        pos(3500, 10_000, 18000),   # late, out of order: no time counted
                        pos(5000, 10_000, 18000),   # 4000 -> 5000 counts, not 3500 -> 5000
                        pos(6000, 200, 27000)):     # landed
                v.send(msg)
            async with asyncio.timeout(3.0):
                while router.vehicles[1].time_boot_ms != 6000:
                    await asyncio.sleep(0.01)
            link = router.vehicles[1]
            v.close()
            return link.heading_deg, link.airborne_s

    heading, airborne = run(main())
    assert heading == pytest.approx(270.0)
    # 2000 -> 4000 -> 5000 ms airborne at both ends; 1000 -> 2000 took off, 5000 -> 6000 landed
    assert airborne == pytest.approx(3.0)
