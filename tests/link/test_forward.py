"""The watch link (--forward): vehicle bytes to a watcher; the watcher's only with commands on."""

from __future__ import annotations

import asyncio
import socket

import pytest

from econdor_gcs.errors import LinkError
from econdor_gcs.link.codec import Codec, Parser, mavlink
from econdor_gcs.link.forward import Forwarder, parse_forward_endpoint
from econdor_gcs.link.router import Router
from tests.helpers.router import ENDPOINT, FakeUdpVehicle, run


def test_parse_forward_endpoint():
    assert parse_forward_endpoint("udp:10.0.0.2:14550") == ("10.0.0.2", 14550)
    for bad in ("udpin:127.0.0.1:14551", "tcp:1.2.3.4:5760", "udpout:host", "udpout:h:0"):
        with pytest.raises(LinkError, match="--forward"):
            parse_forward_endpoint(bad)


class Watcher:
    """A UDP socket standing in for QGroundControl / MAVProxy (sysid 250)."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.codec = Codec(250, 190)
        self.peer: tuple[str, int] | None = None

    @property
    def endpoint(self) -> str:
        return f"udpout:127.0.0.1:{self.sock.getsockname()[1]}"

    async def receive(self, timeout_s: float = 3.0) -> bytes:
        loop = asyncio.get_running_loop()
        async with asyncio.timeout(timeout_s):
            data, self.peer = await loop.sock_recvfrom(self.sock, 65535)
        return data

    def send(self, msg) -> bytes:
        assert self.peer is not None
        data = self.codec.encode(msg)
        self.sock.sendto(data, self.peer)
        return data


@pytest.mark.parametrize("commands", [False, True])
def test_vehicle_messages_reach_the_watcher_byte_for_byte(commands):
    async def main():
        watcher = Watcher()
        async with Router(ENDPOINT, gcs_heartbeat_s=10.0) as router:
            fwd = await Forwarder(router, watcher.endpoint, allow_commands=commands).start()
            vehicle = await FakeUdpVehicle(3).start(router.local_address)
            vehicle.heartbeat()
            await router.wait_for_vehicles([3], timeout_s=3.0)
            data = await watcher.receive()
            (hb,) = Parser().feed(data)
            assert hb.get_type() == "HEARTBEAT" and hb.get_srcSystem() == 3
            vehicle.send(mavlink.MAVLink_statustext_message(6, b"from three"))
            data = await watcher.receive()
            (text,) = Parser().feed(data)
            assert text.text == "from three" and text.get_srcSystem() == 3
            # the watcher asks the vehicle to arm
            sent = watcher.send(mavlink.MAVLink_command_long_message(
                3, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
            if commands:
                got = await vehicle.wait_for("COMMAND_LONG")
                assert bytes(got.get_msgbuf()) == sent and got.get_srcSystem() == 250
                ack = Parser().feed(await watcher.receive())  # its answer, forwarded
                assert ack[0].get_type() == "COMMAND_ACK"
                assert fwd.stats["relayed"] == 1 and fwd.stats["dropped"] == 0
            else:
                await asyncio.sleep(0.3)
                assert not [m for m in vehicle.got if m.get_type() == "COMMAND_LONG"]
                assert fwd.stats["dropped"] == fwd.stats["from_watcher"] == 1
                assert fwd.stats["relayed"] == 0
            assert fwd.stats["forwarded"] >= 2
            fwd.close()
            vehicle.close()
        watcher.sock.close()

    run(main())
