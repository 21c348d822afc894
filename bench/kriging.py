"""Kriging against the spline on the same samples, and our GP fit against scikit-learn's.

Samples are recorded from real in-process runs (the onboard tracer, the same cost
accounting): for each field, seed and planner the run's sample set after each iteration is
reconstructed twice — with the biharmonic spline (``reconstruction: auto``, the default)
and with kriging (``reconstruction: kriging``: Matérn 5/2 fitted by maximum likelihood,
tiled) — and both are scored against the true field. Times are wall seconds on this
machine, with the ratio measured in the same run.

The second part fits the Matérn hyperparameters on the same 400-sample subsample with our
profile likelihood (:func:`econdor_gcs.core.gp.fit_matern`) and with scikit-learn's
``GaussianProcessRegressor`` (constant x Matérn 5/2 + a fixed 1e-10 white kernel, L-BFGS,
one start), the same model, and compares time and the likelihood reached.

With ``--noise SIGMA`` the vehicles' sensor has that noise (``vehicles.noise_std``): both
reconstructions then estimate it (issue 32), and a third part compares the noise each
finds: ours from differences of neighbouring samples along the tracks
(:func:`econdor_gcs.core.noise.estimate_noise`, all samples) and scikit-learn's
``WhiteKernel`` fitted by marginal likelihood with the Matérn 5/2 on the 400-sample
subsample.

    python bench/kriging.py --quick
    python bench/kriging.py --seeds 0:4 --markdown
    python bench/kriging.py --seeds 900:906 --fields plume --noise 1 --markdown
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from econdor_gcs.config import parse_mission  # noqa: E402
from econdor_gcs.core import metrics  # noqa: E402
from econdor_gcs.core.gp import _profile_nll, fit_matern, kriging_reconstruct, thin_samples  # noqa: E402
from econdor_gcs.core.spline import reconstruct  # noqa: E402
from econdor_gcs.dfc.loop import Dfc  # noqa: E402
from econdor_lab.inprocess import InProcessExecutor  # noqa: E402
from econdor_lab.study import parse_seeds  # noqa: E402

FIELDS = {
    "authors": {"model": "authors"},
    "plume": {"model": "plume", "sources": 3, "sigma_min_m": 3.0, "sigma_max_m": 6.0,
              "background": 10.0},
}
BUCKETS = ((0, 1000), (1000, 3000), (3000, 8000), (8000, 30000))


NOISE_STD = [0.0]
"""The sensor noise of the runs (``--noise``)."""


def recorded(field: str, seed: int, planner: str, budget_m: float):
    """Sample sets (prefixes) after every iteration of one real run, and the truth."""
    raw = {"name": "kriging-bench", "field": FIELDS[field],
           "vehicles": {"count": 1, "noise_std": NOISE_STD[0]},
           "algorithm": {"planner": planner, "max_iterations": 1000, "min_iterations": 1000,
                         "flight_budget_m": budget_m}}
    mission = parse_mission(raw, base_dir=ROOT / "missions")
    truth = mission.build_field(seed)
    res = Dfc(mission, InProcessExecutor(mission, truth, seed=seed), planner=planner,
              truth=truth, seed=seed).run()
    xx, yy = mission.grid.mesh
    return res.samples, [r.samples for r in res.records], np.asarray(truth(xx, yy)), mission.grid


def compare_reconstructions(fields: list[str], seeds: list[int], planners: list[str],
                            budget_m: float) -> list[dict[str, float]]:
    out = []
    for field in fields:
        for seed in seeds:
            for planner in planners:
                s, counts, truth, grid = recorded(field, seed, planner, budget_m)
                for n in sorted(set(counts)):
                    x, y, v = s.x_m[:n], s.y_m[:n], s.value[:n]
                    t0 = time.perf_counter()
                    spline = reconstruct(x, y, v, grid)
                    t1 = time.perf_counter()
                    krig = kriging_reconstruct(x, y, v, grid)
                    t2 = time.perf_counter()
                    out.append({"field": field, "seed": seed, "planner": planner, "samples": n,
                                "spline": metrics.mae(truth, spline),
                                "kriging": metrics.mae(truth, krig),
                                "spline_s": t1 - t0, "kriging_s": t2 - t1})
    return out


def compare_noise(fields: list[str], seeds: list[int], budget_m: float
                  ) -> list[dict[str, Any]]:
    """The noise found by differences along the tracks and by scikit-learn's WhiteKernel."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    from econdor_gcs.core.noise import estimate_noise

    out = []
    for field in fields:
        for seed in seeds:
            s, _, _, _ = recorded(field, seed, "lawnmower", budget_m)
            t0 = time.perf_counter()
            ours = estimate_noise(s.x_m, s.y_m, s.value).noise_std
            t1 = time.perf_counter()
            idx = thin_samples(s.x_m, s.y_m, 1.0)
            idx = np.sort(np.random.default_rng(seed).choice(idx, min(400, idx.size), replace=False))
            x, y, v = s.x_m[idx], s.y_m[idx], s.value[idx]
            kernel = (ConstantKernel(float(np.var(v)), (1e-6, 1e6))
                      * Matern(10.0, (0.5, 200.0), nu=2.5)
                      + WhiteKernel(0.01 * float(np.var(v)), (1e-8, 1e4)))
            t2 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ConvergenceWarning)
                gp = GaussianProcessRegressor(kernel, alpha=0.0, n_restarts_optimizer=2,
                                              random_state=seed).fit(
                    np.column_stack([x, y]), v - float(np.mean(v)))
            t3 = time.perf_counter()
            out.append({"field": field, "seed": seed, "ours": ours, "ours_s": t1 - t0,
                        "sklearn": math.sqrt(gp.kernel_.k2.noise_level),
                        "sklearn_s": t3 - t2})
    return out


def compare_fits(fields: list[str], seeds: list[int], budget_m: float) -> list[dict[str, Any]]:
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    out = []
    for field in fields:
        for seed in seeds:
            s, _, _, _ = recorded(field, seed, "lawnmower", budget_m)
            idx = thin_samples(s.x_m, s.y_m, 1.0)
            idx = np.sort(np.random.default_rng(seed).choice(idx, min(400, idx.size), replace=False))
            x, y, v = s.x_m[idx], s.y_m[idx], s.value[idx]
            t0 = time.perf_counter()
            # the same model for both: Matérn 5/2 with a negligible (1e-10) nugget
            ours = fit_matern(x, y, v, nu=2.5, nugget=1e-10, max_points=400, cell_m=1e-6)
            t1 = time.perf_counter()
            d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
            nll_ours = _profile_nll(math.log(ours.length_m), d, v, 2.5, ours.nugget)[0]
            kernel = (ConstantKernel(float(np.var(v)), (1e-6, 1e6))
                      * Matern(10.0, (0.5, 200.0), nu=2.5) + WhiteKernel(1e-10, "fixed"))
            t2 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ConvergenceWarning)
                gp = GaussianProcessRegressor(kernel, alpha=0.0, normalize_y=False).fit(
                    np.column_stack([x, y]), v - ours.mean)
            t3 = time.perf_counter()
            out.append({"field": field, "seed": seed, "ours_s": t1 - t0, "sklearn_s": t3 - t2,
                        "ours_l": ours.length_m, "sklearn_l": gp.kernel_.k1.k2.length_scale,
                        "ours_ll": -nll_ours, "sklearn_ll": gp.log_marginal_likelihood_value_})
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="0:3")
    p.add_argument("--fields", default="authors,plume")
    p.add_argument("--planners", default="lawnmower,adaptive,econdor")
    p.add_argument("--budget", type=float, default=6000.0)
    p.add_argument("--quick", action="store_true", help="1 seed, 2 km")
    p.add_argument("--markdown", action="store_true")
    p.add_argument("--noise", type=float, default=0.0, help="the sensor's noise (field units)")
    a = p.parse_args()
    NOISE_STD[0] = a.noise
    if a.quick:
        a.seeds, a.budget = "0", 2000.0
    seeds, fields, planners = parse_seeds(a.seeds), a.fields.split(","), a.planners.split(",")
    bar = "|" if a.markdown else " "
    rows = compare_reconstructions(fields, seeds, planners, a.budget)
    print(f"# kriging vs spline: {len(rows)} sample sets from {len(fields) * len(seeds) * len(planners)}"
          " real runs (median over the sets in each bucket)\n")
    head = ["field", "samples", "sets", "spline MAE dB", "kriging MAE dB", "kriging/spline MAE",
            "kriging better in", "spline s", "kriging s"]
    print(bar + bar.join(head) + bar)
    if a.markdown:
        print(bar + bar.join("---" for _ in head) + bar)
    for field in fields:
        for lo, hi in BUCKETS:
            sel = [r for r in rows if r["field"] == field and lo <= r["samples"] < hi]
            if not sel:
                continue
            ratio = [r["kriging"] / r["spline"] for r in sel]
            print(bar + bar.join([
                field, f"{lo}-{hi}", str(len(sel)),
                f"{statistics.median(metrics.to_db(r['spline']) for r in sel):.1f}",
                f"{statistics.median(metrics.to_db(r['kriging']) for r in sel):.1f}",
                f"{statistics.median(ratio):.2f}", f"{sum(x < 1 for x in ratio)}/{len(sel)}",
                f"{statistics.median(r['spline_s'] for r in sel):.2f}",
                f"{statistics.median(r['kriging_s'] for r in sel):.2f}"]) + bar)
    fits = compare_fits(fields, seeds, a.budget)
    print("\n# Matérn 5/2 fit on 400 recorded samples: our profile likelihood vs scikit-learn\n")
    head = ["field", "seed", "ours s", "sklearn s", "speed-up", "ours l m", "sklearn l m",
            "log-lik ours", "log-lik sklearn"]
    print(bar + bar.join(head) + bar)
    if a.markdown:
        print(bar + bar.join("---" for _ in head) + bar)
    for f in fits:
        print(bar + bar.join([f["field"], str(f["seed"]), f"{f['ours_s']:.2f}", f"{f['sklearn_s']:.2f}",
                              f"{f['sklearn_s'] / f['ours_s']:.1f}x", f"{f['ours_l']:.1f}",
                              f"{f['sklearn_l']:.1f}", f"{f['ours_ll']:.1f}",
                              f"{f['sklearn_ll']:.1f}"]) + bar)
    if a.noise > 0:
        noise = compare_noise(fields, seeds, a.budget)
        print(f"\n# the sensor noise ({a.noise:g}) found: differences along the tracks (all "
              "samples) vs scikit-learn's WhiteKernel by likelihood (400 samples)\n")
        head = ["field", "seed", "ours", "ours s", "sklearn WhiteKernel", "sklearn s"]
        print(bar + bar.join(head) + bar)
        if a.markdown:
            print(bar + bar.join("---" for _ in head) + bar)
        for f in noise:
            print(bar + bar.join([f["field"], str(f["seed"]), f"{f['ours']:.3f}",
                                  f"{f['ours_s']:.3f}", f"{f['sklearn']:.3f}",
                                  f"{f['sklearn_s']:.2f}"]) + bar)
    return 0


if __name__ == "__main__":
    sys.exit(main())
