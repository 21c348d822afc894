"""The station's byte links, one small asyncio class per kind.

``--connect`` takes the endpoint spellings MAVProxy and QGroundControl users know
(:func:`parse_endpoint`):

============================  ====================================================================
``udpin:HOST:PORT``           bind HOST:PORT; every address that sends to it is a peer (the
                              default; ``udp:`` is a synonym)
``udpout:HOST:PORT``          send to HOST:PORT from a port of our own (a vehicle or a router
                              that listens, e.g. ``sim-vehicle --connect udpin:...``)
``tcp:HOST:PORT``             connect to a TCP server (ArduPilot SITL on 5760, a telemetry
                              bridge); reconnects while the link is open
``tcpin:HOST:PORT``           be a TCP server; every client is a peer
``DEVICE:BAUD``               a serial port, e.g. ``/dev/ttyUSB0:57600`` (a telemetry radio);
                              also ``serial:DEVICE:BAUD``, and ``DEVICE`` alone at 57600
============================  ====================================================================

A transport delivers ``(bytes, peer)`` to the router and sends bytes to a peer; it knows
nothing of MAVLink. Datagram links (UDP) hand over whole datagrams, stream links (TCP,
serial) arbitrary chunks of one byte stream per peer (:attr:`Transport.stream`), which the
router's parser puts back together. Port 0 binds a free port (:attr:`Transport.local_address`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from ..errors import LinkError

__all__ = ["DEFAULT_BAUD", "Address", "Endpoint", "EndpointKind", "Transport", "open_transport",
           "parse_endpoint"]

log = logging.getLogger(__name__)

Address = tuple[str, int]
"""A peer on its link: ``(host, port)``, or ``(device, baud)`` for a serial port."""
DEFAULT_BAUD = 57600
"""A SiK telemetry radio's default rate (ArduPilot's SERIALn_BAUD 57)."""
RCVBUF_BYTES = 4 << 20
"""Requested UDP receive buffer (the kernel caps it at net.core.rmem_max)."""
TCP_RECONNECT_S = 1.0
"""How often a ``tcp:`` link tries again to reach a server that is down or went away."""

OnBytes = Callable[[bytes, Address], None]
OnPeerGone = Callable[[Address], None]


class EndpointKind(StrEnum):
    UDPIN = "udpin"
    UDPOUT = "udpout"
    TCP = "tcp"
    TCPIN = "tcpin"
    SERIAL = "serial"


@dataclass(frozen=True)
class Endpoint:
    """One parsed ``--connect`` value; ``host`` is the device and ``port`` the baud rate of
    a serial port."""

    kind: EndpointKind
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.kind.value}:{self.host}:{self.port}"

    @property
    def stream(self) -> bool:
        return self.kind in (EndpointKind.TCP, EndpointKind.TCPIN, EndpointKind.SERIAL)


_EXAMPLES = ("udpin:0.0.0.0:14550, udpout:HOST:PORT, tcp:127.0.0.1:5760, tcpin:0.0.0.0:5760 "
             "or /dev/ttyUSB0:57600")


def parse_endpoint(text: str) -> Endpoint:
    """A ``--connect`` value -> :class:`Endpoint`; a bad one is a :class:`LinkError` naming it.

    >>> str(parse_endpoint("tcp:127.0.0.1:5760"))
    'tcp:127.0.0.1:5760'
    >>> parse_endpoint("udp:0.0.0.0:14550").kind.value
    'udpin'
    >>> parse_endpoint("/dev/ttyUSB0:57600")
    Endpoint(kind=<EndpointKind.SERIAL: 'serial'>, host='/dev/ttyUSB0', port=57600)
    >>> parse_endpoint("/dev/ttyACM0").port
    57600
    """
    text = text.strip()
    scheme, sep, rest = text.partition(":")
    if scheme == "serial" or text.startswith("/") or scheme.upper().startswith("COM"):
        device_and_baud = rest if scheme == "serial" else text
        return _serial(text, device_and_baud)
    kinds = {"udp": EndpointKind.UDPIN, **{k.value: k for k in EndpointKind}}
    kind = kinds.get(scheme)
    host, sep2, port_text = rest.rpartition(":")
    if kind is None or kind == EndpointKind.SERIAL or not sep or not sep2 or not host:
        raise LinkError(f"cannot connect to {text!r}: expected one of {_EXAMPLES}")
    try:
        port = int(port_text)
    except ValueError:
        raise LinkError(f"bad port {port_text!r} in endpoint {text!r}") from None
    if not 0 <= port <= 65535 or (port == 0 and kind in (EndpointKind.UDPOUT, EndpointKind.TCP)):
        raise LinkError(f"port {port} out of range in endpoint {text!r}")
    return Endpoint(kind, host.strip("[]"), port)


def _serial(text: str, device_and_baud: str) -> Endpoint:
    device, sep, baud_text = device_and_baud.rpartition(":")
    if not sep:
        device, sep, baud_text = device_and_baud.rpartition(",")
    if not sep:
        device, baud_text = device_and_baud, str(DEFAULT_BAUD)
    try:
        baud = int(baud_text)
    except ValueError:
        raise LinkError(f"bad baud rate {baud_text!r} in endpoint {text!r}") from None
    if not device or baud <= 0:
        raise LinkError(f"cannot open {text!r}: expected DEVICE:BAUD, e.g. /dev/ttyUSB0:57600")
    return Endpoint(EndpointKind.SERIAL, device, baud)


class Transport:
    """One link: started with :meth:`open`, bytes out with :meth:`send`.

    ``on_bytes(data, peer)`` gets what arrives (a datagram, or the next chunk of ``peer``'s
    stream); ``on_gone(peer)`` is told when a stream peer closed its connection.
    Counters: ``send_errors`` (a peer that cannot be reached, a full buffer), ``rx_errors``.
    """

    stream = False

    def __init__(self, endpoint: Endpoint) -> None:
        self.endpoint = endpoint
        self.send_errors = 0
        self.rx_errors = 0
        self._on_bytes: OnBytes = lambda data, peer: None
        self._on_gone: OnPeerGone = lambda peer: None

    async def open(self, on_bytes: OnBytes, on_gone: OnPeerGone) -> None:
        self._on_bytes, self._on_gone = on_bytes, on_gone
        await self._open()

    async def _open(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def send(self, data: bytes, peer: Address) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def local_address(self) -> Address:
        """Where this link listens (UDP, TCP server) or which local port it uses."""
        raise LinkError(f"{self.endpoint}: no local address")

    @property
    def peers(self) -> list[Address]:
        """Peers it can send to without having heard from them (``udpout``, ``tcp``, serial)."""
        return []


# --------------------------------------------------------------------------------------------
# UDP


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, owner: UdpTransport) -> None:
        self.owner = owner

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.owner._on_bytes(data, (addr[0], addr[1]))

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable from a peer that went away: count, keep serving
        self.owner.rx_errors += 1


class UdpTransport(Transport):
    """``udpin`` (bind the endpoint) or ``udpout`` (send to it from a port of our own)."""

    def __init__(self, endpoint: Endpoint) -> None:
        super().__init__(endpoint)
        self._transport: asyncio.DatagramTransport | None = None
        self._remote: Address | None = None

    async def _open(self) -> None:
        loop = asyncio.get_running_loop()
        ep = self.endpoint
        try:
            if ep.kind == EndpointKind.UDPOUT:
                infos = await loop.getaddrinfo(ep.host, ep.port, family=socket.AF_INET,
                                               type=socket.SOCK_DGRAM)
                self._remote = (str(infos[0][4][0]), int(infos[0][4][1]))
                local: Address = ("0.0.0.0", 0)
            else:
                local = (ep.host, ep.port)
            transport, _ = await loop.create_datagram_endpoint(lambda: _Datagrams(self),
                                                               local_addr=local)
        except OSError as exc:
            what = "send to" if ep.kind == EndpointKind.UDPOUT else "listen on"
            raise LinkError(f"cannot {what} UDP {ep.host}:{ep.port}: "
                            f"{exc.strerror or exc}") from exc
        self._transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None:  # bursts of samples from many vehicles: a roomy receive buffer
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)

    def send(self, data: bytes, peer: Address) -> None:
        if self._transport is None:
            raise LinkError(f"{self.endpoint}: the link is not open")
        try:
            self._transport.sendto(data, peer)
        except OSError:
            self.send_errors += 1

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    @property
    def local_address(self) -> Address:
        if self._transport is None:
            raise LinkError(f"{self.endpoint}: the link is not open")
        name = self._transport.get_extra_info("sockname")
        return name[0], name[1]

    @property
    def peers(self) -> list[Address]:
        return [self._remote] if self._remote is not None else []


# --------------------------------------------------------------------------------------------
# byte streams: TCP and serial


class _Stream(asyncio.Protocol):
    def __init__(self, owner: Transport, register: Callable[[_Stream], None],
                 unregister: Callable[[_Stream], None]) -> None:
        self.owner = owner
        self.register, self.unregister = register, unregister
        self.transport: asyncio.Transport | None = None
        self.peer: Address = ("", 0)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        name = transport.get_extra_info("peername")
        if isinstance(name, tuple) and len(name) >= 2:
            self.peer = (str(name[0]), int(name[1]))
        if isinstance(transport, asyncio.WriteTransport):
            transport.set_write_buffer_limits(high=1 << 20)
        self.register(self)

    def data_received(self, data: bytes) -> None:
        self.owner._on_bytes(data, self.peer)

    def connection_lost(self, exc: Exception | None) -> None:
        self.unregister(self)
        self.owner._on_gone(self.peer)

    def write(self, data: bytes) -> bool:
        t = self.transport
        if t is None or t.is_closing() or t.get_write_buffer_size() > (4 << 20):
            return False  # a peer that does not read: drop rather than grow without bound
        t.write(data)
        return True


class TcpClientTransport(Transport):
    """``tcp:HOST:PORT``: one connection to a server; while open, it reconnects every
    :data:`TCP_RECONNECT_S` after the server went away (an autopilot that rebooted)."""

    stream = True

    def __init__(self, endpoint: Endpoint) -> None:
        super().__init__(endpoint)
        self._conn: _Stream | None = None
        self._closing = False
        self._retry: asyncio.Task[None] | None = None
        self.connects = 0

    async def _open(self) -> None:
        ep = self.endpoint
        try:
            await self._connect()
        except OSError as exc:
            raise LinkError(f"cannot connect to TCP {ep.host}:{ep.port}: "
                            f"{exc.strerror or exc}") from exc

    async def _connect(self) -> None:
        loop = asyncio.get_running_loop()
        await loop.create_connection(
            lambda: _Stream(self, self._up, self._down), self.endpoint.host, self.endpoint.port)

    def _up(self, conn: _Stream) -> None:
        self._conn = conn
        self.connects += 1
        sock = conn.transport.get_extra_info("socket") if conn.transport else None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def _down(self, conn: _Stream) -> None:
        if self._conn is conn:
            self._conn = None
        if not self._closing and self._retry is None:
            self._retry = asyncio.get_running_loop().create_task(self._reconnect())

    async def _reconnect(self) -> None:
        try:
            while not self._closing and self._conn is None:
                await asyncio.sleep(TCP_RECONNECT_S)
                with contextlib.suppress(OSError):
                    await self._connect()
        finally:
            self._retry = None

    def send(self, data: bytes, peer: Address) -> None:
        if self._conn is None or not self._conn.write(data):
            self.send_errors += 1

    def close(self) -> None:
        self._closing = True
        if self._retry is not None:
            self._retry.cancel()
        if self._conn is not None and self._conn.transport is not None:
            self._conn.transport.close()

    @property
    def local_address(self) -> Address:
        if self._conn is None or self._conn.transport is None:
            raise LinkError(f"{self.endpoint}: not connected")
        name = self._conn.transport.get_extra_info("sockname")
        return name[0], name[1]

    @property
    def peers(self) -> list[Address]:
        return [self._conn.peer] if self._conn is not None else []


class TcpServerTransport(Transport):
    """``tcpin:HOST:PORT``: a TCP server; each client connection is a peer."""

    stream = True

    def __init__(self, endpoint: Endpoint) -> None:
        super().__init__(endpoint)
        self._server: asyncio.Server | None = None
        self._clients: dict[Address, _Stream] = {}

    async def _open(self) -> None:
        ep = self.endpoint
        loop = asyncio.get_running_loop()
        try:
            self._server = await loop.create_server(
                lambda: _Stream(self, self._up, self._down), ep.host, ep.port,
                reuse_address=True)
        except OSError as exc:
            raise LinkError(f"cannot listen on TCP {ep.host}:{ep.port}: "
                            f"{exc.strerror or exc}") from exc

    def _up(self, conn: _Stream) -> None:
        self._clients[conn.peer] = conn

    def _down(self, conn: _Stream) -> None:
        if self._clients.get(conn.peer) is conn:
            del self._clients[conn.peer]

    def send(self, data: bytes, peer: Address) -> None:
        conn = self._clients.get(peer)
        if conn is None or not conn.write(data):
            self.send_errors += 1

    def close(self) -> None:
        if self._server is not None:
            self._server.close()
            self._server = None
        for conn in list(self._clients.values()):
            if conn.transport is not None:
                conn.transport.close()

    @property
    def local_address(self) -> Address:
        if self._server is None or not self._server.sockets:
            raise LinkError(f"{self.endpoint}: the link is not open")
        name = self._server.sockets[0].getsockname()
        return name[0], name[1]


class SerialTransport(Transport):
    """``DEVICE:BAUD``: a serial port (pyserial opens and configures it; the event loop
    reads it when it has bytes). The one peer is ``(DEVICE, BAUD)``."""

    stream = True

    def __init__(self, endpoint: Endpoint) -> None:
        super().__init__(endpoint)
        self._port: Any = None
        self._pending = bytearray()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._writing = False

    @property
    def _peer(self) -> Address:
        return (self.endpoint.host, self.endpoint.port)

    async def _open(self) -> None:
        import serial

        ep = self.endpoint
        try:
            port = serial.Serial(ep.host, ep.port, timeout=0, write_timeout=0,
                                 exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f"cannot open serial port {ep.host} at {ep.port} baud: "
                            f"{exc}") from exc
        self._port = port
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(port.fileno(), self._readable)

    def _readable(self) -> None:
        try:
            data = os.read(self._port.fileno(), 65536)
        except BlockingIOError:
            return
        except OSError:
            self.rx_errors += 1
            self._stop_reading()
            self._on_gone(self._peer)
            return
        if data:
            self._on_bytes(data, self._peer)

    def _stop_reading(self) -> None:
        if self._loop is not None and self._port is not None:
            with contextlib.suppress(ValueError, OSError):
                self._loop.remove_reader(self._port.fileno())
                self._loop.remove_writer(self._port.fileno())

    def send(self, data: bytes, peer: Address) -> None:
        if self._port is None or len(self._pending) > (1 << 20):
            self.send_errors += 1
            return
        self._pending += data
        self._flush()

    def _flush(self) -> None:
        while self._pending:
            try:
                n = os.write(self._port.fileno(), self._pending)
            except BlockingIOError:
                n = 0
            except OSError:
                self.send_errors += 1
                self._pending.clear()
                return
            if n == 0:
                break
            del self._pending[:n]
        want = bool(self._pending)
        if want != self._writing and self._loop is not None:
            if want:
                self._loop.add_writer(self._port.fileno(), self._flush)
            else:
                self._loop.remove_writer(self._port.fileno())
            self._writing = want

    def close(self) -> None:
        self._stop_reading()
        if self._port is not None:
            with contextlib.suppress(OSError):
                self._port.close()
            self._port = None

    @property
    def local_address(self) -> Address:
        return self._peer

    @property
    def peers(self) -> list[Address]:
        return [self._peer] if self._port is not None else []


def open_transport(endpoint: Endpoint | str) -> Transport:
    """The transport for ``endpoint`` (not yet open: ``await transport.open(...)``)."""
    ep = parse_endpoint(endpoint) if isinstance(endpoint, str) else endpoint
    if ep.kind in (EndpointKind.UDPIN, EndpointKind.UDPOUT):
        return UdpTransport(ep)
    if ep.kind == EndpointKind.TCP:
        return TcpClientTransport(ep)
    if ep.kind == EndpointKind.TCPIN:
        return TcpServerTransport(ep)
    return SerialTransport(ep)
