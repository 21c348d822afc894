"""How much flying each planner needs, on the paper's field and on the plume field.

For every field model, seed and planner this runs the whole in-process DFC loop (real
tracing, same reconstruction and cost accounting for all planners) and prints:

* the total flight distance needed to reach MAE targets (median over the seeds that
  reached it, and how many did);
* the MAE reached at fixed flight budgets (the last iteration finished within budget);
* how often a planner stalls: over the second half of its flight it improved by less
  than 1 dB while still worse than the best target;
* the iso-line error (mean distance in metres between the estimated and the true
  contour at 25, 50 and 75 % of the true span) at the same budgets.

    python bench/efficiency.py                 # 20 seeds, both fields
    python bench/efficiency.py --quick         # 4 seeds, a smoke run
    python bench/efficiency.py --seeds 0:40 --workers 2 --markdown
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from econdor_gcs.mission import load_mission, parse_mission  # noqa: E402
from econdor_lab.study import PLANNERS, parse_seeds, run_seed  # noqa: E402

TARGETS_DB = (-10.0, -20.0, -30.0)
FIELDS = {
    "paper": {"model": "authors"},
    "plume": {"model": "plume", "sources": 3, "sigma_min_m": 3.0, "sigma_max_m": 6.0,
              "background": 10.0},
}


def mission_for(field: str, budget_m: float, max_iterations: int):
    base = load_mission(ROOT / "missions" / "paper.yaml")
    raw = {
        "name": f"efficiency-{field}",
        "field": FIELDS[field],
        "vehicles": {"count": 1},
        "algorithm": {"max_iterations": max_iterations, "min_iterations": max_iterations,
                      "flight_budget_m": budget_m, "lloyd_bins": base.algorithm.lloyd_bins},
    }
    return parse_mission(raw, base_dir=ROOT / "missions")


def one(args: tuple[str, int, str, float, int]) -> dict:
    field, seed, planner, budget_m, iters = args
    t0 = time.perf_counter()
    r = run_seed(mission_for(field, budget_m, iters), seed, planner, None)
    return {"field": field, "seed": seed, "planner": planner, "rows": r["rows"],
            "summary": r["summary"], "wall_s": time.perf_counter() - t0}


def distance_to(rows: list[dict], target_db: float) -> float:
    for row in rows:
        if row["mae_db"] <= target_db:
            return row["flight_distance_m"]
    return math.nan


def at_budget(rows: list[dict], budget_m: float, key: str) -> float:
    best = math.nan
    for row in rows:
        if row["flight_distance_m"] <= budget_m:
            best = row[key]
    return best


def iso_mean(row: dict) -> float:
    v = [row[k] for k in ("isoline_p25_m", "isoline_p50_m", "isoline_p75_m")
         if not math.isnan(row[k])]
    return sum(v) / len(v) if v else math.nan


def stalled(rows: list[dict]) -> bool:
    if len(rows) < 3:
        return False
    total = rows[-1]["flight_distance_m"]
    half = at_budget(rows, total / 2, "mae_db")
    final = rows[-1]["mae_db"]
    return final > min(TARGETS_DB) and (math.isnan(half) or half - final < 1.0)


def med(values: list[float]) -> float:
    v = [x for x in values if not math.isnan(x)]
    return statistics.median(v) if v else math.nan


def fmt(x: float, spec: str = ".1f") -> str:
    return "—" if math.isnan(x) else format(x, spec)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="0:20")
    p.add_argument("--fields", default="paper,plume")
    p.add_argument("--planners", default=",".join(PLANNERS))
    p.add_argument("--budget", type=float, default=30_000.0, help="flight budget per run (m)")
    p.add_argument("--iterations", type=int, default=8)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--quick", action="store_true", help="4 seeds, 10 km budget")
    p.add_argument("--markdown", action="store_true", help="print Markdown tables")
    a = p.parse_args()
    if a.quick:
        a.seeds, a.budget = "0:4", 10_000.0
    seeds = parse_seeds(a.seeds)
    fields = a.fields.split(",")
    planners = a.planners.split(",")
    jobs = [(f, s, pl, a.budget, a.iterations) for f in fields for s in seeds for pl in planners]
    t0 = time.perf_counter()
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")  # spawned workers: one BLAS thread each
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=a.workers, mp_context=ctx) as pool:
        results = list(pool.map(one, jobs))
    wall = time.perf_counter() - t0
    budgets = [b for b in (2_000.0, 5_000.0, 10_000.0, 20_000.0, 30_000.0) if b <= a.budget]
    bar = "|" if a.markdown else " "
    print(f"# efficiency: {len(seeds)} seeds, budget {a.budget / 1000:.0f} km, "
          f"max {a.iterations} iterations, {len(jobs)} runs in {wall:.0f} s")
    for field in fields:
        print(f"\n## field: {field}\n")
        head = ["planner", *[f"km to {t:.0f} dB" for t in TARGETS_DB],
                *[f"MAE dB @{b / 1000:.0f} km" for b in budgets],
                *[f"iso m @{b / 1000:.0f} km" for b in budgets], "stalls", "wall s/run"]
        print(bar + bar.join(head) + bar)
        if a.markdown:
            print(bar + bar.join("---" for _ in head) + bar)
        for pl in planners:
            rs = [r for r in results if r["field"] == field and r["planner"] == pl]
            cells = [pl]
            for t in TARGETS_DB:
                d = [distance_to(r["rows"], t) for r in rs]
                n = sum(not math.isnan(x) for x in d)
                cells.append(f"{fmt(med(d) / 1000, '.1f')} ({n}/{len(rs)})")
            for b in budgets:
                cells.append(fmt(med([at_budget(r["rows"], b, "mae_db") for r in rs])))
            for b in budgets:
                isos = []
                for r in rs:
                    row = None
                    for x in r["rows"]:
                        if x["flight_distance_m"] <= b:
                            row = x
                    isos.append(iso_mean(row) if row else math.nan)
                cells.append(fmt(med(isos), ".2f"))
            cells.append(f"{sum(stalled(r['rows']) for r in rs)}/{len(rs)}")
            cells.append(fmt(med([r["wall_s"] for r in rs]), ".0f"))
            print(bar + bar.join(cells) + bar)
    return 0


if __name__ == "__main__":
    sys.exit(main())
