"""Benchmark the reconstructions on samples recorded from real runs, and on noisy surveys.

Usage::

    python bench/reconstruction.py [--quick] [--sizes 2000,5000,20000,50000]
                                   [--exact-max 5000] [--baseline REV] [--no-stream]
                                   [--libraries] [DATA.npz ...]
    python bench/reconstruction.py --surveys [--seeds 900:910] [--fields plume,paper]
                                   [--noise 1,3] [--budgets 2000,4000] [--markdown]

Data: ``bench/data/*.npz`` (written by ``bench/record_samples.py``): every sample of a
real run in the order the station received it, the sample count of each of its
reconstructions, and the true field on the mission grid. ``paper-s0`` is an in-process
run of ``missions/paper.yaml`` (seed 0, one vehicle), cut after its sixth reconstruction;
``demo-mavlink`` is an ``econdor run missions/demo.yaml`` over MAVLink (three vehicles).
The noisy sets were recorded with ``--noise-std``: ``plume-noise1-s900`` and
``plume-noise3-s900`` are in-process runs of ``missions/plume.yaml`` (the adaptive
planner, seed 900) with sensor noise 1 and 3 (about 1 and 3 % of the plume's span of 90),
``paper-noise1-s0`` and ``paper-noise3-s0`` runs of ``missions/paper.yaml`` (seed 0) with
noise 0.56 and 1.67 (the same fractions of the authors' field's span of 50). Each row
gives the noise the reconstruction estimated (0: the samples were taken as exact and
interpolated).

1. **Sizes**: the first N samples of each run (the station's state at that moment) for
   each N in ``--sizes``. Methods: the exact dense solve (the reference, computed where
   N <= ``--exact-max``, else taken from the file if it stores one, ``exact_<N>``);
   the fast spline of this checkout (``reconstruct(method="fast")``); the fast spline of
   git revision ``--baseline`` (the method this work replaces, loaded from git history);
   with ``--libraries`` also scipy's ``RBFInterpolator`` (thin-plate kernel, linear
   term, 64 nearest neighbours, on the same 0.5 m thinning). Columns: wall and CPU
   seconds (fit and prediction on the 101 x 101 grid), MAE against the true field, the
   ratios against the exact solve (MAE, and the mean distance between the surfaces in
   units of the exact MAE) and against the baseline (MAE, time).
2. **Stream**: each reconstruction the run made, as the DFC makes it
   (``reconstruct(method="auto")``): this checkout against the baseline, and the fast
   estimator warm-started on the stream against fresh fits (time, and how many tiles
   were factorised, re-solved from kept factors, or kept).

3. **Surveys** (``--surveys``): the issue's acceptance measure. For each field, noise
   level and seed, a boustrophedon survey sized to each budget is flown in process
   (``lawnmower.budget_m``; the same lines for every seed, the noise drawn per seed), and
   its samples are reconstructed by this checkout (the noise estimated) and by
   interpolating every sample (``noise_std=0``: the reconstruction before issue 32).
   Medians over the seeds of the MAE in dB, the noise estimated, the CPU seconds, and in
   how many seeds each longer survey's map is no worse than the shorter one's.
   ``--noise`` is relative to the plume's span of 90: the paper field (eqs. 8-9, span
   about 93) gets the same fraction of its span.

One core: run with ``OMP_NUM_THREADS=1`` (the estimators limit BLAS to one thread
themselves). Timings are noisy on a shared machine; compare ratios from one run.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from econdor_gcs.core.geometry import Grid, Region  # noqa: E402
from econdor_gcs.core.noise import estimate_noise  # noqa: E402
from econdor_gcs.core.samples import _thin_pick  # noqa: E402
from econdor_gcs.core.spline import FastBiharmonicSpline, fit_field, reconstruct  # noqa: E402

DATA = sorted((REPO / "bench" / "data").glob("*.npz"))
# The reconstruction before issue 32: every sample interpolated, noise or not (the fast
# spline of issue 7; ``--baseline 6c88af8`` compares with the one before issue 7).
BASELINE_REV = "8c646e1"
PLUME_SPAN = 90.0
"""The plume field's span: ``--noise`` is in its units, other fields get the same fraction."""
FIELD_SPANS = {"plume": 90.0, "paper": 93.0}

Method = Callable[[np.ndarray, np.ndarray, np.ndarray, Grid], np.ndarray]


class Run:
    """One recorded run: samples in arrival order, reconstruction counts, truth."""

    def __init__(self, path: Path) -> None:
        with np.load(path) as d:
            self.name = path.stem
            self.x, self.y, self.v = d["x_m"], d["y_m"], d["value"]
            self.counts = [int(c) for c in d["recon_counts"]]
            self.truth = d["truth"]
            xmin, xmax, ymin, ymax = (float(t) for t in d["region"])
            ny, nx = (int(t) for t in d["grid_shape"])
            self.grid = Grid(Region(xmin, xmax, ymin, ymax), nx, ny)
            self.stored_exact = {int(k.split("_")[1]): d[k] for k in d.files
                                 if k.startswith("exact_")}
            self.meta = json.loads(str(d["meta"]))

    def prefix(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.x[:n], self.y[:n], self.v[:n]

    def mae(self, z: np.ndarray) -> float:
        return float(np.mean(np.abs(z - self.truth)))


def load_baseline(rev: str) -> ModuleType | None:
    """``econdor_gcs/core/spline.py`` as it was at ``rev`` (None without git history)."""
    out = subprocess.run(["git", "-C", str(REPO), "show", f"{rev}:econdor_gcs/core/spline.py"],
                         capture_output=True, text=True, check=False)
    if out.returncode != 0:
        print(f"(no baseline: git show {rev} failed: {out.stderr.strip()})")
        return None
    path = Path(tempfile.mkdtemp(prefix="econdor-baseline-")) / f"spline_{rev}.py"
    path.write_text(out.stdout, encoding="utf-8")
    spec = importlib.util.spec_from_file_location(f"spline_{rev}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def rbf_local(x: np.ndarray, y: np.ndarray, v: np.ndarray, grid: Grid) -> np.ndarray:
    """scipy RBFInterpolator: thin-plate spline + linear term, 64 neighbours, 0.5 m thinning."""
    from scipy.interpolate import RBFInterpolator

    xb, yb, vb = _thin_pick(x, y, v, 0.5)
    xx, yy = grid.mesh
    rbf = RBFInterpolator(np.column_stack((xb, yb)), vb, kernel="thin_plate_spline",
                          neighbors=min(64, xb.size))
    return rbf(np.column_stack((xx.ravel(), yy.ravel()))).reshape(grid.shape)


def timed(fn: Method, x: np.ndarray, y: np.ndarray, v: np.ndarray, grid: Grid
          ) -> tuple[np.ndarray, float, float]:
    w0, c0 = time.perf_counter(), time.process_time()
    z = fn(x, y, v, grid)
    return z, time.perf_counter() - w0, time.process_time() - c0


def sizes_table(runs: list[Run], sizes: list[int], exact_max: int,
                baseline: ModuleType | None, rev: str, libraries: bool) -> None:
    methods: dict[str, Method] = {}
    if baseline is not None:  # first, so the ratios of this checkout's method are to hand
        methods[f"fast ({rev})"] = (
            lambda x, y, v, g: baseline.reconstruct(x, y, v, g, method="fast"))
    methods["fast (this)"] = lambda x, y, v, g: reconstruct(x, y, v, g, method="fast")
    noise: dict[tuple[str, int], float] = {}
    if libraries:
        methods["scipy RBF k=64"] = rbf_local
    head = (f"{'run':17} {'N':>6} {'method':16} {'wall_s':>7} {'cpu_s':>7} {'MAE':>10} "
            f"{'MAE/exact':>9} {'|f-ex|/MAEex':>12} {'MAE/base':>8} {'cpu/base':>8} "
            f"{'noise':>7}")
    print(head)
    print("-" * len(head))
    for run in runs:
        for n_asked in sizes:
            n = min(n_asked, run.x.size)
            if n < n_asked and n_asked != max(sizes):
                continue
            x, y, v = run.prefix(n)
            label = f"{run.name:17} {n:6d}"
            noise[run.name, n] = estimate_noise(x, y, v).noise_std
            exact = None
            if n <= exact_max:
                exact, wall, cpu = timed(
                    lambda x, y, v, g: reconstruct(x, y, v, g, method="exact"), x, y, v,
                    run.grid)
                print(f"{label} {'exact':16} {wall:7.2f} {cpu:7.2f} {run.mae(exact):10.3e}",
                      flush=True)
            elif n in run.stored_exact:
                exact = run.stored_exact[n]
                print(f"{label} {'exact (stored)':16} {'':>7} {'':>7} {run.mae(exact):10.3e}",
                      flush=True)
            base_mae = base_cpu = None
            for name, fn in methods.items():
                try:
                    z, wall, cpu = timed(fn, x, y, v, run.grid)
                except np.linalg.LinAlgError as exc:
                    print(f"{label} {name:16} failed: {str(exc).splitlines()[0]}", flush=True)
                    continue
                mae = run.mae(z)
                cols = f"{label} {name:16} {wall:7.2f} {cpu:7.2f} {mae:10.3e}"
                if exact is not None:
                    ex_mae = run.mae(exact)
                    dev = float(np.mean(np.abs(z - exact))) / ex_mae
                    cols += f" {mae / ex_mae:9.3f} {dev:12.3f}"
                else:
                    cols += f" {'n/a':>9} {'n/a':>12}"
                if name == f"fast ({rev})":
                    base_mae, base_cpu = mae, cpu
                    cols += f" {'':>8} {'':>8} {'(0)':>7}"
                elif base_mae is not None and base_cpu:
                    cols += f" {mae / base_mae:8.3f} {cpu / base_cpu:8.3f}"
                    cols += f" {noise[run.name, n]:7.3f}"
                print(cols, flush=True)


def stream_table(runs: list[Run], baseline: ModuleType | None) -> None:
    print()
    print("stream: every reconstruction of the recorded run, reconstruct(method='auto'); "
          "cpu seconds / MAE")
    for run in runs:
        warm = FastBiharmonicSpline(warm_start=True)
        totals = {"this": 0.0, "base": 0.0, "cold": 0.0, "warm": 0.0}
        print(f"{run.name} ({run.meta.get('transport')}, {run.meta.get('vehicles')} vehicle(s))")
        print(f"  {'samples':>8} {'this cpu_s':>10} {'MAE':>10} {'base cpu_s':>10} {'MAE':>10}"
              f" {'fast cold':>9} {'fast warm':>9} {'factored/resolved/kept':>24}")
        for n in run.counts:
            x, y, v = run.prefix(n)
            z, _, cpu = timed(lambda x, y, v, g: reconstruct(x, y, v, g), x, y, v, run.grid)
            totals["this"] += cpu
            row = f"  {n:8d} {cpu:10.3f} {run.mae(z):10.3e}"
            if baseline is not None:
                zb, _, cpub = timed(lambda x, y, v, g: baseline.reconstruct(x, y, v, g),
                                    x, y, v, run.grid)
                totals["base"] += cpub
                row += f" {cpub:10.3f} {run.mae(zb):10.3e}"
            else:
                row += f" {'n/a':>10} {'n/a':>10}"
            xx, yy = run.grid.mesh
            c0 = time.process_time()
            zc = FastBiharmonicSpline().fit(x, y, v).predict(xx, yy)
            c1 = time.process_time()
            zw = warm.fit(x, y, v).predict(xx, yy)
            c2 = time.process_time()
            totals["cold"] += c1 - c0
            totals["warm"] += c2 - c1
            same = "" if np.array_equal(zc, zw) else "  WARM != COLD"
            row += (f" {c1 - c0:9.3f} {c2 - c1:9.3f} "
                    f"{warm.n_factored_:>10}/{warm.n_resolved_}/{warm.n_kept_}{same}")
            print(row, flush=True)
        ratio = (f", ratio {totals['this'] / totals['base']:.3f}" if totals["base"] else "")
        print(f"  total cpu: this {totals['this']:.2f} s, baseline {totals['base']:.2f} s{ratio};"
              f" fast cold {totals['cold']:.2f} s, warm-started {totals['warm']:.2f} s")


def survey_samples(field: str, noise_std: float, budget_m: float, seed: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Grid]:
    """The samples of a survey sized to ``budget_m`` over ``field`` (in process, the order
    they were taken) and the true field on the mission grid."""
    import yaml

    from econdor_gcs.config import parse_mission
    from econdor_gcs.dfc.loop import Dfc
    from econdor_lab.inprocess import InProcessExecutor

    raw = yaml.safe_load((REPO / "missions" / "plume.yaml").read_text(encoding="utf-8"))
    if field != "plume":
        raw["field"] = {"model": field}
    raw["vehicles"]["noise_std"] = noise_std
    # the survey's lines are its first batch; the budget ends the run after them
    raw["algorithm"].update(planner="lawnmower", flight_budget_m=1.5 * budget_m)
    raw["lawnmower"] = {"budget_m": budget_m}
    mission = parse_mission(raw, base_dir=REPO / "missions")
    truth = mission.build_field(seed)
    result = Dfc(mission, InProcessExecutor(mission, truth, seed=seed), planner="lawnmower",
                 truth=None, seed=seed).run()
    s = result.samples
    xx, yy = mission.grid.mesh
    return s.x_m, s.y_m, s.value, np.asarray(truth(xx, yy), dtype=np.float64), mission.grid


def surveys_table(fields: list[str], noises: list[float], budgets: list[float],
                  seeds: list[int], markdown: bool) -> None:
    bar = "|" if markdown else " "
    head = ["field", "noise", "survey", "samples", "interpolated dB", "this dB", "gain dB",
            "noise estimated", "this cpu s",
            "seeds where each longer survey is no worse (this / interpolated)"]
    print(f"# surveys: medians over seeds {seeds[0]}..{seeds[-1]} ({len(seeds)})\n")
    print(bar + bar.join(head) + bar)
    if markdown:
        print(bar + bar.join("---" for _ in head) + bar)
    for field in fields:
        for rel in noises:
            sigma = rel * FIELD_SPANS.get(field, PLUME_SPAN) / PLUME_SPAN
            per: dict[float, dict[str, list[float]]] = {}
            for budget in budgets:
                acc: dict[str, list[float]] = {"this": [], "interp": [], "noise": [],
                                               "cpu": [], "n": []}
                for seed in seeds:
                    x, y, v, truth, grid = survey_samples(field, sigma, budget, seed)
                    c0 = time.process_time()
                    rec = fit_field(x, y, v, grid)
                    acc["cpu"].append(time.process_time() - c0)
                    acc["this"].append(_db(float(np.mean(np.abs(rec.values - truth)))))
                    acc["noise"].append(rec.noise_std)
                    z0 = reconstruct(x, y, v, grid, noise_std=0.0)
                    acc["interp"].append(_db(float(np.mean(np.abs(z0 - truth)))))
                    acc["n"].append(float(x.size))
                per[budget] = acc
            for budget in budgets:
                acc = per[budget]
                cols = [field, f"{sigma:g}", f"{budget / 1000:g} km",
                        f"{statistics.median(acc['n']):.0f}",
                        f"{statistics.median(acc['interp']):.1f}",
                        f"**{statistics.median(acc['this']):.1f}**" if markdown else
                        f"{statistics.median(acc['this']):.1f}",
                        f"{statistics.median(acc['interp']) - statistics.median(acc['this']):.1f}",
                        f"{statistics.median(acc['noise']):.3f}",
                        f"{statistics.median(acc['cpu']):.2f}"]
                if budget == budgets[-1] and len(budgets) > 1:
                    cols.append(f"{_monotone(per, budgets, 'this')} / "
                                f"{_monotone(per, budgets, 'interp')} of {len(seeds)}")
                else:
                    cols.append("")
                print(bar + bar.join(cols) + bar, flush=True)


def _monotone(per: dict[float, dict[str, list[float]]], budgets: list[float], key: str
              ) -> int:
    """Seeds in which the MAE never rises from one budget to the next."""
    rows = np.array([per[b][key] for b in budgets])  # (budgets, seeds)
    return int(np.count_nonzero(np.all(np.diff(rows, axis=0) <= 0.0, axis=0)))


def _db(mae: float) -> float:
    return 20.0 * float(np.log10(mae))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="*", type=Path, default=DATA)
    ap.add_argument("--quick", action="store_true", help="2000 and 5000 samples, no stream")
    ap.add_argument("--sizes", default="2000,5000,20000,50000")
    ap.add_argument("--exact-max", type=int, default=5000,
                    help="compute the exact solve up to this many samples (20000: ~10 min)")
    ap.add_argument("--baseline", default=BASELINE_REV,
                    help="git revision whose fast spline to compare with")
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--no-stream", action="store_true")
    ap.add_argument("--libraries", action="store_true", help="also scipy's RBFInterpolator")
    ap.add_argument("--surveys", action="store_true",
                    help="noisy surveys flown in process, not the recorded runs")
    ap.add_argument("--seeds", default="900:910", help="--surveys: seeds A:B or a list")
    ap.add_argument("--fields", default="plume,paper", help="--surveys: field models")
    ap.add_argument("--noise", default="1,3",
                    help="--surveys: sensor noise in the plume's units (span 90)")
    ap.add_argument("--budgets", default="2000,4000", help="--surveys: survey lengths (m)")
    ap.add_argument("--markdown", action="store_true", help="--surveys: a markdown table")
    args = ap.parse_args(argv)
    if args.surveys:
        from econdor_lab.study import parse_seeds

        surveys_table(args.fields.split(","), [float(t) for t in args.noise.split(",")],
                      [float(t) for t in args.budgets.split(",")], parse_seeds(args.seeds),
                      args.markdown)
        return 0
    if not args.data:
        print("error: no data (bench/data/*.npz; record with bench/record_samples.py)",
              file=sys.stderr)
        return 1
    runs = [Run(p) for p in args.data]
    sizes = [2000, 5000] if args.quick else [int(s) for s in args.sizes.split(",")]
    baseline = None if args.no_baseline else load_baseline(args.baseline)
    sizes_table(runs, sizes, args.exact_max, baseline, args.baseline, args.libraries)
    if not (args.quick or args.no_stream):
        stream_table(runs, baseline)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
