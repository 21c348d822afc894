"""Whole in-process runs, sample for sample, against another revision.

A change that must not change behaviour (a refactoring of the tracer, of the executor) is
checked here on whole runs rather than on the pinned regression seeds alone: every sample
(time, position, value, phase) of each run, and its MAE after every iteration, must be
bit-identical to the other revision's. The runs cover the fields and planners the tracer
serves (paper, plume and front; the E-CONDOR planner, the adaptive planner mapping the
whole field and the adaptive planner mapping the middle iso-line alone) on a 2 km budget,
and the plume with a realistic sensor (noise, lag, GNSS error), so the sensor's paths
through the machine are compared too.

    python bench/same_runs.py --against main            # this tree against main
    python bench/same_runs.py --seeds 0,1 --against HEAD~1
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

BUDGET_M = 2000.0
NOISY = {"noise_std": 1.0, "lag_s": 0.5, "position_std_m": 1.0, "position_tau_s": 10.0}
RUNS: tuple[tuple[str, str, dict[str, Any]], ...] = tuple(
    [(field, planner, {}) for field in ("paper", "plume", "front")
     for planner in ("econdor", "adaptive", "adaptive:threshold")]
    + [("plume", "adaptive", NOISY), ("plume", "adaptive:threshold", NOISY)])
"""(field, planner, sensor): ``:threshold`` maps the field's middle iso-line alone."""


def one_run(field: str, planner: str, sensor: dict[str, Any], seed: int) -> dict[str, Any]:
    import numpy as np
    from runs import mid_level, mission_for

    from econdor_gcs.dfc.loop import Dfc
    from econdor_lab.inprocess import InProcessExecutor

    name = planner.removesuffix(":threshold")
    targets: tuple[float, ...] = ()
    if planner.endswith(":threshold"):
        targets = (mid_level(mission_for(field, BUDGET_M, name, "auto"), seed),)
    mission = mission_for(field, BUDGET_M, name, "auto", targets)
    if sensor:
        mission = mission.with_vehicles(sensor=sensor)
    truth = mission.build_field(seed)
    res = Dfc(mission, InProcessExecutor(mission, truth, seed=seed), planner=name, truth=truth,
              seed=seed).run()
    s = res.samples
    rows = np.ascontiguousarray(np.column_stack(
        [s.t_s, s.x_m, s.y_m, s.value, s.phase.astype(float), s.vehicle.astype(float)]))
    mae = np.array([r.mae for r in res.records])
    return {"field": field, "planner": planner, "sensor": sensor, "seed": seed,
            "samples": len(rows), "samples_sha256": hashlib.sha256(rows.tobytes()).hexdigest(),
            "mae_sha256": hashlib.sha256(mae.tobytes()).hexdigest(),
            "final_mae_db": res.records[-1].mae_db, "stop": res.stop_reason,
            "flight_m": res.flight_distance_m}


def measure(seeds: list[int]) -> list[dict[str, Any]]:
    return [one_run(field, planner, sensor, seed) for seed in seeds
            for field, planner, sensor in RUNS]


def _label(r: dict[str, Any]) -> str:
    return (f"{r['field']} {r['planner']} seed {r['seed']}"
            + (" (noisy sensor)" if r["sensor"] else ""))


def main() -> int:
    import against

    p = against.parser(__doc__.splitlines()[0], settings="", seeds="0")
    a = against.parse(p)
    from econdor_lab.study import parse_seeds

    runs = measure(parse_seeds(a.seeds))
    if a.json:
        print(json.dumps({"runs": runs}))
        return 0
    for r in runs:
        print(f"{_label(r)}: {r['samples']} samples, final MAE {r['final_mae_db']:.2f} dB, "
              f"{r['flight_m']:.0f} m, {r['stop']}")
    if not a.against:
        return 0
    ref = against.run_tree(__file__, a.against, "--seeds", a.seeds)["runs"]
    differ = 0
    for mine, theirs in zip(runs, ref, strict=True):
        same = all(mine[k] == theirs[k] for k in ("samples", "samples_sha256", "mae_sha256"))
        differ += not same
        print(f"{_label(mine)}: {'identical' if same else 'DIFFERENT'} "
              f"({mine['samples']} against {theirs['samples']} samples)")
    print(f"{len(runs) - differ} of {len(runs)} runs identical to {a.against}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
