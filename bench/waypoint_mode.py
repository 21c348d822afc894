"""What flying contours as waypoints (stock autopilots) costs against onboard tracing.

For the demo and the paper missions (and ``plume``: the paper's setting over the
narrow-plume field of ``bench/efficiency.py``, where the first estimates miss the sources)
and each seed, the whole in-process DFC loop runs twice with the same field, planner,
reconstruction and cost accounting: once with the tracer on board (``trace``: search near
the start point, follow the iso-line with the vehicle's own samples), once as a stock
autopilot flies it in ``econdor run`` (``waypoints``: the estimated contour of each piece,
Douglas-Peucker-simplified to ``--tolerance-m``, flown as waypoints). Printed per mission
and style (median over the seeds, and the median of the per-seed differences
waypoints - trace, with how many seeds waypoints was worse):

* final MAE (dB), total flown distance (km), contour distance (km: traced, or flown along the
  estimated contours), levels traced, iterations;
* MAE after the same flight distance (the last iteration finished within the smaller of the
  two runs' totals), so that a style which flies less is not penalised for stopping early.

    python bench/waypoint_mode.py                  # 10 seeds, demo and paper
    python bench/waypoint_mode.py --quick          # 3 seeds, a smoke run
    python bench/waypoint_mode.py --seeds 0:20 --workers 2 --markdown --json runs.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from econdor_gcs.config import Mission, load_mission, parse_mission  # noqa: E402
from econdor_gcs.core.tasks import TaskStyle  # noqa: E402
from econdor_lab.study import parse_seeds, run_seed  # noqa: E402
from econdor_lab.workers import WorkerPool  # noqa: E402

MISSIONS = ("demo", "paper")
PLUME = {"model": "plume", "sources": 3, "sigma_min_m": 3.0, "sigma_max_m": 6.0,
         "background": 10.0}


def mission_named(name: str) -> Mission:
    """``demo`` / ``paper`` from missions/, or ``plume``: the paper's setting, plume field."""
    if name != "plume":
        return load_mission(ROOT / "missions" / f"{name}.yaml")
    base = load_mission(ROOT / "missions" / "paper.yaml")
    return parse_mission({"name": "plume", "field": PLUME, "vehicles": {"count": 1},
                          "algorithm": {"max_iterations": base.algorithm.max_iterations,
                                        "min_iterations": base.algorithm.min_iterations,
                                        "lloyd_bins": base.algorithm.lloyd_bins}},
                         base_dir=ROOT / "missions")
STYLES = (TaskStyle.TRACE, TaskStyle.WAYPOINTS)


def one(args: tuple[str, int, str, float]) -> dict:
    name, seed, style, tolerance_m = args
    mission = mission_named(name)
    t0 = time.perf_counter()
    r = run_seed(mission, seed, mission.algorithm.planner, None, style=TaskStyle(style),
                 tolerance_m=tolerance_m)
    s = r["summary"]
    curve = [(row["flight_distance_m"], row["mae_db"]) for row in r["rows"]]
    return {"mission": name, "seed": seed, "style": style, "wall_s": time.perf_counter() - t0,
            "mae_db": s["final_mae_db"], "flown_m": s["flight_distance_m"],
            "contour_m": s["contour_distance_m"], "iterations": s["iterations"],
            "levels": sum(len(lv) for lv in r["levels"]), "curve": curve}


def mae_at(curve: list[tuple[float, float]], distance_m: float) -> float:
    """MAE (dB) after the last iteration finished within ``distance_m``."""
    done = [mae for d, mae in curve if d <= distance_m + 1e-6]
    return done[-1] if done else math.nan


def med(values: list[float]) -> float:
    v = [x for x in values if not math.isnan(x)]
    return statistics.median(v) if v else math.nan


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default=None, help="A:B or a comma list (default 0:10)")
    ap.add_argument("--quick", action="store_true", help="3 seeds")
    ap.add_argument("--missions", default=",".join(MISSIONS))
    ap.add_argument("--tolerance-m", type=float, default=1.0)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--markdown", action="store_true")
    ap.add_argument("--json", default=None, help="also write every run's numbers here")
    a = ap.parse_args()
    seeds = parse_seeds(a.seeds or ("0:3" if a.quick else "0:10"))
    missions = [m for m in a.missions.split(",") if m]
    jobs = [(m, s, st.value, a.tolerance_m) for m in missions for s in seeds for st in STYLES]
    t0 = time.perf_counter()
    if a.workers > 1:
        with WorkerPool(a.workers) as pool:
            results = list(pool.map(one, jobs))
    else:
        results = [one(j) for j in jobs]
    wall = time.perf_counter() - t0
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")
    by = {(r["mission"], r["seed"], r["style"]): r for r in results}
    print(f"waypoint mode vs onboard tracing: {len(seeds)} seeds x {len(missions)} missions x "
          f"2 styles, tolerance {a.tolerance_m:g} m, {len(results)} runs in {wall:.0f} s wall "
          f"on {a.workers} workers")
    head = ("mission", "style", "final MAE dB", "flown km", "contour km", "levels",
            "iterations", "MAE dB @ same km", "Δ MAE dB (worse)", "Δ flown km")
    if a.markdown:
        print("|" + "|".join(head) + "|")
        print("|" + "|".join("---" for _ in head) + "|")
    else:
        print("  ".join(f"{h:>16}" for h in head))
    for m in missions:
        for st in STYLES:
            rs = [by[(m, s, st.value)] for s in seeds]
            same, d_mae, d_km, worse = [], [], [], 0
            for s in seeds:
                t, w = by[(m, s, "trace")], by[(m, s, "waypoints")]
                common = min(t["flown_m"], w["flown_m"])
                same.append(mae_at(by[(m, s, st.value)]["curve"], common))
                d_mae.append(w["mae_db"] - t["mae_db"])
                d_km.append((w["flown_m"] - t["flown_m"]) / 1000)
                worse += w["mae_db"] > t["mae_db"]
            delta = (f"{med(d_mae):+.1f} ({worse}/{len(seeds)})", f"{med(d_km):+.2f}") \
                if st == TaskStyle.WAYPOINTS else ("—", "—")
            row = (m, st.value, f"{med([r['mae_db'] for r in rs]):.1f}",
                   f"{med([r['flown_m'] for r in rs]) / 1000:.2f}",
                   f"{med([r['contour_m'] for r in rs]) / 1000:.2f}",
                   f"{med([r['levels'] for r in rs]):.0f}",
                   f"{med([r['iterations'] for r in rs]):.0f}", f"{med(same):.1f}", *delta)
            if a.markdown:
                print("|" + "|".join(row) + "|")
            else:
                print("  ".join(f"{c:>16}" for c in row))


if __name__ == "__main__":
    main()
