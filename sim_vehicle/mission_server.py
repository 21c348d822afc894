"""The vehicle side of the MAVLink mission protocol, as a pure state machine.

No I/O and no clock of its own: the caller feeds received messages with
:meth:`MissionServer.receive` (``msg, now -> replies``), calls :meth:`MissionServer.poll`
when :meth:`MissionServer.next_deadline` has passed (retries / timeouts), and sends the
returned pymavlink message objects itself. Things the vehicle must act on (a new mission,
a clear, a set-current) are queued in :attr:`MissionServer.events`.

Supported (per ``mission_type``: MISSION, FENCE, RALLY are stored separately):

* upload: MISSION_COUNT -> MISSION_REQUEST_INT(seq) (or the float MISSION_REQUEST, ArduPilot's
  habit, with ``request_int=False``) ... <- MISSION_ITEM_INT / MISSION_ITEM
  -> MISSION_ACK. A request is resent after ``timeout_s`` without the expected item, at most
  ``max_retries`` times, then MISSION_ACK(ERROR) ends the transfer. An item with a seq other
  than the expected one makes the server re-request the expected seq. A new MISSION_COUNT, or a
  MISSION_ACK from the GCS, cancels a running upload (the stored mission is unchanged).
  Count 0 clears.
* download: MISSION_REQUEST_LIST -> MISSION_COUNT; MISSION_REQUEST_INT -> MISSION_ITEM_INT,
  legacy MISSION_REQUEST -> MISSION_ITEM; items come back as stored (:meth:`MissionServer.stored`
  and :meth:`MissionServer.reported` let a personality change both: ArduPilot overwrites item 0
  with home and reports frames and altitudes its own way).
* items whose command is not in ``accepted_commands`` are refused with
  MAV_MISSION_UNSUPPORTED (the contour item and the sensor lag item only when a companion
  computer runs the tracer); a sensor lag item whose lag (param1) is not a finite number
  >= 0 with MAV_MISSION_INVALID_PARAM1.
* MISSION_CLEAR_ALL -> MISSION_ACK (of the upload's type, or of type ALL, it also ends a running
  upload); MISSION_SET_CURRENT -> MISSION_CURRENT.
* FENCE uploads are checked item by item and as a whole (:func:`sim_vehicle.fence.check_fence`)
  and refused with the ``MAV_MISSION_RESULT`` that says why; RALLY items are stored as given.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.tasks import SENSOR_LAG_COMMAND

from .fence import check_fence, check_fence_item

MISSION = mavlink.MAV_MISSION_TYPE_MISSION
FENCE = mavlink.MAV_MISSION_TYPE_FENCE
RALLY = mavlink.MAV_MISSION_TYPE_RALLY
MISSION_TYPES = (MISSION, FENCE, RALLY)

MAV_CMD_WAYPOINT_USER_1 = mavlink.MAV_CMD_WAYPOINT_USER_1
"""The contour item (DESIGN.md §4); only a vehicle with the tracer on board accepts it."""

GLOBAL_FRAMES = frozenset({
    mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_INT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
})
"""Frames whose x/y are latitude/longitude (scaled by 1e7 in the *_INT messages)."""

NAV_COMMANDS = frozenset({
    mavlink.MAV_CMD_NAV_WAYPOINT,
    mavlink.MAV_CMD_NAV_LOITER_UNLIM,
    mavlink.MAV_CMD_NAV_LOITER_TIME,
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    mavlink.MAV_CMD_NAV_LAND,
    mavlink.MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_WAYPOINT_USER_1,
})
DO_COMMANDS = frozenset({mavlink.MAV_CMD_DO_CHANGE_SPEED, SENSOR_LAG_COMMAND})
SUPPORTED_COMMANDS = NAV_COMMANDS | DO_COMMANDS
"""Everything the navigator can fly, the contour item and the sensor lag item included."""
COMPANION_COMMANDS = frozenset({MAV_CMD_WAYPOINT_USER_1, SENSOR_LAG_COMMAND})
"""The items for the onboard tracer: only a companion computer takes them."""
STOCK_COMMANDS = SUPPORTED_COMMANDS - COMPANION_COMMANDS
"""What a stock autopilot (no companion) accepts."""


@dataclass(frozen=True)
class StoredItem:
    """One mission item as the GCS sent it.

    ``x``/``y`` are the MISSION_ITEM_INT integers; ``xf``/``yf`` the floats of a legacy
    MISSION_ITEM upload (None for an _INT upload), so either form downloads verbatim.
    """

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int = MISSION
    xf: float | None = None
    yf: float | None = None

    @property
    def lat_deg(self) -> float:
        return self.xf if self.xf is not None else self.x / 1e7

    @property
    def lon_deg(self) -> float:
        return self.yf if self.yf is not None else self.y / 1e7

    @property
    def is_global(self) -> bool:
        return self.frame in GLOBAL_FRAMES


def _scale(frame: int) -> float:
    return 1e7 if frame in GLOBAL_FRAMES else 1.0


def item_from_msg(msg: Any) -> StoredItem:
    """A StoredItem from a MISSION_ITEM_INT or legacy MISSION_ITEM message."""
    legacy = msg.get_type() == "MISSION_ITEM"
    mtype = int(getattr(msg, "mission_type", MISSION) or 0)
    if legacy:
        s = _scale(msg.frame)
        xi, yi = int(round(msg.x * s)), int(round(msg.y * s))
        xf, yf = float(msg.x), float(msg.y)
    else:
        xi, yi, xf, yf = int(msg.x), int(msg.y), None, None
    return StoredItem(int(msg.seq), int(msg.frame), int(msg.command), int(msg.current),
                      int(msg.autocontinue), float(msg.param1), float(msg.param2),
                      float(msg.param3), float(msg.param4), xi, yi, float(msg.z), mtype, xf, yf)


def check_item(item: StoredItem, accepted: frozenset[int] = SUPPORTED_COMMANDS) -> int:
    """MAV_MISSION_ACCEPTED, or the MAV_MISSION_RESULT that rejects ``item``."""
    if item.mission_type == FENCE:
        return check_fence_item(item)
    if item.mission_type != MISSION:
        return mavlink.MAV_MISSION_ACCEPTED  # rally: stored as given
    if item.command not in accepted:
        return mavlink.MAV_MISSION_UNSUPPORTED
    if item.command in NAV_COMMANDS:
        ok = set(GLOBAL_FRAMES)
        if item.command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            ok.add(mavlink.MAV_FRAME_MISSION)
    else:
        ok = set(GLOBAL_FRAMES) | {mavlink.MAV_FRAME_MISSION}
    if item.frame not in ok:
        return mavlink.MAV_MISSION_UNSUPPORTED_FRAME
    if item.command == SENSOR_LAG_COMMAND and not (math.isfinite(item.param1)
                                                   and item.param1 >= 0.0):
        return mavlink.MAV_MISSION_INVALID_PARAM1
    if item.command == SENSOR_LAG_COMMAND and item.param2 not in (0.0, 1.0):
        return mavlink.MAV_MISSION_INVALID_PARAM2
    return mavlink.MAV_MISSION_ACCEPTED


@dataclass
class _Upload:
    mission_type: int
    count: int
    peer: tuple[int, int]
    items: list[StoredItem]
    deadline: float
    retries: int = 0


@dataclass(frozen=True)
class MissionEvent:
    """Something the vehicle must act on: kind is 'uploaded', 'cleared' or 'set_current'."""

    kind: str
    mission_type: int = MISSION
    seq: int = 0


class MissionServer:
    """Pure mission-protocol server for one vehicle (see the module docstring)."""

    def __init__(self, timeout_s: float = 0.25, max_retries: int = 5, *,
                 request_int: bool = True,
                 accepted_commands: frozenset[int] = SUPPORTED_COMMANDS) -> None:
        self.timeout_s = timeout_s
        self.max_retries = max_retries
        self.request_int = request_int
        self.accepted_commands = accepted_commands
        self.stores: dict[int, list[StoredItem]] = {t: [] for t in MISSION_TYPES}
        self.current_seq = 0
        self.events: list[MissionEvent] = []
        self.upload: _Upload | None = None
        self.counters = {"uploads": 0, "uploads_failed": 0, "resends": 0, "downloads": 0}
        self.reject_commands: set[int] = set()
        """Test hook: items with these commands are refused (MAV_MISSION_UNSUPPORTED)."""
        # (mission_type, peer, count) of the last completed upload, to re-ACK a late
        # retransmission of its final item when our ACK was lost.
        self._last_done: tuple[int, tuple[int, int], int] | None = None

    # --- public API ------------------------------------------------------------------

    @property
    def mission(self) -> list[StoredItem]:
        return self.stores[MISSION]

    def next_deadline(self) -> float | None:
        return self.upload.deadline if self.upload is not None else None

    def receive(self, msg: Any, now: float) -> list[Any]:
        """Handle one message addressed to this vehicle; return the replies."""
        name = self._HANDLERS.get(msg.get_type())
        if name is None:
            return []
        peer = (msg.get_srcSystem(), msg.get_srcComponent())
        handler: Callable[[Any, tuple[int, int], float], list[Any]] = getattr(self, name)
        return handler(msg, peer, now)

    def poll(self, now: float) -> list[Any]:
        """Resend the outstanding request, or give up, if the deadline has passed."""
        up = self.upload
        if up is None or now < up.deadline:
            return []
        if up.retries >= self.max_retries:
            self.upload = None
            self.counters["uploads_failed"] += 1
            return [self._ack(up.peer, mavlink.MAV_MISSION_ERROR, up.mission_type)]
        up.retries += 1
        self.counters["resends"] += 1
        up.deadline = now + self.timeout_s
        return [self._request(up)]

    def set_current(self, seq: int) -> None:
        """The executor moved to ``seq`` (no reply; the vehicle sends MISSION_CURRENT)."""
        self.current_seq = seq

    # --- handlers ----------------------------------------------------------------------

    @staticmethod
    def _mtype(msg: Any) -> int:
        return int(getattr(msg, "mission_type", MISSION) or 0)

    def _ack(self, peer: tuple[int, int], result: int, mtype: int) -> Any:
        return mavlink.MAVLink_mission_ack_message(peer[0], peer[1], result, mtype)

    def _request(self, up: _Upload) -> Any:
        make = (mavlink.MAVLink_mission_request_int_message if self.request_int
                else mavlink.MAVLink_mission_request_message)
        return make(up.peer[0], up.peer[1], len(up.items), up.mission_type)

    # --- what a personality may change ---------------------------------------------------

    def stored(self, mtype: int, items: list[StoredItem]) -> list[StoredItem]:
        """The items as this vehicle stores an upload (as given, here)."""
        return items

    def reported(self, item: StoredItem) -> StoredItem:
        """An item as this vehicle reports it on download (as stored, here)."""
        return item

    def _on_count(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        mtype = self._mtype(msg)
        self.upload = None  # a new COUNT cancels any running transfer
        if mtype not in self.stores:
            return [self._ack(peer, mavlink.MAV_MISSION_UNSUPPORTED, mtype)]
        if msg.count == 0:
            self._store(mtype, [])
            self.events.append(MissionEvent("cleared", mtype))
            return [self._ack(peer, mavlink.MAV_MISSION_ACCEPTED, mtype)]
        if msg.count > 0xFFFE:
            return [self._ack(peer, mavlink.MAV_MISSION_NO_SPACE, mtype)]
        self.upload = _Upload(mtype, int(msg.count), peer, [], now + self.timeout_s)
        self._last_done = None
        return [self._request(self.upload)]

    def _on_item(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        up = self.upload
        mtype = self._mtype(msg)
        if up is None or up.mission_type != mtype or up.peer != peer:
            done = self._last_done
            if done is not None and done[:2] == (mtype, peer) and msg.seq == done[2] - 1:
                return [self._ack(peer, mavlink.MAV_MISSION_ACCEPTED, mtype)]
            if up is None:
                return [self._ack(peer, mavlink.MAV_MISSION_INVALID_SEQUENCE, mtype)]
            return []  # somebody else's item during our transfer: ignore
        expected = len(up.items)
        if msg.seq != expected:
            # duplicate or skipped item: ask again for the one we need
            up.deadline = now + self.timeout_s
            return [self._request(up)]
        item = item_from_msg(msg)
        result = check_item(item, self.accepted_commands)
        if item.command in self.reject_commands:
            result = mavlink.MAV_MISSION_UNSUPPORTED
        if result != mavlink.MAV_MISSION_ACCEPTED:
            self.upload = None
            self.counters["uploads_failed"] += 1
            return [self._ack(peer, result, mtype)]
        up.items.append(item)
        up.retries = 0
        if len(up.items) < up.count:
            up.deadline = now + self.timeout_s
            return [self._request(up)]
        self.upload = None
        if mtype == FENCE and (result := check_fence(up.items)) != mavlink.MAV_MISSION_ACCEPTED:
            self.counters["uploads_failed"] += 1
            return [self._ack(peer, result, mtype)]
        self._store(mtype, up.items)
        self._last_done = (mtype, peer, up.count)
        self.counters["uploads"] += 1
        self.events.append(MissionEvent("uploaded", mtype))
        return [self._ack(peer, mavlink.MAV_MISSION_ACCEPTED, mtype)]

    def _store(self, mtype: int, items: list[StoredItem]) -> None:
        self.stores[mtype] = self.stored(mtype, list(items)) if items else []
        if mtype == MISSION:
            self.current_seq = 0

    def _on_ack(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        up = self.upload
        if up is not None and up.peer == peer and up.mission_type == self._mtype(msg):
            self.upload = None  # the GCS gave up (or rejected our request)
            self.counters["uploads_failed"] += 1
        return []

    def _on_request_list(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        mtype = self._mtype(msg)
        if mtype not in self.stores:
            return [self._ack(peer, mavlink.MAV_MISSION_UNSUPPORTED, mtype)]
        self.counters["downloads"] += 1
        return [mavlink.MAVLink_mission_count_message(peer[0], peer[1],
                                                      len(self.stores[mtype]), mtype)]

    def _on_request(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        mtype = self._mtype(msg)
        if self.upload is not None and self.upload.peer == peer:
            return []  # a request from the uploading GCS makes no sense; ignore
        items = self.stores.get(mtype)
        if items is None:
            return [self._ack(peer, mavlink.MAV_MISSION_UNSUPPORTED, mtype)]
        if not 0 <= msg.seq < len(items):
            return [self._ack(peer, mavlink.MAV_MISSION_INVALID_SEQUENCE, mtype)]
        it = self.reported(items[msg.seq])
        if msg.get_type() == "MISSION_REQUEST_INT":
            return [mavlink.MAVLink_mission_item_int_message(
                peer[0], peer[1], it.seq, it.frame, it.command, it.current, it.autocontinue,
                it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z, mtype)]
        s = _scale(it.frame)
        xf = it.xf if it.xf is not None else it.x / s
        yf = it.yf if it.yf is not None else it.y / s
        return [mavlink.MAVLink_mission_item_message(
            peer[0], peer[1], it.seq, it.frame, it.command, it.current, it.autocontinue,
            it.param1, it.param2, it.param3, it.param4, xf, yf, it.z, mtype)]

    def _on_clear(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        mtype = self._mtype(msg)
        if mtype == mavlink.MAV_MISSION_TYPE_ALL:
            for t in MISSION_TYPES:
                self._store(t, [])
                self.events.append(MissionEvent("cleared", t))
        elif mtype in self.stores:
            self._store(mtype, [])
            self.events.append(MissionEvent("cleared", mtype))
        else:
            return [self._ack(peer, mavlink.MAV_MISSION_UNSUPPORTED, mtype)]
        up = self.upload
        if up is not None and mtype in (up.mission_type, mavlink.MAV_MISSION_TYPE_ALL):
            self.upload = None  # what it was uploading is cleared: the transfer ends
            self.counters["uploads_failed"] += 1
        return [self._ack(peer, mavlink.MAV_MISSION_ACCEPTED, mtype)]

    def _on_set_current(self, msg: Any, peer: tuple[int, int], now: float) -> list[Any]:
        n = len(self.mission)
        if not 0 <= msg.seq < max(n, 1) or n == 0:
            return [mavlink.MAVLink_statustext_message(
                mavlink.MAV_SEVERITY_WARNING, f"set current {msg.seq}: no such item".encode(),
                0, 0)]
        self.current_seq = int(msg.seq)
        self.events.append(MissionEvent("set_current", MISSION, self.current_seq))
        return [self.mission_current_msg(active=False)]

    def mission_current_msg(self, active: bool, complete: bool = False,
                            paused: bool = False) -> Any:
        """MISSION_CURRENT with its ``mission_state``: ACTIVE while flown, COMPLETE after its
        end, PAUSED when it was left before its end (a mode change, a failsafe), else
        NOT_STARTED (PX4's and ArduPilot's meanings)."""
        n = len(self.mission)
        if n == 0:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif complete or self.current_seq >= n:
            state = mavlink.MISSION_STATE_COMPLETE
        elif active:
            state = mavlink.MISSION_STATE_ACTIVE
        else:
            state = mavlink.MISSION_STATE_PAUSED if paused else mavlink.MISSION_STATE_NOT_STARTED
        return mavlink.MAVLink_mission_current_message(min(self.current_seq, 0xFFFF), n, state,
                                                       1 if active else 0)

    _HANDLERS = {  # by method name, so that a personality's override is the one called
        "MISSION_COUNT": "_on_count",
        "MISSION_ITEM_INT": "_on_item",
        "MISSION_ITEM": "_on_item",
        "MISSION_ACK": "_on_ack",
        "MISSION_REQUEST_LIST": "_on_request_list",
        "MISSION_REQUEST_INT": "_on_request",
        "MISSION_REQUEST": "_on_request",
        "MISSION_CLEAR_ALL": "_on_clear",
        "MISSION_SET_CURRENT": "_on_set_current",
    }

