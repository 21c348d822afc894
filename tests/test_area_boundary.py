"""Traces that meet the area boundary turn inside it (in-process, many contour pieces).

Before issue 9's guard the vehicles left the area by up to 5.5 m where a trace met the
boundary (the leg ended at the boundary and the vehicle turned back with its momentum, the
search's probe legs and spiral overshot too); see ``bench/excursion.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from vehicle_helpers import REPO

from econdor_gcs.config import parse_mission
from econdor_gcs.core.contours import contour_pieces
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.tasks import Phase, TraceTask
from econdor_lab.inprocess import InProcessExecutor

EXCURSION_LIMIT_M = 1e-3
"""The guard's promise: a trace task never ends up farther than this outside the area."""

PLUME = {"model": "plume", "sources": 3, "sigma_min_m": 3.0, "sigma_max_m": 6.0,
         "background": 10.0}


def _mission(field: dict | None):
    raw = yaml.safe_load((REPO / "missions" / "paper.yaml").read_text(encoding="utf-8"))
    if field is not None:
        raw["field"] = field
    return parse_mission(raw, base_dir=REPO / "missions")


def _excursion_m(x: np.ndarray, y: np.ndarray, r: Region) -> np.ndarray:
    dx = np.maximum.reduce([r.xmin - x, np.zeros_like(x), x - r.xmax])
    dy = np.maximum.reduce([r.ymin - y, np.zeros_like(y), y - r.ymax])
    return np.hypot(dx, dy)


def _boundary_tasks(mission, field, n_max: int) -> list[TraceTask]:
    """Trace tasks on true contour pieces that reach the boundary: started at the piece's
    point nearest the boundary or halfway along it (then the trace runs into it)."""
    r = mission.region
    grid = Grid.with_spacing(r, 1.0)
    truth = field(*grid.mesh)
    levels = np.quantile(truth, np.linspace(0.1, 0.9, 9))
    tasks = []
    for k, piece in enumerate(contour_pieces(truth, grid, levels, min_length_m=10.0)):
        p = piece.points_m
        edge = np.minimum.reduce([p[:, 0] - r.xmin, r.xmax - p[:, 0], p[:, 1] - r.ymin,
                                  r.ymax - p[:, 1]])
        if edge.min() > 0.5:
            continue
        x, y = p[int(np.argmin(edge))] if k % 2 else piece.midpoint()
        tasks.append(TraceTask(piece.level, float(x), float(y), 10.0, 0.0, k))
    return tasks[:n_max]


@pytest.mark.parametrize(("field", "seed"), [(None, 0), (None, 1), (PLUME, 2), (PLUME, 3)])
def test_traces_meeting_the_boundary_stay_inside_the_area(field, seed):
    mission = _mission(field)
    truth = mission.build_field(seed)
    tasks = _boundary_tasks(mission, truth, 18)
    assert len(tasks) >= 8
    ex = InProcessExecutor(mission, truth, seed=seed)
    (report,) = ex.fly([tasks], 1)
    s = report.samples
    out = _excursion_m(np.asarray(s.x_m), np.asarray(s.y_m), mission.region)
    statuses = [o.status for o in report.outcomes]
    # the test does what it says: traces were flown and met the boundary
    assert (np.asarray(s.phase) == Phase.TRACE).sum() > 1000
    assert statuses.count("boundary") >= 3, statuses
    worst = int(np.argmax(out))
    assert out.max() <= EXCURSION_LIMIT_M, (
        f"{out.max():.3f} m outside the area at ({s.x_m[worst]:.2f}, {s.y_m[worst]:.2f}), "
        f"phase {Phase(int(s.phase[worst])).name}")
