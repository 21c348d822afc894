"""E-CONDOR with the textbook Lloyd-Max levels (our default) against the authors' variant.

The authors' ``Lloyd_Max_2.m`` recomputes the outer decision thresholds in every iteration
as ``(x0 + l1) / 2`` and ``(lM + xend) / 2`` and their first batch uses a 500-bin histogram;
we implement the textbook eqs. 4-5 (outer thresholds at the ends of the range) with 200
bins. This runs the paper's setting (missions/paper.yaml: authors' field, one vehicle, the
diagonals, 8 iterations) with both and prints, per variant, the median over the seeds of
delta_0, the first batch's levels, the final MAE, the flight and the MAE after 5 and 10 km.

    python bench/fidelity.py --seeds 0:10 --markdown
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from econdor_gcs.config import load_mission  # noqa: E402
from econdor_lab.study import parse_seeds, run_seed  # noqa: E402
from econdor_lab.workers import WorkerPool  # noqa: E402

VARIANTS = ("textbook", "authors")


def one(args: tuple[str, int]) -> dict[str, Any]:
    variant, seed = args
    mission = load_mission(ROOT / "missions" / "paper.yaml").with_overrides(lloyd_variant=variant)
    t0 = time.perf_counter()
    r = run_seed(mission, seed, "econdor", None)
    return {"variant": variant, "seed": seed, "rows": r["rows"], "levels": r["levels"],
            "delta": r["delta"], "wall_s": time.perf_counter() - t0}


def at(rows: list[dict[str, Any]], budget_m: float) -> float:
    best = math.nan
    for row in rows:
        if row["flight_distance_m"] <= budget_m:
            best = row["mae_db"]
    return best


def med(values: list[float]) -> float:
    v = [x for x in values if not math.isnan(x)]
    return statistics.median(v) if v else math.nan


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="0:10")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--markdown", action="store_true")
    a = p.parse_args()
    seeds = parse_seeds(a.seeds)
    t0 = time.perf_counter()
    with WorkerPool(a.workers) as pool:
        results = list(pool.map(one, [(v, s) for v in VARIANTS for s in seeds]))
    bar = "|" if a.markdown else " "
    print(f"# E-CONDOR, paper setting, {len(seeds)} seeds, {time.perf_counter() - t0:.0f} s\n")
    head = ["Lloyd-Max", "delta_0", "first levels (seed 0)", "final MAE dB", "flown km",
            "MAE dB @5 km", "MAE dB @10 km", "levels traced (sum per run)"]
    print(bar + bar.join(head) + bar)
    if a.markdown:
        print(bar + bar.join("---" for _ in head) + bar)
    for v in VARIANTS:
        rs = [r for r in results if r["variant"] == v]
        first = next(r for r in sorted(rs, key=lambda r: r["seed"]))["levels"][1]
        print(bar + bar.join([
            v, f"{med([r['delta'][1] for r in rs]):.2f}",
            ", ".join(f"{x:.1f}" for x in first),
            f"{med([r['rows'][-1]['mae_db'] for r in rs]):.1f}",
            f"{med([r['rows'][-1]['flight_distance_m'] / 1000 for r in rs]):.1f}",
            f"{med([at(r['rows'], 5000.0) for r in rs]):.1f}",
            f"{med([at(r['rows'], 10000.0) for r in rs]):.1f}",
            f"{med([sum(x['levels_traced'] for x in r['rows']) for r in rs]):.0f}"]) + bar)
    return 0


if __name__ == "__main__":
    sys.exit(main())
