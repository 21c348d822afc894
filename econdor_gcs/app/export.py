"""``econdor export``: missions for real aircraft, and GeoJSON of a run.

SOURCE is a run directory or a mission YAML:

* run directory, no ``--iteration``: the batch the planner would fly next, from the run's last
  estimate (``next_batch.json``), split over ``--vehicles`` aircraft (default 1) as the DFC
  would split it: nearest-neighbour order from home, each contour piece entered at its point
  nearest to where the aircraft comes from;
* run directory, ``--iteration N|all [--vehicle S]``: the tasks each vehicle was given in that
  iteration (``missions/iterNN_vS.tasks.json``);
* mission YAML: the initiation, the two main diagonals split over ``--vehicles``, or with
  ``--spacing-m`` a north-south survey at that spacing.

``--style waypoints`` (the default for wpl and plan) flies each contour piece of the estimate
as a NAV_WAYPOINT polyline simplified to ``--tolerance-m`` (Douglas-Peucker,
:mod:`econdor_gcs.core.waypoints`): any stock autopilot flies it. ``--style trace`` gives each
piece as a contour item (``MAV_CMD_WAYPOINT_USER_1``) for an aircraft whose companion computer
runs the tracer; the next batch of a run whose station corrected a sensor lag (``summary.json``
``lag_s``: the known one, or the last estimate) tells that tracer the lag with a sensor lag
item before the first contour item, as the run's own missions did. Every mission is: item 0
home, takeoff to ``--alt-m``, DO_CHANGE_SPEED to ``--speed-mps``, the tasks, return to
launch. A ``.plan`` also carries an inclusion geofence around the area (``--fence-margin-m``
outside it) and a rally point at home.

The formats themselves (QGC WPL 110, QGroundControl ``.plan``) are in
:mod:`econdor_gcs.files.autopilot_files`; GeoJSON (RFC 7946, positions ``[lon, lat]``) is here: one
``LineString`` per vehicle from ``samples.csv``, ``Point`` features for mission waypoints and
trace start points, and the area boundary ``Polygon`` when the run directory tells it.
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

from econdor_gcs.config import Mission, load_mission
from econdor_gcs.core.assignment import assign_jobs
from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.geometry import Region
from econdor_gcs.core.lag import tell_lag, told_lag
from econdor_gcs.core.planners import Job, diagonal_jobs, survey_jobs
from econdor_gcs.core.tasks import Task, TaskStyle
from econdor_gcs.errors import EcondorError, MissionError
from econdor_gcs.files.autopilot_files import is_global_frame, is_home_item, write_plan, write_wpl
from econdor_gcs.files.plans import read_next_batch, read_tasks
from econdor_gcs.link.codec import mavlink
from econdor_gcs.link.items import MissionItemSpec, plan_mission

__all__ = [
    "ExportedMission",
    "SavedMission",
    "export_cli",
    "export_missions",
    "find_missions",
    "geojson_for_run",
    "load_mission_file",
    "write_geojson",
]

MAV_CMD_NAV_WAYPOINT = mavlink.MAV_CMD_NAV_WAYPOINT
MAV_CMD_NAV_LOITER_UNLIM = mavlink.MAV_CMD_NAV_LOITER_UNLIM
MAV_CMD_WAYPOINT_USER_1 = mavlink.MAV_CMD_WAYPOINT_USER_1

PathLike = str | Path


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
        if is_home_item(items):
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
            if not is_global_frame(it.frame) or (it.seq == 0 and is_home_item(items)):
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
# missions for aircraft


@dataclass
class ExportedMission:
    """One aircraft's mission: its file stem and items."""

    stem: str
    items: list[MissionItemSpec]


@dataclass(frozen=True)
class ExportOptions:
    """How to turn tasks into a mission (None: the mission YAML's value)."""

    style: TaskStyle = TaskStyle.WAYPOINTS
    alt_m: float | None = None
    speed_mps: float | None = None
    tolerance_m: float = 1.0
    vehicles: int = 1
    spacing_m: float | None = None


def _mission_items(mission: Mission, tasks: Sequence[Task], opts: ExportOptions
                   ) -> list[MissionItemSpec]:
    alt = opts.alt_m if opts.alt_m is not None else mission.vehicles.altitude_m
    speed = opts.speed_mps if opts.speed_mps is not None else mission.vehicles.speed_mps
    try:
        return plan_mission(mission.origin, tasks, alt, style=opts.style,
                            tolerance_m=opts.tolerance_m, speed_mps=speed, end="rtl").items
    except ValueError as exc:
        raise EcondorError(f"cannot build the mission: {exc}") from None


def _split(jobs: list[Job], mission: Mission, n: int, first_piece_id: int) -> list[list[Task]]:
    """The jobs over ``n`` aircraft starting at home, as the DFC assigns them."""
    homes = [(0.0, 0.0)] * n
    return assign_jobs(jobs, homes, mission.algorithm.search_radius_m,
                       first_piece_id=first_piece_id)


def _from_yaml(mission: Mission, opts: ExportOptions) -> list[ExportedMission]:
    n = opts.vehicles
    if opts.spacing_m is not None:
        r = mission.region
        xs = np.arange(r.xmin, r.xmax + 1e-9, opts.spacing_m)
        plans = _split(survey_jobs(r, xs), mission, n, 0)
        what = "survey"
    else:
        jobs = diagonal_jobs(mission.region, n)
        plans = [list(j.tasks) for j in jobs]
        what = "diagonals"
    return [ExportedMission(f"{mission.name}_{what}_v{k + 1}", _mission_items(mission, p, opts))
            for k, p in enumerate(plans) if p]


def _run_mission(run_dir: Path) -> Mission:
    path = run_dir / "mission.yaml"
    if not path.exists():
        raise EcondorError(f"{run_dir}: no mission.yaml (runs before it was kept cannot be "
                           "re-planned; export a saved mission with --iteration N --style trace)")
    return load_mission(path)


def _next_batch(run_dir: Path, opts: ExportOptions) -> list[ExportedMission]:
    path = run_dir / "next_batch.json"
    if not path.exists():
        raise EcondorError(f"{run_dir}: no next_batch.json (the run did not finish, or "
                           "predates it); pick a saved mission with --iteration N")
    mission = _run_mission(run_dir)
    iteration, jobs = read_next_batch(path)
    if not jobs:
        raise EcondorError(f"{path}: the next batch is empty (nothing left to fly)")
    plans = _split(jobs, mission, opts.vehicles, 1000 * iteration)
    lag = _corrected_lag_s(_read_summary(run_dir))
    plans = tell_lag(plans, told_lag(mission.vehicles.sensor.lag_correction, lag))
    return [ExportedMission(f"next{iteration:02d}_v{k + 1}", _mission_items(mission, p, opts))
            for k, p in enumerate(plans) if p]


def _corrected_lag_s(summary: dict[str, Any]) -> float | None:
    """The sensor lag (s) the run's station corrected the samples for at its end
    (``summary.json`` ``lag_s``: 0 when it corrected none); None when it has none (no
    estimate yet)."""
    lag = summary.get("lag_s")
    if isinstance(lag, bool) or not isinstance(lag, int | float) or not math.isfinite(lag) \
            or lag < 0.0:
        return None
    return float(lag)


def _saved(run_dir: Path, iteration: str, vehicle: int | None,
           opts: ExportOptions) -> list[ExportedMission]:
    missions = find_missions(run_dir)
    if not missions:
        raise EcondorError(f"{run_dir}: no missions saved (only MAVLink runs save them; "
                           "in-process and study runs do not)")
    number = None if iteration == "all" else _iteration_number(iteration)
    chosen = _select(run_dir, missions, number, vehicle)
    out = []
    for m in chosen:
        tasks_path = m.path.with_suffix(".tasks.json")
        if tasks_path.exists():
            items = _mission_items(_run_mission(run_dir), read_tasks(tasks_path), opts)
        elif opts.style == TaskStyle.TRACE:
            items = load_mission_file(m.path)  # as it was sent
        else:
            raise EcondorError(f"{m.path}: no {tasks_path.name} beside it (the estimated "
                               "contours were not saved): only --style trace can export it")
        out.append(ExportedMission(m.stem, items))
    return out


def _iteration_number(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise EcondorError(f"--iteration: expected a number or 'all', got {text!r}") from None
    if n < 0:
        raise EcondorError(f"--iteration: must be >= 0, got {n}")
    return n


def export_missions(source: PathLike, opts: ExportOptions, iteration: str | None = None,
                    vehicle: int | None = None) -> tuple[list[ExportedMission], Mission | None]:
    """The missions SOURCE gives (see the module docstring) and the mission YAML behind them
    (for the geofence; None when a run directory does not keep it)."""
    src = Path(source)
    if src.is_file():
        if iteration is not None or vehicle is not None:
            raise EcondorError("--iteration and --vehicle apply to a run directory, not a "
                               "mission YAML")
        mission = load_mission(src)
        return _from_yaml(mission, opts), mission
    _check_run_dir(src)
    if opts.spacing_m is not None:
        raise EcondorError("--spacing-m applies to a mission YAML, not a run directory")
    if iteration is not None or vehicle is not None:
        found = _saved(src, iteration or "all", vehicle, opts)
        kept = src / "mission.yaml"
        return found, load_mission(kept) if kept.exists() else None
    return _next_batch(src, opts), _run_mission(src)


def fence_polygon(region: Region, origin: Origin, margin_m: float) -> list[tuple[float, float]]:
    """The area's rectangle, ``margin_m`` outside it, as ``(lat, lon)`` vertices."""
    x0, x1 = region.xmin - margin_m, region.xmax + margin_m
    y0, y1 = region.ymin - margin_m, region.ymax + margin_m
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    out = []
    for x, y in corners:
        lat, lon, _ = origin.to_global(x, y)
        out.append((round(lat, 7), round(lon, 7)))
    return out


_SUFFIX = {"wpl": ".waypoints", "plan": ".plan", "geojson": ".geojson"}


def _is_dir_target(out: PathLike) -> bool:
    text = str(out)
    return Path(out).is_dir() or text.endswith(("/", "\\"))


def export_cli(args: argparse.Namespace) -> int:
    """``econdor export SOURCE --format wpl|plan|geojson --out PATH [--style waypoints|trace]
    [--alt-m A] [--speed-mps S] [--tolerance-m T] [--vehicles N] [--spacing-m D]
    [--iteration N|all] [--vehicle S] [--fence-margin-m M]``; prints the paths written."""
    source = Path(args.source)
    fmt = args.format
    if fmt not in _SUFFIX and fmt != "lua":
        raise EcondorError(f"unknown export format {fmt!r} (wpl, plan, geojson or lua)")
    out = Path(args.out)
    to_dir = _is_dir_target(args.out)
    if fmt == "lua":
        return _export_lua(source, out / "econdor_field.lua" if to_dir else out)
    iteration = getattr(args, "iteration", None)
    vehicle = getattr(args, "vehicle", None)
    if fmt == "geojson":
        if not source.is_dir():
            raise EcondorError(f"{source}: GeoJSON is made from a run directory")
        target = out / "run.geojson" if to_dir else out
        target.parent.mkdir(parents=True, exist_ok=True)
        number = None if iteration in (None, "all") else _iteration_number(iteration)
        print(write_geojson(target, source, iteration=number, vehicle=vehicle))
        return 0
    style = TaskStyle(getattr(args, "style", None) or TaskStyle.WAYPOINTS)
    opts = ExportOptions(style=style, alt_m=getattr(args, "alt_m", None),
                         speed_mps=getattr(args, "speed_mps", None),
                         tolerance_m=getattr(args, "tolerance_m", None) or 1.0,
                         vehicles=getattr(args, "vehicles", None) or 1,
                         spacing_m=getattr(args, "spacing_m", None))
    try:
        missions, mission = export_missions(source, opts, iteration, vehicle)
    except MissionError as exc:
        raise EcondorError(f"{source}: {exc}") from None
    if len(missions) > 1 and not to_dir:
        raise EcondorError(
            f"{len(missions)} missions match; pick one with --iteration and --vehicle (or "
            "--vehicles 1), or give --out an existing directory (or a path ending in '/') to "
            "write them all")
    if to_dir:
        out.mkdir(parents=True, exist_ok=True)
    written = []
    for m in missions:
        target = out / f"{m.stem}{_SUFFIX[fmt]}" if to_dir else out
        target.parent.mkdir(parents=True, exist_ok=True)
        if fmt == "wpl":
            write_wpl(target, m.items)
        else:
            written_plan(target, m.items, mission, getattr(args, "fence_margin_m", None),
                         _home_alt(source, mission))
        written.append(target)
    for p in written:
        print(p)
    return 0


def _export_lua(source: Path, target: Path) -> int:
    """``--format lua``: the SITL field script of a mission YAML (:mod:`.payload`)."""
    from econdor_gcs.payload import field_script

    if source.is_dir():
        source = source / "mission.yaml"
    mission = load_mission(source)
    text = field_script(mission)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise EcondorError(f"cannot write {target}: {exc.strerror or exc}") from exc
    print(target)
    return 0


def _home_alt(source: Path, mission: Mission | None) -> float | None:
    """Home altitude AMSL: the mission's origin, else a run's summary.json origin."""
    if mission is not None:
        return mission.origin.alt_m
    if source.is_dir():
        origin = _read_summary(source).get("origin")
        alt = origin.get("alt_m") if isinstance(origin, dict) else None
        if isinstance(alt, int | float):
            return float(alt)
    return None


def written_plan(target: Path, items: list[MissionItemSpec], mission: Mission | None,
                 margin_m: float | None, home_alt_amsl_m: float | None = None) -> Path:
    """A ``.plan`` with the geofence and rally point when the mission YAML is known."""
    if mission is None:
        return write_plan(target, items, home_alt_amsl_m=home_alt_amsl_m)
    o = mission.origin
    margin = 10.0 if margin_m is None else margin_m
    alt = next((it.z for it in items if it.command == mavlink.MAV_CMD_NAV_TAKEOFF),
               mission.vehicles.altitude_m)
    return write_plan(target, items, home_alt_amsl_m=o.alt_m,
                      fence_polygons=[fence_polygon(mission.region, o, margin)],
                      rally_points=[(round(o.lat_deg, 7), round(o.lon_deg, 7), float(alt))])
