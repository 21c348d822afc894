"""What the threshold planner's policy could reach with a perfect tracer.

An idealised study, not the product: the vehicle flies the polylines it is given (sampled
every 0.8 m, transit included, no turning, no search), and a piece of the true iso-line
that its samples cross is traced perfectly — entered at the crossing, a closed piece once
round, an open one to its nearer end first, flown back to the entry and on to the other
end (``--oracle-ends``: straight to the other end and back along the piece when that is
nearer, as if the tracer knew where the piece comes back into the area). The policy is
the product's (``explore: lines``) as it was before its start line became the one from the
vehicle through the centre (the diagonal from the home corner): the line through the
middle from the home corner, in
steps (a crossing traced at once, then the line resumed) or whole (``--whole-start``:
its crossings traced after it), then the line through the most uncovered ground per
metre (north-south or east-west, full width or half, every 5 m), unweighted. The estimate
is checked after every line and every trace, as the bench checks the planner at the end
of each iteration, and the distance at which the mid-level iso-line error is first
≤ 0.5 m is divided by the best survey's for the same error (bench/efficiency.py).

    python bench/ideal_policy.py --seeds 0:40 --cache runs/survey-cache
    python bench/ideal_policy.py --seeds 0:40 --whole-start --cache runs/survey-cache
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from report import ISO_TARGET_M  # noqa: E402
from runs import mid_level, mission_for  # noqa: E402
from surveys import SurveyScan  # noqa: E402

from econdor_gcs.core.contours import contour_pieces  # noqa: E402
from econdor_gcs.core.geometry import path_length  # noqa: E402
from econdor_gcs.core.metrics import isoline_error  # noqa: E402
from econdor_gcs.core.routes import best_lines, gap_lines  # noqa: E402
from econdor_gcs.core.spline import reconstruct  # noqa: E402
from econdor_gcs.core.uncertainty import resample_polyline  # noqa: E402
from econdor_lab.study import parse_seeds  # noqa: E402
from econdor_lab.workers import WorkerPool  # noqa: E402

STEP_M = 0.8
EXPLORE_M = 10.0
MAX_M = 1500.0


class IdealRun:
    """One seed: the true iso-line's pieces, what was flown, and when the error got there."""

    def __init__(self, field: str, seed: int, stepped: bool, oracle_ends: bool) -> None:
        m = mission_for(field, 0.0, "lawnmower", "auto")
        self.mission, self.field = m, m.build_field(seed)
        xx, yy = m.grid.mesh
        self.cells = np.column_stack([xx.ravel(), yy.ravel()])
        self.truth = np.asarray(self.field(xx, yy))
        self.level = mid_level(m, seed)
        self.pieces = [p.points_m for p in contour_pieces(self.truth, m.grid,
                                                          np.array([self.level]), 1.0)]
        self.trees = [cKDTree(p) for p in self.pieces]
        self.traced = [False] * len(self.pieces)
        self.pending: list[tuple[int, np.ndarray]] = []
        self.xy: list[np.ndarray] = []
        self.v: list[float] = []
        self.pos = np.array([m.region.xmin, m.region.ymin])
        self.flown_m = 0.0
        self.reached_m = math.nan
        self.stepped, self.oracle_ends = stepped, oracle_ends

    def check(self) -> None:
        if not math.isnan(self.reached_m) or len(self.xy) < 10:
            return
        p, v = np.array(self.xy), np.array(self.v)
        est = reconstruct(p[:, 0], p[:, 1], v, self.mission.grid)
        if isoline_error(self.truth, est, self.mission.grid, self.level) <= ISO_TARGET_M:
            self.reached_m = self.flown_m

    def piece_at(self, q: np.ndarray) -> int | None:
        d = [float(t.query(q)[0]) for t in self.trees]
        k = int(np.argmin(d))
        return k if d[k] < 3.0 else None

    def fly(self, poly: np.ndarray, stop_at_crossing: bool = False) -> np.ndarray | None:
        """Fly ``poly`` from where the vehicle is; the first crossing of an untraced piece
        if ``stop_at_crossing`` (else such crossings are kept for later)."""
        q = resample_polyline(np.vstack([self.pos, poly]), STEP_M)
        v = np.asarray(self.field(q[:, 0], q[:, 1]))
        for i in range(1, len(q)):
            self.flown_m += float(np.hypot(*(q[i] - q[i - 1])))
            self.xy.append(q[i])
            self.v.append(float(v[i]))
            self.pos = q[i]
            if (v[i] - self.level) * (v[i - 1] - self.level) < 0:
                k = self.piece_at(q[i])
                if k is not None and not self.traced[k]:
                    if stop_at_crossing:
                        return q[i]
                    self.pending.append((k, q[i].copy()))
        return None

    def trace(self, k: int, entry: np.ndarray) -> None:
        self.traced[k] = True
        p = self.pieces[k]
        i = int(self.trees[k].query(entry)[1])
        if np.allclose(p[0], p[-1]):
            self.fly(np.vstack([p[i:-1], p[:i + 1]]))
        else:
            a, b = p[:i + 1][::-1], p[i:]
            first, second = (a, b) if path_length(*a.T) <= path_length(*b.T) else (b, a)
            self.fly(first)
            if self.oracle_ends and (np.hypot(*(first[-1] - second[-1]))
                                     < np.hypot(*(first[-1] - second[0]))):
                self.fly(second[::-1])
            else:
                self.fly(second)  # the flight back to the entry is part of it
        self.check()

    def flush(self) -> None:
        """Trace the crossed pieces not traced yet, nearest first."""
        while True:
            left = [(k, e) for k, e in self.pending if not self.traced[k]]
            if not left:
                self.pending = []
                return
            k, e = min(left, key=lambda ke: float(np.hypot(*(ke[1] - self.pos))))
            self.trace(k, e)

    def run_line(self, poly: np.ndarray) -> None:
        rest = resample_polyline(np.asarray(poly, dtype=float), 1.0)
        while len(rest) >= 2:
            hit = self.fly(rest, stop_at_crossing=self.stepped)
            self.check()
            if hit is None:
                self.flush()
                return
            k = self.piece_at(hit)
            if k is not None:
                self.trace(k, hit)
            self.flush()
            rest = rest[int(np.argmin(np.hypot(*(rest - hit).T))):]

    def explore(self) -> bool:
        near, _ = cKDTree(np.array(self.xy)).query(self.cells)
        ranked = best_lines(self.cells, near, np.ones(len(near)), EXPLORE_M,
                            gap_lines(self.mission.region, 5.0), self.pos)
        if not ranked:
            return False
        self.run_line(ranked[0])
        return True

    def run(self) -> float:
        r = self.mission.region
        mid = 0.5 * (r.xmin + r.xmax)
        self.fly(np.array([[mid, r.ymin + 0.5]]))
        self.run_line(np.array([[mid, r.ymin + 0.5], [mid, r.ymax - 0.5]]))
        while math.isnan(self.reached_m) and self.flown_m < MAX_M and self.explore():
            pass
        self.check()
        return self.reached_m


def one(args: tuple[str, int, bool, bool, str | None]) -> tuple[int, float, float]:
    field, seed, stepped, oracle_ends, cache = args
    scan = SurveyScan(field, seed, "auto", Path(cache) if cache else None)
    row = scan.shortest_reaching(lambda row: row["iso"][1] <= ISO_TARGET_M, 3000.0)
    survey_m = row["flight_m"] if row else math.nan
    return seed, IdealRun(field, seed, stepped, oracle_ends).run(), survey_m


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--field", default="paper")
    p.add_argument("--seeds", default="0:40")
    p.add_argument("--whole-start", action="store_true",
                   help="fly the start line whole, its crossings traced after it")
    p.add_argument("--oracle-ends", action="store_true",
                   help="an open piece's other end is flown to when that is nearer")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--cache", default=None, help="the survey cache of bench/efficiency.py")
    a = p.parse_args()
    jobs = [(a.field, s, not a.whole_start, a.oracle_ends, a.cache)
            for s in parse_seeds(a.seeds)]
    with WorkerPool(a.workers) as pool:
        rows = list(pool.map(one, jobs))
    ratios = []
    for seed, ideal_m, survey_m in rows:
        ratios.append(ideal_m / survey_m if ideal_m == ideal_m else math.inf)
        print(f"seed {seed}: {ideal_m / 1000:.2f} km against the survey's "
              f"{survey_m / 1000:.2f} km: {ratios[-1]:.2f}x")
    print(f"median {statistics.median(ratios):.3f}x, {sum(r <= 0.5 for r in ratios)} of "
          f"{len(ratios)} runs <= 0.5x ({'stepped' if not a.whole_start else 'whole'} start"
          f"{', oracle ends' if a.oracle_ends else ''})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
