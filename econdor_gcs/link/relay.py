"""A fault-injecting UDP relay for MAVLink links on this machine (``econdor relay``).

::

    vehicles ──► LISTEN ══ relay: drop / duplicate / reorder / corrupt ══► TO (the GCS)
             ◄──────────────────────────────────────────────────────────◄

The relay binds ``LISTEN``; each client that sends to it (a vehicle, a tool) gets its own
upstream socket towards ``TO``, so the ground station still sees one address per vehicle and
routes its replies through the relay back to the right client. Both directions suffer the
same :class:`Faults`, each datagram independently:

``drop``
    the datagram is lost;
``duplicate``
    it is delivered twice;
``reorder``
    it is held back and delivered after the next datagram in the same direction (or after
    :data:`REORDER_HOLD_S` if none comes);
``corrupt``
    one random bit of it is flipped (MAVLink's CRC-16 rejects it on the other side).

And whole outages (a radio drop-out): ``outages`` (``--outage START:SECONDS``, START seconds
after the first datagram) or :attr:`Relay.blackout` set by a program (a test that waits
for the moment it wants), during which every datagram both ways is lost.

It relays between loopback addresses only: it is a tool for tests and for users checking
what their own link setup does on a bad link, not a network service.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import math
import random
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ..errors import LinkError

__all__ = ["DirectionStats", "Faults", "Relay", "parse_outage", "parse_relay_endpoint"]

REORDER_HOLD_S = 0.05
"""Longest a held-back datagram waits for the next one before it goes out anyway."""

Address = tuple[str, int]


def parse_relay_endpoint(text: str) -> Address:
    """``[udp|udpin|udpout:]HOST:PORT`` on a loopback address -> ``(HOST, PORT)``.

    >>> parse_relay_endpoint("udpin:127.0.0.1:14550")
    ('127.0.0.1', 14550)
    >>> parse_relay_endpoint("10.0.0.2:14550")
    Traceback (most recent call last):
    ...
    econdor_gcs.errors.LinkError: 10.0.0.2: not a loopback address (the relay only relays on this machine)
    """
    rest = text
    scheme, sep, tail = text.partition(":")
    if sep and scheme in ("udp", "udpin", "udpout"):
        rest = tail
    host, sep, port_text = rest.rpartition(":")
    host = host.strip("[]")
    if not sep or not host:
        raise LinkError(f"bad endpoint {text!r}: expected [udp:]HOST:PORT")
    try:
        port = int(port_text)
    except ValueError:
        raise LinkError(f"bad port {port_text!r} in endpoint {text!r}") from None
    if not 0 <= port <= 65535:
        raise LinkError(f"port {port} out of range in endpoint {text!r}")
    try:
        infos = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except socket.gaierror as exc:
        raise LinkError(f"{host}: cannot resolve it ({exc.strerror})") from None
    addresses = {str(info[4][0]) for info in infos}
    if not all(ipaddress.ip_address(a).is_loopback for a in addresses):
        raise LinkError(f"{host}: not a loopback address (the relay only relays on this "
                        "machine)")
    return sorted(addresses)[0], port


@dataclass(frozen=True)
class Faults:
    """Per-datagram probabilities, each in [0, 1], applied to both directions."""

    drop: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    corrupt: float = 0.0

    def __post_init__(self) -> None:
        for name in ("drop", "duplicate", "reorder", "corrupt"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1], got {p}")


def parse_outage(text: str) -> tuple[float, float]:
    """``START:SECONDS`` -> ``(start_s, duration_s)``.

    >>> parse_outage("40:15")
    (40.0, 15.0)
    """
    start, sep, length = text.partition(":")
    try:
        out = (float(start), float(length))
    except ValueError:
        raise LinkError(f"bad outage {text!r}: expected START:SECONDS, e.g. 40:15") from None
    if not sep or not (out[0] >= 0 and out[1] > 0) or any(map(math.isinf, out)):
        raise LinkError(f"bad outage {text!r}: START >= 0 and SECONDS > 0, both finite")
    return out


@dataclass
class DirectionStats:
    """What the relay did to one direction's datagrams."""

    received: int = 0
    sent: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    corrupted: int = 0
    blacked_out: int = 0

    def line(self) -> str:
        return (f"in {self.received} out {self.sent} dropped {self.dropped} duplicated "
                f"{self.duplicated} reordered {self.reordered} corrupted {self.corrupted} "
                f"blacked out {self.blacked_out}")


@dataclass
class _Lane:
    """One direction of one client: where its datagrams go and the one held back."""

    send: Callable[[bytes], None]
    stats: DirectionStats
    held: bytes | None = None
    timer: asyncio.TimerHandle | None = None


class _Socket(asyncio.DatagramProtocol):
    def __init__(self, on_datagram: Callable[[bytes, Address], None],
                 on_error: Callable[[Exception], None]) -> None:
        self.on_datagram = on_datagram
        self.on_error = on_error

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.on_datagram(data, (addr[0], addr[1]))

    def error_received(self, exc: Exception) -> None:
        self.on_error(exc)  # e.g. ICMP port unreachable: nobody at TO yet


@dataclass
class _Client:
    address: Address
    upstream: asyncio.DatagramTransport
    up: _Lane
    down: _Lane


@dataclass
class Relay:
    """The relay (see the module docstring); :meth:`start` on a running asyncio loop.

    Parameters
    ----------
    listen, to:
        ``(host, port)`` on loopback addresses (:func:`parse_relay_endpoint`); port 0 for
        ``listen`` binds a free port (:attr:`listen_address` after :meth:`start`).
    faults:
        What to do to the datagrams.
    seed:
        Seed of the fault draws (the same traffic in the same order gets the same faults).
    """

    listen: Address
    to: Address
    faults: Faults = field(default_factory=Faults)
    seed: int | None = None
    outages: list[tuple[float, float]] = field(default_factory=list)
    """``(start_s, duration_s)`` after the first datagram: every datagram is lost then."""
    blackout: bool = False
    """Set (from the relay's loop, or with :meth:`set_blackout` from another thread): every
    datagram both ways is lost until it is cleared."""
    upstream_stats: DirectionStats = field(default_factory=DirectionStats)
    """Towards ``to`` (vehicles -> GCS)."""
    downstream_stats: DirectionStats = field(default_factory=DirectionStats)
    """Back to the clients (GCS -> vehicles)."""
    socket_errors: int = 0

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)
        self._clients: dict[Address, _Client] = {}
        self._listener: asyncio.DatagramTransport | None = None
        self._first: float | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    async def start(self) -> Relay:
        loop = self._loop = asyncio.get_running_loop()
        try:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Socket(self._from_client, self._count_error), local_addr=self.listen)
        except OSError as exc:
            raise LinkError(f"relay: cannot listen on {self.listen[0]}:{self.listen[1]}: "
                            f"{exc.strerror or exc}") from exc
        self._listener = transport
        return self

    @property
    def listen_address(self) -> Address:
        if self._listener is None:
            raise LinkError("the relay is not started")
        host, port = self._listener.get_extra_info("sockname")[:2]
        return host, port

    def close(self) -> None:
        for client in self._clients.values():
            for lane in (client.up, client.down):
                self._release(lane)
            client.upstream.close()
        self._clients.clear()
        if self._listener is not None:
            self._listener.close()
            self._listener = None

    def set_blackout(self, on: bool) -> None:
        """Start or end an outage now (any thread)."""
        if self._loop is None:
            self.blackout = on
        else:
            self._loop.call_soon_threadsafe(setattr, self, "blackout", on)

    def _out_now(self) -> bool:
        now = asyncio.get_running_loop().time()
        if self._first is None:
            self._first = now
        t = now - self._first
        return self.blackout or any(a <= t < a + d for a, d in self.outages)

    def stats_line(self) -> str:
        return (f"to {self.to[0]}:{self.to[1]}: {self.upstream_stats.line()}; back: "
                f"{self.downstream_stats.line()}; clients {len(self._clients)}, socket errors "
                f"{self.socket_errors}")

    # -- plumbing -------------------------------------------------------------------------------
    def _count_error(self, exc: Exception) -> None:
        self.socket_errors += 1

    def _from_client(self, data: bytes, addr: Address) -> None:
        client = self._clients.get(addr)
        if client is None:
            asyncio.get_running_loop().create_task(self._connect(data, addr))
            return
        self._pass(client.up, data)

    async def _connect(self, first: bytes, addr: Address) -> None:
        if addr in self._clients:  # two datagrams raced to open the same client
            self._pass(self._clients[addr].up, first)
            return
        loop = asyncio.get_running_loop()
        listener = self._listener
        if listener is None:
            return
        transport, _ = await loop.create_datagram_endpoint(
            lambda: _Socket(lambda data, _a: self._pass(client.down, data), self._count_error),
            remote_addr=self.to)
        if addr in self._clients:
            transport.close()
            self._pass(self._clients[addr].up, first)
            return

        def up_send(data: bytes) -> None:
            transport.sendto(data)

        def down_send(data: bytes) -> None:
            listener.sendto(data, addr)

        client = _Client(addr, transport, _Lane(up_send, self.upstream_stats),
                         _Lane(down_send, self.downstream_stats))
        self._clients[addr] = client
        self._pass(client.up, first)

    def _pass(self, lane: _Lane, data: bytes) -> None:
        """One datagram through the faults of its direction."""
        f, rng, st = self.faults, self._rng, lane.stats
        st.received += 1
        if self._out_now():
            st.blacked_out += 1
            return
        if rng.random() < f.drop:
            st.dropped += 1
            return
        if rng.random() < f.corrupt and data:
            bit = rng.randrange(len(data) * 8)
            buf = bytearray(data)
            buf[bit // 8] ^= 1 << (bit % 8)
            data = bytes(buf)
            st.corrupted += 1
        copies = 2 if rng.random() < f.duplicate else 1
        st.duplicated += copies - 1
        if lane.held is None and rng.random() < f.reorder:
            # hold this one back: it goes out after the next datagram (or the timer)
            st.reordered += 1
            lane.held = data
            lane.timer = asyncio.get_running_loop().call_later(
                REORDER_HOLD_S, self._release, lane)
            copies -= 1
            for _ in range(copies):
                self._out(lane, data)
            return
        for _ in range(copies):
            self._out(lane, data)
        self._release(lane)  # the one held back before this one now comes after it

    def _release(self, lane: _Lane) -> None:
        if lane.timer is not None:
            lane.timer.cancel()
            lane.timer = None
        held, lane.held = lane.held, None
        if held is not None:
            self._out(lane, held)

    def _out(self, lane: _Lane, data: bytes) -> None:
        try:
            lane.send(data)
        except OSError:
            self.socket_errors += 1
            return
        lane.stats.sent += 1


async def serve(relay: Relay, *, duration_s: float | None = None,
                ready: Callable[[Relay], None] | None = None) -> Relay:
    """Run ``relay`` until SIGINT / SIGTERM (or ``duration_s``); return it (its counters)."""
    import signal

    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    handled = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, stop.set)
            handled.append(sig)
        except (NotImplementedError, RuntimeError):  # not the main thread: the caller stops us
            continue
    await relay.start()
    try:
        if ready is not None:
            ready(relay)
        with contextlib.suppress(TimeoutError):  # the duration is over: a normal end
            await asyncio.wait_for(stop.wait(), duration_s)
    finally:
        relay.close()
        for sig in handled:
            loop.remove_signal_handler(sig)
    return relay
