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
  paid nothing to find it, would fly;
* ``kK_dD_cC`` (``--cuts``): the same with each traced part flown as its Douglas-Peucker
  simplification to C m (a path that cuts the iso-line's bends by up to C m);
* ``..._t`` (``--sample-transits``): the same with the transits' samples in the map (a
  vehicle samples on its way; without, only the lines and the traced parts are);
* ``iso``: the iso-line's length, and the error of a map from samples on it alone.

It prints each seed's shortest pattern of each kind that reaches the target, and the
median over the seeds of the best trace-based flight over the best lines-only one: a
floor, on that field, for planners that map an iso-line by tracing it. With ``--surveys``
(a bench's saved rows) also over the bench's best survey for the seed, and the iso-line's
length and ``k0_d0`` (the iso-line and the transits between its pieces, nearest first,
nothing else) over it: about what a flight that passes along the whole iso-line costs.

    python bench/threshold_bounds.py --field authors --seeds 900:920 \
        --surveys docs/results/data/threshold-fresh.jsonl.gz
"""

from __future__ import annotations

import argparse
import gzip
import json
import math
import statistics
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from shapely.geometry import LineString

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


def parts_beyond(pieces: list[ContourPiece], pts: np.ndarray, d_m: float, cut_m: float = 0.0,
                 sample_transits: bool = False) -> tuple[np.ndarray, float]:
    """The parts of ``pieces`` farther than ``d_m`` from ``pts`` (sampled), and the flight
    to trace them: their length and the transits, nearest part next from the home corner.
    ``cut_m`` > 0: each part is flown as its Douglas-Peucker simplification to that
    tolerance (corners cut by up to ``cut_m``: shorter than the iso-line where it bends).
    ``sample_transits``: the samples of the transits are returned too (as a vehicle takes
    them); else only the parts'."""
    tree = cKDTree(pts) if len(pts) else None
    parts = []
    for p in pieces:
        q = resample_polyline(p.points_m, STEP_M)
        far = np.ones(len(q), bool) if tree is None else tree.query(q)[0] > d_m
        edges = np.flatnonzero(np.diff(np.r_[0, far.astype(np.int8), 0]))
        parts += [q[a:b] for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= 2]
    if cut_m > 0.0:
        parts = [resample_polyline(np.asarray(LineString(s).simplify(cut_m).coords), STEP_M)
                 for s in parts]
    flight = sum(path_length(s[:, 0], s[:, 1]) for s in parts)
    pos, left, transits = np.zeros(2), list(parts), []
    while left:
        gaps = [min(np.hypot(*(s[0] - pos)), np.hypot(*(s[-1] - pos))) for s in left]
        i = int(np.argmin(gaps))
        s = left.pop(i)
        flight += gaps[i]
        near, far_end = (s[0], s[-1]) if np.hypot(*(s[0] - pos)) <= np.hypot(*(s[-1] - pos)) \
            else (s[-1], s[0])
        if sample_transits and gaps[i] > STEP_M:
            transits.append(resample_polyline(np.array([pos, near]), STEP_M))
        pos = far_end
    return (np.vstack(parts + transits) if parts else np.zeros((0, 2))), flight


def one_seed(field: str, seed: int, cuts: tuple[float, ...] = (0.0,),
             transits: tuple[bool, ...] = (False,)) -> dict[str, tuple[float, float]]:
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
    # the iso-line itself: its length, and the error of a map made from it alone
    on_line = np.vstack([resample_polyline(p.points_m, STEP_M) for p in pieces])
    out["iso"] = (sum(path_length(p.points_m[:, 0], p.points_m[:, 1]) for p in pieces),
                  error(on_line))
    for k in range(2, 16):
        for edges, name in ((True, "survey"), (False, "lines")):
            pts, flight = lines(k, edges)
            out[f"{name}{k}"] = (flight, error(pts))
    for k in range(4):
        for d in (0.0, 3.0, 5.0, 8.0, 10.0):
            for cut in cuts:
                for sampled in transits:
                    pts, flight = lines(k, False)
                    traced, more = parts_beyond(pieces, pts, d if k else 0.0, cut, sampled)
                    both = np.vstack([pts, traced])
                    if len(both) >= 10:
                        name = (f"k{k}_d{d:g}" + (f"_c{cut:g}" if cut else "")
                                + ("_t" if sampled else ""))
                        out[name] = (flight + more, error(both))
    return out


def _bench_surveys(path: str, field: str) -> dict[int, float]:
    """Per seed, the flight of the bench's best survey to the iso-line target (its
    ``to_iso``), from a bench's saved rows."""
    opener = gzip.open if path.endswith(".gz") else open
    with opener(path, "rt") as f:
        rows = [json.loads(line) for line in f if line.strip()]
    return {int(r["seed"]): float(r["to_iso"]["flight_m"]) for r in rows
            if r.get("kind") == "survey" and r.get("field") == field
            and r.get("to_iso", {}).get("flight_m") is not None}


def main() -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--field", default="authors")
    p.add_argument("--seeds", default="900:920")
    p.add_argument("--json", default=None, help="write every pattern's flight and error here")
    p.add_argument("--cuts", default="0", help=(
        "Douglas-Peucker tolerances (m, comma-separated) the traced parts are also flown "
        "simplified to: a path that cuts the iso-line's bends instead of following them"))
    p.add_argument("--surveys", default=None, help=(
        "the bench's saved rows (e.g. docs/results/data/threshold-fresh.jsonl.gz): also "
        "give the best trace-based flight over the bench's best survey for the seed"))
    p.add_argument("--sample-transits", action="store_true", help=(
        "also fly each trace-based pattern with the samples of its transits between the "
        "parts (as a vehicle takes them; names ending _t)"))
    a = p.parse_args()
    cuts = tuple(float(c) for c in a.cuts.split(","))
    transits = (False, True) if a.sample_transits else (False,)
    bench = _bench_surveys(a.surveys, a.field) if a.surveys else {}
    ratios, to_bench, saved = [], [], {}
    iso_only: list[tuple[float, float, float, float]] = []
    for seed in parse_seeds(a.seeds):
        got = one_seed(a.field, seed, cuts, transits)
        saved[seed] = got

        def best(prefix: str, got: dict[str, tuple[float, float]] = got
                 ) -> tuple[float, str]:
            ok = [(f, k) for k, (f, e) in got.items() if k.startswith(prefix) and e <= TARGET_M]
            return min(ok) if ok else (math.inf, "—")

        lines_only = min(best("survey"), best("lines"))
        traced = best("k")
        # no lines-only pattern of the study (2-15 lines) reaching the target: no ratio
        ratios.append(traced[0] / lines_only[0] if math.isfinite(lines_only[0]) else math.nan)
        also = ""
        if seed in bench:
            to_bench.append(traced[0] / bench[seed])
            iso_only.append((got["iso"][0] / bench[seed], got["k0_d0"][0] / bench[seed],
                             got["k0_d0"][1], got.get("k0_d0_t", (math.nan, math.nan))[1]))
            also = (f"; bench survey {bench[seed]:.0f} m: {to_bench[-1]:.3f}; the iso-line "
                    f"{got['iso'][0]:.0f} m, with the transits between its pieces "
                    f"{got['k0_d0'][0]:.0f} m (error {got['k0_d0'][1]:.2f} m)")
        print(f"{a.field} {seed}: lines only {lines_only[0]:.0f} m ({lines_only[1]}), "
              f"traced {traced[0]:.0f} m ({traced[1]}): {ratios[-1]:.3f}{also}", flush=True)
    known = [r for r in ratios if not math.isnan(r)]
    unknown = (f"; {len(ratios) - len(known)} seeds without a lines-only pattern of 2-15 lines "
               "that reaches the target left out" if len(known) < len(ratios) else "")
    print(f"median, traced over lines only: {statistics.median(known) if known else math.nan:.3f} "
          f"({sum(r <= 0.5 for r in known)} of {len(known)} seeds <= 0.5{unknown})")
    if to_bench:
        print(f"median, traced over the bench's best survey: {statistics.median(to_bench):.3f} "
              f"({sum(r <= 0.5 for r in to_bench)} of {len(to_bench)} seeds <= 0.5)")
        alone, flown, errs, errs_t = zip(*iso_only, strict=True)
        with_t = (f"; with the transits' samples on {sum(e <= TARGET_M for e in errs_t)}"
                  if a.sample_transits else "")
        print(f"median over the bench's best survey: the iso-line's length "
              f"{statistics.median(alone):.3f}, the iso-line and the transits between its "
              f"pieces, nearest first from the home corner, {statistics.median(flown):.3f} (a "
              f"map from the iso-line's samples alone within {TARGET_M} m on "
              f"{sum(e <= TARGET_M for e in errs)}{with_t} of {len(errs)} seeds)")
    if a.json:
        Path(a.json).write_text(json.dumps(saved))
    return 0


if __name__ == "__main__":
    sys.exit(main())
