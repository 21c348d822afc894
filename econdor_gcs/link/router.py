"""The station's MAVLink shell: its links, one parser, and subscriptions (DESIGN.md §4).

The :class:`Router` is the only asyncio part of the link layer, and stays thin: it opens the
``--connect`` links (:mod:`.transports`: UDP, TCP, serial; several at once), decodes what
arrives (:mod:`.codec`), and hands each message with its source and the time to the pure
parts: the :class:`~.vehicles.VehicleTable` (who is who, routes, twins, strangers, liveness),
the :class:`~.pairing.SamplePairer` (samples placed on the position track) and the protocol
machines of :mod:`.mission`, driven by :meth:`Router.run_protocol`. The command vocabulary
(arm, modes, missions, ...) is :class:`~.commands.CommandVocabulary`.

One subscription style: :meth:`Router.subscribe` ``(kinds, handler)`` calls ``handler`` on the
station's loop thread with every object of those types: the table's events
(:class:`VehicleDiscovered`, :class:`VehicleLost`, :class:`TwinRefused`, ...), each placed
:class:`Sample`, and every accepted message as :class:`Received`. :meth:`Router.queue` is
the same subscription delivering into an :class:`asyncio.Queue`.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from econdor_gcs.link.signing import SigningKey

from ..errors import LinkError, VehicleTimeout
from .codec import GCS_COMPONENT_ID, GCS_SYSTEM_ID, Codec, MAVLinkMessage, Parser, mavlink
from .commands import CommandVocabulary, Machine
from .pairing import Sample, SamplePairer
from .tlog import TlogWriter
from .transports import Address, Endpoint, Transport, open_transport, parse_endpoint
from .vehicles import (
    AIRBORNE_ALT_M,
    AUTOPILOT_COMPONENT,
    ComponentDiscovered,
    Event,
    ForeignVehicle,
    MissionItemReached,
    Source,
    StatusText,
    TwinRefused,
    VehicleDiscovered,
    VehicleLink,
    VehicleLost,
    VehicleMoved,
    VehicleRecovered,
    VehicleTable,
)

__all__ = [
    "AIRBORNE_ALT_M",
    "DEFAULT_ENDPOINT",
    "ComponentDiscovered",
    "ForeignVehicle",
    "MissionItemReached",
    "Received",
    "Router",
    "Sample",
    "SamplePairer",
    "StatusText",
    "Subscription",
    "TwinRefused",
    "VehicleDiscovered",
    "VehicleLink",
    "VehicleLost",
    "VehicleMoved",
    "VehicleRecovered",
    "parse_endpoint",
]

DEFAULT_ENDPOINT = "udpin:127.0.0.1:14550"
log = logging.getLogger(__name__)
T = TypeVar("T")


@dataclass(frozen=True)
class Received:
    """A message from vehicle ``sysid`` that the vehicle table accepted."""

    sysid: int
    msg: MAVLinkMessage


class Subscription:
    """One handler for some types of object; :meth:`close` ends it."""

    def __init__(self, router: Router, kinds: tuple[type, ...], handler: Callable[[Any], None],
                 sysid: int | None) -> None:
        self.router, self.kinds, self.handler, self.sysid = router, kinds, handler, sysid

    def close(self) -> None:
        with contextlib.suppress(ValueError):
            self.router._subs.remove(self)


class Router(CommandVocabulary):
    """The GCS endpoint: one or more links, many vehicles.

    Parameters
    ----------
    endpoint:
        A ``--connect`` value (:func:`~.transports.parse_endpoint`), or several: each is one
        link, and a vehicle is routed to the link and address its autopilot speaks from.
        ``udpin`` with port 0 picks a free port, see :attr:`local_address`.
    tlog:
        Every message in and out is written here when given.
    heartbeat_timeout_s:
        A vehicle silent for longer is lost (:class:`VehicleLost`); a second source of its
        autopilot is refused until then.
    gcs_heartbeat_s:
        Period of our own HEARTBEAT (MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID) to every known vehicle
        and to every link's fixed peer (``udpout``, ``tcp``, serial).
    signing:
        MAVLink 2 signing: everything we send is signed with this key, and whatever
        arrives unsigned or wrongly signed is dropped and counted
        (``parser.unsigned_packets``, ``parser.bad_signature_packets``).
    """

    def __init__(self, endpoint: str | Sequence[str] = DEFAULT_ENDPOINT, *,
                 tlog: TlogWriter | None = None, heartbeat_timeout_s: float = 5.0,
                 gcs_heartbeat_s: float = 1.0, system_id: int = GCS_SYSTEM_ID,
                 component_id: int = GCS_COMPONENT_ID, signing: SigningKey | None = None
                 ) -> None:
        texts = [endpoint] if isinstance(endpoint, str) else list(endpoint)
        if not texts:
            raise LinkError("no endpoint to serve")
        self.endpoints: list[Endpoint] = [parse_endpoint(t) for t in texts]
        self.links: list[Transport] = [open_transport(ep) for ep in self.endpoints]
        self.tlog = tlog
        self.gcs_heartbeat_s = gcs_heartbeat_s
        self.codec = Codec(system_id, component_id, signing)
        self.parser = Parser(signing)
        self.table = VehicleTable(heartbeat_timeout_s)
        self.pairer = SamplePairer()
        self.vehicles: dict[int, VehicleLink] = self.table.vehicles
        self.stats: dict[str, int] = {
            "datagrams_in": 0, "messages_in": 0, "messages_out": 0, "foreign": 0,
            "not_vehicle": 0, "handler_errors": 0,
        }
        self._subs: list[Subscription] = []
        self._mission_locks: dict[int, asyncio.Lock] = {}
        self._housekeeping: asyncio.Task[None] | None = None
        self._open: list[Transport] = []
        self._changed = asyncio.Event()

    @property
    def heartbeat_timeout_s(self) -> float:
        return self.table.heartbeat_timeout_s

    # -- lifecycle ------------------------------------------------------------------------------
    async def start(self) -> Router:
        if self._housekeeping is not None:
            return self
        try:
            for i, transport in enumerate(self.links):
                await transport.open(functools.partial(self._on_bytes, i),
                                     functools.partial(self._on_gone, i))
                self._open.append(transport)
        except LinkError:
            self._close_links()
            raise
        self._housekeeping = asyncio.create_task(self._housekeeping_loop())
        return self

    async def close(self) -> None:
        task, self._housekeeping = self._housekeeping, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._close_links()
        if self.tlog is not None:
            self.tlog.flush()

    def _close_links(self) -> None:
        for transport in self._open:
            transport.close()
        self._open.clear()

    async def __aenter__(self) -> Router:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    @property
    def local_address(self) -> Address:
        """The first link's local ``(host, port)`` (after :meth:`start`)."""
        if not self._open:
            raise LinkError("the GCS endpoint is not started")
        return self.links[0].local_address

    @property
    def bad_packets(self) -> int:
        """Garbage / corrupt / truncated packets dropped so far."""
        return self.parser.bad_packets

    # -- subscriptions --------------------------------------------------------------------------
    def subscribe(self, kinds: type | tuple[type, ...], handler: Callable[[Any], None], *,
                  sysid: int | None = None) -> Subscription:
        """Call ``handler(obj)`` for every event, :class:`Sample` or :class:`Received` of
        ``kinds`` from now on (of vehicle ``sysid`` only, if given). A failing handler is
        logged and counted (``stats["handler_errors"]``), never stops the others."""
        sub = Subscription(self, kinds if isinstance(kinds, tuple) else (kinds,), handler,
                           sysid)
        self._subs.append(sub)
        return sub

    def queue(self, kinds: type | tuple[type, ...], *, sysid: int | None = None
              ) -> asyncio.Queue[Any]:
        """A queue receiving every object of ``kinds`` from now on (:meth:`subscribe`)."""
        q: asyncio.Queue[Any] = asyncio.Queue()
        self.subscribe(kinds, q.put_nowait, sysid=sysid)
        return q

    def _emit(self, obj: Event | Sample | Received) -> None:
        sysid = obj.sysid
        for sub in list(self._subs):
            if isinstance(obj, sub.kinds) and (sub.sysid is None or sub.sysid == sysid):
                try:
                    sub.handler(obj)
                except Exception:
                    self.stats["handler_errors"] += 1
                    log.exception("GCS endpoint: a %s handler failed", type(obj).__name__)
        self._changed.set()

    # -- the fleet ------------------------------------------------------------------------------
    def expect(self, sysids: Iterable[int]) -> None:
        """The run's fleet: any other system is a stranger from now on (reported, dropped)."""
        for event in self.table.expect(sysids):
            self._emit(event)

    # -- sending --------------------------------------------------------------------------------
    def _route(self, sysid: int) -> tuple[Transport, Address]:
        link = self.vehicles.get(sysid)
        if link is None:
            raise LinkError(f"vehicle {sysid} has never been heard from")
        if not self._open:
            raise LinkError("the GCS endpoint is not started")
        return self.links[link.link], link.address

    def send(self, sysid: int, msg: MAVLinkMessage) -> None:
        """Send ``msg`` to vehicle ``sysid``'s route (where its autopilot speaks from)."""
        transport, address = self._route(sysid)
        self._send_to(transport, address, self.codec.encode(msg))

    def send_raw(self, sysid: int, data: bytes) -> None:
        """Send already encoded MAVLink bytes (another sender's message) to ``sysid``."""
        transport, address = self._route(sysid)
        self._send_to(transport, address, data)

    def _send_to(self, transport: Transport, address: Address, data: bytes) -> None:
        transport.send(data, address)
        self.stats["messages_out"] += 1
        if self.tlog is not None:
            self.tlog.write(data)

    def send_heartbeat(self) -> None:
        """Our HEARTBEAT to every known vehicle, and to each link's fixed peer (a vehicle
        behind ``udpout`` hears of us only this way)."""
        if not self._open:
            return
        data = self.codec.encode(mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE,
            3))
        targets = {(link.link, link.address) for link in self.vehicles.values()}
        for i, transport in enumerate(self.links):
            targets.update((i, peer) for peer in transport.peers)
        for i, address in sorted(targets):
            self._send_to(self.links[i], address, data)

    # -- receiving ------------------------------------------------------------------------------
    def _on_bytes(self, link: int, data: bytes, peer: Address) -> None:
        self.stats["datagrams_in"] += 1
        stream = (link, peer) if self.links[link].stream else None
        source = Source(link, peer)
        for msg in self.parser.feed(data, stream):
            self._on_message(msg, source)

    def _on_gone(self, link: int, peer: Address) -> None:
        self.parser.forget((link, peer))
        self.table.source_gone(Source(link, peer))

    def _on_message(self, msg: MAVLinkMessage, source: Source) -> None:
        sysid = msg.get_srcSystem()
        if sysid == self.codec.system_id or sysid == 0:
            self.stats["foreign"] += 1  # our own echo, another GCS with our id, or nonsense
            return
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.codec.system_id):
            self.stats["foreign"] += 1  # addressed to someone else
            return
        now = time.monotonic()
        link, events = self.table.receive(msg, source, now)
        for event in events:
            self._emit(event)
        if link is None:
            self.stats["not_vehicle"] += 1  # before its heartbeat, a twin's, a stranger's
            return
        self.stats["messages_in"] += 1
        if self.tlog is not None:
            self.tlog.write(msg)
        kind = msg.get_type()
        if kind in ("GLOBAL_POSITION_INT", "NAMED_VALUE_FLOAT"):
            autopilot = msg.get_srcComponent() == AUTOPILOT_COMPONENT
            for sample in self.pairer.add(sysid, msg, now, position_source=autopilot):
                self._emit(sample)
        self._emit(Received(sysid, msg))

    async def _housekeeping_loop(self) -> None:
        tick = max(0.02, min(self.gcs_heartbeat_s, self.heartbeat_timeout_s / 4))
        next_heartbeat = time.monotonic()
        while True:
            now = time.monotonic()
            if now >= next_heartbeat:
                self.send_heartbeat()
                next_heartbeat = now + self.gcs_heartbeat_s
            self.check_liveness(now)
            self.pairer.expire(now)
            await asyncio.sleep(tick)

    def check_liveness(self, now: float | None = None) -> list[int]:
        """Mark vehicles silent for > ``heartbeat_timeout_s`` lost; return the newly lost."""
        events = self.table.check(time.monotonic() if now is None else now)
        for event in events:
            self._emit(event)
        return [e.sysid for e in events]

    # -- driving protocols ----------------------------------------------------------------------
    async def run_protocol(self, sysid: int, machine: Machine,
                           timeout_s: float | None = None) -> Any:
        """Drive ``machine`` against vehicle ``sysid`` until it is done; return its result.

        The machine sees only what its target component sends. Raises the machine's error, or
        :class:`VehicleTimeout` if ``timeout_s`` (overall) runs out first.
        """
        if sysid not in self.vehicles:
            raise LinkError(f"vehicle {sysid} has never been heard from")
        queue: asyncio.Queue[Received] = asyncio.Queue()
        compid = machine.target_component

        def mine(r: Received) -> None:
            if compid == 0 or r.msg.get_srcComponent() == compid:
                queue.put_nowait(r)

        sub = self.subscribe(Received, mine, sysid=sysid)
        try:
            async with asyncio.timeout(timeout_s):
                while True:
                    now = time.monotonic()
                    for msg in machine.poll(now):
                        self.send(sysid, msg)
                    if machine.done:
                        break
                    deadline = machine.next_deadline()
                    wait = None if deadline is None else max(0.0, deadline - time.monotonic())
                    try:
                        got = await asyncio.wait_for(queue.get(), wait)
                    except TimeoutError:
                        continue
                    machine.receive(got.msg, time.monotonic())
                    while not queue.empty() and not machine.done:
                        machine.receive(queue.get_nowait().msg, time.monotonic())
        except TimeoutError:
            raise VehicleTimeout(
                f"vehicle {sysid}: {getattr(machine, 'what', 'protocol')} did not finish "
                f"within {timeout_s:g} s") from None
        finally:
            sub.close()
        if machine.error is not None:
            raise machine.error
        return machine.result

    async def wait_for_vehicles(self, vehicles: int | Iterable[int],
                                timeout_s: float = 10.0) -> list[int]:
        """Wait until ``vehicles`` (a count, or the system ids) have heartbeated.

        Returns the sorted system ids seen (for a count: the first ``n`` once ``n`` are seen).
        Raises :class:`VehicleTimeout` naming the missing ones.
        """
        count = vehicles if isinstance(vehicles, int) else None
        wanted = None if isinstance(vehicles, int) else sorted(set(vehicles))

        def ready() -> bool:
            if count is not None:
                return len(self.vehicles) >= count
            return all(s in self.vehicles for s in wanted or ())

        try:
            async with asyncio.timeout(timeout_s):
                while not ready():
                    self._changed.clear()
                    await self._changed.wait()
        except TimeoutError:
            if count is not None:
                raise VehicleTimeout(
                    f"only {len(self.vehicles)} of {count} vehicles appeared within "
                    f"{timeout_s:g} s") from None
            missing = [s for s in wanted or () if s not in self.vehicles]
            plural = "s" if len(missing) > 1 else ""
            raise VehicleTimeout(
                f"vehicle{plural} {', '.join(map(str, missing))} never appeared within "
                f"{timeout_s:g} s") from None
        if count is not None:
            return sorted(self.vehicles)[:count]
        return wanted or []
