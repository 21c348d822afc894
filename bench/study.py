"""Benchmark: a study of many in-process runs on local worker processes and on Dask.

It runs ``run_study`` (what ``econdor study`` runs) over ``--seeds`` of the paper setting
(``missions/paper.yaml``, one planner) twice: on ``--workers`` local processes and on a Dask
``LocalCluster`` with as many single-threaded worker processes. For each it prints the
study's wall time, runs per minute and the per-run wall times (first run of each worker
against the others), and checks that worker processes reuse the compiled tracer: each run
reports its process id and how often numba compiled or loaded (from its disk cache) the
tracer in that process so far (``econdor_lab.study.worker_info``). A worker that compiled
per run would show these growing with its runs.

    OMP_NUM_THREADS=1 python bench/study.py --seeds 0:100 --workers 2
    OMP_NUM_THREADS=1 python bench/study.py --seeds 0:10 --workers 2 --only local
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from econdor_gcs.config import load_mission  # noqa: E402
from econdor_lab.study import parse_seeds, run_study  # noqa: E402


def _report(name: str, summary: dict[str, Any], results: list[dict[str, Any]]) -> None:
    runs = summary["runs"]
    wall = summary["wall_s"]
    print(f"\n## {name}: {len(runs)} runs in {wall:.0f} s ({60 * len(runs) / wall:.1f} runs/min)")
    by_pid: dict[int, list[dict[str, Any]]] = {}
    for r in results:
        by_pid.setdefault(r["worker"]["pid"], []).append(r)
    print("| worker pid | runs | first run s | median later run s | numba compilations | "
          "cache loads | compiled signatures |")
    print("|---|---|---|---|---|---|---|")
    for pid, rs in sorted(by_pid.items()):
        walls = [r["summary"]["wall_s"] for r in rs]
        later = statistics.median(walls[1:]) if len(walls) > 1 else float("nan")
        last = max((r["worker"] for r in rs), key=lambda w: w["tracer_cache_loads"]
                   + w["tracer_compilations"])
        print(f"| {pid} | {len(rs)} | {walls[0]:.2f} | {later:.2f} | "
              f"{last['tracer_compilations']} | {last['tracer_cache_loads']} | "
              f"{last['tracer_signatures']} |")
    recon = statistics.median(s["reconstruction_s"] for s in runs)
    per_run = statistics.median(s["wall_s"] for s in runs)
    print(f"median run wall {per_run:.2f} s, of which reconstruction {recon:.2f} s")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="0:100")
    p.add_argument("--planner", default="econdor")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--only", choices=("local", "dask"), help="run only one of the two")
    p.add_argument("--dask-malloc-trim", action="store_true",
                   help="keep Dask's default MALLOC_TRIM_THRESHOLD_ for its workers")
    a = p.parse_args()
    mission = load_mission(REPO / "missions" / "paper.yaml")
    seeds = parse_seeds(a.seeds)
    print(f"# study: {len(seeds)} seeds of the paper setting, planner {a.planner}, "
          f"{a.workers} workers, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}")
    if a.only != "dask":
        results: list[dict[str, Any]] = []
        with tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            summary = run_study(mission, seeds, [a.planner], out, workers=a.workers,
                                progress=results.append, figures=False)
            summary["wall_s"] = time.perf_counter() - t0
        _report(f"local, {a.workers} processes", summary, results)
    if a.only != "local":
        import dask
        from dask.distributed import LocalCluster

        if not a.dask_malloc_trim:
            # Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which turns off
            # glibc's adaptive mmap threshold: every large numpy temporary is then mapped and
            # unmapped afresh; measured here, that doubles the reconstruction's CPU time
            dask.config.set({"distributed.nanny.pre-spawn-environ": {
                k: 1 for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")}})
        results = []
        with LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, \
                tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            summary = run_study(mission, seeds, [a.planner], out,
                                scheduler=cluster.scheduler_address,
                                progress=results.append, figures=False)
            summary["wall_s"] = time.perf_counter() - t0
        trim = "Dask's default" if a.dask_malloc_trim else "glibc's default"
        _report(f"Dask LocalCluster, {a.workers} worker processes ({trim} malloc trim)",
                summary, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
