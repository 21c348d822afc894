"""``--connect`` beyond UDP-in: the router over ``tcp:`` (as to ArduPilot SITL), ``tcpin:``,
``udpout:`` and a serial device (a pty pair stands for the radio), with the simulated
vehicle or a fake one on the other end; byte streams cut anywhere parse the same."""

from __future__ import annotations

import asyncio
import os
import tty

from hypothesis import given, settings
from hypothesis import strategies as st

from econdor_gcs.link.codec import Codec, Parser, mavlink
from econdor_gcs.link.router import Router
from tests.helpers.vehicles import free_port, inproc_vehicle

HB = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR,
                                       mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 3, 3)


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 30.0))


@settings(max_examples=100, deadline=None, derandomize=True)
@given(st.lists(st.integers(0, 400), max_size=12))
def test_a_stream_cut_anywhere_parses_the_same(cuts):
    codec = Codec(3, 1)
    data = b"".join(codec.encode(mavlink.MAVLink_named_value_float_message(t, b"FIELD", t / 7))
                    for t in range(12))
    parser = Parser()
    got = []
    points = sorted({min(c, len(data)) for c in cuts}) + [len(data)]
    start = 0
    for p in points:
        got += parser.feed(data[start:p], stream="peer")
        start = p
    assert [m.time_boot_ms for m in got] == list(range(12))
    assert parser.bad_packets == 0


async def _vehicle_over(endpoint_for_router: str, vehicle_connect: str) -> None:
    with inproc_vehicle(connect=vehicle_connect, speedup=20.0, autopilot="ardupilot"):
        async with Router(endpoint_for_router) as router:
            await router.wait_for_vehicles([1], 10.0)
            router.request_data_streams(1)
            ack = await router.command(1, mavlink.MAV_CMD_REQUEST_MESSAGE,
                                       mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            assert ack.result == mavlink.MAV_RESULT_ACCEPTED
            items = await router.download_mission(1)
            assert items == []


def test_tcp_client_to_a_vehicle_that_serves_tcp():
    """``tcp:HOST:PORT``, as to ArduPilot SITL's 5760."""
    port = free_port(kind=__import__("socket").SOCK_STREAM)
    run(_vehicle_over(f"tcp:127.0.0.1:{port}", f"tcpin:127.0.0.1:{port}"))


def test_udpout_to_a_vehicle_that_listens():
    """``udpout:``: the vehicle hears of the station only from its heartbeats."""
    port = free_port()
    run(_vehicle_over(f"udpout:127.0.0.1:{port}", f"udpin:127.0.0.1:{port}"))


def test_tcpin_serves_a_vehicle_that_connects():
    async def main() -> None:
        async with Router("tcpin:127.0.0.1:0") as router:
            host, port = router.local_address
            reader, writer = await asyncio.open_connection(host, port)
            codec = Codec(5, 1)
            writer.write(codec.encode(HB))
            await writer.drain()
            await router.wait_for_vehicles([5], 5.0)
            router.send(5, mavlink.MAVLink_statustext_message(6, b"over tcpin"))
            parser = Parser()
            async with asyncio.timeout(5.0):
                while True:
                    msgs = parser.feed(await reader.read(4096), stream="s")
                    if any(m.get_type() == "STATUSTEXT" for m in msgs):
                        break
            writer.close()

    run(main())


def test_serial_device_with_baud_rate_through_a_pty():
    """``/dev/pts/N:57600``: a pty pair stands for a telemetry radio; the far end is a
    vehicle writing raw MAVLink bytes, one byte at a time at first."""
    master, slave = os.openpty()
    tty.setraw(master)
    device = os.ttyname(slave)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        async with Router(f"{device}:57600") as router:
            data = Codec(7, 1).encode(HB)
            for b in data:  # a radio delivers bytes, not packets
                os.write(master, bytes([b]))
                await asyncio.sleep(0)
            await router.wait_for_vehicles([7], 5.0)
            assert router.vehicles[7].address == (device, 57600)
            router.send(7, mavlink.MAVLink_statustext_message(6, b"over the radio"))
            parser = Parser()
            os.set_blocking(master, False)
            async with asyncio.timeout(5.0):
                while True:
                    try:
                        chunk = os.read(master, 4096)
                    except BlockingIOError:
                        await asyncio.sleep(0.01)
                        continue
                    msgs = parser.feed(chunk, stream="radio")
                    if any(m.get_type() == "STATUSTEXT" and m.text == "over the radio"
                           for m in msgs):
                        break
            del loop

    try:
        run(main())
    finally:
        os.close(master)
        os.close(slave)


def test_a_bad_endpoint_or_device_is_one_line():
    import pytest

    from econdor_gcs.errors import LinkError

    async def main() -> None:
        with pytest.raises(LinkError, match="cannot open serial port /dev/nonexistent"):
            await Router("/dev/nonexistent:57600").start()
        port = free_port(kind=__import__("socket").SOCK_STREAM)
        with pytest.raises(LinkError, match=f"cannot connect to TCP 127.0.0.1:{port}"):
            await Router(f"tcp:127.0.0.1:{port}").start()

    run(main())
