"""The watch link: every vehicle message to a watcher, as MAVProxy's ``--out`` does.

``econdor run --forward udpout:127.0.0.1:14551`` sends each MAVLink message the station
receives from a vehicle, byte for byte (sender ids, sequence numbers and signatures kept), to
that UDP address, so that QGroundControl (listening on 14550 by default) or MAVProxy
(``mavproxy.py --master=udpin:127.0.0.1:14551``) shows the fleet live beside the run.

What the watcher sends back (its heartbeats, stream requests, commands) is dropped and
counted, unless ``--forward-commands`` is given: then messages addressed to a vehicle (or
broadcast, target system 0) are relayed to it unchanged. Its answers reach the station and,
through this link, the watcher; commanding a vehicle that the station is flying is the
watcher's own risk.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from ..errors import LinkError
from .codec import Parser
from .router import Received, Router

__all__ = ["Forwarder", "parse_forward_endpoint"]

log = logging.getLogger(__name__)


def parse_forward_endpoint(endpoint: str) -> tuple[str, int]:
    """``"udpout:HOST:PORT"`` (or ``"udp:HOST:PORT"``, MAVProxy's ``--out`` spelling).

    >>> parse_forward_endpoint("udpout:127.0.0.1:14551")
    ('127.0.0.1', 14551)
    """
    scheme, sep, rest = endpoint.partition(":")
    host, sep2, port_text = rest.rpartition(":")
    if not sep or not sep2 or scheme not in ("udpout", "udp") or not host:
        raise LinkError(f"--forward {endpoint!r}: expected udpout:HOST:PORT, e.g. "
                        "udpout:127.0.0.1:14551")
    try:
        port = int(port_text)
    except ValueError:
        raise LinkError(f"--forward {endpoint!r}: port {port_text!r} is not a number") from None
    if not 0 < port <= 65535:
        raise LinkError(f"--forward {endpoint!r}: port {port} out of range")
    return host.strip("[]"), port


class Forwarder(asyncio.DatagramProtocol):
    """Forward vehicle messages to a watcher; relay the watcher's only if ``allow_commands``.

    Counters (:attr:`stats`): ``forwarded`` messages sent to the watcher, ``from_watcher``
    messages it sent, ``relayed`` of those passed on to vehicles, ``dropped`` the others,
    ``send_errors`` (the watcher is not listening: ICMP unreachable, ...).
    """

    def __init__(self, router: Router, endpoint: str, allow_commands: bool = False) -> None:
        self.router = router
        self.address = parse_forward_endpoint(endpoint)
        self.allow_commands = allow_commands
        self.parser = Parser()
        self.stats = {"forwarded": 0, "from_watcher": 0, "relayed": 0, "dropped": 0,
                      "send_errors": 0}
        self._transport: asyncio.DatagramTransport | None = None

    async def start(self) -> Forwarder:
        loop = asyncio.get_running_loop()
        try:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: self, remote_addr=self.address)
        except OSError as exc:
            host, port = self.address
            raise LinkError(f"--forward: cannot send to UDP {host}:{port}: "
                            f"{exc.strerror or exc}") from exc
        self._transport = transport
        self.router.subscribe(Received, self._on_vehicle_message)
        return self

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    # -- to the watcher ---------------------------------------------------------------------------
    def _on_vehicle_message(self, received: Received) -> None:
        if self._transport is None:
            return
        self._transport.sendto(bytes(received.msg.get_msgbuf()))
        self.stats["forwarded"] += 1

    def error_received(self, exc: Exception) -> None:
        self.stats["send_errors"] += 1

    # -- from the watcher -------------------------------------------------------------------------
    def datagram_received(self, data: bytes, addr: Any) -> None:
        for msg in self.parser.feed(data):
            self.stats["from_watcher"] += 1
            if not self.allow_commands:
                self.stats["dropped"] += 1
                continue
            target = getattr(msg, "target_system", 0) or 0
            targets = [target] if target else list(self.router.vehicles)
            known = [t for t in targets if t in self.router.vehicles]
            if not known:
                self.stats["dropped"] += 1
                continue
            raw = bytes(msg.get_msgbuf())
            for sysid in known:
                try:
                    self.router.send_raw(sysid, raw)
                except LinkError as exc:  # the station's endpoint is closing
                    self.stats["dropped"] += 1
                    log.warning("--forward-commands: %s", exc)
                    return
            self.stats["relayed"] += 1
