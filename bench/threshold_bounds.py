"""How short a flight could map a field's mid-level iso-line to 0.5 m, if one knew where it is.

An idealised study, not the product: samples every 0.8 m along the given polylines (as at
8 m/s and 10 Hz), no turning, no search, no tracer, the product's reconstruction
(``auto``) and iso-line error. Per seed it evaluates:

* ``surveyK``: K north-south lines from the west edge to the east edge (the ``lawnmower``
  planner's lines), the lines and the cross legs counted;
* ``linesK``: K lines at the centres of equal strips (the adaptive planner's start);
* ``kK_dD``: K such lines, then every part of the *true* iso-line farther than D m from
  them traced exactly (D = 0: all of it), the parts visited nearest first from the home
  corner, the transits counted — what a planner that knew where the iso-line is, and
  paid nothing to find it, would fly.

It prints each seed's shortest pattern of each kind that reaches the target, and the
median over the seeds of the best trace-based flight over the best lines-only one: a
floor, on that field, for planners that map an iso-line by tracing it.

    python bench/threshold_bounds.py --field authors --seeds 900:920
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runs import mid_level, mission_for  # noqa: E402

from econdor_gcs.core.contours import ContourPiece, contour_pieces  # noqa: E402
from econdor_gcs.core.geometry import path_length  # noqa: E402
from econdor_gcs.core.metrics import isoline_error  # noqa: E402
from econdor_gcs.core.spline import reconstruct  # noqa: E402
from econdor_gcs.core.uncertainty import resample_polyline  # noqa: E402
from econdor_lab.study import parse_seeds  # noqa: E402

TARGET_M = 0.5
STEP_M = 0.8


def lines(k: int, edges: bool) -> tuple[np.ndarray, float]:
    """Samples of ``k`` north-south lines and their flight (lines and cross legs)."""
    if k == 0:
        return np.zeros((0, 2)), 0.0
    xs = np.linspace(0.0, 100.0, k) if edges else (np.arange(k) + 0.5) * 100.0 / k
    ys = np.arange(0.5, 99.5 + 1e-9, STEP_M)
    pts = np.column_stack([np.repeat(xs, ys.size), np.tile(ys, k)])
    return pts, k * float(ys[-1] - ys[0]) + float(xs[-1] - xs[0])


def parts_beyond(pieces: list[ContourPiece], pts: np.ndarray, d_m: float
                 ) -> tuple[np.ndarray, float]:
    """The parts of ``pieces`` farther than ``d_m`` from ``pts`` (sampled), and the flight
    to trace them: their length and the transits, nearest part next from the home corner."""
    tree = cKDTree(pts) if len(pts) else None
    parts = []
    for p in pieces:
        q = resample_polyline(p.points_m, STEP_M)
        far = np.ones(len(q), bool) if tree is None else tree.query(q)[0] > d_m
        edges = np.flatnonzero(np.diff(np.r_[0, far.astype(np.int8), 0]))
        parts += [q[a:b] for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= 2]
    flight = sum(path_length(s[:, 0], s[:, 1]) for s in parts)
    pos, left = np.zeros(2), list(parts)
    while left:
        gaps = [min(np.hypot(*(s[0] - pos)), np.hypot(*(s[-1] - pos))) for s in left]
        i = int(np.argmin(gaps))
        s = left.pop(i)
        flight += gaps[i]
        pos = s[-1] if np.hypot(*(s[0] - pos)) <= np.hypot(*(s[-1] - pos)) else s[0]
    return (np.vstack(parts) if parts else np.zeros((0, 2))), flight


def one_seed(field: str, seed: int) -> dict[str, tuple[float, float]]:
    m = mission_for(field, 0.0, "lawnmower", "auto")
    truth, grid = m.build_field(seed), m.grid
    xx, yy = grid.mesh
    tg = np.asarray(truth(xx, yy))
    level = mid_level(m, seed)
    pieces = contour_pieces(tg, grid, np.array([level]), 1.0)

    def error(pts: np.ndarray) -> float:
        v = np.asarray(truth(pts[:, 0], pts[:, 1]))
        return isoline_error(tg, reconstruct(pts[:, 0], pts[:, 1], v, grid), grid, level)

    out: dict[str, tuple[float, float]] = {}
    for k in range(2, 16):
        for edges, name in ((True, "survey"), (False, "lines")):
            pts, flight = lines(k, edges)
            out[f"{name}{k}"] = (flight, error(pts))
    for k in range(4):
        for d in (0.0, 3.0, 5.0, 8.0, 10.0):
            pts, flight = lines(k, False)
            traced, more = parts_beyond(pieces, pts, d if k else 0.0)
            both = np.vstack([pts, traced])
            if len(both) >= 10:
                out[f"k{k}_d{d:g}"] = (flight + more, error(both))
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--field", default="authors")
    p.add_argument("--seeds", default="900:920")
    p.add_argument("--json", default=None, help="write every pattern's flight and error here")
    a = p.parse_args()
    ratios, saved = [], {}
    for seed in parse_seeds(a.seeds):
        got = one_seed(a.field, seed)
        saved[seed] = got

        def best(prefix: str, got: dict[str, tuple[float, float]] = got
                 ) -> tuple[float, str]:
            ok = [(f, k) for k, (f, e) in got.items() if k.startswith(prefix) and e <= TARGET_M]
            return min(ok) if ok else (math.inf, "—")

        lines_only = min(best("survey"), best("lines"))
        traced = best("k")
        ratios.append(traced[0] / lines_only[0])
        print(f"{a.field} {seed}: lines only {lines_only[0]:.0f} m ({lines_only[1]}), "
              f"traced {traced[0]:.0f} m ({traced[1]}): {ratios[-1]:.3f}", flush=True)
    print(f"median, traced over lines only: {statistics.median(ratios):.3f} "
          f"({sum(r <= 0.5 for r in ratios)} of {len(ratios)} seeds <= 0.5)")
    if a.json:
        Path(a.json).write_text(json.dumps(saved))
    return 0


if __name__ == "__main__":
    sys.exit(main())
