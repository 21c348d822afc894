"""A fake vehicle on its own UDP socket for the router's tests (shared by the router and the
watch-link tests)."""

from __future__ import annotations

import asyncio

from econdor_gcs.link.codec import Codec, Parser, mavlink
from econdor_gcs.link.transfer import MissionItemSpec

ENDPOINT = "udpin:127.0.0.1:0"


class FakeUdpVehicle(asyncio.DatagramProtocol):
    """A vehicle on its own UDP socket: heartbeats, a mission server, accepts every command."""

    def __init__(self, sysid: int, *, deny: set[int] | None = None) -> None:
        self.sysid = sysid
        self.codec = Codec(sysid, 1)
        self.parser = Parser()
        self.inbox: asyncio.Queue = asyncio.Queue()
        self.got: list = []
        self.mission: list[MissionItemSpec] = []
        self.incoming: list[MissionItemSpec] = []
        self.expected: int | None = None
        self.deny = deny or set()
        self.base_mode = 0
        self.transport: asyncio.DatagramTransport | None = None

    async def start(self, router_address) -> FakeUdpVehicle:
        loop = asyncio.get_running_loop()
        await loop.create_datagram_endpoint(lambda: self, local_addr=("127.0.0.1", 0),
                                            remote_addr=router_address)
        return self

    def connection_made(self, transport) -> None:
        self.transport = transport

    @property
    def address(self):
        return self.transport.get_extra_info("sockname")[:2]

    def close(self) -> None:
        self.transport.close()

    def send(self, msg) -> None:
        self.transport.sendto(self.codec.encode(msg))

    def heartbeat(self) -> None:
        self.send(mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC, self.base_mode, 4,
            mavlink.MAV_STATE_ACTIVE, 3))

    async def wait_for(self, kind: str, timeout_s: float = 3.0):
        async with asyncio.timeout(timeout_s):
            while True:
                msg = await self.inbox.get()
                if msg.get_type() == kind:
                    return msg

    def datagram_received(self, data, addr) -> None:
        for msg in self.parser.feed(data):
            self.got.append(msg)
            self.inbox.put_nowait(msg)
            for reply in self.handle(msg):
                self.send(reply)

    def _ack(self, result: int):
        return mavlink.MAVLink_mission_ack_message(255, 190, result, 0)

    def handle(self, msg) -> list:
        kind = msg.get_type()
        if kind == "MISSION_COUNT":
            self.expected, self.incoming = msg.count, []
            return [mavlink.MAVLink_mission_request_int_message(255, 190, 0, 0)]
        if kind == "MISSION_ITEM_INT" and self.expected is not None:
            if msg.seq == len(self.incoming):
                self.incoming.append(MissionItemSpec.from_message(msg))
            if len(self.incoming) == self.expected:
                self.mission = list(self.incoming)
                return [self._ack(mavlink.MAV_MISSION_ACCEPTED)]
            return [mavlink.MAVLink_mission_request_int_message(255, 190, len(self.incoming), 0)]
        if kind == "MISSION_REQUEST_LIST":
            return [mavlink.MAVLink_mission_count_message(255, 190, len(self.mission), 0)]
        if kind == "MISSION_REQUEST_INT":
            return [self.mission[msg.seq].to_message(255, 190)]
        if kind == "MISSION_CLEAR_ALL":
            self.mission = []
            return [self._ack(mavlink.MAV_MISSION_ACCEPTED)]
        if kind == "COMMAND_LONG":
            result = (mavlink.MAV_RESULT_DENIED if msg.command in self.deny
                      else mavlink.MAV_RESULT_ACCEPTED)
            if msg.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and result == 0:
                self.base_mode = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if msg.param1 else 0
            return [mavlink.MAVLink_command_ack_message(msg.command, result, 0, 0, 255, 190)]
        return []


async def next_event(queue: asyncio.Queue, kind: type, timeout_s: float = 3.0):
    async with asyncio.timeout(timeout_s):
        while True:
            event = await queue.get()
            if isinstance(event, kind):
                return event


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 20.0))
