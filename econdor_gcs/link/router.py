"""One GCS UDP endpoint serving many vehicles, routed by system id (DESIGN.md §4).

pymavlink's ``udpin`` connection remembers a single peer, so the ground station does its own
routing: :class:`Router` binds one UDP socket, remembers the address each system id was last
heard from, and sends a vehicle's messages there.  It is the only asyncio part of the link
layer; the protocols themselves are the pure state machines of :mod:`.mission`, driven by
:meth:`Router.run_protocol`.

Events (dataclasses, delivered to :meth:`Router.add_event_handler` callbacks and to queues
from :meth:`Router.event_queue`): :class:`VehicleDiscovered`, :class:`VehicleLost`,
:class:`VehicleRecovered`, :class:`MissionItemReached`, :class:`StatusText`.  Paired samples
(:class:`Sample`) go to :meth:`Router.sample_queue` queues and :meth:`Router.add_sample_handler`
callbacks; every message to :meth:`Router.add_message_handler` callbacks.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

from ..errors import LinkError, VehicleTimeout
from ..signing import SigningKey
from .codec import GCS_COMPONENT_ID, GCS_SYSTEM_ID, Codec, MAVLinkMessage, Parser, mavlink
from .mission import (
    DEFAULT_RETRIES,
    DEFAULT_TIMEOUT_S,
    CommandSender,
    MissionClear,
    MissionDownloader,
    MissionItemSpec,
    MissionUploader,
)
from .tlog import TlogWriter

__all__ = [
    "DEFAULT_ENDPOINT",
    "MissionItemReached",
    "Router",
    "Sample",
    "SamplePairer",
    "StatusText",
    "VehicleDiscovered",
    "VehicleLink",
    "VehicleLost",
    "VehicleRecovered",
    "parse_endpoint",
]

DEFAULT_ENDPOINT = "udpin:127.0.0.1:14550"
RCVBUF_BYTES = 4 << 20
"""Requested UDP receive buffer (the kernel caps it at net.core.rmem_max)."""
log = logging.getLogger(__name__)
SAMPLE_NAME = "FIELD"
HDG_UNKNOWN = 0xFFFF
"""``GLOBAL_POSITION_INT.hdg`` when the heading is unknown (UINT16_MAX, MAVLink common)."""
AIRBORNE_ALT_M = 0.5
"""Above home by more than this, a vehicle counts as flying (for ``VehicleLink.airborne_s``)."""
REBOOT_MS = 10_000
"""A ``time_boot_ms`` this far behind the last one means the vehicle restarted."""
Address = tuple[str, int]


def parse_endpoint(endpoint: str) -> Address:
    """``"udpin:HOST:PORT"`` (or ``"udp:HOST:PORT"``, same meaning) -> ``(HOST, PORT)``."""
    scheme, sep, rest = endpoint.partition(":")
    host, sep2, port_text = rest.rpartition(":")
    if not sep or not sep2 or scheme not in ("udpin", "udp") or not host:
        raise LinkError(
            f"cannot serve {endpoint!r}: expected udpin:HOST:PORT, e.g. {DEFAULT_ENDPOINT}")
    try:
        port = int(port_text)
    except ValueError:
        raise LinkError(f"bad port {port_text!r} in endpoint {endpoint!r}") from None
    if not 0 <= port <= 65535:
        raise LinkError(f"port {port} out of range in endpoint {endpoint!r}")
    return host.strip("[]"), port


# --------------------------------------------------------------------------------------------
# events and per-vehicle state


@dataclass(frozen=True)
class VehicleDiscovered:
    """The first HEARTBEAT from a system id."""

    sysid: int
    address: Address


@dataclass(frozen=True)
class VehicleLost:
    """No HEARTBEAT from ``sysid`` for longer than the router's ``heartbeat_timeout_s``."""

    sysid: int
    silent_s: float


@dataclass(frozen=True)
class VehicleRecovered:
    """A lost vehicle's heartbeat is back."""

    sysid: int
    address: Address


@dataclass(frozen=True)
class MissionItemReached:
    sysid: int
    seq: int


@dataclass(frozen=True)
class StatusText:
    sysid: int
    severity: int
    text: str


@dataclass(frozen=True)
class Sample:
    """One field measurement: ``NAMED_VALUE_FLOAT("FIELD")`` + ``GLOBAL_POSITION_INT`` with the
    same ``time_boot_ms`` from the same vehicle.  ``rel_alt_m`` is above home."""

    sysid: int
    time_boot_ms: int
    lat_deg: float
    lon_deg: float
    rel_alt_m: float
    value: float


Event = VehicleDiscovered | VehicleLost | VehicleRecovered | MissionItemReached | StatusText


@dataclass
class VehicleLink:
    """What the ground station knows about one vehicle (updated from its messages)."""

    sysid: int
    address: Address
    compid: int = 1
    first_seen: float = 0.0          # wall time (Unix s)
    last_heartbeat: float = 0.0      # wall time (Unix s)
    last_heartbeat_mono: float = 0.0  # time.monotonic() of the same heartbeat
    lost: bool = False
    # last HEARTBEAT
    mav_type: int = 0
    autopilot: int = 0
    base_mode: int = 0
    custom_mode: int = 0
    system_status: int = 0
    # last GLOBAL_POSITION_INT
    time_boot_ms: int | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None       # AMSL
    rel_alt_m: float | None = None   # above home
    heading_deg: float | None = None  # last known (GLOBAL_POSITION_INT.hdg; kept while unknown)
    airborne_s: float = 0.0
    """Vehicle (sim) time spent above ``AIRBORNE_ALT_M``: the sum of the ``time_boot_ms``
    steps between consecutive positions that were both airborne (late, out-of-order
    positions are left out)."""
    last_fix_ms: int | None = None
    last_fix_airborne: bool = False
    # last SYS_STATUS
    sensors_present: int | None = None
    sensors_health: int = 0
    # mission progress
    mission_current: int | None = None
    mission_reached: int | None = None
    statustexts: list[tuple[float, int, str]] = field(default_factory=list)
    messages: int = 0

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def prearm_ok(self) -> bool | None:
        """The pre-arm checks pass (SYS_STATUS health bit); None if the vehicle does not say."""
        bit = mavlink.MAV_SYS_STATUS_PREARM_CHECK
        if self.sensors_present is None or not self.sensors_present & bit:
            return None
        return bool(self.sensors_health & bit)


class SamplePairer:
    """Pair ``NAMED_VALUE_FLOAT("FIELD")`` with ``GLOBAL_POSITION_INT`` by (sysid, time_boot_ms).

    Whichever half arrives first waits; :meth:`add` returns the :class:`Sample` when the second
    arrives.  Halves still unpaired ``horizon_s`` after they arrived are dropped (counted in
    ``dropped``); at most ``max_pending`` halves per kind are kept.
    """

    def __init__(self, horizon_s: float = 5.0, name: str = SAMPLE_NAME,
                 max_pending: int = 100_000) -> None:
        self.horizon_s = horizon_s
        self.name = name
        self.max_pending = max_pending
        self.dropped = 0
        self.paired = 0
        # key -> (arrival time, payload)
        self._positions: dict[tuple[int, int], tuple[float, tuple[float, float, float]]] = {}
        self._values: dict[tuple[int, int], tuple[float, float]] = {}

    def add(self, sysid: int, msg: MAVLinkMessage, now: float) -> Sample | None:
        """Offer one message from ``sysid`` (others are ignored); return a completed sample."""
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            key = (sysid, msg.time_boot_ms)
            pos = (msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1000.0)
            waiting = self._values.pop(key, None)
            if waiting is None:
                self._positions[key] = (now, pos)
                self._limit(self._positions)
                self.expire(now)
                return None
            value = waiting[1]
        elif kind == "NAMED_VALUE_FLOAT" and _text(msg.name) == self.name:
            key = (sysid, msg.time_boot_ms)
            value = float(msg.value)
            waiting_pos = self._positions.pop(key, None)
            if waiting_pos is None:
                self._values[key] = (now, value)
                self._limit(self._values)
                self.expire(now)
                return None
            pos = waiting_pos[1]
        else:
            return None
        self.paired += 1
        return Sample(sysid, key[1], pos[0], pos[1], pos[2], value)

    @property
    def pending(self) -> int:
        return len(self._positions) + len(self._values)

    def expire(self, now: float) -> int:
        """Drop halves that waited longer than the horizon; return how many."""
        limit = now - self.horizon_s
        n = 0
        for table in (self._positions, self._values):
            # dicts keep insertion order, which is arrival order
            while table:
                key = next(iter(table))
                if table[key][0] >= limit:
                    break
                del table[key]
                n += 1
        self.dropped += n
        return n

    def _limit(self, table: dict[Any, Any]) -> None:
        while len(table) > self.max_pending:
            del table[next(iter(table))]
            self.dropped += 1


def _text(value: object) -> str:
    if isinstance(value, bytes | bytearray):
        value = value.decode("utf-8", "replace")
    return str(value).rstrip("\x00")


# --------------------------------------------------------------------------------------------
# the asyncio shell


class Machine(Protocol):
    done: bool
    result: object
    error: Exception | None

    def receive(self, msg: MAVLinkMessage, now: float) -> None: ...
    def poll(self, now: float) -> list[MAVLinkMessage]: ...
    def next_deadline(self) -> float | None: ...


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, router: Router) -> None:
        self._router = router

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self._router._on_datagram(data, (addr[0], addr[1]))

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable from a vehicle that went away: count, keep serving.
        self._router.stats["socket_errors"] += 1


MessageHandler = Callable[[int, MAVLinkMessage], None]


class Router:
    """The GCS endpoint: one UDP socket, many vehicles.

    Parameters
    ----------
    endpoint:
        ``"udpin:HOST:PORT"`` (``"udp:"`` accepted as a synonym); port 0 picks a free port, see
        :attr:`local_address` after :meth:`start`.
    tlog:
        Every message in and out is written here when given.
    heartbeat_timeout_s:
        A vehicle silent for longer is marked lost (:class:`VehicleLost`).
    gcs_heartbeat_s:
        Period of our own HEARTBEAT (MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID) to every known vehicle.
    sample_horizon_s:
        How long an unpaired sample half waits (:class:`SamplePairer`).
    signing:
        MAVLink 2 signing: everything we send is signed with this key, and whatever
        arrives unsigned or wrongly signed is dropped and counted
        (``parser.unsigned_packets``, ``parser.bad_signature_packets``).
    """

    def __init__(self, endpoint: str = DEFAULT_ENDPOINT, *, tlog: TlogWriter | None = None,
                 heartbeat_timeout_s: float = 5.0, gcs_heartbeat_s: float = 1.0,
                 sample_horizon_s: float = 5.0, system_id: int = GCS_SYSTEM_ID,
                 component_id: int = GCS_COMPONENT_ID, signing: SigningKey | None = None
                 ) -> None:
        self.endpoint = endpoint
        self.bind_address = parse_endpoint(endpoint)
        self.tlog = tlog
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.gcs_heartbeat_s = gcs_heartbeat_s
        self.codec = Codec(system_id, component_id, signing)
        self.parser = Parser(signing)
        self.pairer = SamplePairer(sample_horizon_s)
        self.vehicles: dict[int, VehicleLink] = {}
        self.stats: dict[str, int] = {
            "datagrams_in": 0, "messages_in": 0, "messages_out": 0, "foreign": 0,
            "socket_errors": 0, "handler_errors": 0,
        }
        self._transport: asyncio.DatagramTransport | None = None
        self._housekeeping: asyncio.Task[None] | None = None
        self._message_handlers: list[MessageHandler] = []
        self._event_handlers: list[Callable[[Event], None]] = []
        self._sample_handlers: list[Callable[[Sample], None]] = []
        self._event_queues: list[asyncio.Queue[Event]] = []
        self._sample_queues: list[asyncio.Queue[Sample]] = []
        self._protocol_queues: dict[int, list[asyncio.Queue[MAVLinkMessage]]] = {}
        self._mission_locks: dict[int, asyncio.Lock] = {}
        self._changed = asyncio.Event()

    # -- lifecycle ------------------------------------------------------------------------------
    async def start(self) -> Router:
        if self._transport is not None:
            return self
        loop = asyncio.get_running_loop()
        try:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Datagrams(self), local_addr=self.bind_address)
        except OSError as exc:
            host, port = self.bind_address
            raise LinkError(f"cannot listen on UDP {host}:{port}: {exc.strerror or exc}") from exc
        self._transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None:  # bursts of samples from many vehicles: a roomy receive buffer
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
        self._housekeeping = asyncio.create_task(self._housekeeping_loop())
        return self

    async def close(self) -> None:
        task, self._housekeeping = self._housekeeping, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        if self.tlog is not None:
            self.tlog.flush()

    async def __aenter__(self) -> Router:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    @property
    def local_address(self) -> Address:
        """The bound ``(host, port)`` (after :meth:`start`)."""
        if self._transport is None:
            raise LinkError("the GCS endpoint is not started")
        sock = self._transport.get_extra_info("sockname")
        return sock[0], sock[1]

    @property
    def bad_packets(self) -> int:
        """Garbage / corrupt / truncated packets dropped so far."""
        return self.parser.bad_packets

    # -- subscriptions --------------------------------------------------------------------------
    def add_message_handler(self, handler: MessageHandler) -> None:
        """``handler(sysid, msg)`` for every message from a vehicle."""
        self._message_handlers.append(handler)

    def add_event_handler(self, handler: Callable[[Event], None]) -> None:
        self._event_handlers.append(handler)

    def add_sample_handler(self, handler: Callable[[Sample], None]) -> None:
        self._sample_handlers.append(handler)

    def event_queue(self) -> asyncio.Queue[Event]:
        """A new queue receiving every event from now on."""
        q: asyncio.Queue[Event] = asyncio.Queue()
        self._event_queues.append(q)
        return q

    def sample_queue(self) -> asyncio.Queue[Sample]:
        """A new queue receiving every paired :class:`Sample` from now on."""
        q: asyncio.Queue[Sample] = asyncio.Queue()
        self._sample_queues.append(q)
        return q

    # -- sending --------------------------------------------------------------------------------
    def send(self, sysid: int, msg: MAVLinkMessage) -> None:
        """Send ``msg`` to the address ``sysid`` was last heard from."""
        link = self.vehicles.get(sysid)
        if link is None:
            raise LinkError(f"vehicle {sysid} has never been heard from")
        self._send_to(link.address, msg)

    def send_raw(self, sysid: int, data: bytes) -> None:
        """Send already encoded MAVLink bytes (another sender's message) to ``sysid``."""
        link = self.vehicles.get(sysid)
        if link is None:
            raise LinkError(f"vehicle {sysid} has never been heard from")
        if self._transport is None:
            raise LinkError("the GCS endpoint is not started")
        self._transport.sendto(data, link.address)
        self.stats["messages_out"] += 1
        if self.tlog is not None:
            self.tlog.write(data)

    def _send_to(self, address: Address, msg: MAVLinkMessage) -> None:
        if self._transport is None:
            raise LinkError("the GCS endpoint is not started")
        data = self.codec.encode(msg)
        self._transport.sendto(data, address)
        self.stats["messages_out"] += 1
        if self.tlog is not None:
            self.tlog.write(data)

    def send_heartbeat(self) -> None:
        """Our HEARTBEAT to every known vehicle."""
        for link in list(self.vehicles.values()):
            msg = mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                mavlink.MAV_STATE_ACTIVE, 3)
            self._send_to(link.address, msg)

    # -- receiving ------------------------------------------------------------------------------
    def _on_datagram(self, data: bytes, addr: Address) -> None:
        self.stats["datagrams_in"] += 1
        for msg in self.parser.feed(data):
            self._on_message(msg, addr)

    def _on_message(self, msg: MAVLinkMessage, addr: Address) -> None:
        sysid = msg.get_srcSystem()
        if sysid == self.codec.system_id or sysid == 0:
            self.stats["foreign"] += 1  # our own echo, another GCS with our id, or nonsense
            return
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.codec.system_id):
            self.stats["foreign"] += 1  # addressed to someone else
            return
        self.stats["messages_in"] += 1
        if self.tlog is not None:
            self.tlog.write(msg)
        now_mono, now_wall = time.monotonic(), time.time()
        kind = msg.get_type()
        link = self.vehicles.get(sysid)
        if kind == "HEARTBEAT" and msg.type != mavlink.MAV_TYPE_GCS:
            if link is None:
                link = VehicleLink(sysid, addr, compid=msg.get_srcComponent(),
                                   first_seen=now_wall)
                self.vehicles[sysid] = link
                self._emit(VehicleDiscovered(sysid, addr))
                self._changed.set()
            elif link.lost:
                link.lost = False
                self._emit(VehicleRecovered(sysid, addr))
            link.compid = msg.get_srcComponent()
            link.last_heartbeat, link.last_heartbeat_mono = now_wall, now_mono
            link.mav_type, link.autopilot = msg.type, msg.autopilot
            link.base_mode, link.custom_mode = msg.base_mode, msg.custom_mode
            link.system_status = msg.system_status
        if link is None:
            return  # not a vehicle until it heartbeats
        link.address = addr
        link.messages += 1
        if kind == "GLOBAL_POSITION_INT":
            rel_alt_m = msg.relative_alt / 1000.0
            t_ms, last_ms = msg.time_boot_ms, link.last_fix_ms
            if last_ms is None or t_ms > last_ms or t_ms < last_ms - REBOOT_MS:
                airborne = rel_alt_m > AIRBORNE_ALT_M
                if last_ms is not None and t_ms > last_ms and airborne and link.last_fix_airborne:
                    link.airborne_s += (t_ms - last_ms) / 1000.0
                link.last_fix_ms, link.last_fix_airborne = t_ms, airborne
            link.time_boot_ms = msg.time_boot_ms
            link.lat_deg, link.lon_deg = msg.lat / 1e7, msg.lon / 1e7
            link.alt_m, link.rel_alt_m = msg.alt / 1000.0, rel_alt_m
            if msg.hdg != HDG_UNKNOWN:
                link.heading_deg = msg.hdg / 100.0
        elif kind == "SYS_STATUS":
            link.sensors_present = msg.onboard_control_sensors_present
            link.sensors_health = msg.onboard_control_sensors_health
        elif kind == "MISSION_CURRENT":
            link.mission_current = msg.seq
        elif kind == "MISSION_ITEM_REACHED":
            link.mission_reached = msg.seq
            self._emit(MissionItemReached(sysid, msg.seq))
        elif kind == "STATUSTEXT":
            text = _text(msg.text)
            link.statustexts.append((now_wall, msg.severity, text))
            del link.statustexts[:-200]
            self._emit(StatusText(sysid, msg.severity, text))
        if kind in ("GLOBAL_POSITION_INT", "NAMED_VALUE_FLOAT"):
            sample = self.pairer.add(sysid, msg, now_mono)
            if sample is not None:
                for on_sample in self._sample_handlers:
                    self._call(on_sample, sample)
                for q in self._sample_queues:
                    q.put_nowait(sample)
        for handler in self._message_handlers:
            self._call(handler, sysid, msg)
        for q in self._protocol_queues.get(sysid, ()):
            q.put_nowait(msg)

    def _call(self, handler: Callable[..., None], *args: Any) -> None:
        """Run a user callback; a failing one is logged and counted, never kills the endpoint."""
        try:
            handler(*args)
        except Exception:
            self.stats["handler_errors"] += 1
            log.exception("GCS endpoint: a %s handler failed", type(args[-1]).__name__)

    def _emit(self, event: Event) -> None:
        for handler in self._event_handlers:
            self._call(handler, event)
        for q in self._event_queues:
            q.put_nowait(event)

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
        now = time.monotonic() if now is None else now
        newly: list[int] = []
        for link in self.vehicles.values():
            silent = now - link.last_heartbeat_mono
            if not link.lost and silent > self.heartbeat_timeout_s:
                link.lost = True
                newly.append(link.sysid)
                self._emit(VehicleLost(link.sysid, silent))
        return newly

    # -- driving protocols ----------------------------------------------------------------------
    async def run_protocol(self, sysid: int, machine: Machine,
                           timeout_s: float | None = None) -> Any:
        """Drive ``machine`` against vehicle ``sysid`` until it is done; return its result.

        Raises the machine's error, or :class:`VehicleTimeout` if ``timeout_s`` (overall) runs
        out first.
        """
        if sysid not in self.vehicles:
            raise LinkError(f"vehicle {sysid} has never been heard from")
        queue: asyncio.Queue[MAVLinkMessage] = asyncio.Queue()
        self._protocol_queues.setdefault(sysid, []).append(queue)
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
                        msg = await asyncio.wait_for(queue.get(), wait)
                    except TimeoutError:
                        continue
                    machine.receive(msg, time.monotonic())
                    while not queue.empty() and not machine.done:
                        machine.receive(queue.get_nowait(), time.monotonic())
        except TimeoutError:
            raise VehicleTimeout(
                f"vehicle {sysid}: {getattr(machine, 'what', 'protocol')} did not finish "
                f"within {timeout_s:g} s") from None
        finally:
            self._protocol_queues[sysid].remove(queue)
        if machine.error is not None:
            raise machine.error
        return machine.result

    def _lock(self, sysid: int) -> asyncio.Lock:
        return self._mission_locks.setdefault(sysid, asyncio.Lock())

    def _compid(self, sysid: int) -> int:
        link = self.vehicles.get(sysid)
        return link.compid if link is not None else 1

    async def upload_mission(self, sysid: int, items: list[MissionItemSpec], *,
                             mission_type: int = 0, timeout_s: float = DEFAULT_TIMEOUT_S,
                             retries: int = DEFAULT_RETRIES, legacy_items: bool = False) -> int:
        """Upload a mission; return the number of items.  One mission transfer per vehicle at a
        time (later calls wait)."""
        async with self._lock(sysid):
            machine = MissionUploader(sysid, self._compid(sysid), items, mission_type,
                                      timeout_s=timeout_s, retries=retries,
                                      legacy_items=legacy_items)
            return int(await self.run_protocol(sysid, machine))

    async def download_mission(self, sysid: int, *, mission_type: int = 0,
                               timeout_s: float = DEFAULT_TIMEOUT_S,
                               retries: int = DEFAULT_RETRIES) -> list[MissionItemSpec]:
        async with self._lock(sysid):
            machine = MissionDownloader(sysid, self._compid(sysid), mission_type,
                                        timeout_s=timeout_s, retries=retries)
            return list(await self.run_protocol(sysid, machine))

    async def clear_mission(self, sysid: int, *, mission_type: int = 0,
                            timeout_s: float = DEFAULT_TIMEOUT_S,
                            retries: int = DEFAULT_RETRIES) -> None:
        async with self._lock(sysid):
            machine = MissionClear(sysid, self._compid(sysid), mission_type,
                                   timeout_s=timeout_s, retries=retries)
            await self.run_protocol(sysid, machine)

    async def command(self, sysid: int, cmd: int, *params: float,
                      timeout_s: float = DEFAULT_TIMEOUT_S,
                      retries: int = DEFAULT_RETRIES) -> MAVLinkMessage:
        """COMMAND_LONG with up to 7 params; return the accepting COMMAND_ACK."""
        machine = CommandSender(sysid, self._compid(sysid), cmd, params, timeout_s=timeout_s,
                                retries=retries)
        return await self.run_protocol(sysid, machine)

    async def command_int(self, sysid: int, cmd: int, x: int, y: int, z: float = 0.0,
                          *params: float, timeout_s: float = DEFAULT_TIMEOUT_S,
                          retries: int = DEFAULT_RETRIES) -> MAVLinkMessage:
        """COMMAND_INT with exact int32 ``x``/``y``; return the accepting COMMAND_ACK."""
        machine = CommandSender(sysid, self._compid(sysid), cmd, params, timeout_s=timeout_s,
                                retries=retries, position=(x, y, z))
        return await self.run_protocol(sysid, machine)

    def send_command_int(self, sysid: int, cmd: int, x: int, y: int, z: float = 0.0) -> None:
        """COMMAND_INT without waiting for its answer (requests whose effect is seen)."""
        self.send(sysid, mavlink.MAVLink_command_int_message(
            sysid, self._compid(sysid), mavlink.MAV_FRAME_GLOBAL_INT, cmd, 0, 0, 0.0, 0.0, 0.0,
            0.0, x, y, z))

    async def arm(self, sysid: int, *, force: bool = False) -> MAVLinkMessage:
        return await self.command(sysid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1,
                                  21196 if force else 0)

    async def disarm(self, sysid: int, *, force: bool = False) -> MAVLinkMessage:
        return await self.command(sysid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                  21196 if force else 0)

    async def set_mode(self, sysid: int, main_mode: int, sub_mode: int = 0,
                       base_mode: int = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                       ) -> MAVLinkMessage:
        """MAV_CMD_DO_SET_MODE: param1 ``base_mode``, param2 the custom main mode, param3 the
        custom sub mode.

        PX4 reads its main mode (4 = AUTO) from param2 and the AUTO sub mode (2 TAKEOFF,
        3 LOITER, 4 MISSION, 5 RTL, 6 LAND) from param3 -- not the packed
        ``main << 16 | sub << 24`` of its HEARTBEAT; ArduPilot reads its mode number from
        param2 (``sub_mode`` 0).
        """
        return await self.command(sysid, mavlink.MAV_CMD_DO_SET_MODE, base_mode, main_mode,
                                  sub_mode)

    async def takeoff(self, sysid: int, alt_rel_m: float) -> MAVLinkMessage:
        """MAV_CMD_NAV_TAKEOFF to ``alt_rel_m`` above home, here.

        PX4 (and our simulated vehicle) read param7 as an altitude AMSL: home's AMSL altitude
        comes from the vehicle's last GLOBAL_POSITION_INT (``alt - relative_alt``). ArduPilot
        reads param7 above home, so it gets ``alt_rel_m`` as is.
        """
        link = self.vehicles.get(sysid)
        if link is None:
            raise LinkError(f"vehicle {sysid} has never been heard from")
        param7 = alt_rel_m
        if link.autopilot != mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
            if link.alt_m is None or link.rel_alt_m is None:
                raise LinkError(f"vehicle {sysid}: no position yet, so no home altitude to "
                                "take off from")
            param7 = link.alt_m - link.rel_alt_m + alt_rel_m
        nan = float("nan")
        return await self.command(sysid, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan,
                                  param7)

    async def start_mission(self, sysid: int, first: int = 0, last: int = 0) -> MAVLinkMessage:
        """MAV_CMD_MISSION_START (``first = last = 0``: the whole mission)."""
        return await self.command(sysid, mavlink.MAV_CMD_MISSION_START, first, last)

    async def return_to_launch(self, sysid: int) -> MAVLinkMessage:
        return await self.command(sysid, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)

    async def set_message_interval(self, sysid: int, message_id: int,
                                   interval_s: float) -> MAVLinkMessage:
        """MAV_CMD_SET_MESSAGE_INTERVAL (``interval_s <= 0``: -1, stop the stream)."""
        interval_us = -1 if interval_s <= 0 else interval_s * 1e6
        return await self.command(sysid, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, message_id,
                                  interval_us)

    def request_data_streams(self, sysid: int, rate_hz: int = 4) -> None:
        """Ask for all telemetry streams the legacy way (REQUEST_DATA_STREAM; ArduPilot sends only
        heartbeats until asked).  Fire and forget; PX4 and our simulated vehicle ignore it."""
        self.send(sysid, mavlink.MAVLink_request_data_stream_message(
            sysid, self._compid(sysid), mavlink.MAV_DATA_STREAM_ALL, rate_hz, 1))

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

