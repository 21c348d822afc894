"""Who is who on the link: the vehicles the station knows, kept from what arrives (sans-IO).

:class:`VehicleTable` is given every message with where it came from and the time
(``receive(msg, source, now)``), and the time alone for the liveness check
(``check(now)``); it returns events (dataclasses) and never reads a clock or a socket, so it
is tested without either. The rules:

* **A vehicle is an autopilot**: a system id becomes a vehicle with the HEARTBEAT of its
  autopilot component (:data:`AUTOPILOT_COMPONENT`, as PX4 and ArduPilot send it). Other
  components of the system (a companion computer, a camera) are listed in
  :attr:`VehicleLink.components`; their heartbeats never replace the autopilot's type, mode or
  state, and what they send never moves the vehicle's **route** (the source commands go to),
  which is the autopilot's.
* **Twins**: a second source of a known system's autopilot (another address, another link)
  while the first is alive is refused: its messages are dropped, and the first conflicting one
  is reported (:class:`TwinRefused`, with both addresses) and kept in :attr:`conflicts`. Once
  the first source has been silent for the heartbeat timeout, a new source takes over
  (:class:`VehicleMoved`): a vehicle that restarted on another port.
* **Strangers**: once the station has named its fleet (:meth:`VehicleTable.expect`), a system
  outside it is reported once (:class:`ForeignVehicle`) and its messages are dropped, never
  mixed in.
* **Liveness**: a vehicle whose autopilot has not heartbeated for ``heartbeat_timeout_s`` is
  lost (:class:`VehicleLost`) until it is heard again (:class:`VehicleRecovered`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from .codec import MAVLinkMessage, mavlink
from .transports import Address

__all__ = [
    "AUTOPILOT_COMPONENT",
    "ComponentDiscovered",
    "Conflict",
    "ConflictKind",
    "EVENTS",
    "Event",
    "ForeignVehicle",
    "MissionItemReached",
    "Source",
    "StatusText",
    "TwinRefused",
    "VehicleDiscovered",
    "VehicleLink",
    "VehicleLost",
    "VehicleMoved",
    "VehicleRecovered",
    "VehicleTable",
]

AUTOPILOT_COMPONENT = mavlink.MAV_COMP_ID_AUTOPILOT1
HDG_UNKNOWN = 0xFFFF
"""``GLOBAL_POSITION_INT.hdg`` when the heading is unknown (UINT16_MAX, MAVLink common)."""
AIRBORNE_ALT_M = 0.5
"""Above home by more than this, a vehicle counts as flying (for ``VehicleLink.airborne_s``)."""
CLOCK_SPAN_S = 5.0
"""A vehicle's clock rate is taken over at least this much of our time (the staleness of one
position, up to a quarter second, then hardly counts)."""
REBOOT_MS = 10_000
"""A ``time_boot_ms`` this far behind the last one means the vehicle restarted."""
NOT_VEHICLES = frozenset({mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                          mavlink.MAV_TYPE_GIMBAL, mavlink.MAV_TYPE_CAMERA,
                          mavlink.MAV_TYPE_ADSB, mavlink.MAV_TYPE_ANTENNA_TRACKER})
"""Heartbeat types that are never an autopilot, whatever component id they use."""


@dataclass(frozen=True)
class Source:
    """Where a message came from: the link (index of the ``--connect`` endpoint) and the
    peer's address on it."""

    link: int
    address: Address

    def __str__(self) -> str:
        return f"{self.address[0]}:{self.address[1]}" + (f" (link {self.link})"
                                                         if self.link else "")


# --------------------------------------------------------------------------------------------
# events


@dataclass(frozen=True)
class VehicleDiscovered:
    """The first HEARTBEAT of a system's autopilot."""

    sysid: int
    address: Address


@dataclass(frozen=True)
class ComponentDiscovered:
    """Another component of a vehicle's system (a companion computer, ...) heartbeated."""

    sysid: int
    compid: int
    mav_type: int
    address: Address


@dataclass(frozen=True)
class VehicleLost:
    """No HEARTBEAT from ``sysid``'s autopilot for longer than the heartbeat timeout."""

    sysid: int
    silent_s: float


@dataclass(frozen=True)
class VehicleRecovered:
    """A lost vehicle's heartbeat is back."""

    sysid: int
    address: Address


@dataclass(frozen=True)
class VehicleMoved:
    """The vehicle's autopilot now speaks from another source (the old one fell silent)."""

    sysid: int
    old: Address
    new: Address


@dataclass(frozen=True)
class TwinRefused:
    """A second source of a known system's autopilot, refused while the first is alive."""

    sysid: int
    address: Address
    known: Address
    message: str
    """The type of the first conflicting message."""


@dataclass(frozen=True)
class ForeignVehicle:
    """A system outside the fleet sends to the station; its messages are dropped."""

    sysid: int
    address: Address
    message: str


@dataclass(frozen=True)
class MissionItemReached:
    sysid: int
    seq: int


@dataclass(frozen=True)
class StatusText:
    sysid: int
    severity: int
    text: str


Event = (VehicleDiscovered | ComponentDiscovered | VehicleLost | VehicleRecovered
         | VehicleMoved | TwinRefused | ForeignVehicle | MissionItemReached | StatusText)
EVENTS: tuple[type, ...] = (VehicleDiscovered, ComponentDiscovered, VehicleLost,
                            VehicleRecovered, VehicleMoved, TwinRefused, ForeignVehicle,
                            MissionItemReached, StatusText)
"""Every event type, for a subscription to all of them."""


class ConflictKind(StrEnum):
    TWIN = "twin"
    FOREIGN = "foreign"
    MOVED = "moved"


@dataclass
class Conflict:
    """One refused (or taken-over) source, for the run log and ``summary.json``."""

    kind: ConflictKind
    sysid: int
    address: Address
    known: Address | None
    first_message: str
    first_at: float
    messages: int = 1

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind.value, "sysid": self.sysid,
                "address": f"{self.address[0]}:{self.address[1]}",
                "known_address": (f"{self.known[0]}:{self.known[1]}" if self.known else None),
                "first_message": self.first_message, "messages": self.messages}


# --------------------------------------------------------------------------------------------
# per vehicle


@dataclass
class ComponentInfo:
    compid: int
    mav_type: int
    source: Source
    last_heartbeat: float


@dataclass
class VehicleLink:
    """What the ground station knows about one vehicle (updated from its messages).

    ``address`` / ``link`` are its route: where its autopilot speaks from, where commands go.
    Times (``first_seen``, ``last_heartbeat``) are the table's clock (what ``now`` was).
    """

    sysid: int
    address: Address
    compid: int = AUTOPILOT_COMPONENT
    link: int = 0
    first_seen: float = 0.0
    last_heartbeat: float = 0.0
    last_heard: float = 0.0
    """Last message of any kind from the autopilot's source."""
    lost: bool = False
    components: dict[int, ComponentInfo] = field(default_factory=dict)
    """The system's other components, by component id (never the autopilot)."""
    sample_compid: int | None = None
    """The component its samples come from (the payload: the autopilot's Lua script, or a
    companion computer); the one asked for lost samples."""
    # last HEARTBEAT of the autopilot
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
    mission_state: int = 0
    """``mission_state`` of its last MISSION_CURRENT (0: MISSION_STATE_UNKNOWN, an autopilot
    that does not say)."""
    mission_state_at: float = 0.0
    """When that MISSION_CURRENT arrived."""
    mission_reached: int | None = None
    partial_missions: set[int] = field(default_factory=set)
    """Mission types whose last upload ended part-way on an autopilot that stores items as
    they come (ArduPilot's mission and rally points): what it stores of that type is now the
    new items it took, then the ones it had before (up to the new count). Forgotten when an
    upload or a clear of that type succeeds."""
    clock_first: tuple[float, int] | None = None
    """(our time, ``time_boot_ms``) of its first position, ..."""
    clock_last: tuple[float, int] | None = None
    """... and of its newest (a resent, older one is no news): how fast its clock runs
    against ours (:attr:`clock_rate`)."""
    statustexts: list[tuple[float, int, str]] = field(default_factory=list)
    messages: int = 0

    @property
    def source(self) -> Source:
        return Source(self.link, self.address)

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

    @property
    def clock_rate(self) -> float | None:
        """Its clock's speed against ours since its first position (its sim speed-up), once
        heard over :data:`CLOCK_SPAN_S` or more (None before)."""
        a, b = self.clock_first, self.clock_last
        if a is None or b is None or b[0] - a[0] < CLOCK_SPAN_S:
            return None
        return (b[1] - a[1]) / 1000.0 / (b[0] - a[0])

    def account(self, msg: MAVLinkMessage, now: float) -> list[Event]:
        """Take in a message of its autopilot other than a HEARTBEAT (received at
        ``now``); return the events it caused."""
        events: list[Event] = []
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            pair = (now, int(msg.time_boot_ms))
            if self.clock_first is None:
                self.clock_first = pair
            elif self.clock_last is None or pair[1] > self.clock_last[1]:
                self.clock_last = pair
        if kind == "GLOBAL_POSITION_INT" and no_position(msg):
            self.time_boot_ms = msg.time_boot_ms
        elif kind == "GLOBAL_POSITION_INT":
            rel_alt_m = msg.relative_alt / 1000.0
            t_ms, last_ms = msg.time_boot_ms, self.last_fix_ms
            if last_ms is None or t_ms > last_ms or t_ms < last_ms - REBOOT_MS:
                airborne = rel_alt_m > AIRBORNE_ALT_M
                if last_ms is not None and t_ms > last_ms and airborne and self.last_fix_airborne:
                    self.airborne_s += (t_ms - last_ms) / 1000.0
                self.last_fix_ms, self.last_fix_airborne = t_ms, airborne
            self.time_boot_ms = msg.time_boot_ms
            self.lat_deg, self.lon_deg = msg.lat / 1e7, msg.lon / 1e7
            self.alt_m, self.rel_alt_m = msg.alt / 1000.0, rel_alt_m
            if msg.hdg != HDG_UNKNOWN:
                self.heading_deg = msg.hdg / 100.0
        elif kind == "SYS_STATUS":
            self.sensors_present = msg.onboard_control_sensors_present
            self.sensors_health = msg.onboard_control_sensors_health
        elif kind == "MISSION_CURRENT":
            self.mission_current = msg.seq
            self.mission_state = int(getattr(msg, "mission_state", 0) or 0)
            self.mission_state_at = now
        elif kind == "MISSION_ITEM_REACHED":
            self.mission_reached = msg.seq
            events.append(MissionItemReached(self.sysid, msg.seq))
        elif kind == "STATUSTEXT":
            text = _text(msg.text)
            self.statustexts.append((now, msg.severity, text))
            del self.statustexts[:-200]
            events.append(StatusText(self.sysid, msg.severity, text))
        return events

    @property
    def companions(self) -> list[int]:
        return sorted(c for c, info in self.components.items()
                      if info.mav_type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER)


def no_position(msg: MAVLinkMessage) -> bool:
    """A GLOBAL_POSITION_INT without a position: ArduPilot sends latitude = longitude = 0
    until its EKF has one (the point off Africa is nobody's mission area)."""
    return msg.lat == 0 and msg.lon == 0


def _text(value: object) -> str:
    if isinstance(value, bytes | bytearray):
        value = value.decode("utf-8", "replace")
    return str(value).rstrip("\x00")


class VehicleTable:
    """The vehicles on the station's links (module docstring for the rules).

    Parameters
    ----------
    heartbeat_timeout_s:
        A vehicle whose autopilot is silent for longer is lost; a second source of its
        autopilot is refused until then.
    """

    def __init__(self, heartbeat_timeout_s: float = 5.0) -> None:
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.vehicles: dict[int, VehicleLink] = {}
        self.fleet: frozenset[int] | None = None
        self.conflicts: list[Conflict] = []
        self._conflict_at: dict[tuple[int, Source], Conflict] = {}
        self._pending_components: dict[int, dict[int, ComponentInfo]] = {}
        self.refused = 0
        """Messages dropped from twins and strangers."""

    def expect(self, sysids: Iterable[int]) -> list[Event]:
        """The fleet is these systems: anyone else is a stranger from now on (reported
        once, now for those already heard)."""
        self.fleet = frozenset(sysids)
        events: list[Event] = []
        for sysid in sorted(set(self.vehicles) - self.fleet):
            link = self.vehicles.pop(sysid)
            events.append(self._conflict(ConflictKind.FOREIGN, sysid, link.source, None,
                                         "HEARTBEAT", link.last_heard))
        return events

    def receive(self, msg: MAVLinkMessage, source: Source, now: float
                ) -> tuple[VehicleLink | None, list[Event]]:
        """Account for one message; return the vehicle it belongs to (None: it is not a
        vehicle's, or it was refused) and the events it caused."""
        sysid, compid = msg.get_srcSystem(), msg.get_srcComponent()
        kind = msg.get_type()
        events: list[Event] = []
        if self.fleet is not None and sysid not in self.fleet:
            key = (sysid, source)
            seen = self._conflict_at.get(key)
            if seen is None:
                events.append(self._conflict(ConflictKind.FOREIGN, sysid, source, None, kind,
                                             now))
            else:
                seen.messages += 1
            self.refused += 1
            return None, events
        link = self.vehicles.get(sysid)
        is_autopilot = compid == AUTOPILOT_COMPONENT
        heartbeat = kind == "HEARTBEAT"
        if heartbeat and (msg.type in NOT_VEHICLES or not is_autopilot):
            if msg.type == mavlink.MAV_TYPE_GCS:
                return None, events  # another ground station; not a vehicle
            return self._component(link, sysid, compid, msg, source, now)
        if link is None:
            if not (heartbeat and is_autopilot):
                return None, events  # not a vehicle until its autopilot heartbeats
            link = VehicleLink(sysid, source.address, link=source.link, first_seen=now,
                               last_heartbeat=now, last_heard=now)
            link.components = self._pending_components.pop(sysid, {})
            self.vehicles[sysid] = link
            events.append(VehicleDiscovered(sysid, source.address))
        elif is_autopilot and source != link.source:
            if now - link.last_heard <= self.heartbeat_timeout_s and not link.lost:
                key = (sysid, source)
                seen = self._conflict_at.get(key)
                if seen is None:
                    events.append(self._conflict(ConflictKind.TWIN, sysid, source,
                                                 link.address, kind, now))
                else:
                    seen.messages += 1
                self.refused += 1
                return None, events
            old = link.address
            link.address, link.link = source.address, source.link
            self.conflicts.append(Conflict(ConflictKind.MOVED, sysid, source.address, old,
                                           kind, now))
            events.append(VehicleMoved(sysid, old, source.address))
        link.messages += 1
        if is_autopilot:
            link.last_heard = now
            if heartbeat:
                if link.lost:
                    link.lost = False
                    events.append(VehicleRecovered(sysid, source.address))
                link.last_heartbeat = now
                link.mav_type, link.autopilot = msg.type, msg.autopilot
                link.base_mode, link.custom_mode = msg.base_mode, msg.custom_mode
                link.system_status = msg.system_status
            else:
                events.extend(link.account(msg, now))
        elif compid in link.components and link.components[compid].source != source:
            # a component that moved (or a second one with its id): it is followed, but it
            # never takes the vehicle's route
            link.components[compid].source = source
        if kind == "NAMED_VALUE_FLOAT":
            link.sample_compid = compid
        return link, events

    def _component(self, link: VehicleLink | None, sysid: int, compid: int,
                   msg: MAVLinkMessage, source: Source, now: float
                   ) -> tuple[VehicleLink | None, list[Event]]:
        """The heartbeat of a component that is not the autopilot."""
        table = link.components if link is not None else \
            self._pending_components.setdefault(sysid, {})
        events: list[Event] = []
        info = table.get(compid)
        if info is None:
            table[compid] = ComponentInfo(compid, msg.type, source, now)
            if link is not None:
                events.append(ComponentDiscovered(sysid, compid, msg.type, source.address))
        else:
            info.mav_type, info.source, info.last_heartbeat = msg.type, source, now
        if link is not None:
            link.messages += 1
        return link, events

    def _conflict(self, kind: ConflictKind, sysid: int, source: Source,
                  known: Address | None, message: str, now: float) -> Event:
        c = Conflict(kind, sysid, source.address, known, message, now)
        self.conflicts.append(c)
        self._conflict_at[(sysid, source)] = c
        if kind == ConflictKind.TWIN:
            assert known is not None
            return TwinRefused(sysid, source.address, known, message)
        return ForeignVehicle(sysid, source.address, message)

    def source_gone(self, source: Source) -> None:
        """A stream peer closed its connection: a vehicle that spoke from it may come back
        from another source at once (a reconnect is no twin)."""
        for link in self.vehicles.values():
            if link.source == source:
                link.last_heard = -float("inf")

    def check(self, now: float) -> list[Event]:
        """Mark vehicles silent for longer than the heartbeat timeout lost."""
        events: list[Event] = []
        for link in self.vehicles.values():
            silent = now - link.last_heartbeat
            if not link.lost and silent > self.heartbeat_timeout_s:
                link.lost = True
                events.append(VehicleLost(link.sysid, silent))
        return events
