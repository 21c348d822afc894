"""How the onboard tracer keeps an iso-line with a noisy, lagging, mispositioned sensor.

Two measurements, both in-process (the compiled tracer of :mod:`sim_vehicle.machine`, the
sensor model of :mod:`sim_vehicle.sensor`), on the benchmark fields of ``bench/runs.py``
(plume and paper, 100 x 100 m, one vehicle at 8 m/s, 10 Hz):

``traces``
    Single trace tasks. For every seed the field's 25/50/75 % iso-lines (of its range on
    the grid); each is traced from a start 5 m off a random point of it (search radius
    15 m), the vehicle coming from a random point of the area. Per sensor: the outcomes'
    shares (not found, lost, closed, boundary, other), the distance of the traced samples
    (their reported positions) to the true iso-line (median and p90 over all samples,
    from a dense polyline of the true field's contour on a 0.25 m grid), the turning
    of the traced path (median over traces of the mean absolute heading change per metre
    of the reported positions: a zigzag turns much more than the iso-line's own bends; a
    GNSS error's jitter counts too) and, for traces that closed on a closed iso-line, the
    traced length over the loop's (a loop "closed" well short of 1 closed on something
    else).
``runs``
    Whole runs of the adaptive planner mapping the field on a 4 km budget (as
    ``bench/sensor.py --experiment map``): the trace outcomes of the whole run, the
    iso-line error at 25/50/75 % (medians) and the final MAE (dB).

Noise is given for the plume (field units; its range is about 90) and scaled to the same
share of the paper field's range (``PAPER_NOISE_SCALE``). Sensors are ``n<noise>l<lag>g<gnss>``
(GNSS: standard deviation in metres, correlation time 10 s); the default grid is noise
0 / 1 / 3, lag 0 / 0.5 / 1 s, GNSS 0 / 1 m.

    python bench/tracer_noise.py --seeds 0:10 --workers 2 --out docs/results/tracer-noise.md
    python bench/tracer_noise.py --part traces --seeds 0:3 --sensors n0l0g0,n3l0g0
"""

from __future__ import annotations

import argparse
import itertools
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from report import stamp  # noqa: E402
from runs import mission_for  # noqa: E402

from econdor_lab.study import parse_seeds  # noqa: E402
from econdor_lab.workers import WorkerPool  # noqa: E402

NOISES = (0.0, 1.0, 3.0)
LAGS_S = (0.0, 0.5, 1.0)
GNSS_M = (0.0, 1.0)
GNSS_TAU_S = 10.0
RUN_BUDGET_M = 4000.0
START_OFF_M = 5.0
SEARCH_RADIUS_M = 15.0
LEVEL_FRACTIONS = (0.25, 0.5, 0.75)
PLUME_SPAN = 90.0
"""About the plume fields' range (background 10, three sources): noise 1 is 1.1 % of it."""


def sensor_name(noise: float, lag_s: float, gnss_m: float) -> str:
    return f"n{noise:g}l{lag_s:g}g{gnss_m:g}"


def parse_sensor(name: str) -> tuple[float, float, float]:
    rest = name.removeprefix("n")
    noise, rest = rest.split("l")
    lag, gnss = rest.split("g")
    return float(noise), float(lag), float(gnss)


def sensor_keys(field: str, name: str, span: float) -> dict[str, float]:
    noise, lag_s, gnss_m = parse_sensor(name)
    if field != "plume":
        noise *= span / PLUME_SPAN
    keys = {"noise_std": noise, "lag_s": lag_s, "position_std_m": gnss_m}
    if gnss_m > 0.0:
        keys["position_tau_s"] = GNSS_TAU_S
    return keys


def _truth(field: str, seed: int) -> tuple[Any, Any, np.ndarray, np.ndarray, np.ndarray]:
    mission = mission_for(field, RUN_BUDGET_M, "adaptive", "auto")
    truth = mission.build_field(seed)
    reg = mission.region
    xs = np.arange(reg.xmin, reg.xmax + 1e-9, 0.25)
    ys = np.arange(reg.ymin, reg.ymax + 1e-9, 0.25)
    xx, yy = np.meshgrid(xs, ys)
    return mission, truth, xs, ys, np.asarray(truth(xx, yy), dtype=float)


def _contours(xs: np.ndarray, ys: np.ndarray, grid: np.ndarray, level: float
              ) -> list[np.ndarray]:
    from skimage.measure import find_contours

    step = xs[1] - xs[0]
    return [np.column_stack([xs[0] + c[:, 1] * step, ys[0] + c[:, 0] * step])
            for c in find_contours(grid, level) if len(c) >= 8]


def _turning_per_m(xy: np.ndarray) -> float:
    d = np.diff(xy, axis=0)
    seg = np.hypot(d[:, 0], d[:, 1])
    keep = seg > 1e-6
    d, seg = d[keep], seg[keep]
    if len(seg) < 3:
        return math.nan
    h = np.arctan2(d[:, 1], d[:, 0])
    dh = np.abs((np.diff(h) + np.pi) % (2 * np.pi) - np.pi)
    return float(dh.sum() / seg[1:].sum())


def trace_job(args: tuple[str, int, str]) -> dict[str, Any]:
    from scipy.spatial import cKDTree

    from econdor_gcs.core.tasks import Phase, TraceTask
    from sim_vehicle.body import SimBody
    from sim_vehicle.sensor import SensorModel
    from sim_vehicle.tracer import TracerParams, run_task_batch

    field, seed, name = args
    mission, truth, xs, ys, grid = _truth(field, seed)
    lo, hi = float(grid.min()), float(grid.max())
    keys = sensor_keys(field, name, hi - lo)
    rng = np.random.default_rng(1000 + seed)
    reg = mission.region
    out: dict[str, Any] = {"field": field, "seed": seed, "sensor": name, "traces": []}
    for j, frac in enumerate(LEVEL_FRACTIONS):
        level = lo + frac * (hi - lo)
        pieces = _contours(xs, ys, grid, level)
        if not pieces:
            continue
        line = max(pieces, key=len)
        k = int(rng.integers(len(line)))
        p0, p1 = line[max(k - 1, 0)], line[min(k + 1, len(line) - 1)]
        tx, ty = p1 - p0
        nrm = np.array([-ty, tx]) / max(math.hypot(tx, ty), 1e-9)
        side = 1.0 if rng.random() < 0.5 else -1.0
        sx, sy = line[k] + side * START_OFF_M * nrm
        sx = min(max(sx, reg.xmin + 1.0), reg.xmax - 1.0)
        sy = min(max(sy, reg.ymin + 1.0), reg.ymax - 1.0)
        bx, by = rng.uniform(reg.xmin, reg.xmax), rng.uniform(reg.ymin, reg.ymax)
        body = SimBody(truth, reg, bx, by, sensor=SensorModel(**keys),
                       rng=np.random.default_rng(seed * 100 + j),
                       position_rng=np.random.default_rng(seed * 100 + j + 50))
        task = TraceTask(level, float(sx), float(sy), SEARCH_RADIUS_M, 0.0, j)
        rows, outcome = run_task_batch(body, task, TracerParams(speed_mps=8.0,
                                                                sensor_lag_s=keys["lag_s"]))
        traced = rows[rows[:, 4] == int(Phase.TRACE)]
        dense = np.vstack(pieces)
        dist = (cKDTree(dense).query(traced[:, 1:3])[0] if len(traced)
                else np.zeros(0))
        closed_loop = bool(np.hypot(*(line[0] - line[-1])) < 1.0)
        out["traces"].append({"level_fraction": frac, "status": outcome.status,
                              "loop_m": (float(np.hypot(*np.diff(line, axis=0).T).sum())
                                         if closed_loop else math.nan),
                              "traced_m": outcome.traced_m, "flown_m": outcome.flown_m,
                              "dist": dist.round(3).tolist(),
                              "turning_per_m": _turning_per_m(traced[:, 1:3])})
    return out


def run_job(args: tuple[str, int, str]) -> dict[str, Any]:
    from econdor_gcs.dfc.loop import Dfc
    from econdor_lab.inprocess import InProcessExecutor

    field, seed, name = args
    mission, truth, _, _, grid = _truth(field, seed)
    mission = mission.with_vehicles(
        sensor=sensor_keys(field, name, float(grid.max() - grid.min())))
    t0 = time.perf_counter()
    res = Dfc(mission, InProcessExecutor(mission, truth, seed=seed), truth=truth,
              seed=seed).run()
    outcomes: dict[str, int] = {}
    for rec in res.records:
        for k, n in rec.outcomes.items():
            outcomes[k] = outcomes.get(k, 0) + n
    iso = res.isoline_error_m
    return {"field": field, "seed": seed, "sensor": name, "outcomes": outcomes,
            "iso": [iso.get(k, math.nan) for k in ("p25", "p50", "p75")],
            "mae_db": res.records[-1].mae_db, "wall_s": time.perf_counter() - t0}


def _med(xs: list[float]) -> float:
    xs = [x for x in xs if not math.isnan(x)]
    return statistics.median(xs) if xs else math.nan


def _shares(statuses: list[str]) -> str:
    n = max(len(statuses), 1)
    found = [s for s in statuses if s != "not_found"]
    cells = [len(found) / n] + [sum(s == k for s in statuses) / n
                                for k in ("lost", "closed", "boundary")]
    other = 1.0 - sum(cells[1:]) - (n - len(found)) / n
    return " | ".join(f"{100 * c:.0f} %" for c in [*cells, max(other, 0.0)])


def _ratio(traces: list[dict[str, Any]]) -> str:
    """Traced length over the true loop's for the traces that closed on a closed iso-line
    (a loop closed well short of it closed on something else)."""
    r = [t["traced_m"] / t["loop_m"] for t in traces
         if t["status"] == "closed" and not math.isnan(t.get("loop_m", math.nan))]
    return f"{statistics.median(r):.2f} ({min(r):.2f}, n={len(r)})" if r else "-"


def trace_table(results: list[dict[str, Any]], field: str) -> list[str]:
    rs = [r for r in results if r["field"] == field]
    seeds = sorted({r["seed"] for r in rs})
    lines = [f"\n### Traces, {field} (seeds {seeds[0]}-{seeds[-1]}, n={len(seeds)}, "
             f"{len(LEVEL_FRACTIONS)} levels each)\n",
             "| sensor | traces | found | lost | closed | boundary | other | "
             "distance to the true iso-line, median / p90 (m) | turning (rad/m), median | "
             "closed loops: traced / true length, median (min) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name in dict.fromkeys(r["sensor"] for r in rs):
        traces = [t for r in rs if r["sensor"] == name for t in r["traces"]]
        dist = np.array([d for t in traces for d in t["dist"]])
        med, p90 = (np.median(dist), np.percentile(dist, 90)) if len(dist) else (math.nan,) * 2
        lines.append(f"| {name} | {len(traces)} | {_shares([t['status'] for t in traces])} | "
                     f"{med:.2f} / {p90:.2f} | "
                     f"{_med([t['turning_per_m'] for t in traces]):.3f} | "
                     f"{_ratio(traces)} |")
    return lines


def run_table(results: list[dict[str, Any]], field: str) -> list[str]:
    rs = [r for r in results if r["field"] == field]
    if not rs:
        return []
    seeds = sorted({r["seed"] for r in rs})
    lines = [f"\n### Whole runs, {field} (adaptive, {RUN_BUDGET_M / 1000:g} km; seeds "
             f"{seeds[0]}-{seeds[-1]}, n={len(seeds)})\n",
             "| sensor | pieces | found | lost | closed | boundary | other | "
             "iso-line error 25/50/75 %, medians (m) | MAE, median (dB) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name in dict.fromkeys(r["sensor"] for r in rs):
        mine = [r for r in rs if r["sensor"] == name]
        statuses = [k for r in mine for k, n in r["outcomes"].items() for _ in range(n)]
        iso = [_med([r["iso"][k] for r in mine]) for k in range(3)]
        lines.append(f"| {name} | {len(statuses)} | {_shares(statuses)} | "
                     f"{' / '.join(f'{x:.2f}' for x in iso)} | "
                     f"{_med([r['mae_db'] for r in mine]):.1f} |")
    return lines


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--part", choices=("traces", "runs", "both"), default="both")
    p.add_argument("--fields", default="plume,paper")
    p.add_argument("--seeds", default="0:10")
    p.add_argument("--sensors", default=None, help="comma list of n<noise>l<lag>g<gnss>")
    p.add_argument("--run-sensors", default="n0l0g0,n1l0g0,n3l0g0,n1l0.5g1,n3l1g1",
                   help="sensors of the whole runs")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--out", default=None, help="also write the report here (Markdown, "
                   "stamped with the command and the commit)")
    a = p.parse_args()
    fields = a.fields.split(",")
    seeds = parse_seeds(a.seeds)
    sensors = (a.sensors.split(",") if a.sensors else
               [sensor_name(*c) for c in itertools.product(NOISES, LAGS_S, GNSS_M)])
    lines = ["# The tracer with a noisy sensor", "", *(stamp(sys.argv) if a.out else [])]
    with WorkerPool(a.workers) as pool:
        if a.part in ("traces", "both"):
            jobs = [(f, s, n) for f in fields for s in seeds for n in sensors]
            results = list(pool.map(trace_job, jobs))
            for f in fields:
                lines += trace_table(results, f)
        if a.part in ("runs", "both"):
            jobs = [(f, s, n) for f in fields for s in seeds for n in a.run_sensors.split(",")]
            results = list(pool.map(run_job, jobs))
            for f in fields:
                lines += run_table(results, f)
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
