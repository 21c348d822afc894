"""Benchmark: how far the vehicles leave the mission area, in whole in-process runs.

Every sample a vehicle takes is at its own position, ten times a second, so the samples
trace its path. For whole in-process DFC runs (econdor planner) of the paper setting
(``missions/paper.yaml``: authors' field, one vehicle, diagonals then 8 iterations), the
plume setting (the same with the plume field of ``bench/efficiency.py``) and the demo
setting (``missions/demo.yaml``: the paper's field model, 3 vehicles, 5 iterations) it
prints, per setting and phase (transit, search, trace, survey), how many samples lie
outside the area and the largest distance outside it (the *excursion*), plus the samples,
traced distance and final MAE of the runs (so a change that keeps vehicles inside by
flying less shows), and, where the tree has a geofence guard, how often it braked
(``guard brakes``: ticks its hard stage stopped a command) and how often the fence itself
had to stop a vehicle (``fence attempts``, 0 when the fence is never in the way).

``--against REF`` runs the same measurement on the git revision REF (``git archive`` into a
temporary directory, a subprocess with that tree first on ``sys.path``), right after this
tree's, so before/after are measured in the same run on the same machine.

    OMP_NUM_THREADS=1 python bench/excursion.py --seeds 0:10 --against main
    OMP_NUM_THREADS=1 python bench/excursion.py --quick
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]

PLUME = {"model": "plume", "sources": 3, "sigma_min_m": 3.0, "sigma_max_m": 6.0,
         "background": 10.0}
PHASES = ("transit", "search", "trace", "survey")


def _mission(setting: str) -> Any:
    import yaml

    from econdor_gcs.config import parse_mission

    name = "demo" if setting == "demo" else "paper"
    raw = yaml.safe_load((REPO / "missions" / f"{name}.yaml").read_text(encoding="utf-8"))
    if setting == "plume":
        raw["field"] = PLUME
        raw["name"] = "plume"
    return parse_mission(raw, base_dir=REPO / "missions")


def excursion_m(x: Any, y: Any, region: Any) -> Any:
    """Distance of each point outside the rectangle ``region`` (0 inside)."""
    import numpy as np

    dx = np.maximum.reduce([region.xmin - x, np.zeros_like(x), x - region.xmax])
    dy = np.maximum.reduce([region.ymin - y, np.zeros_like(y), y - region.ymax])
    return np.hypot(dx, dy)


def one_run(setting: str, seed: int) -> dict[str, Any]:
    """One whole in-process run: the excursion of its samples, per phase."""
    import numpy as np

    from econdor_gcs.dfc.loop import Dfc
    from econdor_lab.inprocess import InProcessExecutor

    mission = _mission(setting)
    field = mission.build_field(seed)
    t0 = time.perf_counter()
    executor = InProcessExecutor(mission, field, seed=seed)
    result = Dfc(mission, executor, planner="econdor", truth=field, seed=seed).run()
    wall = time.perf_counter() - t0
    s = result.samples
    out = excursion_m(np.asarray(s.x_m), np.asarray(s.y_m), mission.region)
    per_phase = {}
    for k, name in enumerate(PHASES):
        sel = np.asarray(s.phase) == k
        per_phase[name] = {"samples": int(sel.sum()),
                           "outside": int((out[sel] > 1e-9).sum()),
                           "max_m": float(out[sel].max()) if sel.any() else 0.0}
    names = executor.bodies[0].state.dtype.names or ()
    guard = {key: int(sum(b.state[0][key] for b in executor.bodies)) if key in names else None
             for key in ("guard_brakes", "fence_attempts")}
    return {"setting": setting, "seed": seed, "wall_s": wall, "samples": len(s), **guard,
            "max_m": float(out.max()), "outside": int((out > 1e-9).sum()),
            "phases": per_phase, "final_mae_db": result.records[-1].mae_db,
            "contour_m": result.contour_distance_m, "flown_m": result.flight_distance_m}


def measure(settings: list[str], seeds: list[int]) -> dict[str, Any]:
    return {"runs": [one_run(setting, seed) for setting in settings for seed in seeds]}


def _total(runs: list[dict[str, Any]], key: str) -> str:
    values = [r.get(key) for r in runs]
    return "—" if any(v is None for v in values) else str(sum(v for v in values if v is not None))


def _table(title: str, data: dict[str, Any]) -> None:
    print(f"\n## {title}\n")
    print("| setting | runs | samples | outside the area | max excursion m | "
          + " | ".join(f"{p}: outside / max m" for p in PHASES)
          + " | median final MAE dB | median traced m | median flown m | guard brakes"
          " | fence attempts |")
    print("|---|---|---|---|---|" + "---|" * len(PHASES) + "---|---|---|---|---|")
    for setting in dict.fromkeys(r["setting"] for r in data["runs"]):
        rs = [r for r in data["runs"] if r["setting"] == setting]
        cells = []
        for p in PHASES:
            outside = sum(r["phases"][p]["outside"] for r in rs)
            worst = max(r["phases"][p]["max_m"] for r in rs)
            cells.append(f"{outside} / {worst:.2f}")
        print(f"| {setting} | {len(rs)} | {sum(r['samples'] for r in rs)} | "
              f"{sum(r['outside'] for r in rs)} | {max(r['max_m'] for r in rs):.2f} | "
              + " | ".join(cells)
              + f" | {statistics.median(r['final_mae_db'] for r in rs):.1f} | "
              f"{statistics.median(r['contour_m'] for r in rs):.0f} | "
              f"{statistics.median(r['flown_m'] for r in rs):.0f} | "
              f"{_total(rs, 'guard_brakes')} | {_total(rs, 'fence_attempts')} |")
    worst = max(data["runs"], key=lambda r: r["max_m"])
    print(f"\nlargest excursion: {worst['max_m']:.2f} m ({worst['setting']} seed "
          f"{worst['seed']}); per run (setting:seed=max m): "
          + ", ".join(f"{r['setting']}:{r['seed']}={r['max_m']:.2f}" for r in data["runs"]))


def main() -> int:
    import against

    p = against.parser(__doc__.splitlines()[0], settings="paper,plume,demo", seeds="0:5")
    a = against.parse(p)
    from econdor_lab.study import parse_seeds

    seeds = parse_seeds(a.seeds)
    settings = a.settings.split(",")
    if os.environ.get("OMP_NUM_THREADS") != "1":
        print("note: OMP_NUM_THREADS is not 1; the runs may use several cores", file=sys.stderr)
    data = measure(settings, seeds)
    if a.json:
        print(json.dumps(data))
        return 0
    print(f"# in-process runs, econdor planner: samples outside the area ({REPO.name})")
    _table("this tree", data)
    if a.against:
        _table(f"revision {a.against}", against.run_tree(
            __file__, a.against, "--settings", a.settings, "--seeds", a.seeds))
    return 0


if __name__ == "__main__":
    sys.exit(main())
