"""The fault-injecting relay (``econdor relay``) on real loopback sockets."""

from __future__ import annotations

import asyncio
import re
import subprocess
import sys

import pytest

from econdor import cli
from econdor_gcs.errors import LinkError
from econdor_gcs.link.codec import Codec, mavlink
from econdor_gcs.link.relay import Faults, Relay, parse_relay_endpoint
from econdor_gcs.link.router import Router

LOOPBACK = ("127.0.0.1", 0)


class Endpoint(asyncio.DatagramProtocol):
    """A UDP socket that keeps what it receives (and from where)."""

    def __init__(self) -> None:
        self.got: list[tuple[bytes, tuple[str, int]]] = []
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr) -> None:
        self.got.append((data, (addr[0], addr[1])))

    @property
    def address(self) -> tuple[str, int]:
        assert self.transport is not None
        return self.transport.get_extra_info("sockname")[:2]

    def send(self, data: bytes, addr: tuple[str, int]) -> None:
        assert self.transport is not None
        self.transport.sendto(data, addr)


async def endpoint() -> Endpoint:
    loop = asyncio.get_running_loop()
    _, ep = await loop.create_datagram_endpoint(Endpoint, local_addr=LOOPBACK)
    return ep


def close(*endpoints: Endpoint) -> None:
    for ep in endpoints:
        assert ep.transport is not None
        ep.transport.close()


async def settle(cond, timeout_s: float = 5.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not cond():
            await asyncio.sleep(0.01)


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 30.0))


def test_every_fault_at_its_rate_and_the_counts_add_up() -> None:
    n = 2000

    async def main() -> tuple[Relay, list[bytes]]:
        gcs, vehicle = await endpoint(), await endpoint()
        relay = await Relay(LOOPBACK, gcs.address,
                            Faults(drop=0.1, duplicate=0.05, reorder=0.05, corrupt=0.05),
                            seed=7).start()
        st = relay.upstream_stats
        for k in range(n):
            vehicle.send(k.to_bytes(4, "big") * 4, relay.listen_address)
            if k % 50 == 49:  # the relay takes each burst before the next: no socket overflows
                await settle(lambda k=k: st.received == k + 1)
        # everything out (the last one held back goes on the relay's timer) and received
        await settle(lambda: st.received == n and st.sent == n - st.dropped + st.duplicated
                     and len(gcs.got) == st.sent)
        relay.close()
        close(gcs, vehicle)
        return relay, [d for d, _ in gcs.got]

    relay, got = run(main())
    st = relay.upstream_stats
    assert st.received == n
    assert st.sent == len(got) == n - st.dropped + st.duplicated
    for name, p in (("dropped", 0.1), ("duplicated", 0.05 * 0.9), ("reordered", 0.05 * 0.9),
                    ("corrupted", 0.05 * 0.9)):
        assert getattr(st, name) == pytest.approx(p * n, rel=0.3), name
    intact = [d for d in got if d[:4] * 4 == d]
    assert len(got) - len(intact) == pytest.approx(st.corrupted * 1.05, abs=st.duplicated)
    order = [int.from_bytes(d[:4], "big") for d in intact]
    assert sum(b < a for a, b in zip(order, order[1:], strict=False)) > 0.5 * st.reordered
    assert len(set(order)) < len(order)  # duplicates arrive
    # corrupted datagrams differ from their original in exactly one bit
    for d in got:
        if d not in intact:
            k = max(set(d[i:i + 4] for i in range(0, 16, 4)), key=lambda c: d.count(c))
            flips = sum(bin(a ^ b).count("1") for a, b in zip(d, k * 4, strict=True))
            assert flips == 1


def test_each_client_gets_its_own_address_and_its_own_replies() -> None:
    async def main() -> None:
        gcs, a, b = await endpoint(), await endpoint(), await endpoint()
        relay = await Relay(LOOPBACK, gcs.address).start()
        a.send(b"from a", relay.listen_address)
        b.send(b"from b", relay.listen_address)
        await settle(lambda: len(gcs.got) == 2)
        sources = {data: addr for data, addr in gcs.got}
        assert sources[b"from a"] != sources[b"from b"]
        gcs.send(b"to a", sources[b"from a"])
        gcs.send(b"to b", sources[b"from b"])
        await settle(lambda: a.got and b.got)
        assert [d for d, _ in a.got] == [b"to a"] and [d for d, _ in b.got] == [b"to b"]
        assert a.got[0][1] == relay.listen_address  # replies come from where a sent to
        relay.close()
        close(gcs, a, b)

    run(main())


def test_corrupted_mavlink_is_counted_and_dropped_by_the_station() -> None:
    """Every frame with a flipped bit fails the CRC: counted as bad, never delivered."""

    async def main() -> None:
        async with Router("udpin:127.0.0.1:0") as router:
            relay = await Relay(LOOPBACK, router.local_address, Faults(corrupt=1.0),
                                seed=3).start()
            vehicle = await endpoint()
            codec = Codec(1, 1)
            for _ in range(200):
                vehicle.send(codec.encode(mavlink.MAVLink_heartbeat_message(
                    mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 3, 3)),
                    relay.listen_address)
            await settle(lambda: router.stats["datagrams_in"] == 200)
            # every datagram counted at least once as damage (bad CRC, garbage, cut short)
            assert router.bad_packets + router.parser.unknown_packets >= 200
            # a flipped bit that the CRC passes would be a 1 in 65536 event per frame
            assert router.stats["messages_in"] == 0 and router.vehicles == {}
            relay.close()
            close(vehicle)

    run(main())


@pytest.mark.parametrize("text", ["udpin:10.1.2.3:14550", "192.168.1.5:5760",
                                  "udp:8.8.8.8:53"])
def test_only_loopback(text: str) -> None:
    with pytest.raises(LinkError, match="not a loopback address"):
        parse_relay_endpoint(text)


def test_cli_refuses_a_remote_endpoint_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["relay", "--listen", "udpin:127.0.0.1:0", "--to", "10.0.0.9:14550",
                     "--drop", "10%"])
    assert code == 1
    assert capsys.readouterr().err.strip() == (
        "econdor: error: 10.0.0.9: not a loopback address (the relay only relays on this "
        "machine)")


@pytest.mark.parametrize("bad", ["1.5", "-0.1", "150%", "often"])
def test_cli_probabilities(bad: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["relay", "--listen", "127.0.0.1:0", "--to", "127.0.0.1:9", "--drop", bad])
    assert exc.value.code == 2 and "--drop" in capsys.readouterr().err


@pytest.mark.e2e
def test_cli_relays_and_reports_its_counts() -> None:
    """``econdor relay`` as a process: the ready line, traffic, the counts at exit."""
    import socket

    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(LOOPBACK)
    sink.settimeout(5.0)
    proc = subprocess.Popen(
        [sys.executable, "-m", "econdor", "relay", "--listen", "udpin:127.0.0.1:0", "--to",
         f"udpout:127.0.0.1:{sink.getsockname()[1]}", "--drop", "50%", "--seed", "1",
         "--duration", "3"], stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        ready = proc.stderr.readline()
        m = re.match(r"relay: listening on udpin:127\.0\.0\.1:(\d+) -> udpout:127\.0\.0\.1:\d+$",
                     ready.strip())
        assert m, ready
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as src:
            for k in range(100):
                src.sendto(bytes([k]), ("127.0.0.1", int(m[1])))
        got = 0
        sink.settimeout(1.0)
        while True:
            try:
                sink.recv(16)
            except TimeoutError:
                break
            got += 1
        _, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        sink.close()
    assert proc.returncode == 0
    last = err.strip().splitlines()[-1]
    m2 = re.search(r"in (\d+) out (\d+) dropped (\d+)", last)
    assert m2 and int(m2[1]) == 100 and int(m2[2]) == got and int(m2[3]) == 100 - got
    assert 25 < got < 75


def test_an_outage_loses_everything_both_ways_then_the_link_is_back() -> None:
    """A blackout set from another thread, and a scripted one: every datagram both ways is
    lost (counted), and what follows goes through again."""

    async def main() -> None:
        gcs, vehicle = await endpoint(), await endpoint()
        relay = await Relay(LOOPBACK, gcs.address, outages=[(3600.0, 1.0)]).start()
        vehicle.send(b"before", relay.listen_address)
        await settle(lambda: len(gcs.got) == 1)
        relay.set_blackout(True)
        await settle(lambda: relay.blackout)
        vehicle.send(b"during", relay.listen_address)
        gcs.send(b"down during", gcs.got[0][1])
        await settle(lambda: relay.upstream_stats.blacked_out == 1
                     and relay.downstream_stats.blacked_out == 1)
        relay.set_blackout(False)
        await settle(lambda: not relay.blackout)
        vehicle.send(b"after", relay.listen_address)
        await settle(lambda: len(gcs.got) == 2)
        assert [d for d, _ in gcs.got] == [b"before", b"after"] and vehicle.got == []
        # a scripted outage, START seconds after the first datagram
        relay.outages[:] = [(0.0, 3600.0)]
        vehicle.send(b"scripted", relay.listen_address)
        await settle(lambda: relay.upstream_stats.blacked_out == 2)
        assert len(gcs.got) == 2
        relay.close()
        close(gcs, vehicle)

    run(main())


def test_relay_outage_argument() -> None:
    from econdor_gcs.link.relay import parse_outage

    assert parse_outage("40:15") == (40.0, 15.0)
    for bad in ("40", "a:b", "-1:5", "5:0", "inf:5"):
        with pytest.raises(LinkError, match="bad outage"):
            parse_outage(bad)
