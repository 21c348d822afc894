"""Mission items and plans: what the station uploads, without the protocol that uploads it.

:class:`MissionItemSpec` (one ``MISSION_ITEM_INT`` without its addressing), the item
builders (home, takeoff, waypoint, contour item, sensor lag, speed, RTL, loiter, fence
vertices) and :func:`plan_mission`, a vehicle's mission "item 0 home, takeoff,
[DO_CHANGE_SPEED], the tasks, the end item" (DESIGN.md §4). The transfer protocols are in
:mod:`.mission`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ..core.geodesy import Origin
from ..core.geometry import Region
from ..core.tasks import SENSOR_LAG_COMMAND, Phase, Task, TaskStyle, TraceTask, Waypoint
from ..core.waypoints import task_waypoints
from .codec import MAVLinkMessage, mavlink

__all__ = [
    "FLOAT_TO_INT_FRAME",
    "INT_TO_FLOAT_FRAME",
    "MAV_CMD_WAYPOINT_USER_1",
    "MissionItemSpec",
    "MissionPlan",
    "SENSOR_LAG_COMMAND",
    "build_mission",
    "change_speed_item",
    "command_name",
    "enum_name",
    "fence_items",
    "home_item",
    "loiter_item",
    "plan_mission",
    "rtl_item",
    "sensor_lag_item",
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


def sensor_lag_item(seq: int, lag_s: float, unknown: bool = False) -> MissionItemSpec:
    """The sensor lag for the onboard tracer from this item on: :data:`SENSOR_LAG_COMMAND`
    (``MAV_CMD_USER_4``, 31013), param1 = the lag (s), param2 = 1 when the sensor lags by
    an amount not known yet (param1 then 0; ``TraceTask.lag_unknown``), no position, in
    ``MAV_FRAME_MISSION`` as :func:`change_speed_item`.

    >>> it = sensor_lag_item(3, 0.75)
    >>> (it.command, it.param1, it.param2, it.x, it.y, it.z)
    (31013, 0.75, 0.0, 0, 0, 0.0)
    >>> sensor_lag_item(3, 0.0, unknown=True).param2
    1.0
    """
    return MissionItemSpec(seq, mavlink.MAV_FRAME_MISSION, SENSOR_LAG_COMMAND,
                           param1=float(lag_s), param2=1.0 if unknown else 0.0)


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
        With ``style=TRACE`` a trace item whose task carries a ``sensor_lag_s`` (or
        ``lag_unknown``) other than the last one told in this mission comes after a
        :func:`sensor_lag_item`, which
        belongs to no task (``task_seqs``, ``item_phases``: as DO_CHANGE_SPEED).
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
    told: tuple[float, bool] | None = None
    for task in tasks:
        if isinstance(task, TraceTask) and style == TaskStyle.TRACE:
            if task.sensor_lag_s is not None and (task.sensor_lag_s, task.lag_unknown) != told:
                told = (task.sensor_lag_s, task.lag_unknown)
                items.append(sensor_lag_item(len(items), *told))
            first = len(items)
            lat, lon, _ = origin.to_global(task.x_m, task.y_m)
            items.append(trace_item(first, lat, lon, altitude_m, task.level,
                                    task.search_radius_m, task.max_length_m, task.piece_id))
            phases[first] = Phase.SEARCH
        elif isinstance(task, TraceTask | Waypoint):
            first = len(items)
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


MISSION_FENCE_MARGIN_M = 5.0
"""The inclusion fence every vehicle of a run gets: the mission area plus this on every side
(the station uploads it; the in-process executor flies inside the same fence)."""


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
