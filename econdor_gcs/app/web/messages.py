"""The page's messages, built from a run's data (shared by the live and the replay feed).

Every message is a JSON object with a ``type``. Large arrays travel as base64 of their
little-endian bytes (``f32``: float32, ``u8``: uint8); polylines as lists of flat
``[x0, y0, x1, y1, ...]`` lists in metres, rounded to centimetres.
"""

from __future__ import annotations

import base64
import math
from collections.abc import Sequence
from dataclasses import asdict
from functools import cache
from typing import Any

import numpy as np
from skimage import measure

from econdor_gcs.core.geometry import FloatArray
from econdor_gcs.core.tasks import Phase, SampleLog
from econdor_gcs.files.rundir import LogLine, PlannedPiece
from econdor_gcs.station.executor import VehicleStatus

Message = dict[str, Any]

CONTOUR_LINES = 10
"""Contour lines drawn over the estimate, evenly spaced inside its range."""

RECORD_KEYS = ("iteration", "mae_db", "mae", "learning_error", "kappa", "delta",
               "flight_distance_m", "contour_distance_m", "levels_traced", "samples",
               "span_ratio", "pieces")
"""What the page plots and tabulates per iteration (a subset of ``iterations.json``)."""


def b64(array: np.ndarray, dtype: str) -> str:
    """Little-endian bytes of ``array`` as ``dtype``, base64.

    >>> b64(np.array([1.0]), "<f4")
    'AACAPw=='
    """
    return base64.b64encode(np.ascontiguousarray(array, dtype=dtype).tobytes()).decode("ascii")


def _finite(value: Any) -> Any:
    """JSON has no NaN: non-finite floats become ``None``."""
    if isinstance(value, float | np.floating):
        v = float(value)
        return v if math.isfinite(v) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _flat(points_m: FloatArray) -> list[float]:
    return [round(float(v), 2) for v in np.asarray(points_m, dtype=float).ravel()]


@cache
def colormap() -> list[list[int]]:
    """viridis as 256 RGB triples (from matplotlib, the figures' colour map)."""
    from matplotlib import colormaps

    rgb = colormaps["viridis"](np.linspace(0.0, 1.0, 256))[:, :3]
    return np.round(rgb * 255).astype(int).tolist()


def phases() -> dict[str, int]:
    return {p.name.lower(): int(p) for p in Phase}


def hello(mode: str, *, mission: str, planner: str, region: dict[str, float],
          vehicles: Sequence[int], controls: bool, truth_known: bool,
          max_iterations: int | None, run_dir: str) -> Message:
    """The first message: what the page is about and how to draw it."""
    return {"type": "hello", "mode": mode, "mission": mission, "planner": planner,
            "region": region, "sysids": list(vehicles), "controls": controls,
            "truth_known": truth_known, "max_iterations": max_iterations,
            "run_dir": run_dir, "phases": phases(), "colormap": colormap()}


def contours(estimate: FloatArray, grid_x: FloatArray, grid_y: FloatArray,
             n: int = CONTOUR_LINES) -> list[dict[str, Any]]:
    """Iso-lines of ``estimate`` at ``n`` evenly spaced levels (scikit-image marching squares)."""
    lo, hi = float(np.nanmin(estimate)), float(np.nanmax(estimate))
    if not hi > lo:
        return []
    dx = (grid_x[-1] - grid_x[0]) / (len(grid_x) - 1)
    dy = (grid_y[-1] - grid_y[0]) / (len(grid_y) - 1)
    out = []
    for level in np.linspace(lo, hi, n + 2)[1:-1]:
        paths = []
        for rc in measure.find_contours(estimate, float(level)):
            xy = np.column_stack([grid_x[0] + rc[:, 1] * dx, grid_y[0] + rc[:, 0] * dy])
            paths.append(_flat(xy))
        out.append({"level": round(float(level), 4), "paths": paths})
    return out


def pieces(planned: Sequence[PlannedPiece]) -> list[dict[str, Any]]:
    return [{"vehicle": p.vehicle, "piece_id": p.piece_id, "level": _finite(p.level),
             "points": _flat(p.points_m)} for p in planned]


def frame(iteration: int, grid_x: FloatArray, grid_y: FloatArray, estimate: FloatArray,
          planned: Sequence[PlannedPiece]) -> Message:
    """The estimate after ``iteration`` (colour map + contour lines) and what it flew."""
    est = np.asarray(estimate, dtype=np.float32)
    return {"type": "frame", "iteration": iteration,
            "nx": int(est.shape[1]), "ny": int(est.shape[0]),
            "x0": float(grid_x[0]), "x1": float(grid_x[-1]),
            "y0": float(grid_y[0]), "y1": float(grid_y[-1]),
            "min": float(np.nanmin(est)), "max": float(np.nanmax(est)),
            "estimate": b64(est, "<f4"),
            "contours": contours(np.asarray(estimate, dtype=float), np.asarray(grid_x),
                                 np.asarray(grid_y)),
            "pieces": pieces(planned)}


def plan(iteration: int, planned: Sequence[PlannedPiece]) -> Message:
    """The pieces of the iteration being flown, with their vehicles."""
    return {"type": "plan", "iteration": iteration, "pieces": pieces(planned)}


def samples(log: SampleLog) -> Message:
    """Samples the DFC accounted (exact phases), appended to the page's paths."""
    return {"type": "samples", "n": len(log),
            "x": b64(log.x_m, "<f4"), "y": b64(log.y_m, "<f4"),
            "phase": b64(log.phase, "u1"), "vehicle": b64(log.vehicle, "u1")}


def trail(reset: bool, x_m: FloatArray, y_m: FloatArray, vehicle: np.ndarray,
          phase: np.ndarray) -> Message:
    """Samples still in flight (not yet accounted); ``reset`` drops the page's previous trail."""
    return {"type": "trail", "reset": reset, "n": len(x_m),
            "x": b64(x_m, "<f4"), "y": b64(y_m, "<f4"),
            "phase": b64(phase, "u1"), "vehicle": b64(vehicle, "u1")}


def record(rec: dict[str, Any]) -> dict[str, Any]:
    """The keys of one ``iterations.json`` record the page uses (NaN -> null)."""
    return {k: _finite(rec.get(k)) for k in RECORD_KEYS}


def records(recs: Sequence[dict[str, Any]]) -> Message:
    return {"type": "records", "records": [record(r) for r in recs]}


def vehicle(v: VehicleStatus, pieces_by_vehicle: dict[int, list[int]]) -> dict[str, Any]:
    d = {k: _finite(val) for k, val in asdict(v).items()}
    d["phase"] = Phase(v.phase).name.lower()
    d["pieces"] = pieces_by_vehicle.get(v.index, [])
    return d


def vehicles(rows: Sequence[VehicleStatus], pieces_by_vehicle: dict[int, list[int]]) -> Message:
    return {"type": "vehicles", "vehicles": [vehicle(v, pieces_by_vehicle) for v in rows]}


def log(lines: Sequence[LogLine]) -> Message:
    return {"type": "log", "lines": [{**asdict(ln), "severity": str(ln.severity)}
                                     for ln in lines]}


def control(state: str, iteration: int) -> Message:
    return {"type": "control", "state": state, "iteration": iteration}


def done(summary: dict[str, Any]) -> Message:
    keep = ("stop_reason", "iterations", "final_mae_db", "flight_distance_m",
            "contour_distance_m", "samples", "converged", "error")
    return {"type": "done", "summary": {k: _finite(summary.get(k)) for k in keep if k in summary}}
