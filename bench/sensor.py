"""What a realistic sensor costs, and what the station's lag correction gives back.

In-process runs (the same sensor model as sim-vehicle, :mod:`sim_vehicle.sensor`) on the
benchmark missions of ``bench/efficiency.py`` (100 x 100 m, one vehicle at 8 m/s, the
diagonals, the same reconstruction and cost accounting for every variant):

``--experiment lag``
    Threshold mapping (the adaptive planner given the middle of the true range as its one
    target level, a 10 km safety budget; it stops when no place is left where the iso-line
    could be): the iso-line error at the target and the distance flown, lag-free against
    a 1 s lag the station knows (corrected) and one it does not (left in).
``--experiment map``
    Mapping the whole field with every planner on a 4 km budget (``lawnmower``: the
    survey whose line spacing fills 4 km): final MAE (dB) and the iso-line errors at
    25/50/75 % of the span, with the same three sensors and with a GNSS error of 1 m
    (correlation time 10 s) instead.

    python bench/sensor.py --experiment lag --fields plume,paper --seeds 0:10 --workers 2
    python bench/sensor.py --from-json runs/sensor-lag.json          # tables again

Variants are sensor settings (``vehicles.sensor``) written ``name=key:value;key:value``
with ``--variants`` (replacing an experiment's own), e.g. ``lag05=lag_s:0.5``.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from runs import mid_level, mission_for  # noqa: E402

from econdor_gcs.dfc.loop import Dfc  # noqa: E402
from econdor_lab.inprocess import InProcessExecutor  # noqa: E402
from econdor_lab.study import parse_seeds  # noqa: E402
from econdor_lab.workers import WorkerPool  # noqa: E402

LAG: dict[str, dict[str, Any]] = {
    "lag-free": {},
    "lag 1 s, known": {"lag_s": 1.0},
    "lag 1 s, unknown": {"lag_s": 1.0, "lag_correction": "none"},
}
POSITION: dict[str, dict[str, Any]] = {
    "GNSS 1 m, 10 s": {"position_std_m": 1.0, "position_tau_s": 10.0},
}
EXPERIMENTS: dict[str, tuple[dict[str, dict[str, Any]], tuple[str, ...]]] = {
    "lag": (LAG, ("adaptive:threshold",)),
    "map": ({**LAG, **POSITION}, ("adaptive", "econdor", "no-sg", "lawnmower")),
}
THRESHOLD_BUDGET_M = 10_000.0
MAP_BUDGET_M = 4_000.0
SURVEY_LINES = 39
"""A lawnmower of 39 north-south lines 100 m long (plus the 100 m across) flies 4 km."""


def parse_variants(text: str) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, _, spec = part.partition("=")
        keys: dict[str, Any] = {}
        for kv in filter(None, spec.split(";")):
            k, _, v = kv.partition(":")
            try:
                keys[k.strip()] = float(v)
            except ValueError:
                keys[k.strip()] = v.strip()
        out[name.strip()] = keys
    return out


def run_one(args: tuple[str, int, str, str, dict[str, Any]]) -> dict[str, Any]:
    field, seed, planner, variant, sensor = args
    threshold = planner.endswith(":threshold")
    name = planner.removesuffix(":threshold")
    if threshold:
        base = mission_for(field, THRESHOLD_BUDGET_M, name, "auto")
        mission = mission_for(field, THRESHOLD_BUDGET_M, name, "auto",
                              (mid_level(base, seed),))
    elif name == "lawnmower":
        mission = mission_for(field, MAP_BUDGET_M, name, "auto", survey_lines=SURVEY_LINES)
    else:
        mission = mission_for(field, MAP_BUDGET_M, name, "auto")
    mission = mission.with_vehicles(sensor=sensor)
    truth = mission.build_field(seed)
    t0 = time.perf_counter()
    res = Dfc(mission, InProcessExecutor(mission, truth, seed=seed), truth=truth,
              seed=seed).run()
    iso = res.isoline_error_m
    last = res.records[-1]
    return {"field": field, "seed": seed, "planner": planner, "variant": variant,
            "sensor": sensor, "iso_target": iso.get("target", math.nan),
            "iso": [iso.get(k, math.nan) for k in ("p25", "p50", "p75")],
            "mae_db": last.mae_db, "mae": last.mae,
            "flight_m": res.flight_distance_m - res.return_m, "stop": res.stop_reason,
            "wall_s": time.perf_counter() - t0}


def med(xs: list[float]) -> float:
    xs = [x for x in xs if not math.isnan(x)]
    return statistics.median(xs) if xs else math.nan


def tables(runs: list[dict[str, Any]]) -> None:
    fields = sorted({r["field"] for r in runs})
    planners = list(dict.fromkeys(r["planner"] for r in runs))
    # the perfect sensor first (the base of the comparisons), then as the experiments list them
    known = [*LAG, *POSITION]
    variants = sorted(dict.fromkeys(r["variant"] for r in runs),
                      key=lambda v: (next((0 for r in runs if r["variant"] == v
                                           and not r["sensor"]), 1),
                                     known.index(v) if v in known else len(known)))
    for field in fields:
        for planner in planners:
            rs = [r for r in runs if r["field"] == field and r["planner"] == planner]
            if not rs:
                continue
            seeds = sorted({r["seed"] for r in rs})
            print(f"\n### {field}, {planner} (seeds {seeds[0]}-{seeds[-1]}, n={len(seeds)})\n")
            base = variants[0]
            by = {(r["variant"], r["seed"]): r for r in rs}
            if planner.endswith(":threshold"):
                print(f"| sensor | iso-line error at the target, median (m) | mean | "
                      f"seeds within 0.5 m of {base} | distance, median (m) | stops |")
                print("|---|---|---|---|---|---|")
                for v in variants:
                    mine = [by[(v, s)] for s in seeds if (v, s) in by]
                    isos = [r["iso_target"] for r in mine]
                    close = sum(1 for s in seeds if (v, s) in by and (base, s) in by
                                and by[(v, s)]["iso_target"] - by[(base, s)]["iso_target"]
                                <= 0.5)
                    stops: dict[str, int] = {}
                    for r in mine:
                        stops[r["stop"]] = stops.get(r["stop"], 0) + 1
                    mean = statistics.fmean(isos) if isos else math.nan
                    print(f"| {v} | {med(isos):.3f} | {mean:.3f} | {close}/{len(mine)} | "
                          f"{med([r['flight_m'] for r in mine]):.0f} | "
                          f"{', '.join(f'{k} {n}' for k, n in sorted(stops.items()))} |")
            else:
                print("| sensor | MAE, median (dB) | iso-line error 25/50/75 %, medians (m) | "
                      f"MAE change against {base}, median (dB) | distance, median (m) |")
                print("|---|---|---|---|---|")
                for v in variants:
                    mine = [by[(v, s)] for s in seeds if (v, s) in by]
                    iso = [med([r["iso"][k] for r in mine]) for k in range(3)]
                    delta = [by[(v, s)]["mae_db"] - by[(base, s)]["mae_db"] for s in seeds
                             if (v, s) in by and (base, s) in by]
                    print(f"| {v} | {med([r['mae_db'] for r in mine]):.1f} | "
                          f"{' / '.join(f'{x:.2f}' for x in iso)} | {med(delta):+.1f} | "
                          f"{med([r['flight_m'] for r in mine]):.0f} |")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--experiment", choices=sorted(EXPERIMENTS), default="lag")
    p.add_argument("--fields", default="plume,paper")
    p.add_argument("--seeds", default="0:10")
    p.add_argument("--planners", default=None, help="override the experiment's planners")
    p.add_argument("--variants", default=None, help="override the experiment's sensors")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--json", default=None, help="write every run here (appended as it goes; "
                   "runs already there are not flown again)")
    p.add_argument("--from-json", default=None, help="print the tables of a saved run")
    a = p.parse_args()
    if a.from_json:
        runs = [json.loads(line) for line in Path(a.from_json).read_text().splitlines() if line]
        tables(runs)
        return 0
    variants, planners = EXPERIMENTS[a.experiment]
    if a.variants:
        variants = parse_variants(a.variants)
    if a.planners:
        planners = tuple(a.planners.split(","))
    jobs = [(f, s, pl, v, sensor) for f in a.fields.split(",") for s in parse_seeds(a.seeds)
            for pl in planners for v, sensor in variants.items()]
    runs = []
    if a.json and Path(a.json).exists():
        runs = [json.loads(line) for line in Path(a.json).read_text().splitlines() if line]
        done = {(r["field"], r["seed"], r["planner"], r["variant"]) for r in runs}
        jobs = [j for j in jobs if j[:4] not in done]
        print(f"{len(done)} runs in {a.json}, {len(jobs)} to fly", flush=True)
    with WorkerPool(a.workers) as pool:
        for r in pool.map(run_one, jobs):
            runs.append(r)
            print(f"{r['field']} {r['seed']} {r['planner']} {r['variant']}: iso "
                  f"{r['iso_target']:.3f} / {r['iso'][1]:.3f}, MAE {r['mae_db']:.1f} dB, "
                  f"{r['flight_m']:.0f} m, {r['stop']}, {r['wall_s']:.0f} s", flush=True)
            if a.json:
                with Path(a.json).open("a", encoding="utf-8") as f:
                    f.write(json.dumps(r) + "\n")
    tables(runs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
