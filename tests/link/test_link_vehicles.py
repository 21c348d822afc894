"""The vehicle table without sockets or clocks (``receive(msg, source, now)``): routes by the
autopilot component, companions, twins and strangers (issue 33, issue 34 point 4); then the
same through the router on real sockets, and in a run's summary."""

from __future__ import annotations

import asyncio

from econdor_gcs.link.codec import Codec, Parser, mavlink
from econdor_gcs.link.router import Received, Router
from econdor_gcs.link.vehicles import (
    EVENTS,
    ComponentDiscovered,
    ConflictKind,
    ForeignVehicle,
    Source,
    TwinRefused,
    VehicleDiscovered,
    VehicleLost,
    VehicleMoved,
    VehicleTable,
)

A = Source(0, ("127.0.0.1", 5001))
B = Source(0, ("127.0.0.1", 5002))
COMPANION = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER


def rx(msg, sysid=1, compid=1):
    [got] = Parser().feed(Codec(sysid, compid).encode(msg))
    return got


def hb(sysid=1, compid=1, mav_type=mavlink.MAV_TYPE_QUADROTOR, custom_mode=3, armed=False):
    base = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
    return rx(mavlink.MAVLink_heartbeat_message(mav_type, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
                                                if compid == 1 else mavlink.MAV_AUTOPILOT_INVALID,
                                                base, custom_mode, 4, 3), sysid, compid)


def test_a_companions_heartbeat_never_replaces_the_autopilots():
    t = VehicleTable(heartbeat_timeout_s=5.0)
    link, events = t.receive(hb(custom_mode=4, armed=True), A, 0.0)
    assert events == [VehicleDiscovered(1, A.address)]
    # the companion: on another socket, its own type and mode
    link2, events = t.receive(hb(compid=COMPANION, mav_type=mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                 custom_mode=0), B, 0.1)
    assert link2 is link and events == [ComponentDiscovered(1, COMPANION,
                                                            mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                                            B.address)]
    assert (link.custom_mode, link.armed, link.mav_type) == (4, True,
                                                            mavlink.MAV_TYPE_QUADROTOR)
    assert link.companions == [COMPANION]
    # what it sends (samples) is the vehicle's, but never moves the route
    sample = rx(mavlink.MAVLink_named_value_float_message(1000, b"FIELD", 2.0), 1, COMPANION)
    assert t.receive(sample, B, 0.2)[0] is link
    assert link.source == A and link.sample_compid == COMPANION


def _position(ms, lat=47.4, lon=8.5):
    return rx(mavlink.MAVLink_global_position_int_message(ms, int(lat * 1e7), int(lon * 1e7),
                                                          518000, 30000, 0, 0, 0, 9000))


def test_the_table_keeps_mission_state_and_clock_rate_no_other_record_does():
    """The vehicle's MISSION_CURRENT state and its clock against ours are the link's: the
    station's own record of a vehicle reads them here (issue 35)."""
    from econdor_gcs.station.telemetry import VehicleState

    t = VehicleTable(heartbeat_timeout_s=5.0)
    link, _ = t.receive(hb(), A, 0.0)
    t.receive(rx(mavlink.MAVLink_mission_current_message(3, 5, mavlink.MISSION_STATE_ACTIVE,
                                                         1)), A, 1.5)
    assert (link.mission_current, link.mission_state, link.mission_state_at) == \
        (3, mavlink.MISSION_STATE_ACTIVE, 1.5)
    t.receive(_position(10_000), A, 2.0)
    t.receive(_position(30_000), A, 6.0)  # 20 s of its time in 4 s of ours ...
    assert link.clock_rate is None  # ... too short a span to say
    t.receive(_position(25_000), A, 6.5)  # a resent, older position: no news
    t.receive(_position(60_000), A, 12.0)
    assert link.clock_rate == 5.0
    assert {"mission_state", "mission_state_at", "clock_first", "clock_last"}.isdisjoint(
        VehicleState.__dataclass_fields__)


def test_a_companion_before_its_autopilot_is_no_vehicle():
    t = VehicleTable()
    link, events = t.receive(hb(compid=COMPANION, mav_type=mavlink.MAV_TYPE_ONBOARD_CONTROLLER),
                             B, 0.0)
    assert link is None and events == [] and t.vehicles == {}
    link, _ = t.receive(hb(), A, 0.1)
    assert link is not None and link.companions == [COMPANION] and link.source == A


def test_a_twin_is_refused_and_reported_at_its_first_message():
    t = VehicleTable(heartbeat_timeout_s=5.0)
    link, _ = t.receive(hb(), A, 0.0)
    pos = rx(mavlink.MAVLink_global_position_int_message(500, 473977420, 85455940, 0, 0, 0, 0,
                                                          0, 0))
    got, events = t.receive(pos, B, 1.0)
    assert got is None and events == [TwinRefused(1, B.address, A.address,
                                                  "GLOBAL_POSITION_INT")]
    for now in (1.5, 2.0, 2.5):
        assert t.receive(hb(), B, now) == (None, [])  # reported once, refused always
        t.receive(hb(), A, now)
    assert link.source == A and link.lat_deg is None
    [c] = t.conflicts
    assert (c.kind, c.messages, c.as_dict()["address"]) == (ConflictKind.TWIN, 4,
                                                            "127.0.0.1:5002")


def test_a_vehicle_silent_past_the_timeout_may_come_back_from_another_source():
    t = VehicleTable(heartbeat_timeout_s=1.0)
    link, _ = t.receive(hb(), A, 0.0)
    assert t.check(1.5) == [VehicleLost(1, 1.5)]
    got, events = t.receive(hb(), B, 1.6)
    assert got is link and link.source == B
    assert VehicleMoved(1, A.address, B.address) in events


def test_a_stranger_is_reported_once_and_never_mixed_in():
    t = VehicleTable()
    t.receive(hb(sysid=1), A, 0.0)
    t.receive(hb(sysid=7), B, 0.0)
    events = t.expect([1])
    assert events == [ForeignVehicle(7, B.address, "HEARTBEAT")] and list(t.vehicles) == [1]
    assert t.receive(hb(sysid=7), B, 0.5) == (None, [])
    got, events = t.receive(hb(sysid=9), B, 0.6)
    assert got is None and events == [ForeignVehicle(9, B.address, "HEARTBEAT")]
    assert [c.kind for c in t.conflicts] == [ConflictKind.FOREIGN] * 2


def test_router_routes_commands_to_the_autopilot_not_to_whoever_spoke_last():
    """Over real sockets: a companion on its own socket sends samples and heartbeats;
    commands still go to the autopilot's socket; a twin autopilot is refused."""

    async def main() -> None:
        async with Router("udpin:127.0.0.1:0") as router:
            events = router.queue(EVENTS)
            received = router.queue(Received)
            loop = asyncio.get_running_loop()

            class Peer(asyncio.DatagramProtocol):
                def __init__(self) -> None:
                    self.got: asyncio.Queue = asyncio.Queue()

                def datagram_received(self, data, addr) -> None:
                    for m in Parser().feed(data):
                        self.got.put_nowait(m)

            peers = []
            for _ in range(3):
                tr, p = await loop.create_datagram_endpoint(
                    Peer, local_addr=("127.0.0.1", 0), remote_addr=router.local_address)
                peers.append((tr, p))
            (ap_tr, ap), (comp_tr, comp), (twin_tr, twin) = peers
            ap_tr.sendto(Codec(1, 1).encode(mavlink.MAVLink_heartbeat_message(
                2, 3, 0, 0, 4, 3)))
            await router.wait_for_vehicles([1], 3.0)
            comp_tr.sendto(Codec(1, COMPANION).encode(mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_ONBOARD_CONTROLLER, 8, 0, 0, 4, 3)))
            comp_tr.sendto(Codec(1, COMPANION).encode(
                mavlink.MAVLink_named_value_float_message(10, b"FIELD", 1.0)))
            twin_tr.sendto(Codec(1, 1).encode(mavlink.MAVLink_heartbeat_message(
                2, 3, 0, 0, 4, 3)))
            kinds = set()
            async with asyncio.timeout(3.0):
                while not {ComponentDiscovered, TwinRefused} <= kinds:
                    kinds.add(type(await events.get()))
            async with asyncio.timeout(3.0):
                while (await received.get()).msg.get_type() != "NAMED_VALUE_FLOAT":
                    pass
            router.send(1, mavlink.MAVLink_statustext_message(6, b"to the autopilot"))
            async with asyncio.timeout(3.0):
                while (await ap.got.get()).get_type() != "STATUSTEXT":
                    pass
            for p in (comp, twin):
                assert all(m.get_type() != "STATUSTEXT" for m in list(p.got._queue))
            assert [c.kind for c in router.table.conflicts] == [ConflictKind.TWIN]
            for tr, _ in peers:
                tr.close()

    asyncio.run(asyncio.wait_for(main(), 20.0))
