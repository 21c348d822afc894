"""MAVLink mission and command protocols as pure state machines (no I/O, time passed in).

Every machine has the same small interface, in the style of aioquic's connection objects:

``poll(now) -> list[message]``
    messages to send now: the first request, answers to what was received, and retries when a
    deadline passed.  Call it after every :meth:`receive` and whenever :meth:`next_deadline`
    is reached.
``receive(msg, now) -> None``
    feed one message that came from the target vehicle (the shell routes by system id).
``next_deadline() -> float | None``
    when :meth:`poll` must be called again even if nothing arrives (``None`` once done).
``done``, ``result``, ``error``
    ``error`` is an exception instance (:class:`~econdor_gcs.errors.ProtocolError` for a refusal,
    :class:`~econdor_gcs.errors.VehicleTimeout` when the retries ran out) or ``None``.

``now`` is any monotonic clock in seconds.  Machines ignore messages that do not belong to
them (other message types, other mission types, stale answers), so several can listen to one
vehicle's stream.

Mission conventions (DESIGN.md §4): items are ``MISSION_ITEM_INT`` in
``MAV_FRAME_GLOBAL_RELATIVE_ALT_INT``, mission type 0, "item 0 home, takeoff, trace items, then
return or loiter", exactly one item with ``current = 1`` (item 0).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from ..core.geodesy import Origin
from ..core.geometry import Region
from ..core.tasks import Phase, Task, TaskStyle, TraceTask, Waypoint
from ..core.waypoints import task_waypoints
from ..errors import CommandRejected, MissionRejected, ProtocolError, VehicleTimeout
from .codec import MAVLinkMessage, mavlink

__all__ = [
    "CommandSender",
    "MissionClear",
    "MissionDownloader",
    "MissionItemSpec",
    "MissionPlan",
    "MissionUploader",
    "build_mission",
    "change_speed_item",
    "command_name",
    "enum_name",
    "fence_items",
    "home_item",
    "loiter_item",
    "plan_mission",
    "rtl_item",
    "takeoff_item",
    "trace_item",
    "waypoint_item",
]

MAV_CMD_WAYPOINT_USER_1 = mavlink.MAV_CMD_WAYPOINT_USER_1
FRAME_REL_INT = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
INT_TO_FLOAT_FRAME = {  # the _INT frames and their float twins (MISSION_ITEM, files)
    mavlink.MAV_FRAME_GLOBAL_INT: mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
}
FLOAT_TO_INT_FRAME = {v: k for k, v in INT_TO_FLOAT_FRAME.items()}

DEFAULT_TIMEOUT_S = 1.5
DEFAULT_RETRIES = 5


def enum_name(enum: str, value: int) -> str:
    """``enum_name("MAV_MISSION_RESULT", 2) -> "MAV_MISSION_UNSUPPORTED_FRAME"``."""
    entry = mavlink.enums.get(enum, {}).get(value)
    return entry.name if entry is not None else f"{enum}({value})"


def command_name(command: int) -> str:
    return enum_name("MAV_CMD", command)


# --------------------------------------------------------------------------------------------
# mission items


@dataclass(frozen=True)
class MissionItemSpec:
    """One ``MISSION_ITEM_INT`` without its addressing.

    ``x`` / ``y`` are latitude / longitude in degE7 (int) for global frames; ``z`` is the
    altitude in metres in the item's ``frame``.
    """

    seq: int
    frame: int
    command: int
    current: int = 0
    autocontinue: int = 1
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: int = 0
    y: int = 0
    z: float = 0.0
    mission_type: int = mavlink.MAV_MISSION_TYPE_MISSION

    @property
    def lat_deg(self) -> float:
        return self.x / 1e7

    @property
    def lon_deg(self) -> float:
        return self.y / 1e7

    def to_message(self, target_system: int, target_component: int) -> MAVLinkMessage:
        """As ``MISSION_ITEM_INT``."""
        return mavlink.MAVLink_mission_item_int_message(
            target_system, target_component, self.seq, self.frame, self.command, self.current,
            self.autocontinue, self.param1, self.param2, self.param3, self.param4,
            self.x, self.y, self.z, self.mission_type,
        )

    def to_legacy_message(self, target_system: int, target_component: int) -> MAVLinkMessage:
        """As the deprecated float ``MISSION_ITEM`` (``_INT`` frames mapped to float frames)."""
        global_frame = self.frame in INT_TO_FLOAT_FRAME or self.frame in FLOAT_TO_INT_FRAME
        x = self.x / 1e7 if global_frame else float(self.x)
        y = self.y / 1e7 if global_frame else float(self.y)
        return mavlink.MAVLink_mission_item_message(
            target_system, target_component, self.seq,
            INT_TO_FLOAT_FRAME.get(self.frame, self.frame),
            self.command, self.current, self.autocontinue, self.param1, self.param2, self.param3,
            self.param4, x, y, self.z, self.mission_type,
        )

    @classmethod
    def from_message(cls, msg: MAVLinkMessage) -> MissionItemSpec:
        """From a ``MISSION_ITEM_INT`` or a legacy ``MISSION_ITEM`` (float frames -> ``_INT``)."""
        frame, x, y = msg.frame, msg.x, msg.y
        if msg.get_type() == "MISSION_ITEM":
            if frame in FLOAT_TO_INT_FRAME:
                frame = FLOAT_TO_INT_FRAME[frame]
                x, y = round(x * 1e7), round(y * 1e7)
            else:
                x, y = round(x), round(y)
        return cls(
            seq=msg.seq, frame=frame, command=msg.command, current=msg.current,
            autocontinue=msg.autocontinue, param1=msg.param1, param2=msg.param2,
            param3=msg.param3, param4=msg.param4, x=int(x), y=int(y), z=float(msg.z),
            mission_type=getattr(msg, "mission_type", 0) or 0,
        )


def _e7(deg: float) -> int:
    return int(round(deg * 1e7))


def trace_item(
    seq: int, lat_deg: float, lon_deg: float, alt_m: float, level: float,
    search_radius_m: float, max_length_m: float, piece_id: int,
) -> MissionItemSpec:
    """A contour assignment: ``MAV_CMD_WAYPOINT_USER_1`` (31000), DESIGN.md §4.

    x/y = start point, z = altitude above home, param1 = level, param2 = search radius (m),
    param3 = max trace length (m, 0 = until closed), param4 = piece id.
    """
    return MissionItemSpec(
        seq, FRAME_REL_INT, MAV_CMD_WAYPOINT_USER_1, param1=float(level),
        param2=float(search_radius_m), param3=float(max_length_m), param4=float(piece_id),
        x=_e7(lat_deg), y=_e7(lon_deg), z=float(alt_m),
    )


def waypoint_item(
    seq: int, lat_deg: float, lon_deg: float, alt_m: float, *, hold_s: float = 0.0,
    acceptance_radius_m: float = 0.0,
) -> MissionItemSpec:
    """``MAV_CMD_NAV_WAYPOINT`` at ``alt_m`` above home."""
    return MissionItemSpec(
        seq, FRAME_REL_INT, mavlink.MAV_CMD_NAV_WAYPOINT, param1=hold_s,
        param2=acceptance_radius_m, x=_e7(lat_deg), y=_e7(lon_deg), z=float(alt_m),
    )


def takeoff_item(seq: int, lat_deg: float, lon_deg: float, alt_m: float) -> MissionItemSpec:
    """``MAV_CMD_NAV_TAKEOFF`` to ``alt_m`` above home."""
    return MissionItemSpec(
        seq, FRAME_REL_INT, mavlink.MAV_CMD_NAV_TAKEOFF, x=_e7(lat_deg), y=_e7(lon_deg),
        z=float(alt_m),
    )


def change_speed_item(seq: int, speed_mps: float) -> MissionItemSpec:
    """``MAV_CMD_DO_CHANGE_SPEED`` to a ground speed (param1 1 = ground speed, param3 -1 =
    throttle unchanged), in ``MAV_FRAME_MISSION`` as QGroundControl writes it."""
    return MissionItemSpec(seq, mavlink.MAV_FRAME_MISSION, mavlink.MAV_CMD_DO_CHANGE_SPEED,
                           param1=1.0, param2=float(speed_mps), param3=-1.0)


def rtl_item(seq: int) -> MissionItemSpec:
    """``MAV_CMD_NAV_RETURN_TO_LAUNCH`` (no position)."""
    return MissionItemSpec(seq, FRAME_REL_INT, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)


def loiter_item(
    seq: int, lat_deg: float, lon_deg: float, alt_m: float, *, radius_m: float = 0.0,
) -> MissionItemSpec:
    """``MAV_CMD_NAV_LOITER_UNLIM`` at a given point (hover for a multicopter)."""
    return MissionItemSpec(
        seq, FRAME_REL_INT, mavlink.MAV_CMD_NAV_LOITER_UNLIM, param3=radius_m,
        x=_e7(lat_deg), y=_e7(lon_deg), z=float(alt_m),
    )


def home_item(seq: int, lat_deg: float, lon_deg: float, alt_m: float = 0.0, *,
              current: int = 1) -> MissionItemSpec:
    """Item 0: home, as a ``MAV_CMD_NAV_WAYPOINT`` at ground level with ``current = 1``.

    ArduPilot treats item 0 as home and overwrites it (its own copy uses ``MAV_FRAME_GLOBAL``,
    absolute altitude); PX4/MAVSDK fly item 0 like any waypoint, which at ground level above
    home is harmless only because the takeoff item follows.  Our simulated vehicle stores the
    mission verbatim and skips item 0.
    """
    return MissionItemSpec(
        seq, FRAME_REL_INT, mavlink.MAV_CMD_NAV_WAYPOINT, current=current,
        x=_e7(lat_deg), y=_e7(lon_deg), z=float(alt_m),
    )


@dataclass(frozen=True)
class MissionPlan:
    """A vehicle's mission and where each task sits in it.

    ``task_seqs[k]`` is the ``(first, last)`` item seq of task ``k`` (one item, or a trace
    task's waypoint polyline); ``item_phases`` the sample phase each item implies, for
    vehicles that report none (a polyline's first waypoint is reached in transit, the rest
    flies along the estimated contour).
    """

    items: list[MissionItemSpec]
    task_seqs: list[tuple[int, int]]
    item_phases: dict[int, Phase]
    style: TaskStyle

    @property
    def last_task_seq(self) -> int | None:
        return self.task_seqs[-1][1] if self.task_seqs else None


def plan_mission(
    origin: Origin,
    tasks: Sequence[Task],
    altitude_m: float,
    *,
    style: TaskStyle = TaskStyle.TRACE,
    tolerance_m: float = 1.0,
    home: tuple[float, float] = (0.0, 0.0),
    speed_mps: float | None = None,
    end: str = "rtl",
) -> MissionPlan:
    """A vehicle's mission: item 0 home, takeoff, [DO_CHANGE_SPEED], the tasks, the end item.

    Parameters
    ----------
    origin:
        The ENU frame of the task coordinates.
    tasks:
        :class:`Waypoint` -> ``MAV_CMD_NAV_WAYPOINT``; :class:`TraceTask` ->
        ``MAV_CMD_WAYPOINT_USER_1`` (:func:`trace_item`) with ``style=TRACE``, or its
        estimated contour as ``NAV_WAYPOINT`` items (Douglas-Peucker to ``tolerance_m``,
        :func:`~econdor_gcs.core.waypoints.task_waypoints`) with ``style=WAYPOINTS``.
    altitude_m:
        Flight altitude above home (frame ``MAV_FRAME_GLOBAL_RELATIVE_ALT_INT``).
    home:
        Home / takeoff point, local ENU metres.
    speed_mps:
        If given, a ``DO_CHANGE_SPEED`` follows the takeoff.
    end:
        ``"rtl"`` (return to launch), ``"loiter"`` (hold, unlimited, at the last task's point or
        home) or ``"none"``.

    Only item 0 has ``current = 1`` (MAVSDK insists on exactly one).
    """
    if end not in ("rtl", "loiter", "none"):
        raise ValueError(f"end must be 'rtl', 'loiter' or 'none', not {end!r}")
    if not altitude_m > 0:
        raise ValueError(f"altitude_m must be positive, got {altitude_m}")
    if speed_mps is not None and not speed_mps > 0:
        raise ValueError(f"speed_mps must be positive, got {speed_mps}")
    home_lat, home_lon, _ = origin.to_global(home[0], home[1])
    items = [home_item(0, home_lat, home_lon, 0.0),
             takeoff_item(1, home_lat, home_lon, altitude_m)]
    phases: dict[int, Phase] = {}
    if speed_mps is not None:
        items.append(change_speed_item(len(items), speed_mps))
    task_seqs: list[tuple[int, int]] = []
    last = (home_lat, home_lon)
    for task in tasks:
        first = len(items)
        if isinstance(task, TraceTask) and style == TaskStyle.TRACE:
            lat, lon, _ = origin.to_global(task.x_m, task.y_m)
            items.append(trace_item(first, lat, lon, altitude_m, task.level,
                                    task.search_radius_m, task.max_length_m, task.piece_id))
            phases[first] = Phase.SEARCH
        elif isinstance(task, TraceTask | Waypoint):
            along = isinstance(task, TraceTask)
            for k, wp in enumerate(task_waypoints(task, tolerance_m)):
                lat, lon, _ = origin.to_global(wp.x_m, wp.y_m)
                phases[len(items)] = Phase.TRACE if along and k > 0 else Phase.TRANSIT
                items.append(waypoint_item(len(items), lat, lon, altitude_m))
        else:
            raise TypeError(f"tasks must be Waypoint or TraceTask, got {type(task).__name__}")
        last = (items[-1].lat_deg, items[-1].lon_deg)
        task_seqs.append((first, len(items) - 1))
    if end == "rtl":
        items.append(rtl_item(len(items)))
    elif end == "loiter":
        items.append(loiter_item(len(items), last[0], last[1], altitude_m))
    return MissionPlan(items, task_seqs, phases, style)


def build_mission(
    origin: Origin,
    tasks: Sequence[Waypoint | TraceTask],
    altitude_m: float,
    home: tuple[float, float] = (0.0, 0.0),
    end: str = "rtl",
) -> list[MissionItemSpec]:
    """The items of :func:`plan_mission` with contour items (``style=TRACE``)."""
    return plan_mission(origin, tasks, altitude_m, home=home, end=end).items


def fence_items(origin: Origin, region: Region, margin_m: float) -> list[MissionItemSpec]:
    """The area plus ``margin_m`` on every side as an inclusion fence: four
    ``MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION`` items (param1 = vertex count), mission
    type FENCE, counter-clockwise from the south-west corner, in ``MAV_FRAME_GLOBAL_INT``
    (fence vertices have no altitude), as PX4 and ArduPilot take them.

    >>> from econdor_gcs.core.geodesy import Origin
    >>> from econdor_gcs.core.geometry import Region
    >>> items = fence_items(Origin(47.0, 8.0, 400.0), Region(0, 100, 0, 50), 5.0)
    >>> [(it.seq, it.command, it.param1, it.mission_type) for it in items][:2]
    [(0, 5001, 4.0, 1), (1, 5001, 4.0, 1)]
    """
    if not margin_m >= 0:
        raise ValueError(f"margin_m must be >= 0, got {margin_m}")
    corners = [(region.xmin - margin_m, region.ymin - margin_m),
               (region.xmax + margin_m, region.ymin - margin_m),
               (region.xmax + margin_m, region.ymax + margin_m),
               (region.xmin - margin_m, region.ymax + margin_m)]
    items = []
    for seq, (x, y) in enumerate(corners):
        lat, lon, _ = origin.to_global(x, y)
        items.append(MissionItemSpec(
            seq, mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
            param1=float(len(corners)), x=_e7(lat), y=_e7(lon),
            mission_type=mavlink.MAV_MISSION_TYPE_FENCE))
    return items


# --------------------------------------------------------------------------------------------
# state machines


class _Machine:
    """Shared bookkeeping: outbox, one deadline, a retry budget, the outcome."""

    what = "protocol"

    def __init__(self, target_system: int, target_component: int, timeout_s: float,
                 retries: int) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self.target_system = target_system
        self.target_component = target_component
        self.timeout_s = timeout_s
        self.retries = retries
        self.done = False
        self.result: object = None
        self.error: Exception | None = None
        self.retries_used = 0  # in total, for statistics
        self._retries_left = retries
        self._deadline: float | None = None
        self._started = False
        self._outbox: list[MAVLinkMessage] = []
        self._last: MAVLinkMessage | None = None

    # -- interface --------------------------------------------------------------------------
    def poll(self, now: float) -> list[MAVLinkMessage]:
        if not self._started and not self.done:
            self._started = True
            self._start(now)
        elif not self.done and self._deadline is not None and now >= self._deadline:
            if self._retries_left > 0:
                self._retries_left -= 1
                self.retries_used += 1
                self._retry(now)
            else:
                self._fail(VehicleTimeout(
                    f"vehicle {self.target_system} did not answer {self.what} "
                    f"({self._waiting_for()}) after {self.retries} retries of "
                    f"{self.timeout_s:g} s"))
        out, self._outbox = self._outbox, []
        return out

    def receive(self, msg: MAVLinkMessage, now: float) -> None:
        if self.done or not self._started:
            return
        self._on_message(msg, now)

    def next_deadline(self) -> float | None:
        if self.done:
            return None
        if not self._started:
            return float("-inf")  # poll at once
        return self._deadline

    # -- helpers for subclasses ---------------------------------------------------------------
    def _send(self, msg: MAVLinkMessage, now: float, *, progress: bool = False) -> None:
        """Queue ``msg``, remember it for a resend, arm the deadline."""
        self._outbox.append(msg)
        self._last = msg
        self._deadline = now + self.timeout_s
        if progress:
            self._retries_left = self.retries

    def _retry(self, now: float) -> None:
        if self._last is not None:
            self._send(self._last, now)

    def _succeed(self, result: object) -> None:
        self.done = True
        self.result = result
        self._deadline = None

    def _fail(self, error: Exception) -> None:
        self.done = True
        self.error = error
        self._deadline = None

    def _mine(self, msg: MAVLinkMessage, mission_type: int) -> bool:
        return (getattr(msg, "mission_type", 0) or 0) == mission_type

    def _start(self, now: float) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _on_message(self, msg: MAVLinkMessage, now: float) -> None:  # pragma: no cover
        raise NotImplementedError

    def _waiting_for(self) -> str:
        return "no answer"


class MissionUploader(_Machine):
    """Upload ``items`` (GCS side of MISSION_COUNT -> MISSION_REQUEST(_INT) -> ... -> MISSION_ACK).

    The vehicle pulls items in any order (re-requests are answered again).  ``MISSION_REQUEST``
    (the float protocol, ArduPilot's habit) is answered with ``MISSION_ITEM_INT`` as the MAVLink
    spec allows, or with a float ``MISSION_ITEM`` if ``legacy_items`` is set.  On a timeout the
    last message (``MISSION_COUNT`` or the last item) is sent again; ``retries`` resends per
    step.  ``result`` is the number of items on success.

    The items' ``seq`` must be ``0..n-1`` in order; their ``mission_type`` is forced to
    ``mission_type``.

    ``MAV_MISSION_INVALID_SEQUENCE`` during the transfer is an answer to a stale copy of an
    item, not the end of it: ArduPilot requests an item again after one second of *its* time
    (0.1 s of wall time at a 10x speed-up), so a busy station answers both requests, and the
    second copy arrives when ArduPilot already waits for the next item; it says
    INVALID_SEQUENCE and goes on requesting. Only when no request follows within the timeout
    is it the vehicle's verdict (a vehicle with no transfer running), and the upload fails
    with it (``stale_acks`` counts the others).
    """

    what = "mission upload"

    def __init__(self, target_system: int, target_component: int,
                 items: Sequence[MissionItemSpec], mission_type: int = 0, *,
                 timeout_s: float = DEFAULT_TIMEOUT_S, retries: int = DEFAULT_RETRIES,
                 legacy_items: bool = False) -> None:
        super().__init__(target_system, target_component, timeout_s, retries)
        for i, item in enumerate(items):
            if item.seq != i:
                raise ValueError(
                    f"mission item {i} has seq {item.seq}; items must be numbered 0..n-1")
        self.items = [replace(it, mission_type=mission_type) for it in items]
        self.mission_type = mission_type
        self.legacy_items = legacy_items
        self.requested: set[int] = set()
        self.stale_acks = 0
        self._last_seq: int | None = None
        self._invalid: MAVLinkMessage | None = None

    def _count_msg(self) -> MAVLinkMessage:
        return mavlink.MAVLink_mission_count_message(
            self.target_system, self.target_component, len(self.items), self.mission_type)

    def _start(self, now: float) -> None:
        self._send(self._count_msg(), now)

    def _waiting_for(self) -> str:
        if self._last_seq is None:
            return "no MISSION_REQUEST after MISSION_COUNT"
        if self._last_seq == len(self.items) - 1:
            return "no MISSION_ACK after the last item"
        return f"no request after item {self._last_seq}"

    def _on_message(self, msg: MAVLinkMessage, now: float) -> None:
        kind = msg.get_type()
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            if not self._mine(msg, self.mission_type):
                return
            seq = msg.seq
            if not 0 <= seq < len(self.items):
                self._fail(ProtocolError(
                    f"vehicle {self.target_system} requested mission item {seq} of a "
                    f"{len(self.items)}-item mission"))
                return
            item = self.items[seq]
            if kind == "MISSION_REQUEST" and self.legacy_items:
                reply = item.to_legacy_message(self.target_system, self.target_component)
            else:
                reply = item.to_message(self.target_system, self.target_component)
            new = seq not in self.requested
            self.requested.add(seq)
            self._last_seq = seq
            self._invalid = None
            self._send(reply, now, progress=new)
        elif kind == "MISSION_ACK":
            if not self._mine(msg, self.mission_type):
                return
            if msg.type == mavlink.MAV_MISSION_ACCEPTED:
                # An ACCEPTED before the last item was asked for is a stale answer (e.g. to an
                # earlier clear); an empty mission is accepted right after the count.
                if not self.items or (len(self.items) - 1) in self.requested:
                    self._succeed(len(self.items))
                return
            if msg.type == mavlink.MAV_MISSION_INVALID_SEQUENCE and self._last_seq is not None:
                self.stale_acks += 1
                self._invalid = msg  # the verdict only if no request follows (_retry)
                return
            self._refused(msg)

    def _retry(self, now: float) -> None:
        if self._invalid is not None:
            self._refused(self._invalid)
        else:
            super()._retry(now)

    def _refused(self, msg: MAVLinkMessage) -> None:
        result = enum_name("MAV_MISSION_RESULT", msg.type)
        seq = self._last_seq
        if seq is None:
            text = (f"vehicle {self.target_system} rejected the mission "
                    f"({len(self.items)} items): {result}")
        else:
            text = (f"vehicle {self.target_system} rejected mission item {seq}: "
                    f"{result}")
        command = self.items[seq].command if seq is not None else None
        self._fail(MissionRejected(text, int(msg.type), seq, command))


class MissionDownloader(_Machine):
    """Download the vehicle's mission: MISSION_REQUEST_LIST -> MISSION_COUNT ->
    MISSION_REQUEST_INT per item -> MISSION_ITEM_INT -> our MISSION_ACK.

    ``result`` is the list of :class:`MissionItemSpec` (legacy ``MISSION_ITEM`` answers are
    converted to ``_INT`` frames).  On a timeout the last request is repeated.
    """

    what = "mission download"

    def __init__(self, target_system: int, target_component: int, mission_type: int = 0, *,
                 timeout_s: float = DEFAULT_TIMEOUT_S, retries: int = DEFAULT_RETRIES) -> None:
        super().__init__(target_system, target_component, timeout_s, retries)
        self.mission_type = mission_type
        self.count: int | None = None
        self.items: list[MissionItemSpec] = []

    def _start(self, now: float) -> None:
        self._send(mavlink.MAVLink_mission_request_list_message(
            self.target_system, self.target_component, self.mission_type), now)

    def _waiting_for(self) -> str:
        if self.count is None:
            return "no MISSION_COUNT after MISSION_REQUEST_LIST"
        return f"no mission item {len(self.items)} of {self.count}"

    def _request(self, seq: int, now: float) -> None:
        self._send(mavlink.MAVLink_mission_request_int_message(
            self.target_system, self.target_component, seq, self.mission_type), now,
            progress=True)

    def _ack(self, result: int) -> MAVLinkMessage:
        return mavlink.MAVLink_mission_ack_message(
            self.target_system, self.target_component, result, self.mission_type)

    def _on_message(self, msg: MAVLinkMessage, now: float) -> None:
        kind = msg.get_type()
        if not self._mine(msg, self.mission_type):
            return
        if kind == "MISSION_COUNT":
            if self.count is not None:
                return  # a duplicate answer to a repeated MISSION_REQUEST_LIST
            self.count = msg.count
            if self.count == 0:
                self._outbox.append(self._ack(mavlink.MAV_MISSION_ACCEPTED))
                self._succeed([])
            else:
                self._request(0, now)
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            if self.count is None or msg.seq != len(self.items):
                return  # unsolicited or a duplicate; the pending request stands
            self.items.append(MissionItemSpec.from_message(msg))
            if len(self.items) < self.count:
                self._request(len(self.items), now)
            else:
                self._outbox.append(self._ack(mavlink.MAV_MISSION_ACCEPTED))
                self._succeed(list(self.items))
        elif kind == "MISSION_ACK" and msg.type != mavlink.MAV_MISSION_ACCEPTED:
            self._fail(ProtocolError(
                f"vehicle {self.target_system} refused the mission download: "
                f"{enum_name('MAV_MISSION_RESULT', msg.type)}"))


class MissionClear(_Machine):
    """MISSION_CLEAR_ALL -> MISSION_ACK (``result`` is ``True``)."""

    what = "mission clear"

    def __init__(self, target_system: int, target_component: int, mission_type: int = 0, *,
                 timeout_s: float = DEFAULT_TIMEOUT_S, retries: int = DEFAULT_RETRIES) -> None:
        super().__init__(target_system, target_component, timeout_s, retries)
        self.mission_type = mission_type

    def _start(self, now: float) -> None:
        self._send(mavlink.MAVLink_mission_clear_all_message(
            self.target_system, self.target_component, self.mission_type), now)

    def _waiting_for(self) -> str:
        return "no MISSION_ACK after MISSION_CLEAR_ALL"

    def _on_message(self, msg: MAVLinkMessage, now: float) -> None:
        if msg.get_type() != "MISSION_ACK" or not self._mine(msg, self.mission_type):
            return
        if msg.type == mavlink.MAV_MISSION_ACCEPTED:
            self._succeed(True)
        else:
            self._fail(ProtocolError(
                f"vehicle {self.target_system} refused to clear its mission: "
                f"{enum_name('MAV_MISSION_RESULT', msg.type)}"))


class CommandSender(_Machine):
    """COMMAND_LONG -> COMMAND_ACK.

    A retry resends the command with ``confirmation`` incremented.  ``MAV_RESULT_IN_PROGRESS``
    keeps waiting (the deadline is pushed out, nothing is resent; ``progress`` holds the last
    percentage).  ``MAV_RESULT_ACCEPTED`` succeeds with the ``COMMAND_ACK`` as ``result``; any
    other result fails with a :class:`ProtocolError` naming the command and the result.
    """

    what = "command"

    def __init__(self, target_system: int, target_component: int, command: int,
                 params: Sequence[float] = (), *, timeout_s: float = DEFAULT_TIMEOUT_S,
                 retries: int = DEFAULT_RETRIES,
                 position: tuple[int, int, float] | None = None) -> None:
        super().__init__(target_system, target_component, timeout_s, retries)
        limit = 4 if position is not None else 7
        if len(params) > limit:
            raise ValueError(f"the command takes at most {limit} params, got {len(params)}")
        self.command = command
        self.params = [float(p) for p in params] + [0.0] * (7 - len(params))
        self.position = position
        """``(x, y, z)`` sends COMMAND_INT (exact int32 x/y, MAV_FRAME_GLOBAL_INT) instead of
        COMMAND_LONG."""
        self.confirmation = 0
        self.progress: int | None = None
        self.what = f"command {command_name(command)}"

    def _message(self) -> MAVLinkMessage:
        if self.position is not None:
            x, y, z = self.position
            return mavlink.MAVLink_command_int_message(
                self.target_system, self.target_component, mavlink.MAV_FRAME_GLOBAL_INT,
                self.command, 0, 0, *self.params[:4], x, y, z)
        return mavlink.MAVLink_command_long_message(
            self.target_system, self.target_component, self.command, self.confirmation % 256,
            *self.params)

    def _start(self, now: float) -> None:
        self._send(self._message(), now)

    def _retry(self, now: float) -> None:
        if self.progress is not None:  # in progress: keep waiting, do not restart the command
            self._deadline = now + self.timeout_s
            return
        self.confirmation += 1
        self._send(self._message(), now)

    def _waiting_for(self) -> str:
        return "no COMMAND_ACK" if self.progress is None else f"stalled at {self.progress} %"

    def _on_message(self, msg: MAVLinkMessage, now: float) -> None:
        if msg.get_type() != "COMMAND_ACK" or msg.command != self.command:
            return
        if msg.result == mavlink.MAV_RESULT_ACCEPTED:
            self._succeed(msg)
        elif msg.result == mavlink.MAV_RESULT_IN_PROGRESS:
            self.progress = msg.progress
            self._deadline = now + self.timeout_s
            self._retries_left = self.retries
        else:
            self._fail(CommandRejected(
                f"vehicle {self.target_system} answered {command_name(self.command)} with "
                f"{enum_name('MAV_RESULT', msg.result)}", self.command, int(msg.result)))
