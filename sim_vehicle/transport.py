"""Byte transports for a simulated vehicle: UDP (out / in) and a TCP server.

Endpoints (``parse_endpoint``):

* ``udpout:HOST:PORT``: the vehicle sends to HOST:PORT from an ephemeral local port and also
  to every address it has heard from recently (so any GCS that talks to it gets replies).
* ``udpin:HOST:PORT``: the vehicle binds HOST:PORT and sends to whoever sent to it.
* ``tcpin:HOST:PORT``: the vehicle is a TCP server (like ArduPilot SITL on 5760); every
  connected client gets every message. Port 0 binds an ephemeral port (see ``local_address``).

All sockets are non-blocking; the owner multiplexes them with ``select`` on ``fileno_list()``.
Incoming bytes come back tagged with a peer key (UDP address or TCP connection id) so each
peer can have its own parser. Sending never blocks: what does not fit is dropped and counted.
"""

from __future__ import annotations

import contextlib
import errno
import socket
import time
from dataclasses import dataclass

MAX_UDP_PEERS = 16
PEER_EXPIRY_S = 30.0
MAX_TCP_CLIENTS = 16
TCP_PENDING_LIMIT = 4 * 1024 * 1024


@dataclass(frozen=True)
class Endpoint:
    kind: str  # "udpout" | "udpin" | "tcpin"
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.kind}:{self.host}:{self.port}"


def parse_endpoint(text: str) -> Endpoint:
    """``udpout:HOST:PORT`` / ``udpin:HOST:PORT`` / ``tcpin:HOST:PORT`` -> Endpoint."""
    parts = text.split(":")
    if len(parts) != 3 or parts[0] not in ("udpout", "udpin", "tcpin"):
        raise ValueError(f"bad endpoint {text!r}: expected udpout|udpin|tcpin:HOST:PORT")
    kind, host, port_s = parts
    try:
        port = int(port_s)
    except ValueError:
        raise ValueError(f"bad endpoint {text!r}: port must be an integer") from None
    if not 0 <= port <= 65535 or (kind == "udpout" and port == 0):
        raise ValueError(f"bad endpoint {text!r}: port out of range")
    if not host:
        raise ValueError(f"bad endpoint {text!r}: empty host")
    return Endpoint(kind, host, port)


class Transport:
    """Base: subclasses fill ``recv_all`` and ``send``."""

    stream = False
    """True for byte streams (TCP): a parser keeps partial packets across reads."""

    def __init__(self) -> None:
        self.tx_dropped = 0
        self.tx_packets = 0
        self.tx_bytes = 0
        self.rx_errors = 0
        """Socket errors while receiving (ICMP unreachable, a TCP client reset, ...): each is
        counted; the transport keeps serving."""

    def fileno_list(self) -> list[socket.socket]:
        raise NotImplementedError

    def want_write(self) -> list[socket.socket]:
        return []

    def recv_all(self, max_chunks: int) -> list[tuple[object, bytes]]:
        raise NotImplementedError

    def send(self, data: bytes) -> None:
        raise NotImplementedError

    def flush(self) -> None:
        """Push out buffered bytes (TCP)."""

    def close(self) -> None:
        raise NotImplementedError

    @property
    def local_address(self) -> tuple[str, int]:
        raise NotImplementedError

    @property
    def has_peer(self) -> bool:
        return True


class UdpTransport(Transport):
    def __init__(self, ep: Endpoint) -> None:
        super().__init__()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        for opt in (socket.SO_SNDBUF, socket.SO_RCVBUF):
            with contextlib.suppress(OSError):  # platform limits
                self.sock.setsockopt(socket.SOL_SOCKET, opt, 1 << 20)
        self.fixed: tuple[str, int] | None = None
        try:
            if ep.kind == "udpout":
                self.fixed = (socket.gethostbyname(ep.host), ep.port)
                self.sock.bind(("0.0.0.0", 0))
            else:
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self.sock.bind((ep.host, ep.port))
        except OSError:
            self.sock.close()
            raise
        self.peers: dict[tuple[str, int], float] = {}

    def fileno_list(self) -> list[socket.socket]:
        return [self.sock]

    def recv_all(self, max_chunks: int) -> list[tuple[object, bytes]]:
        out: list[tuple[object, bytes]] = []
        now = time.monotonic()
        for _ in range(max_chunks):
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                # ICMP port unreachable from a previous send (Linux reports it here)
                self.rx_errors += 1
                continue
            if addr != self.fixed:
                if addr not in self.peers and len(self.peers) >= MAX_UDP_PEERS:
                    oldest = min(self.peers, key=self.peers.__getitem__)
                    del self.peers[oldest]
                self.peers[addr] = now
            out.append((addr, data))
        return out

    def _targets(self) -> list[tuple[str, int]]:
        now = time.monotonic()
        stale = [a for a, t in self.peers.items() if now - t > PEER_EXPIRY_S]
        for a in stale:
            del self.peers[a]
        targets = list(self.peers)
        if self.fixed is not None:
            targets.insert(0, self.fixed)
        return targets

    @property
    def has_peer(self) -> bool:
        return self.fixed is not None or bool(self.peers)

    def send(self, data: bytes) -> None:
        for addr in self._targets():
            try:
                self.sock.sendto(data, addr)
                self.tx_packets += 1
                self.tx_bytes += len(data)
            except (BlockingIOError, InterruptedError):
                self.tx_dropped += 1
            except OSError as exc:
                # nobody listening yet (ECONNREFUSED) or transient: drop
                if exc.errno not in (errno.ECONNREFUSED, errno.ENOBUFS, errno.EHOSTUNREACH,
                                     errno.ENETUNREACH, errno.EPERM):
                    raise
                self.tx_dropped += 1

    def close(self) -> None:
        self.sock.close()

    @property
    def local_address(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()[:2]
        return host, port


class _TcpClient:
    def __init__(self, sock: socket.socket, cid: int) -> None:
        self.sock = sock
        self.cid = cid
        self.pending = bytearray()


class TcpServerTransport(Transport):
    stream = True

    def __init__(self, ep: Endpoint) -> None:
        super().__init__()
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.server.bind((ep.host, ep.port))
            self.server.listen(4)
        except OSError:
            self.server.close()
            raise
        self.server.setblocking(False)
        self.clients: dict[socket.socket, _TcpClient] = {}
        self._next_id = 0
        self.connects = 0

    def fileno_list(self) -> list[socket.socket]:
        return [self.server, *self.clients]

    def want_write(self) -> list[socket.socket]:
        return [s for s, c in self.clients.items() if c.pending]

    @property
    def has_peer(self) -> bool:
        return bool(self.clients)

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self.server.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self.rx_errors += 1
                return
            if len(self.clients) >= MAX_TCP_CLIENTS:
                sock.close()
                continue
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._next_id += 1
            self.connects += 1
            self.clients[sock] = _TcpClient(sock, self._next_id)

    def _drop(self, sock: socket.socket) -> None:
        self.clients.pop(sock, None)
        with contextlib.suppress(OSError):
            sock.close()

    def recv_all(self, max_chunks: int) -> list[tuple[object, bytes]]:
        self._accept()
        out: list[tuple[object, bytes]] = []
        for sock, client in list(self.clients.items()):
            for _ in range(max(1, max_chunks // max(1, len(self.clients)))):
                try:
                    data = sock.recv(65536)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    self.rx_errors += 1
                    self._drop(sock)
                    break
                if not data:
                    self._drop(sock)
                    break
                out.append((("tcp", client.cid), data))
        return out

    def send(self, data: bytes) -> None:
        for client in list(self.clients.values()):
            if len(client.pending) + len(data) > TCP_PENDING_LIMIT:
                self.tx_dropped += 1
                continue
            client.pending += data
            self.tx_packets += 1
            self.tx_bytes += len(data)

    def flush(self) -> None:
        for sock, client in list(self.clients.items()):
            if not client.pending:
                continue
            try:
                n = sock.send(client.pending)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                self.tx_dropped += 1
                self._drop(sock)
                continue
            del client.pending[:n]

    def close(self) -> None:
        for sock in list(self.clients):
            self._drop(sock)
        self.server.close()

    @property
    def local_address(self) -> tuple[str, int]:
        host, port = self.server.getsockname()[:2]
        return host, port


def open_transport(ep: Endpoint | str) -> Transport:
    if isinstance(ep, str):
        ep = parse_endpoint(ep)
    if ep.kind == "tcpin":
        return TcpServerTransport(ep)
    return UdpTransport(ep)
