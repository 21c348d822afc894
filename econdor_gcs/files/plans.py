"""Plans as files, so that a run's planned flights can be exported for other aircraft.

``econdor run`` leaves in its run directory:

``mission.yaml``
    a copy of the mission it ran (written with ``run.json``; origin, area, altitude, speed,
    search radius);
``missions/iter{NN}_v{sysid}.tasks.json``
    the tasks each vehicle was given in iteration NN, trace tasks with their estimated
    contour (``route_m``), so that ``econdor export --iteration NN`` can rebuild the mission
    in either style;
``next_batch.json``
    the batch the planner would fly next (its jobs: contour pieces with their polylines,
    survey lines), so that ``econdor export RUN_DIR`` can hand it to real aircraft.

All positions are local ENU metres of the mission's origin.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from econdor_gcs.config import Mission
from econdor_gcs.core.contours import ContourPiece
from econdor_gcs.core.planners import Batch, Job, PlanContext, Planner
from econdor_gcs.core.tasks import Task, TraceTask, Waypoint
from econdor_gcs.errors import EcondorError, RunError

if TYPE_CHECKING:
    from econdor_gcs.dfc.loop import RunResult

__all__ = ["read_next_batch", "read_tasks", "save_next_batch",
           "task_from_json", "task_to_json", "write_next_batch", "write_tasks"]

FORMAT_VERSION = 1


def task_to_json(task: Task) -> dict[str, Any]:
    """One task as a JSON object (a trace task's ``sensor_lag_s`` only when it has one, its
    ``lag_unknown`` only when true)."""
    if isinstance(task, Waypoint):
        return {"kind": "waypoint", "x_m": task.x_m, "y_m": task.y_m}
    d = {"kind": "trace", "level": task.level, "x_m": task.x_m, "y_m": task.y_m,
         "search_radius_m": task.search_radius_m, "max_length_m": task.max_length_m,
         "piece_id": task.piece_id, "route_m": [list(p) for p in task.route_m]}
    if task.sensor_lag_s is not None:
        d["sensor_lag_s"] = task.sensor_lag_s
    if task.lag_unknown:
        d["lag_unknown"] = True
    return d


def _num(d: dict[str, Any], key: str, where: str) -> float:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise EcondorError(f"{where}.{key}: expected a finite number, got {v!r}")
    return float(v)


def _points(v: Any, where: str) -> list[tuple[float, float]]:
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise EcondorError(f"{where}: expected a list of [x_m, y_m] points") from None
    if a.size == 0:
        return []
    if a.ndim != 2 or a.shape[1] != 2 or not np.all(np.isfinite(a)):
        raise EcondorError(f"{where}: expected a list of finite [x_m, y_m] points")
    return [(float(x), float(y)) for x, y in a]


def task_from_json(d: Any, where: str) -> Task:
    """One task from its JSON object; errors name ``where`` and the key."""
    if not isinstance(d, dict):
        raise EcondorError(f"{where}: not an object")
    kind = d.get("kind")
    if kind == "waypoint":
        return Waypoint(_num(d, "x_m", where), _num(d, "y_m", where))
    if kind == "trace":
        level, x, y, radius, max_len, piece = (
            _num(d, key, where) for key in ("level", "x_m", "y_m", "search_radius_m",
                                            "max_length_m", "piece_id"))
        lag = None
        if "sensor_lag_s" in d:
            v = d["sensor_lag_s"]
            if isinstance(v, bool) or not isinstance(v, int | float) or not v >= 0 \
                    or not math.isfinite(v):
                raise EcondorError(f"{where}.sensor_lag_s: expected a finite number >= 0 "
                                   f"(seconds), got {v!r}")
            lag = float(v)
        unknown = d.get("lag_unknown", False)
        if not isinstance(unknown, bool) or (unknown and lag != 0.0):
            raise EcondorError(f"{where}.lag_unknown: expected true or false, true only with "
                               f"sensor_lag_s 0, got {unknown!r}")
        return TraceTask(level, x, y, radius, max_len, int(piece),
                         route_m=tuple(_points(d.get("route_m", []), f"{where}.route_m")),
                         sensor_lag_s=lag, lag_unknown=unknown)
    raise EcondorError(f"{where}.kind: expected 'waypoint' or 'trace', got {kind!r}")


def _write(path: Path, doc: dict[str, Any]) -> Path:
    path.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return path


def _read(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise EcondorError(f"{path}: cannot read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise EcondorError(f"{path} line {exc.lineno}: not valid JSON ({exc.msg})") from None
    if not isinstance(doc, dict) or doc.get("version") != FORMAT_VERSION:
        raise EcondorError(f"{path}: not an econdor plan file (version {FORMAT_VERSION})")
    return doc


def write_tasks(path: str | Path, tasks: Sequence[Task]) -> Path:
    """``tasks`` as ``{"version": 1, "tasks": [...]}``."""
    return _write(Path(path), {"version": FORMAT_VERSION,
                               "tasks": [task_to_json(t) for t in tasks]})


def read_tasks(path: str | Path) -> list[Task]:
    path = Path(path)
    doc = _read(path)
    tasks = doc.get("tasks")
    if not isinstance(tasks, list):
        raise EcondorError(f"{path}: tasks must be a list")
    return [task_from_json(t, f"{path}: tasks[{i}]") for i, t in enumerate(tasks)]


def _job_to_json(job: Job) -> dict[str, Any]:
    d: dict[str, Any] = {"length_m": job.length_m, "start_m": list(job.start_m),
                         "end_m": list(job.end_m), "tasks": [task_to_json(t) for t in job.tasks]}
    if job.piece is not None:
        d["piece"] = {"level": job.piece.level, "closed": job.piece.closed,
                      "points_m": job.piece.points_m.tolist()}
    return d


def _job_from_json(d: Any, where: str) -> Job:
    if not isinstance(d, dict):
        raise EcondorError(f"{where}: not an object")
    tasks = d.get("tasks", [])
    if not isinstance(tasks, list):
        raise EcondorError(f"{where}.tasks: expected a list")
    start = _points([d.get("start_m")], f"{where}.start_m")[0]
    end = _points([d.get("end_m")], f"{where}.end_m")[0]
    piece = None
    if d.get("piece") is not None:
        p = d["piece"]
        if not isinstance(p, dict):
            raise EcondorError(f"{where}.piece: not an object")
        pts = _points(p.get("points_m"), f"{where}.piece.points_m")
        if len(pts) < 2:
            raise EcondorError(f"{where}.piece.points_m: a piece needs at least 2 points")
        piece = ContourPiece(_num(p, "level", f"{where}.piece"), np.asarray(pts),
                             bool(p.get("closed", False)))
    return Job([task_from_json(t, f"{where}.tasks[{i}]") for i, t in enumerate(tasks)],
               start, end, _num(d, "length_m", where), piece=piece)


def write_next_batch(path: str | Path, batch: Batch, iteration: int) -> Path:
    """The batch the planner would fly in ``iteration`` (its jobs and levels)."""
    return _write(Path(path), {
        "version": FORMAT_VERSION, "iteration": iteration,
        "levels": [float(v) for v in batch.levels],
        "jobs": [_job_to_json(j) for j in batch.jobs]})


def read_next_batch(path: str | Path) -> tuple[int, list[Job]]:
    """``(iteration, jobs)`` of a ``next_batch.json``."""
    path = Path(path)
    doc = _read(path)
    jobs = doc.get("jobs")
    if not isinstance(jobs, list):
        raise EcondorError(f"{path}: jobs must be a list")
    it = doc.get("iteration")
    if not isinstance(it, int) or isinstance(it, bool):
        raise EcondorError(f"{path}: iteration must be an integer")
    return it, [_job_from_json(j, f"{path}: jobs[{i}]") for i, j in enumerate(jobs)]


def _last_noise_std(result: RunResult) -> float:
    """The noise the run's last reconstruction estimated (0 when none, or not recorded)."""
    noise = result.records[-1].noise_std if result.records else 0.0
    return noise if math.isfinite(noise) else 0.0


def save_next_batch(run_dir: Path, planner: Planner, mission: Mission,
                    result: RunResult) -> Path:
    """``next_batch.json``: what ``planner`` would fly next from the run's final estimate.

    The planner is asked once more, as the DFC would ask it (vehicles at home); nothing is
    flown.
    """
    iteration = len(result.records)
    context = PlanContext(iteration=iteration, region=mission.region,
                          n_vehicles=result.vehicles, grid=result.grid,
                          estimate=result.estimate, samples=result.samples,
                          positions_m=[(0.0, 0.0)] * result.vehicles,
                          noise_std=_last_noise_std(result))
    batch = planner.next_batch(context)
    try:
        return write_next_batch(run_dir / "next_batch.json", batch, iteration)
    except OSError as exc:
        raise RunError(f"{run_dir}: cannot write next_batch.json ({exc.strerror or exc})"
                       ) from exc
