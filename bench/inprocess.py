"""Benchmark: one in-process DFC run, where its wall time goes.

For the paper setting (``missions/paper.yaml``: authors' field, one vehicle, diagonals then
8 iterations, econdor planner) and the plume setting (the same with the plume field of
``bench/efficiency.py``) it runs whole in-process runs in this process, one after another
(one core; set ``OMP_NUM_THREADS=1``), and prints per run:

* wall time (field + truth grid set-up and the DFC loop) and its split: vehicle simulation
  (the executor's flights), reconstruction, planning (levels, contour pieces, assignment),
  metrics (MAE, iso-line errors, records) and set-up;
* simulated seconds per wall second (sim time flown / wall time of the run);
* samples per run and the final MAE (so a faster run that does something else shows).

The split is taken without touching the DFC: the executor is wrapped to time its flights,
the reconstruction time is the DFC's own, and the DFC's progress events (a batch planned
after planning, an iteration done after the metrics) stamp the rest.

The first run in a process also loads the compiled tracer from numba's on-disk cache (or
compiles it); that is timed separately as "warm-up".

``--against REF`` runs the same measurement on the git revision REF (``git archive`` into a
temporary directory, a subprocess with that tree first on ``sys.path``) right after this
tree's, so before/after are measured in the same run on the same machine.

    OMP_NUM_THREADS=1 python bench/inprocess.py                  # seeds 0:3 of both settings
    OMP_NUM_THREADS=1 python bench/inprocess.py --quick          # seed 0 only
    OMP_NUM_THREADS=1 python bench/inprocess.py --against main   # before/after
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
_EVENT_NAMES = {"RunStarted": "start", "IterationPlanned": "plan", "IterationDone": "iteration",
                "RunDone": "done"}
KEYS = ("wall_s", "vehicle_s", "reconstruction_s", "planning_s", "metrics_s", "setup_s")


def _mission(setting: str) -> Any:
    import yaml

    from econdor_gcs.config import parse_mission

    raw = yaml.safe_load((REPO / "missions" / "paper.yaml").read_text(encoding="utf-8"))
    if setting == "plume":
        raw["field"] = PLUME
        raw["name"] = "plume"
    return parse_mission(raw, base_dir=REPO / "missions")


class _TimedExecutor:
    """Forwards to the in-process executor and times its flights."""

    def __init__(self, inner: Any, flights: list[tuple[float, float]]) -> None:
        self.inner = inner
        self.n_vehicles = inner.n_vehicles
        self._flights = flights

    def positions(self) -> list[tuple[float, float]]:
        return self.inner.positions()

    def fly(self, plans: Any, iteration: int, *, survey: bool = False) -> Any:
        t0 = time.perf_counter()
        try:
            return self.inner.fly(plans, iteration, survey=survey)
        finally:
            self._flights.append((t0, time.perf_counter()))

    def finish(self) -> Any:
        t0 = time.perf_counter()
        try:
            return self.inner.finish()
        finally:
            self._flights.append((t0, time.perf_counter()))


def one_run(setting: str, seed: int) -> dict[str, Any]:
    """One whole in-process run with its wall-time split."""
    from econdor_gcs.dfc.loop import Dfc
    from econdor_lab.inprocess import InProcessExecutor

    mission = _mission(setting)
    t0 = time.perf_counter()
    field = mission.build_field(seed)
    flights: list[tuple[float, float]] = []
    executor = _TimedExecutor(InProcessExecutor(mission, field, seed=seed), flights)
    stamps: list[tuple[str, float]] = []

    def stamp(event: Any, *_: Any) -> None:
        # typed events (RunStarted, ...) or, in older trees, (name, info) pairs
        name = event if isinstance(event, str) else _EVENT_NAMES.get(type(event).__name__, "")
        stamps.append((name, time.perf_counter()))

    dfc = Dfc(mission, executor, planner="econdor", truth=field, seed=seed, progress=stamp)
    t_setup = time.perf_counter() - t0
    result = dfc.run()
    wall = time.perf_counter() - t0
    vehicle = sum(b - a for a, b in flights)
    # planning: from the previous "iteration" (or "start") stamp to the first flight or "plan"
    # after it; metrics: from the end of that step's flight to its "iteration" stamp, less
    # its reconstruction
    planning = metrics = 0.0
    recon = [r.reconstruction_s for r in result.records]
    mark = t0
    k = 0
    for event, t in stamps:
        if event == "start":  # the initiation is planned, then flown
            planning += flights[0][0] - t
            mark = flights[0][1]
        elif event == "plan":
            planning += t - mark
            nxt = [b for a, b in flights if a >= t]
            mark = nxt[0] if nxt else t
        elif event == "iteration":
            metrics += max(0.0, t - mark - recon[k])
            k += 1
            mark = t
    return {"setting": setting, "seed": seed, "wall_s": wall, "vehicle_s": vehicle,
            "reconstruction_s": result.reconstruction_s, "planning_s": planning,
            "metrics_s": metrics, "setup_s": t_setup, "sim_s": result.sim_s,
            "samples": len(result.samples), "final_mae_db": result.records[-1].mae_db,
            "iterations": len(result.records) - 1}


def measure(settings: list[str], seeds: list[int]) -> dict[str, Any]:
    t0 = time.perf_counter()
    warm = _mission("paper").with_overrides(max_iterations=1, min_iterations=1)
    from econdor_gcs.dfc.loop import Dfc
    from econdor_lab.inprocess import InProcessExecutor

    field = warm.build_field(0)
    Dfc(warm, InProcessExecutor(warm, field, seed=0), truth=field).run()
    warm_s = time.perf_counter() - t0
    runs = [one_run(setting, seed) for setting in settings for seed in seeds]
    return {"warm_up_s": warm_s, "runs": runs}


def _table(title: str, data: dict[str, Any]) -> None:
    print(f"\n## {title}  (warm-up: first run in the process {data['warm_up_s']:.1f} s)\n")
    print("| setting | seed | wall s | vehicle sim s | reconstruction s | planning s | metrics s"
          " | set-up s | sim s / wall s | samples | final MAE dB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in data["runs"]:
        print(f"| {r['setting']} | {r['seed']} | {r['wall_s']:.2f} | {r['vehicle_s']:.2f} | "
              f"{r['reconstruction_s']:.2f} | {r['planning_s']:.2f} | {r['metrics_s']:.2f} | "
              f"{r['setup_s']:.2f} | {r['sim_s'] / r['wall_s']:.0f} | {r['samples']} | "
              f"{r['final_mae_db']:.1f} |")
    for setting in sorted({r["setting"] for r in data["runs"]}):
        rs = [r for r in data["runs"] if r["setting"] == setting]
        med = {k: statistics.median(r[k] for r in rs) for k in KEYS}
        rate = statistics.median(r["sim_s"] / r["wall_s"] for r in rs)
        print(f"| {setting} | median | {med['wall_s']:.2f} | {med['vehicle_s']:.2f} | "
              f"{med['reconstruction_s']:.2f} | {med['planning_s']:.2f} | "
              f"{med['metrics_s']:.2f} | {med['setup_s']:.2f} | {rate:.0f} | | |")


def main() -> int:
    import against

    p = against.parser(__doc__.splitlines()[0], settings="paper,plume", seeds="0:3")
    a = against.parse(p)
    from econdor_lab.study import parse_seeds

    seeds = parse_seeds(a.seeds)
    settings = a.settings.split(",")
    if os.environ.get("OMP_NUM_THREADS") != "1":
        print("note: OMP_NUM_THREADS is not 1; the numbers below may use several cores",
              file=sys.stderr)
    data = measure(settings, seeds)
    if a.json:
        print(json.dumps(data))
        return 0
    print(f"# in-process runs, econdor planner, one vehicle ({REPO.name})")
    _table("this tree", data)
    if a.against:
        ref = against.run_tree(__file__, a.against, "--settings", a.settings, "--seeds", a.seeds)
        _table(f"revision {a.against}", ref)
        for setting in settings:
            new = statistics.median(r["wall_s"] for r in data["runs"] if r["setting"] == setting)
            old = statistics.median(r["wall_s"] for r in ref["runs"] if r["setting"] == setting)
            new_v = statistics.median(r["vehicle_s"] for r in data["runs"]
                                      if r["setting"] == setting)
            old_v = statistics.median(r["vehicle_s"] for r in ref["runs"]
                                      if r["setting"] == setting)
            print(f"\n{setting}: median wall per run {old:.2f} s -> {new:.2f} s "
                  f"({old / new:.1f}x); vehicle simulation {old_v:.2f} s -> {new_v:.2f} s "
                  f"({old_v / new_v:.1f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
