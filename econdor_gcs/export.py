"""Export a run's missions for ordinary tools: QGC WPL 110, QGroundControl ``.plan``, GeoJSON.

The MAVLink run saves every mission it sends as ``missions/iter{NN}_v{sysid}.json`` (a JSON list
of :class:`~econdor_gcs.link.mission.MissionItemSpec` dicts, absolute lat/lon in degE7), so the
exports need no mission YAML.

Formats
-------
QGC WPL 110 (``.waypoints``, the plain-text format of mavlink.io/en/file_formats and of
``pymavlink.mavwp.MAVWPLoader``, which MAVProxy's ``wp load`` uses)::

    QGC WPL 110
    INDEX  CURRENT  FRAME  COMMAND  P1  P2  P3  P4  LAT/X  LON/Y  ALT/Z  AUTOCONTINUE

one tab-separated line per item.  The file holds float ``MISSION_ITEM`` values, so the ``_INT``
frames are written as their float twins (``MAV_FRAME_GLOBAL_RELATIVE_ALT_INT`` 6 -> 3,
``MAV_FRAME_GLOBAL_INT`` 5 -> 0, ``MAV_FRAME_GLOBAL_TERRAIN_ALT_INT`` 11 -> 10); MAVProxy uploads
the file's frame as is.  Latitude / longitude get 8 decimals (degE7 is exact), params and
altitude the shortest text that reads back to the same float (``nan`` allowed).

QGroundControl ``.plan`` (JSON, docs.qgroundcontrol.com "Plan File Format"): item 0, the home
item, becomes ``mission.plannedHomePosition`` ``[lat, lon, alt]`` and is not in ``items``;
every other item is a ``SimpleItem`` with ``params`` ``[p1, p2, p3, p4, lat, lon, alt]`` (NaN
written as ``null``, as QGC does), a 1-based ``doJumpId`` and the float frame.  The contour
command ``MAV_CMD_WAYPOINT_USER_1`` (31000) is kept as a plain ``SimpleItem`` with its params
and position: QGC has no editor for it and shows it as an unknown/user command, but loads,
keeps and uploads it unchanged.

GeoJSON (RFC 7946, positions ``[lon, lat]``): one ``LineString`` per vehicle from
``samples.csv``, ``Point`` features for mission waypoints and trace start points, and the area
boundary ``Polygon`` when the run directory tells it.
"""

from __future__ import annotations

import argparse
import json
import math
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d

from .errors import EcondorError
from .link.mission import MissionItemSpec

__all__ = [
    "SavedMission",
    "export_cli",
    "find_missions",
    "geojson_for_run",
    "items_to_plan",
    "items_to_wpl",
    "load_mission_file",
    "plan_to_items",
    "read_plan",
    "read_wpl",
    "write_geojson",
    "write_plan",
    "write_wpl",
]

WPL_HEADER = "QGC WPL 110"
_WPL_HEADERS = ("QGC WPL 110", "QGC WPL 120")  # 120 (mavros) has the same columns

MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_LOITER_UNLIM = 17
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_WAYPOINT_USER_1 = 31000
MAV_AUTOPILOT_GENERIC = 0
MAV_AUTOPILOT_PX4 = 12
MAV_TYPE_QUADROTOR = 2

# MAV_FRAME: _INT frame -> float frame (the files hold float MISSION_ITEM values)
_INT_TO_FLOAT = {5: 0, 6: 3, 11: 10}
_FLOAT_TO_INT = {v: k for k, v in _INT_TO_FLOAT.items()}
_GLOBAL_FRAMES = frozenset((0, 3, 5, 6, 10, 11))
# QGC's AltitudeMode: 1 relative to home, 2 absolute (AMSL), 4 terrain frame
_ALTITUDE_MODE = {0: 2, 5: 2, 3: 1, 6: 1, 10: 4, 11: 4}

PathLike = str | Path


# --------------------------------------------------------------------------------------------
# QGC WPL 110


def _num(v: float) -> str:
    """Shortest text that reads back (``float(text)``) to the same value."""
    v = float(v)
    return "nan" if math.isnan(v) else repr(v)


def _is_global(frame: int) -> bool:
    return frame in _GLOBAL_FRAMES


def items_to_wpl(items: Sequence[MissionItemSpec]) -> str:
    """The mission as QGC WPL 110 text (header line + one tab-separated line per item).

    ``_INT`` frames are written as their float twins (6 -> 3, 5 -> 0, 11 -> 10); for global
    frames x / y (degE7) become latitude / longitude with 8 decimals, otherwise x / y are
    written as they are.
    """
    lines = [WPL_HEADER]
    for it in items:
        if _is_global(it.frame):
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
    if _is_global(item.frame):
        if not -90 * 10**7 <= item.x <= 90 * 10**7:
            raise EcondorError(f"{where}: latitude {item.x / 1e7} out of range [-90, 90]")
        if not -180 * 10**7 <= item.y <= 180 * 10**7:
            raise EcondorError(f"{where}: longitude {item.y / 1e7} out of range [-180, 180]")
    for name in ("x", "y"):
        v = getattr(item, name)
        if not -(2**31) <= v < 2**31:
            raise EcondorError(f"{where}: {name} {v} does not fit an int32")
    return item


def read_wpl(path_or_text: PathLike, *, int_frames: bool = False) -> list[MissionItemSpec]:
    """Parse QGC WPL 110 (a path, or the text itself if it contains a newline).

    The file's frame is kept (3 stays 3) unless ``int_frames`` is set, which maps the float
    global frames back to the ``_INT`` ones (3 -> 6, 0 -> 5, 10 -> 11), giving back exactly what
    :func:`items_to_wpl` was given.  Latitude / longitude of global frames become degE7 ints.
    Like MAVProxy, values may be separated by any whitespace, and blank lines and ``#`` comment
    lines are skipped.  Errors name the file and line.
    """
    text, name = _text_and_name(path_or_text)
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
        cols = line.split()
        if len(cols) != 12:
            raise EcondorError(
                f"{name} line {lineno}: expected 12 tab-separated values, got {len(cols)}")
        try:
            seq, current, frame, command = (int(c) for c in cols[:4])
            p1, p2, p3, p4, x, y, z = (float(c) for c in cols[4:11])
            autocontinue = int(cols[11])
        except ValueError:
            raise EcondorError(f"{name} line {lineno}: not a number in {line[:60]!r}") from None
        if _is_global(frame):
            if not (math.isfinite(x) and math.isfinite(y)):
                raise EcondorError(f"{name} line {lineno}: latitude/longitude must be finite")
            xi, yi = round(x * 1e7), round(y * 1e7)
        else:
            xi, yi = round(x) if math.isfinite(x) else 0, round(y) if math.isfinite(y) else 0
        if int_frames:
            frame = _FLOAT_TO_INT.get(frame, frame)
        items.append(_checked(MissionItemSpec(
            seq=seq, frame=frame, command=command, current=current, autocontinue=autocontinue,
            param1=p1, param2=p2, param3=p3, param4=p4, x=int(xi), y=int(yi), z=z),
            f"{name} line {lineno}"))
    return items


# --------------------------------------------------------------------------------------------
# QGroundControl .plan


def _is_home(items: Sequence[MissionItemSpec]) -> bool:
    """Item 0 is the home item (DESIGN.md §4: seq 0, a NAV_WAYPOINT in a global frame)."""
    return bool(items) and items[0].seq == 0 and items[0].command == MAV_CMD_NAV_WAYPOINT \
        and _is_global(items[0].frame)


def _json_num(v: float) -> float | int | None:
    v = float(v)
    if not math.isfinite(v):
        return None
    return int(v) if v == int(v) and abs(v) < 1e15 else v


def items_to_plan(
    items: Sequence[MissionItemSpec], *, firmware_type: int = MAV_AUTOPILOT_PX4,
    vehicle_type: int = MAV_TYPE_QUADROTOR, cruise_speed: float = 15.0,
    hover_speed: float = 5.0, home_alt_amsl_m: float | None = None,
) -> dict[str, Any]:
    """The mission as a QGroundControl ``.plan`` document (a JSON-ready dict).

    Item 0, if it is the home item, becomes ``plannedHomePosition`` ``[lat, lon, alt]`` (alt =
    ``home_alt_amsl_m`` if given, QGC's convention, else the item's own z) and is left out of
    ``items``; without a home item the first positioned item gives ``plannedHomePosition``.
    """
    home_alt = home_alt_amsl_m
    body = list(items)
    if _is_home(body):
        home = body.pop(0)
        planned = [home.x / 1e7, home.y / 1e7, float(home.z if home_alt is None else home_alt)]
    else:
        first = next((it for it in body if _is_global(it.frame) and (it.x or it.y)), None)
        planned = ([first.x / 1e7, first.y / 1e7, float(home_alt or 0.0)] if first
                   else [0.0, 0.0, float(home_alt or 0.0)])
    plan_items: list[dict[str, Any]] = []
    for jump_id, it in enumerate(body, start=1):
        glob = _is_global(it.frame)
        lat = it.x / 1e7 if glob else float(it.x)
        lon = it.y / 1e7 if glob else float(it.y)
        entry: dict[str, Any] = {}
        if glob and it.command != MAV_CMD_NAV_RETURN_TO_LAUNCH:
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
        "geoFence": {"circles": [], "polygons": [], "version": 2},
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
        "rallyPoints": {"points": [], "version": 2},
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


def plan_to_items(doc: Any, *, name: str = "<plan>",
                  int_frames: bool = False) -> list[MissionItemSpec]:
    """Mission items of a ``.plan`` document (see :func:`read_plan`)."""
    if not isinstance(doc, dict) or doc.get("fileType") != "Plan":
        raise EcondorError(f"{name}: not a QGroundControl plan (fileType is not \"Plan\")")
    mission = doc.get("mission")
    if not isinstance(mission, dict) or not isinstance(mission.get("items"), list):
        raise EcondorError(f"{name}: plan has no mission.items list")

    def frame_of(f: int) -> int:
        return _FLOAT_TO_INT.get(f, f) if int_frames else f

    items: list[MissionItemSpec] = []
    home = mission.get("plannedHomePosition")
    if home is not None:
        if not (isinstance(home, list) and len(home) == 3):
            raise EcondorError(f"{name}: mission.plannedHomePosition must be [lat, lon, alt]")
        lat = _float(home[0], f"{name}: plannedHomePosition")
        lon = _float(home[1], f"{name}: plannedHomePosition")
        if not (math.isfinite(lat) and math.isfinite(lon)):
            raise EcondorError(f"{name}: mission.plannedHomePosition needs a finite latitude "
                               "and longitude")
        items.append(_checked(MissionItemSpec(0, frame_of(3), MAV_CMD_NAV_WAYPOINT, current=1,
                                              x=round(lat * 1e7), y=round(lon * 1e7), z=0.0),
                              f"{name}: mission.plannedHomePosition"))
    for i, entry in enumerate(mission["items"]):
        where = f"{name}: mission.items[{i}]"
        if not isinstance(entry, dict):
            raise EcondorError(f"{where}: not an object")
        if entry.get("type") != "SimpleItem":
            raise EcondorError(
                f"{where}: {entry.get('type')!r} items are not supported (only SimpleItem)")
        params = entry.get("params")
        if not isinstance(params, list) or len(params) != 7:
            raise EcondorError(f"{where}: params must be a list of 7 values")
        try:
            frame, command = int(entry["frame"]), int(entry["command"])
        except (KeyError, TypeError, ValueError, OverflowError):
            raise EcondorError(f"{where}: needs integer frame and command") from None
        p = [_float(v, where) for v in params]
        scale = 1e7 if _is_global(frame) else 1.0
        x, y = (round(v * scale) if math.isfinite(v) else 0 for v in p[4:6])
        items.append(_checked(MissionItemSpec(
            seq=len(items), frame=frame_of(frame), command=command,
            current=1 if not items else 0, autocontinue=int(bool(entry.get("autoContinue", True))),
            param1=p[0], param2=p[1], param3=p[2], param4=p[3], x=int(x), y=int(y),
            z=p[6] if math.isfinite(p[6]) else 0.0), where))
    return items


def read_plan(path_or_doc: PathLike | dict[str, Any], *,
              int_frames: bool = False) -> list[MissionItemSpec]:
    """Read a ``.plan`` back into mission items.

    ``plannedHomePosition`` becomes item 0 (a ``NAV_WAYPOINT`` with ``current = 1`` at 0 m
    above home, the shape of :func:`~econdor_gcs.link.mission.home_item`), the ``SimpleItem``\\ s
    follow in order, renumbered.  Frames as in the file unless ``int_frames`` (3 -> 6, ...);
    ``null`` params read as NaN (altitude: 0).  ComplexItems (surveys, ...) are refused.
    """
    if isinstance(path_or_doc, dict):
        return plan_to_items(path_or_doc, int_frames=int_frames)
    text, name = _text_and_name(Path(path_or_doc))
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise EcondorError(f"{name} line {exc.lineno}: not valid JSON ({exc.msg})") from None
    return plan_to_items(doc, name=name, int_frames=int_frames)


# --------------------------------------------------------------------------------------------
# run directory: saved missions


_MISSION_NAME = re.compile(r"^iter(\d+)_v(\d+)\.json$")


@dataclass(frozen=True)
class SavedMission:
    iteration: int
    vehicle: int
    path: Path

    @property
    def stem(self) -> str:
        return f"iter{self.iteration:02d}_v{self.vehicle}"


def load_mission_file(path: PathLike) -> list[MissionItemSpec]:
    """One ``missions/iter{NN}_v{sysid}.json`` (a list of ``MissionItemSpec`` dicts)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise EcondorError(f"{path}: cannot read the saved mission ({exc})") from None
    names = {f.name for f in fields(MissionItemSpec)}
    if not isinstance(data, list):
        raise EcondorError(f"{path}: a saved mission must be a JSON list of items")
    items = []
    for i, d in enumerate(data):
        if not isinstance(d, dict):
            raise EcondorError(f"{path}: item {i} is not an object")
        unknown = sorted(set(d) - names)
        if unknown:
            raise EcondorError(f"{path}: item {i} has unknown keys {', '.join(unknown)}")
        try:
            items.append(MissionItemSpec(**d))
        except TypeError as exc:
            raise EcondorError(f"{path}: item {i}: {exc}") from None
    return items


def find_missions(run_dir: PathLike) -> list[SavedMission]:
    """The saved missions of a run, sorted by iteration then vehicle."""
    mdir = Path(run_dir) / "missions"
    found = []
    if mdir.is_dir():
        for p in mdir.iterdir():
            m = _MISSION_NAME.match(p.name)
            if m and p.is_file():
                found.append(SavedMission(int(m.group(1)), int(m.group(2)), p))
    return sorted(found, key=lambda s: (s.iteration, s.vehicle))


def _read_summary(run_dir: Path) -> dict[str, Any]:
    path = run_dir / "summary.json"
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise EcondorError(f"{path}: cannot read ({exc})") from None
    return data if isinstance(data, dict) else {}


def _check_run_dir(run_dir: Path) -> None:
    if not run_dir.is_dir():
        raise EcondorError(f"{run_dir}: no such run directory")
    if not any((run_dir / n).exists()
               for n in ("summary.json", "metrics.csv", "samples.csv", "missions")):
        raise EcondorError(f"{run_dir}: not a run directory (no summary.json, samples.csv "
                           "or missions/)")


def _ranges(values: Iterable[int]) -> str:
    return ", ".join(str(v) for v in sorted(set(values)))


def _select(run_dir: Path, missions: list[SavedMission], iteration: int | None,
            vehicle: int | None) -> list[SavedMission]:
    chosen = missions
    if iteration is not None:
        chosen = [m for m in chosen if m.iteration == iteration]
        if not chosen:
            raise EcondorError(f"{run_dir}: no mission saved for iteration {iteration} "
                               f"(saved iterations: {_ranges(m.iteration for m in missions)})")
    if vehicle is not None:
        pool = chosen
        chosen = [m for m in pool if m.vehicle == vehicle]
        if not chosen:
            where = f" in iteration {iteration}" if iteration is not None else ""
            raise EcondorError(f"{run_dir}: no mission saved for vehicle {vehicle}{where} "
                               f"(saved vehicles: {_ranges(m.vehicle for m in pool)})")
    return chosen


# --------------------------------------------------------------------------------------------
# GeoJSON


def _origin_of(run_dir: Path, summary: dict[str, Any],
               missions: list[SavedMission]) -> tuple[float, float, float] | None:
    o = summary.get("origin")
    if isinstance(o, dict) and "lat_deg" in o and "lon_deg" in o:
        return float(o["lat_deg"]), float(o["lon_deg"]), float(o.get("alt_m", 0.0) or 0.0)
    for m in missions:  # the home item sits at the ENU origin (vehicles start there)
        items = load_mission_file(m.path)
        if _is_home(items):
            return items[0].x / 1e7, items[0].y / 1e7, 0.0
    return None


def _area_of(run_dir: Path, summary: dict[str, Any]) -> tuple[float, float, float, float] | None:
    """``(xmin, xmax, ymin, ymax)`` local metres, if the run directory tells it."""
    for key in ("region", "area"):
        a = summary.get(key)
        if isinstance(a, dict):
            if all(k in a for k in ("xmin", "xmax", "ymin", "ymax")):
                return float(a["xmin"]), float(a["xmax"]), float(a["ymin"]), float(a["ymax"])
            if "width_m" in a and "height_m" in a:
                return 0.0, float(a["width_m"]), 0.0, float(a["height_m"])
    npz = run_dir / "fields.npz"
    if npz.exists():
        try:
            with np.load(npz) as f:
                gx, gy = np.asarray(f["grid_x"]), np.asarray(f["grid_y"])
            return float(gx.min()), float(gx.max()), float(gy.min()), float(gy.max())
        except (OSError, KeyError, ValueError):
            return None
    return None


def _lonlat(origin: tuple[float, float, float], x: Any, y: Any) -> tuple[Any, Any]:
    lat, lon, _ = pymap3d.enu2geodetic(np.asarray(x, float), np.asarray(y, float),
                                       np.zeros(np.shape(x)), *origin)
    return np.round(lon, 7), np.round(lat, 7)


def _pos(lon: float, lat: float) -> list[float]:
    return [round(float(lon), 7), round(float(lat), 7)]


def _load_samples(path: Path) -> np.ndarray:
    try:
        a = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise EcondorError(f"{path}: cannot read the samples ({exc})") from None
    return a if a.size else np.zeros((0, 6))


def _sysids_of(summary: dict[str, Any]) -> Callable[[int], int]:
    """Vehicle index (``samples.csv``) -> system id (missions, ``--vehicle``).

    ``summary.json``'s ``sysids`` list is in index order; without it (runs whose vehicles
    the station started itself number them 1..N) the system id is the index + 1.

    >>> f = _sysids_of({"sysids": [7, 9]})
    >>> f(0), f(1), _sysids_of({})(0)
    (7, 9, 1)
    """
    sysids = summary.get("sysids")
    if isinstance(sysids, list) and all(isinstance(s, int) for s in sysids):
        def lookup(index: int) -> int:
            return int(sysids[index]) if 0 <= index < len(sysids) else index + 1
        return lookup
    return lambda index: index + 1


def geojson_for_run(run_dir: PathLike, *, iteration: int | None = None,
                    vehicle: int | None = None) -> dict[str, Any]:
    """A FeatureCollection of the run: sample paths, mission points, area boundary.

    Sample paths (``samples.csv`` local ENU) are placed with ``summary.json``'s ``origin``
    ``{lat_deg, lon_deg, alt_m}`` or, failing that, the home item of a saved mission (vehicles
    start at the origin).  ``iteration`` / ``vehicle`` filter the mission points; ``vehicle``
    (a system id, as in the mission file names) also the sample paths, whose
    ``samples.csv`` vehicle index is mapped to the system id with ``summary.json``'s
    ``sysids``.
    """
    run_dir = Path(run_dir)
    _check_run_dir(run_dir)
    summary = _read_summary(run_dir)
    missions = find_missions(run_dir)
    origin = _origin_of(run_dir, summary, missions)
    features: list[dict[str, Any]] = []

    samples_path = run_dir / "samples.csv"
    if samples_path.exists():
        a = _load_samples(samples_path)
        if len(a) and origin is None:
            raise EcondorError(f"{run_dir}: cannot place the samples on the map: summary.json "
                               "has no origin and no mission with a home item was saved")
        sysid_of = _sysids_of(summary)
        for index in sorted({int(v) for v in a[:, 5]}) if len(a) else []:
            sysid = sysid_of(index)
            if vehicle is not None and sysid != vehicle:
                continue
            rows = a[a[:, 5] == index]
            rows = rows[np.argsort(rows[:, 0], kind="stable")]
            assert origin is not None
            lon, lat = _lonlat(origin, rows[:, 1], rows[:, 2])
            coords = [_pos(o, t) for o, t in zip(lon, lat, strict=True)]
            geometry = ({"type": "LineString", "coordinates": coords} if len(coords) > 1
                        else {"type": "Point", "coordinates": coords[0]})
            features.append({"type": "Feature", "geometry": geometry, "properties": {
                "kind": "samples", "vehicle": sysid, "samples": len(coords),
                "value_min": float(rows[:, 3].min()), "value_max": float(rows[:, 3].max())}})

    chosen = missions
    if iteration is not None or vehicle is not None:
        chosen = [m for m in missions if (iteration is None or m.iteration == iteration)
                  and (vehicle is None or m.vehicle == vehicle)]
    for m in chosen:
        items = load_mission_file(m.path)
        for it in items:
            if not _is_global(it.frame) or (it.seq == 0 and _is_home(items)):
                continue
            if it.command == MAV_CMD_WAYPOINT_USER_1:
                kind, level, piece = "trace_start", it.param1, int(it.param4)
            elif it.command in (MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_LOITER_UNLIM):
                kind, level, piece = ("waypoint" if it.command == MAV_CMD_NAV_WAYPOINT
                                      else "loiter"), None, None
            else:
                continue
            features.append({"type": "Feature",
                             "geometry": {"type": "Point",
                                          "coordinates": _pos(it.y / 1e7, it.x / 1e7)},
                             "properties": {"kind": kind, "iteration": m.iteration,
                                            "vehicle": m.vehicle, "seq": it.seq,
                                            "command": it.command, "level": level,
                                            "piece_id": piece, "alt_m": it.z}})

    area = _area_of(run_dir, summary)
    if area is not None and origin is not None:
        x0, x1, y0, y1 = area
        lon, lat = _lonlat(origin, [x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0])
        ring = [_pos(o, t) for o, t in zip(lon, lat, strict=True)]
        features.append({"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ring]},
                         "properties": {"kind": "area", "xmin_m": x0, "xmax_m": x1,
                                        "ymin_m": y0, "ymax_m": y1}})
    return {"type": "FeatureCollection", "features": features}


def write_geojson(path: PathLike, run_dir: PathLike, **kwargs: Any) -> Path:
    """Write :func:`geojson_for_run` (keyword arguments as there)."""
    path = Path(path)
    doc = geojson_for_run(run_dir, **kwargs)
    path.write_text(json.dumps(doc, allow_nan=False) + "\n", encoding="utf-8")
    return path


# --------------------------------------------------------------------------------------------
# CLI


_SUFFIX = {"wpl": ".waypoints", "plan": ".plan", "geojson": ".geojson"}


def _is_dir_target(out: PathLike) -> bool:
    text = str(out)
    return Path(out).is_dir() or text.endswith(("/", "\\"))


def export_cli(args: argparse.Namespace) -> int:
    """``econdor export RUN_DIR --format wpl|plan|geojson --out PATH [--iteration N]
    [--vehicle ID]``; prints the paths written."""
    run_dir = Path(args.run_dir)
    fmt = args.format
    out_arg = args.out
    iteration = getattr(args, "iteration", None)
    vehicle = getattr(args, "vehicle", None)
    _check_run_dir(run_dir)
    to_dir = _is_dir_target(out_arg)
    out = Path(out_arg)
    if fmt not in _SUFFIX:
        raise EcondorError(f"unknown export format {fmt!r} (wpl, plan or geojson)")

    if fmt == "geojson":
        target = out / "run.geojson" if to_dir else out
        target.parent.mkdir(parents=True, exist_ok=True)
        print(write_geojson(target, run_dir, iteration=iteration, vehicle=vehicle))
        return 0

    missions = find_missions(run_dir)
    if not missions:
        raise EcondorError(f"{run_dir}: no missions saved (only MAVLink runs save them; "
                           "in-process and study runs do not)")
    chosen = _select(run_dir, missions, iteration, vehicle)
    if len(chosen) > 1 and not to_dir:
        raise EcondorError(
            f"{len(chosen)} missions match; pick one with --iteration and --vehicle, or give "
            "--out an existing directory (or a path ending in '/') to write them all")
    summary = _read_summary(run_dir)
    origin = summary.get("origin")
    if not isinstance(origin, dict):
        origin = {}
    written = []
    if to_dir:
        out.mkdir(parents=True, exist_ok=True)
    for m in chosen:
        items = load_mission_file(m.path)
        target = out / f"{m.stem}{_SUFFIX[fmt]}" if to_dir else out
        target.parent.mkdir(parents=True, exist_ok=True)
        if fmt == "wpl":
            write_wpl(target, items)
        else:
            alt = origin.get("alt_m")
            write_plan(target, items,
                       home_alt_amsl_m=float(alt) if isinstance(alt, int | float) else None)
        written.append(target)
    for p in written:
        print(p)
    return 0

