"""Where a threshold run's metres go: the start line, the lines, the traces, the probes and
legs, and the flight to each (its approach), up to the estimate from which the iso-line
error stays within the target, and to the end of the run.

:func:`instrument` wraps a DFC run of the threshold planner (its jobs tagged by kind as the
planner makes them, each task's flight taken from the vehicle's report); the efficiency
bench keeps the result in each row of a threshold run (``row["metres"]``). This script
reads a saved bench run (``--json``) and sums it up, beside what each seed's true iso-line
is like (its pieces, their length, how many meet the area's edge) and, with ``--ideal``,
what a tracer that knew where the iso-line is would fly (:func:`ideal_tracer`).

    python bench/efficiency.py --fields authors --seeds 900:920 --threshold-only --json runs/a.jsonl
    python bench/anatomy.py runs/a.jsonl --ideal
    python bench/anatomy.py docs/results/data/threshold-fresh.jsonl.gz
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from report import ISO_TARGET_M, Table  # noqa: E402
from runs import mid_level, mission_for  # noqa: E402
from saved_rows import current_code, load  # noqa: E402
from summaries import fmt, stays_reached  # noqa: E402

from econdor_gcs.core.candidates import CandidateKind  # noqa: E402
from econdor_gcs.core.contours import contour_pieces  # noqa: E402
from econdor_gcs.core.geometry import path_length  # noqa: E402
from econdor_gcs.core.gp import kriging_reconstruct  # noqa: E402
from econdor_gcs.core.metrics import isoline_error  # noqa: E402
from econdor_gcs.core.spline import reconstruct  # noqa: E402
from econdor_gcs.core.tasks import TraceTask  # noqa: E402
from econdor_gcs.core.uncertainty import resample_polyline  # noqa: E402

CONTINUED_M = 3.0
"""A step that begins this close to where the vehicle is continues its line."""
KINDS = ("start", "line", "trace", "probe", "leg")
"""The start line (in steps), the lines through uncovered ground (in steps), traces,
probes across a track at a sampled extremum, and the greedy's legs, sweeps and lines."""


def instrument(dfc: Any) -> dict[int, dict[str, float]]:
    """Tag the threshold planner's jobs by kind and book what the vehicle flew for each:
    ``<kind>`` on the job, ``<kind>_approach`` getting to it (the flight to a line's first
    point, or a trace's transit and search), ``other`` the rest (braking). Returns the
    metres per iteration, filled as the run goes. The plans are the planner's own: the
    run is the run the bench would fly without it."""
    planner, executor = dfc.planner, dfc.executor
    metres: dict[int, dict[str, float]] = {}
    kinds: list[str] = []
    route_kinds: list[str] = []
    planned: dict[int, list[tuple[Any, str, bool]]] = {}
    start_route, step_batch, make_batch = planner._route.start, planner._step_batch, planner._batch

    def start(route: Any) -> None:
        route_kinds.append("start" if not route_kinds else "line")
        start_route(route)

    def step(step_: Any, levels_planned: int) -> Any:
        batch = step_batch(step_, levels_planned)
        kinds.extend(route_kinds[-1:] * len(batch.jobs))
        return batch

    def batch(picks: Any, levels: Any, whole_cap_m: float = 0.0) -> Any:
        out = make_batch(picks, levels, whole_cap_m)
        for route in picks:
            for pick in route:
                c = pick.candidate
                kinds.append("trace" if c.kind == CandidateKind.TRACE else
                             "probe" if c.first else "leg")
        return out

    def planning(method: Any) -> Any:
        def call(context: Any) -> Any:
            kinds.clear()
            got = method(context)
            if got is not None:
                if len(kinds) != len(got.jobs):
                    raise RuntimeError(f"{len(got.jobs)} jobs, {len(kinds)} kinds")
                planned[context.iteration] = [
                    (_key(task), kind, j == 0) for job, kind in zip(got.jobs, kinds, strict=True)
                    for j, task in enumerate(job.tasks)]
            return got
        return call

    fly = executor.fly

    def flying(plans: list[Any], iteration: int, *, survey: bool = False) -> list[Any]:
        before: list[tuple[float, float] | None] = list(executor.positions())
        reports = fly(plans, iteration, survey=survey)
        if iteration < 0:
            return reports
        booked: dict[str, float] = defaultdict(float)
        tasks = list(planned.pop(iteration, []))
        for report, pos in zip(reports, before, strict=True):
            for o in report.outcomes:
                k = next(i for i, (key, _, _) in enumerate(tasks) if key == _key(o.task))
                _, kind, job_first = tasks[k]
                tasks[k] = (None, kind, job_first)  # matched
                if isinstance(o.task, TraceTask):
                    booked[kind] += o.traced_m
                    booked[kind + "_approach"] += o.flown_m - o.traced_m
                    pos = None
                    continue
                wp = (o.task.x_m, o.task.y_m)
                # a line's next step begins a sample's spacing beyond where the last one
                # ended: flying on along the line, not getting to it
                going_on = (kind in ("start", "line") and pos is not None
                            and math.dist(pos, wp) < CONTINUED_M)
                if job_first and not going_on:
                    booked[kind + "_approach"] += o.flown_m
                else:
                    booked[kind] += o.flown_m
                pos = wp
            booked["other"] += report.flown_m - sum(o.flown_m for o in report.outcomes)
        metres[iteration] = dict(booked)
        return reports

    planner._route.start = start
    planner._step_batch = step
    planner._batch = batch
    planner.next_batch = planning(planner.next_batch)
    planner.initiation = planning(planner.initiation)
    executor.fly = flying
    return metres


def _key(task: Any) -> tuple[Any, ...]:
    """A task as planned and as flown (the fleet assignment numbers the trace pieces)."""
    if isinstance(task, TraceTask):
        return ("trace", task.level, task.x_m, task.y_m)
    return ("waypoint", task.x_m, task.y_m)


def ideal_tracer(field: str, seed: int, recon: str = "auto", max_lines: int = 40,
                 min_lines: int = 0) -> dict[str, Any]:
    """What a planner that knew where the iso-line is would fly: every piece of the true
    iso-line at the middle level (sampled every 0.8 m, as at 8 m/s and 10 Hz) after the
    fewest even survey lines (0, 1, 2, ...) with which the estimate's iso-line error is
    ≤ ISO_TARGET_M. Its distance counts the flight from the home corner to the first line,
    the lines, the pieces and the transits between them (nearest piece next), no search: a
    floor for planners that find the iso-line by flying on it, not a bound for all."""
    mission = mission_for(field, 0.0, "lawnmower", recon)
    truth, grid, region = mission.build_field(seed), mission.grid, mission.region
    level = mid_level(mission, seed)
    xx, yy = grid.mesh
    true_grid = np.asarray(truth(xx, yy))
    pieces = [(p.points_m, p.closed)
              for p in contour_pieces(true_grid, grid, np.array([level]), 1.0)]
    for lines in range(min_lines, max_lines + 1):
        xs = region.xmin + (np.arange(lines) + 0.5) * region.width_m / max(lines, 1)
        ys = np.arange(region.ymin + 0.5, region.ymax - 0.5 + 1e-9, 0.8)
        pts = [np.column_stack([np.repeat(xs, ys.size), np.tile(ys, lines)])]
        flown = lines * float(ys[-1] - ys[0]) + (
            float(xs[-1] - xs[0]) + math.hypot(xs[0] - region.xmin, ys[0] - region.ymin)
            if lines else 0.0)
        pos = np.array([xs[-1], ys[-1] if lines % 2 else ys[0]]) if lines else np.array(
            [region.xmin, region.ymin])
        left = list(pieces)
        while left:
            gaps = [float(np.min(np.hypot(*(q - pos).T))) for q, _ in left]
            k = int(np.argmin(gaps))
            q, closed = left.pop(k)
            i = int(np.argmin(np.hypot(*(q - pos).T)))
            q = np.vstack([q[i:-1], q[:i + 1]]) if closed and i else q
            flown += gaps[k] + path_length(q[:, 0], q[:, 1])
            pts.append(resample_polyline(q, 0.8))
            pos = q[-1]
        p = np.vstack(pts)
        v = np.asarray(truth(p[:, 0], p[:, 1]))
        est = (kriging_reconstruct(p[:, 0], p[:, 1], v, grid) if recon == "kriging"
               else reconstruct(p[:, 0], p[:, 1], v, grid))
        err = isoline_error(true_grid, est, grid, level)
        if err <= ISO_TARGET_M:
            return {"m": flown, "lines": lines, "iso": err}
    return {"m": math.inf, "lines": max_lines, "iso": math.nan}


def iso_line(field: str, seed: int) -> dict[str, float]:
    """The true iso-line at the middle level: its pieces, their length, those that meet
    the area's edge, and its longest piece."""
    mission = mission_for(field, 0.0, "lawnmower", "auto")
    xx, yy = mission.grid.mesh
    truth = np.asarray(mission.build_field(seed)(xx, yy))
    pieces = contour_pieces(truth, mission.grid, np.array([mid_level(mission, seed)]), 1.0)
    lengths = [p.length_m for p in pieces]
    return {"pieces": len(pieces), "open": sum(not p.closed for p in pieces),
            "length_m": float(sum(lengths)), "longest_m": max(lengths, default=0.0)}


def booked_until(rows: list[dict[str, Any]], upto_m: float) -> dict[str, float]:
    """The metres by kind of every row up to the one at ``upto_m`` (inclusive)."""
    out: dict[str, float] = defaultdict(float)
    for row in rows:
        if row["flight_m"] > upto_m:
            break
        for k, v in row.get("metres", {}).items():
            out[k] += v
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("json", help="bench/efficiency.py --json files with threshold runs "
                                "(comma-separated)")
    p.add_argument("--ideal", action="store_true", help="add the ideal tracer (slow)")
    p.add_argument("--markdown", action="store_true")
    a = p.parse_args()
    saved: dict[str, list[dict[str, Any]]] = {"runs": [], "surveys": []}
    for row in load(a.json, current_code):
        saved["runs" if row["kind"] == "run" else "surveys"].append(row)
    surveys = {(s["field"], s["seed"]): s for s in saved["surveys"]}
    cols = [f"{k}{part}" for k in KINDS for part in ("_approach", "")] + ["other"]
    for label in dict.fromkeys(r["planner"] for r in saved["runs"]
                               if r["planner"].endswith(":threshold")):
        runs = [r for r in saved["runs"] if r["planner"] == label]
        table = Table(["field", "seed", "pieces (open)", "iso-line m", "survey m (lines)",
                       "stays m", *cols, *(["ideal m (lines)"] if a.ideal else [])])
        sums: dict[str, list[float]] = defaultdict(list)
        for r in sorted(runs, key=lambda r: (r["field"], r["seed"])):
            sv = surveys[(r["field"], r["seed"])]["to_iso"]
            stays = stays_reached(r["rows"], lambda row: row["iso_target"] <= ISO_TARGET_M)
            got = booked_until(r["rows"], stays if math.isfinite(stays) else math.inf)
            line = iso_line(r["field"], r["seed"])
            cells = [r["field"], str(r["seed"]), f"{line['pieces']} ({line['open']})",
                     f"{line['length_m']:.0f}", f"{fmt(sv['flight_m'], '.0f')} ({sv['lines']})",
                     fmt(stays, ".0f"), *(f"{got.get(c, 0.0):.0f}" for c in cols)]
            for c in cols:
                sums[c].append(got.get(c, 0.0))
            for key, value in (("pieces", line["pieces"]), ("iso_m", line["length_m"]),
                               ("survey_m", sv["flight_m"]), ("stays_m", stays)):
                sums[key].append(value)
            if a.ideal:
                ideal = ideal_tracer(r["field"], r["seed"])
                cells.append(f"{fmt(ideal['m'], '.0f')} ({ideal['lines']})")
                sums["ideal_m"].append(ideal["m"])
                sums["ideal_ratio"].append(ideal["m"] / sv["flight_m"])
            table.add(cells)
        print(f"\n## {label}: metres by kind up to the estimate from which the error stays "
              f"≤ {ISO_TARGET_M} m (a run that never stays there: to its end)\n")
        print("\n".join(table.lines(a.markdown)))
        print("\nmedians: " + ", ".join(f"{k} {statistics.median(v):.0f}" for k, v in
                                        sums.items() if not k.endswith("ratio")))
        print("means: " + ", ".join(f"{k} {statistics.fmean(v):.0f}" for k, v in sums.items()
                                    if all(math.isfinite(x) for x in v)))
        if a.ideal:
            print(f"ideal tracer / best survey: median {statistics.median(sums['ideal_ratio']):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
