"""In-process studies: the whole DFC loop over many seeds and planners, in parallel.

Each (seed, planner) run builds the seed's true field, flies the in-process executor
(the same tracer as the MAVLink vehicle) and writes a small run directory under
``OUT/runs/<planner>-<seed>/``. Runs go to local worker processes, or to an existing Dask
cluster when a scheduler address is given. The study writes ``OUT/study.csv`` (one row
per seed, planner and iteration), ``OUT/summary.json`` and the figures.
"""

from __future__ import annotations

import csv
import math
import os
import statistics
import time
from collections.abc import Callable, Iterable
from concurrent.futures import as_completed
from pathlib import Path
from typing import Any

from econdor_gcs.config import Mission
from econdor_gcs.core.planners import PLANNER_NAMES as PLANNERS
from econdor_gcs.core.tasks import TaskStyle
from econdor_gcs.dfc.loop import Dfc, IterationRecord
from econdor_gcs.errors import EcondorError
from econdor_gcs.files.layout import RunDirMode
from econdor_gcs.files.rundir import write_json
from sim_vehicle.tracer import warm_up

from .inprocess import InProcessExecutor, run_inprocess
from .workers import WorkerPool

EXTRA_COLUMNS = ("mae_rel", "isoline_p25_m", "isoline_p50_m", "isoline_p75_m", "forced_levels",
                 "isoline_target_m", "isoline_target_missed", "noise_std")
STUDY_COLUMNS = ("seed", "planner", *IterationRecord.CSV_COLUMNS, *EXTRA_COLUMNS)


def study_row(seed: int, planner: str, r: IterationRecord) -> dict[str, Any]:
    """One study.csv row: the metrics.csv columns plus seed, planner and extras (among
    them ``noise_std``: the sensor noise that iteration's reconstruction estimated from
    the samples)."""
    iso = r.isoline_error_m
    return {"seed": seed, "planner": planner, **r.csv_row(), "mae_rel": r.mae_rel,
            "isoline_p25_m": iso.get("p25", math.nan), "isoline_p50_m": iso.get("p50", math.nan),
            "isoline_p75_m": iso.get("p75", math.nan), "forced_levels": r.forced,
            "isoline_target_m": iso.get("target", math.nan),
            "isoline_target_missed": iso.get("target_missed", math.nan),
            "noise_std": r.noise_std}


def parse_seeds(text: str) -> list[int]:
    """``"A:B"`` -> A..B-1 (Python slice convention); ``"3"`` -> [3]; ``"1,4,7"`` -> list."""
    try:
        if ":" in text:
            a, b = text.split(":", 1)
            seeds = list(range(int(a), int(b)))
        else:
            seeds = [int(s) for s in text.split(",") if s.strip()]
    except ValueError as exc:
        raise EcondorError(f"--seeds: expected A:B or a comma list of integers, got {text!r}") from exc
    if not seeds or min(seeds) < 0:
        raise EcondorError(f"--seeds: need at least one seed >= 0, got {text!r}")
    return seeds


def run_seed(mission: Mission, seed: int, planner: str, out_dir: str | None,
             n_vehicles: int | None = None, style: TaskStyle = TaskStyle.TRACE,
             tolerance_m: float = 1.0) -> dict[str, Any]:
    """One in-process run. Returns ``{"summary": ..., "rows": [...], "run_dir": ...}``.

    ``style`` is how the vehicles get contour pieces (``WAYPOINTS``: as stock autopilots,
    the estimated contour simplified to ``tolerance_m``)."""
    run_dir = None
    if out_dir is not None:
        # a study owns its runs/ folder: a re-run of the same study replaces its runs
        run_dir = str(Path(out_dir) / "runs" / f"{planner}-{seed}")
        result = run_inprocess(mission, run_dir, planner=planner, seed=seed,
                               n_vehicles=n_vehicles, mode=RunDirMode.FORCE, style=style,
                               tolerance_m=tolerance_m)
    else:
        field = mission.build_field(seed)
        executor = InProcessExecutor(mission, field, n_vehicles=n_vehicles, seed=seed,
                                     style=style, tolerance_m=tolerance_m)
        result = Dfc(mission, executor, planner=planner, truth=field, seed=seed).run()
    rows = [study_row(seed, planner, r) for r in result.records]
    return {"summary": result.summary(), "rows": rows, "run_dir": run_dir,
            "worker": worker_info(),
            "levels": [r.levels for r in result.records],
            "kappa": [r.kappa for r in result.records],
            "delta": [r.delta for r in result.records]}


def worker_info() -> dict[str, int]:
    """The process a run ran in, and how often numba compiled (``tracer_compilations``) or
    loaded from its disk cache (``tracer_cache_loads``) the tracer there so far: a worker
    that reuses its compiled code shows one load (or one compilation) however many runs."""
    from sim_vehicle import machine

    stats = machine.advance.stats
    return {"pid": os.getpid(), "tracer_compilations": sum(stats.cache_misses.values()),
            "tracer_cache_loads": sum(stats.cache_hits.values()),
            "tracer_signatures": len(machine.advance.signatures)}


def _median(values: Iterable[float]) -> float:
    v = [x for x in values if x is not None and not math.isnan(x)]
    return statistics.median(v) if v else math.nan


def aggregate(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Per-planner medians of the final metrics."""
    out: dict[str, Any] = {}
    for planner in sorted({r["summary"]["planner"] for r in results}):
        rs = [r["summary"] for r in results if r["summary"]["planner"] == planner]
        out[planner] = {
            "runs": len(rs),
            "median_final_mae_db": _median(s["final_mae_db"] for s in rs),
            "median_final_mae": _median(s["final_mae"] for s in rs),
            "median_flight_distance_m": _median(s["flight_distance_m"] for s in rs),
            "median_contour_distance_m": _median(s["contour_distance_m"] for s in rs),
            "median_iterations": _median(s["iterations"] for s in rs),
            "median_span_ratio": _median(s["span_ratio"] for s in rs),
            "converged": sum(bool(s["converged"]) for s in rs),
            "median_isoline_error_m": {
                k: _median(s["isoline_error_m"].get(k, math.nan) for s in rs)
                for k in ("p25", "p50", "p75")
            },
        }
    return out


def run_study(
    mission: Mission,
    seeds: list[int],
    planners: list[str],
    out_dir: str | Path,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
    figures: bool = True,
    connect_timeout_s: float = 10.0,
) -> dict[str, Any]:
    """Run every (seed, planner) and write the study outputs. Returns the summary."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(seed, planner) for seed in seeds for planner in planners]
    t0 = time.perf_counter()
    results: list[dict[str, Any]] = []
    notify = progress or (lambda r: None)
    # load the compiled tracer (compile it, on a cold cache) once, before any run: the runs'
    # wall times are then the runs', and workers load it from the disk cache
    warm_up()
    if scheduler:
        results = _run_dask(mission, jobs, str(out), scheduler, notify, connect_timeout_s)
    elif (workers or 1) <= 1 or len(jobs) == 1:
        for seed, planner in jobs:
            r = run_seed(mission, seed, planner, str(out))
            results.append(r)
            notify(r)
    else:
        with WorkerPool(workers or 1) as pool:
            futs = [pool.submit(run_seed, mission, s, p, str(out)) for s, p in jobs]
            for fut in as_completed(futs):
                r = fut.result()
                results.append(r)
                notify(r)
    results.sort(key=lambda r: (PLANNERS.index(r["summary"]["planner"]), r["summary"]["seed"]))
    rows = [row for r in results for row in r["rows"]]
    with (out / "study.csv").open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=STUDY_COLUMNS)
        w.writeheader()
        w.writerows(rows)
    summary = {
        "mission": mission.name,
        "seeds": seeds,
        "planners": planners,
        "wall_s": time.perf_counter() - t0,
        "by_planner": aggregate(results),
        "runs": [r["summary"] for r in results],
    }
    write_json(out / "summary.json", summary)
    if figures:
        from econdor_gcs.files.study_figures import plot_study

        maps = {r["summary"]["planner"]: r["run_dir"] for r in results
                if r["summary"]["seed"] == seeds[0] and r["run_dir"]}
        plot_study(rows, out / "figures", maps=maps)
    return summary


def _run_dask(mission: Mission, jobs: list[tuple[int, str]], out: str, scheduler: str,
              notify: Callable[[dict[str, Any]], None], timeout_s: float) -> list[dict[str, Any]]:
    try:
        from dask.distributed import Client
        from dask.distributed import as_completed as dask_completed
    except ImportError as exc:
        raise EcondorError("--scheduler needs dask[distributed]: pip install 'econdor[dask]'") from exc
    try:
        client = Client(scheduler, timeout=f"{timeout_s}s")
    except (OSError, TimeoutError) as exc:
        raise EcondorError(f"--scheduler: cannot reach Dask scheduler at {scheduler}: {exc}") from exc
    try:
        futs = [client.submit(run_seed, mission, s, p, out, pure=False) for s, p in jobs]
        results = []
        for fut in dask_completed(futs):
            r = fut.result()
            results.append(r)
            notify(r)
        return results
    finally:
        client.close()


def default_workers() -> int:
    return max(1, os.cpu_count() or 1)
