"""Mission files for ordinary tools: QGC WPL 110 and QGroundControl ``.plan``, read and written.

Reading validates what an autopilot would choke on and names the line (WPL) or the key
(``.plan``) at fault: a wrong header or file type, missing columns or keys, numbers that are
not numbers, NaN or out-of-range coordinates, unknown frames and commands, items out of order.
Writing then reading gives back exactly the same :class:`~econdor_gcs.link.transfer.MissionItemSpec`
values (latitude/longitude are degE7 integers; params and altitudes are written as the shortest
text that reads back to the same float).

QGC WPL 110 (``.waypoints``, the plain-text format of mavlink.io/en/file_formats and of
``pymavlink.mavwp.MAVWPLoader``, which MAVProxy's ``wp load`` uses)::

    QGC WPL 110
    INDEX  CURRENT  FRAME  COMMAND  P1  P2  P3  P4  LAT/X  LON/Y  ALT/Z  AUTOCONTINUE

one tab-separated line per item. The file holds float ``MISSION_ITEM`` values, so the ``_INT``
frames are written as their float twins (``MAV_FRAME_GLOBAL_RELATIVE_ALT_INT`` 6 -> 3,
``MAV_FRAME_GLOBAL_INT`` 5 -> 0, ``MAV_FRAME_GLOBAL_TERRAIN_ALT_INT`` 11 -> 10); MAVProxy uploads
the file's frame as is. Latitude / longitude get 8 decimals (degE7 is exact). WPL holds only
the mission: no geofence, no rally points.

QGroundControl ``.plan`` (JSON, docs.qgroundcontrol.com "Plan File Format"): item 0, the home
item, becomes ``mission.plannedHomePosition`` ``[lat, lon, alt AMSL]`` and is not in ``items``;
every other item is a ``SimpleItem`` with ``params`` ``[p1, p2, p3, p4, lat, lon, alt]`` (NaN
written as ``null``, as QGC does), a 1-based ``doJumpId`` and the float frame. The contour command
``MAV_CMD_WAYPOINT_USER_1`` (31000) is kept as a plain ``SimpleItem``. ``geoFence.polygons``
(``{"inclusion", "polygon": [[lat, lon], ...], "version": 1}``), ``geoFence.circles`` and
``rallyPoints.points`` (``[lat, lon, alt above home]``) are read into fence and rally items as
MAVSDK's QGC-plan import makes them (``MAV_CMD_NAV_FENCE_*`` vertices with the vertex count in
param1; ``MAV_CMD_NAV_RALLY_POINT``), ready for a ``MISSION_COUNT`` of mission type FENCE/RALLY.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from econdor_gcs.errors import EcondorError
from econdor_gcs.link.codec import mavlink
from econdor_gcs.link.transfer import FLOAT_TO_INT_FRAME, INT_TO_FLOAT_FRAME, MissionItemSpec

__all__ = [
    "MissionFile",
    "is_global_frame",
    "is_home_item",
    "items_to_plan",
    "items_to_wpl",
    "plan_to_file",
    "plan_to_items",
    "read_mission_file",
    "read_plan",
    "read_wpl",
    "write_plan",
    "write_wpl",
]

WPL_HEADER = "QGC WPL 110"
_WPL_HEADERS = ("QGC WPL 110", "QGC WPL 120")  # 120 (mavros) has the same columns

NAV_WAYPOINT = mavlink.MAV_CMD_NAV_WAYPOINT
NAV_RTL = mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH
FENCE_VERTEX_IN = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
FENCE_VERTEX_OUT = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
FENCE_CIRCLE_IN = mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION
FENCE_CIRCLE_OUT = mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION
RALLY_POINT = mavlink.MAV_CMD_NAV_RALLY_POINT

# _INT frame -> float frame (the files hold float MISSION_ITEM values)
_INT_TO_FLOAT = INT_TO_FLOAT_FRAME
_FLOAT_TO_INT = FLOAT_TO_INT_FRAME
_GLOBAL_FRAMES = frozenset((*_INT_TO_FLOAT, *_FLOAT_TO_INT))
# QGC's AltitudeMode: 1 relative to home, 2 absolute (AMSL), 4 terrain frame
_ALTITUDE_MODE = {mavlink.MAV_FRAME_GLOBAL: 2, mavlink.MAV_FRAME_GLOBAL_INT: 2,
                  mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT: 1,
                  mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: 1,
                  mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT: 4,
                  mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: 4}


def _enum_values(name: str) -> frozenset[int]:
    return frozenset(k for k, e in mavlink.enums[name].items() if not e.name.endswith("ENUM_END"))


KNOWN_FRAMES = _enum_values("MAV_FRAME")
KNOWN_COMMANDS = _enum_values("MAV_CMD")

PathLike = str | Path


@dataclass
class MissionFile:
    """What a mission file holds: the mission, and (``.plan`` only) geofence and rally items.

    ``home_alt_amsl_m`` is the plan's planned home altitude (None for WPL).
    """

    items: list[MissionItemSpec]
    fence: list[MissionItemSpec] = field(default_factory=list)
    rally: list[MissionItemSpec] = field(default_factory=list)
    home_alt_amsl_m: float | None = None


# --------------------------------------------------------------------------------------------
# shared checks


def _num(v: float) -> str:
    """Shortest text that reads back (``float(text)``) to the same value."""
    v = float(v)
    return "nan" if math.isnan(v) else repr(v)


def is_global_frame(frame: int) -> bool:
    """x / y of ``frame`` are latitude / longitude."""
    return frame in _GLOBAL_FRAMES


_FLOAT32_MAX = 3.4028234663852886e38
_UINT = {"seq": 0xFFFF, "command": 0xFFFF, "frame": 0xFF, "current": 0xFF,
         "autocontinue": 0xFF}


def _checked(item: MissionItemSpec, where: str) -> MissionItemSpec:
    """``item`` if it fits a MISSION_ITEM_INT (and its position is on the globe), else an
    :class:`EcondorError` naming the field.

    >>> _checked(MissionItemSpec(0, 6, 16, x=900_000_001), "f line 2")
    Traceback (most recent call last):
    ...
    econdor_gcs.errors.EcondorError: f line 2: latitude 90.0000001 out of range [-90, 90]
    """
    for name, top in _UINT.items():
        v = getattr(item, name)
        if not 0 <= v <= top:
            raise EcondorError(f"{where}: {name} {v} out of range [0, {top}]")
    for name in ("param1", "param2", "param3", "param4", "z"):
        v = getattr(item, name)
        if math.isfinite(v) and abs(v) > _FLOAT32_MAX:
            raise EcondorError(f"{where}: {name} {v:g} does not fit a float32")
    if is_global_frame(item.frame):
        if not -90 * 10**7 <= item.x <= 90 * 10**7:
            raise EcondorError(f"{where}: latitude {item.x / 1e7} out of range [-90, 90]")
        if not -180 * 10**7 <= item.y <= 180 * 10**7:
            raise EcondorError(f"{where}: longitude {item.y / 1e7} out of range [-180, 180]")
    for name in ("x", "y"):
        v = getattr(item, name)
        if not -(2**31) <= v < 2**31:
            raise EcondorError(f"{where}: {name} {v} does not fit an int32")
    return item


def _check_item(where: str, seq: int, expected_seq: int, frame: int, command: int,
                lat: float, lon: float, z: float) -> None:
    """One item's sanity: order, known frame and command, coordinates in range."""
    if seq != expected_seq:
        raise EcondorError(f"{where}: item index {seq}, expected {expected_seq} (items must "
                           "be numbered 0, 1, 2, ... in order)")
    if frame not in KNOWN_FRAMES:
        raise EcondorError(f"{where}: unknown frame {frame}")
    if command not in KNOWN_COMMANDS:
        raise EcondorError(f"{where}: unknown command {command}")
    if is_global_frame(frame):
        if not (math.isfinite(lat) and math.isfinite(lon)):
            raise EcondorError(f"{where}: latitude/longitude must be finite, got {lat}, {lon}")
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise EcondorError(f"{where}: latitude/longitude out of range: {lat}, {lon}")
        if not math.isfinite(z):
            raise EcondorError(f"{where}: altitude must be finite, got {z}")


# --------------------------------------------------------------------------------------------
# QGC WPL 110


def items_to_wpl(items: Sequence[MissionItemSpec]) -> str:
    """The mission as QGC WPL 110 text (header line + one tab-separated line per item).

    ``_INT`` frames are written as their float twins (6 -> 3, 5 -> 0, 11 -> 10); for global
    frames x / y (degE7) become latitude / longitude with 8 decimals, otherwise x / y are
    written as they are.
    """
    lines = [WPL_HEADER]
    for it in items:
        if is_global_frame(it.frame):
            x, y = f"{it.x / 1e7:.8f}", f"{it.y / 1e7:.8f}"
        else:
            x, y = _num(it.x), _num(it.y)
        cols = [str(int(it.seq)), str(int(it.current)), str(_INT_TO_FLOAT.get(it.frame, it.frame)),
                str(int(it.command)), _num(it.param1), _num(it.param2), _num(it.param3),
                _num(it.param4), x, y, _num(it.z), str(int(it.autocontinue))]
        lines.append("\t".join(cols))
    return "\n".join(lines) + "\n"


def write_wpl(path: PathLike, items: Sequence[MissionItemSpec]) -> Path:
    path = Path(path)
    path.write_text(items_to_wpl(items), encoding="utf-8")
    return path


def _text_and_name(path_or_text: PathLike) -> tuple[str, str]:
    if isinstance(path_or_text, Path) or "\n" not in path_or_text:
        path = Path(path_or_text)
        try:
            return path.read_text(encoding="utf-8"), str(path)
        except OSError as exc:
            raise EcondorError(f"{path}: cannot read ({exc.strerror or exc})") from None
        except UnicodeDecodeError:
            raise EcondorError(f"{path}: not a text file") from None
    return path_or_text, "<text>"


def read_wpl(path_or_text: PathLike, *, int_frames: bool = False) -> list[MissionItemSpec]:
    """Parse QGC WPL 110 (a path, or the text itself if it contains a newline).

    The file's frame is kept (3 stays 3) unless ``int_frames`` is set, which maps the float
    global frames back to the ``_INT`` ones (3 -> 6, 0 -> 5, 10 -> 11), giving back exactly what
    :func:`items_to_wpl` was given. Latitude / longitude of global frames become degE7 ints.
    Like MAVProxy, values may be separated by any whitespace, and blank lines and ``#`` comment
    lines are skipped. Errors name the file and line.
    """
    text, name = _text_and_name(path_or_text)
    return _parse_wpl(text, name, int_frames)


def _parse_wpl(text: str, name: str, int_frames: bool) -> list[MissionItemSpec]:
    lines = text.splitlines()
    header = lines[0].strip() if lines else ""
    if header not in _WPL_HEADERS:
        raise EcondorError(
            f"{name} line 1: not a QGC WPL 110 file (header {header[:40]!r}, "
            f"expected {WPL_HEADER!r})")
    items: list[MissionItemSpec] = []
    for lineno, raw in enumerate(lines[1:], start=2):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        where = f"{name} line {lineno}"
        cols = line.split()
        if len(cols) != 12:
            raise EcondorError(f"{where}: expected 12 tab-separated values, got {len(cols)}")
        try:
            seq, current, frame, command = (int(c) for c in cols[:4])
            p1, p2, p3, p4, x, y, z = (float(c) for c in cols[4:11])
            autocontinue = int(cols[11])
        except ValueError:
            raise EcondorError(f"{where}: not a number in {line[:60]!r}") from None
        _check_item(where, seq, len(items), frame, command, x, y, z)
        if current not in (0, 1) or autocontinue not in (0, 1):
            raise EcondorError(f"{where}: CURRENT and AUTOCONTINUE must be 0 or 1")
        if is_global_frame(frame):
            xi, yi = round(x * 1e7), round(y * 1e7)
        else:
            xi, yi = round(x) if math.isfinite(x) else 0, round(y) if math.isfinite(y) else 0
        if int_frames:
            frame = _FLOAT_TO_INT.get(frame, frame)
        items.append(_checked(MissionItemSpec(
            seq=seq, frame=frame, command=command, current=current, autocontinue=autocontinue,
            param1=p1, param2=p2, param3=p3, param4=p4, x=int(xi), y=int(yi), z=z), where))
    return items


# --------------------------------------------------------------------------------------------
# QGroundControl .plan


def is_home_item(items: Sequence[MissionItemSpec]) -> bool:
    """Item 0 is the home item (DESIGN.md §4: seq 0, a NAV_WAYPOINT in a global frame)."""
    return bool(items) and items[0].seq == 0 and items[0].command == NAV_WAYPOINT \
        and is_global_frame(items[0].frame)


def _json_num(v: float) -> float | int | None:
    v = float(v)
    if not math.isfinite(v):
        return None
    return int(v) if v == int(v) and abs(v) < 1e15 else v


def items_to_plan(
    items: Sequence[MissionItemSpec], *, firmware_type: int = mavlink.MAV_AUTOPILOT_PX4,
    vehicle_type: int = mavlink.MAV_TYPE_QUADROTOR, cruise_speed: float = 15.0,
    hover_speed: float = 5.0, home_alt_amsl_m: float | None = None,
    fence_polygons: Sequence[Sequence[tuple[float, float]]] = (),
    rally_points: Sequence[tuple[float, float, float]] = (),
) -> dict[str, Any]:
    """The mission as a QGroundControl ``.plan`` document (a JSON-ready dict).

    Item 0, if it is the home item, becomes ``plannedHomePosition`` ``[lat, lon, alt]`` (alt =
    ``home_alt_amsl_m`` if given, QGC's convention, else the item's own z) and is left out of
    ``items``; without a home item the first positioned item gives ``plannedHomePosition``.
    ``fence_polygons`` are inclusion polygons of ``(lat, lon)`` vertices; ``rally_points``
    are ``(lat, lon, alt above home)``.
    """
    home_alt = home_alt_amsl_m
    body = list(items)
    if is_home_item(body):
        home = body.pop(0)
        planned = [home.x / 1e7, home.y / 1e7, float(home.z if home_alt is None else home_alt)]
    else:
        first = next((it for it in body if is_global_frame(it.frame) and (it.x or it.y)), None)
        planned = ([first.x / 1e7, first.y / 1e7, float(home_alt or 0.0)] if first
                   else [0.0, 0.0, float(home_alt or 0.0)])
    plan_items: list[dict[str, Any]] = []
    for jump_id, it in enumerate(body, start=1):
        glob = is_global_frame(it.frame)
        lat = it.x / 1e7 if glob else float(it.x)
        lon = it.y / 1e7 if glob else float(it.y)
        entry: dict[str, Any] = {}
        if glob and it.command != NAV_RTL:
            entry.update(AMSLAltAboveTerrain=None, Altitude=_json_num(it.z),
                         AltitudeMode=_ALTITUDE_MODE[it.frame])
        entry.update(
            autoContinue=bool(it.autocontinue), command=int(it.command), doJumpId=jump_id,
            frame=_INT_TO_FLOAT.get(it.frame, it.frame),
            params=[_json_num(it.param1), _json_num(it.param2), _json_num(it.param3),
                    _json_num(it.param4), lat, lon, _json_num(it.z)],
            type="SimpleItem")
        plan_items.append(entry)
    return {
        "fileType": "Plan",
        "geoFence": {"circles": [],
                     "polygons": [{"inclusion": True, "polygon": [[la, lo] for la, lo in poly],
                                   "version": 1} for poly in fence_polygons],
                     "version": 2},
        "groundStation": "QGroundControl",
        "mission": {
            "cruiseSpeed": cruise_speed,
            "firmwareType": firmware_type,
            "globalPlanAltitudeMode": 1,
            "hoverSpeed": hover_speed,
            "items": plan_items,
            "plannedHomePosition": planned,
            "vehicleType": vehicle_type,
            "version": 2,
        },
        "rallyPoints": {"points": [[la, lo, alt] for la, lo, alt in rally_points], "version": 2},
        "version": 1,
    }


def write_plan(path: PathLike, items: Sequence[MissionItemSpec], **kwargs: Any) -> Path:
    """Write :func:`items_to_plan` as indented JSON (keyword arguments as there)."""
    path = Path(path)
    doc = items_to_plan(items, **kwargs)
    path.write_text(json.dumps(doc, indent=4, allow_nan=False) + "\n", encoding="utf-8")
    return path


def _float(v: Any, where: str) -> float:
    if v is None:
        return math.nan
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise EcondorError(f"{where}: expected a number, got {v!r}")
    return float(v)


def _int(v: Any, where: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise EcondorError(f"{where}: expected an integer, got {v!r}")
    return v


def _latlon(v: Any, where: str, n: int = 2) -> list[float]:
    if not isinstance(v, list) or len(v) != n:
        raise EcondorError(f"{where}: expected [lat, lon{', alt' if n == 3 else ''}]")
    vals = [_float(x, f"{where}[{i}]") for i, x in enumerate(v)]
    lat, lon = vals[0], vals[1]
    if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90
            and -180 <= lon <= 180):
        raise EcondorError(f"{where}: latitude/longitude out of range or not finite: "
                           f"{lat}, {lon}")
    return vals


def _version(doc: Any, expected: int, where: str) -> None:
    if doc.get("version") != expected:
        raise EcondorError(f"{where}.version: expected {expected}, got {doc.get('version')!r}")


def _fence_items(fence: Any, name: str) -> list[MissionItemSpec]:
    where = f"{name}: geoFence"
    if not isinstance(fence, dict):
        raise EcondorError(f"{where}: not an object")
    _version(fence, 2, where)
    out: list[MissionItemSpec] = []
    polygons = fence.get("polygons", [])
    if not isinstance(polygons, list):
        raise EcondorError(f"{where}.polygons: expected a list")
    for i, poly in enumerate(polygons):
        w = f"{where}.polygons[{i}]"
        if not isinstance(poly, dict) or not isinstance(poly.get("polygon"), list):
            raise EcondorError(f"{w}: expected an object with a polygon list")
        vertices = [_latlon(p, f"{w}.polygon[{k}]") for k, p in enumerate(poly["polygon"])]
        if len(vertices) < 3:
            raise EcondorError(f"{w}.polygon: a polygon needs at least 3 vertices")
        cmd = FENCE_VERTEX_IN if poly.get("inclusion", True) else FENCE_VERTEX_OUT
        for lat, lon in vertices:
            out.append(MissionItemSpec(len(out), mavlink.MAV_FRAME_GLOBAL_INT, cmd,
                                       param1=float(len(vertices)), x=round(lat * 1e7),
                                       y=round(lon * 1e7),
                                       mission_type=mavlink.MAV_MISSION_TYPE_FENCE))
    circles = fence.get("circles", [])
    if not isinstance(circles, list):
        raise EcondorError(f"{where}.circles: expected a list")
    for i, c in enumerate(circles):
        w = f"{where}.circles[{i}]"
        circle = c.get("circle") if isinstance(c, dict) else None
        if not isinstance(circle, dict):
            raise EcondorError(f"{w}: expected an object with a circle")
        lat, lon = _latlon(circle.get("center"), f"{w}.circle.center")
        radius = _float(circle.get("radius"), f"{w}.circle.radius")
        if not (math.isfinite(radius) and radius > 0):
            raise EcondorError(f"{w}.circle.radius: must be > 0, got {radius}")
        cmd = FENCE_CIRCLE_IN if c.get("inclusion", True) else FENCE_CIRCLE_OUT
        out.append(MissionItemSpec(len(out), mavlink.MAV_FRAME_GLOBAL_INT, cmd, param1=radius,
                                   x=round(lat * 1e7), y=round(lon * 1e7),
                                   mission_type=mavlink.MAV_MISSION_TYPE_FENCE))
    return out


def _rally_items(rally: Any, name: str) -> list[MissionItemSpec]:
    where = f"{name}: rallyPoints"
    if not isinstance(rally, dict):
        raise EcondorError(f"{where}: not an object")
    _version(rally, 2, where)
    points = rally.get("points", [])
    if not isinstance(points, list):
        raise EcondorError(f"{where}.points: expected a list")
    out = []
    for i, p in enumerate(points):
        lat, lon, alt = _latlon(p, f"{where}.points[{i}]", n=3)
        out.append(MissionItemSpec(i, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, RALLY_POINT,
                                   x=round(lat * 1e7), y=round(lon * 1e7),
                                   z=alt if math.isfinite(alt) else 0.0,
                                   mission_type=mavlink.MAV_MISSION_TYPE_RALLY))
    return out


def plan_to_file(doc: Any, *, name: str = "<plan>", int_frames: bool = False) -> MissionFile:
    """Mission, fence and rally items of a ``.plan`` document (see :func:`read_plan`)."""
    if not isinstance(doc, dict) or doc.get("fileType") != "Plan":
        raise EcondorError(f"{name}: not a QGroundControl plan (fileType is not \"Plan\")")
    _version(doc, 1, name)
    mission = doc.get("mission")
    if not isinstance(mission, dict) or not isinstance(mission.get("items"), list):
        raise EcondorError(f"{name}: plan has no mission.items list")
    _version(mission, 2, f"{name}: mission")

    def frame_of(f: int) -> int:
        return _FLOAT_TO_INT.get(f, f) if int_frames else f

    items: list[MissionItemSpec] = []
    home = mission.get("plannedHomePosition")
    home_alt = None
    if home is not None:
        lat, lon, home_alt = _latlon(home, f"{name}: mission.plannedHomePosition", n=3)
        items.append(MissionItemSpec(0, frame_of(mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT),
                                     NAV_WAYPOINT, current=1, x=round(lat * 1e7),
                                     y=round(lon * 1e7), z=0.0))
    for i, entry in enumerate(mission["items"]):
        where = f"{name}: mission.items[{i}]"
        if not isinstance(entry, dict):
            raise EcondorError(f"{where}: not an object")
        if entry.get("type") != "SimpleItem":
            raise EcondorError(
                f"{where}: {entry.get('type')!r} items are not supported (only SimpleItem)")
        for key in ("command", "frame", "params"):
            if key not in entry:
                raise EcondorError(f"{where}: missing key {key!r}")
        params = entry["params"]
        if not isinstance(params, list) or len(params) != 7:
            raise EcondorError(f"{where}: params must be a list of 7 values")
        frame = _int(entry["frame"], f"{where}.frame")
        command = _int(entry["command"], f"{where}.command")
        p = [_float(v, f"{where}.params[{k}]") for k, v in enumerate(params)]
        _check_item(where, len(items), len(items), frame, command, p[4], p[5],
                    p[6] if math.isfinite(p[6]) else 0.0)
        scale = 1e7 if is_global_frame(frame) else 1.0
        x, y = (round(v * scale) if math.isfinite(v) else 0 for v in p[4:6])
        items.append(_checked(MissionItemSpec(
            seq=len(items), frame=frame_of(frame), command=command,
            current=1 if not items else 0, autocontinue=int(bool(entry.get("autoContinue", True))),
            param1=p[0], param2=p[1], param3=p[2], param4=p[3], x=int(x), y=int(y),
            z=p[6] if math.isfinite(p[6]) else 0.0), where))
    fence = _fence_items(doc["geoFence"], name) if "geoFence" in doc else []
    rally = _rally_items(doc["rallyPoints"], name) if "rallyPoints" in doc else []
    return MissionFile(items, fence, rally, home_alt)


def plan_to_items(doc: Any, *, name: str = "<plan>",
                  int_frames: bool = False) -> list[MissionItemSpec]:
    """Mission items of a ``.plan`` document (see :func:`read_plan`)."""
    return plan_to_file(doc, name=name, int_frames=int_frames).items


def _load_plan(path_or_doc: PathLike | dict[str, Any]) -> tuple[Any, str]:
    if isinstance(path_or_doc, dict):
        return path_or_doc, "<plan>"
    text, name = _text_and_name(Path(path_or_doc))
    try:
        return json.loads(text), name
    except json.JSONDecodeError as exc:
        raise EcondorError(f"{name} line {exc.lineno}: not valid JSON ({exc.msg})") from None


def read_plan(path_or_doc: PathLike | dict[str, Any], *,
              int_frames: bool = False) -> list[MissionItemSpec]:
    """Read a ``.plan``'s mission back into items.

    ``plannedHomePosition`` becomes item 0 (a ``NAV_WAYPOINT`` with ``current = 1`` at 0 m
    above home, the shape of :func:`~econdor_gcs.link.transfer.home_item`), the ``SimpleItem``\\ s
    follow in order, renumbered. Frames as in the file unless ``int_frames`` (3 -> 6, ...);
    ``null`` params read as NaN (altitude: 0). ComplexItems (surveys, ...) are refused.
    """
    doc, name = _load_plan(path_or_doc)
    return plan_to_items(doc, name=name, int_frames=int_frames)


def read_mission_file(path: PathLike, *, int_frames: bool = True) -> MissionFile:
    """A WPL or ``.plan`` file (by its first non-blank character: ``{`` is a plan), with the
    ``_INT`` frames a MISSION_ITEM_INT upload needs (unless ``int_frames`` is False)."""
    path = Path(path)
    text, name = _text_and_name(path)
    if text.lstrip().startswith("{"):
        doc, name = _load_plan(path)
        return plan_to_file(doc, name=name, int_frames=int_frames)
    return MissionFile(_parse_wpl(text, name, int_frames))


def describe(mfile: MissionFile) -> list[str]:
    """A few lines saying what a mission file holds (for ``econdor import``)."""
    items = mfile.items
    names: dict[str, int] = {}
    for it in items:
        entry = mavlink.enums["MAV_CMD"].get(it.command)
        name = entry.name.removeprefix("MAV_CMD_") if entry is not None else str(it.command)
        names[name] = names.get(name, 0) + 1
    lines = [f"mission: {len(items)} items ("
             + ", ".join(f"{n} {name}" for name, n in names.items()) + ")"]
    glob = [it for it in items[1:] if is_global_frame(it.frame) and (it.x or it.y)]
    if glob:
        lat = [it.x / 1e7 for it in glob]
        lon = [it.y / 1e7 for it in glob]
        alts = sorted({it.z for it in glob})
        lines.append(f"  extent lat {min(lat):.7f}..{max(lat):.7f}, lon {min(lon):.7f}.."
                     f"{max(lon):.7f}; altitudes {', '.join(f'{a:g}' for a in alts[:4])}"
                     f"{' ...' if len(alts) > 4 else ''} m")
    if mfile.fence:
        lines.append(f"fence: {len(mfile.fence)} items")
    if mfile.rally:
        lines.append(f"rally: {len(mfile.rally)} points")
    return lines
