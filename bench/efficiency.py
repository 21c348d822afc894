"""How much flying each planner needs, with budgets that bind and the best survey as baseline.

Budget-true: every planner flies until the flight budget is spent (the iteration cap is
far beyond reach, so the budget binds), on the same fields, with the same reconstruction
and the same cost accounting (the initiation, every transit, search and trace metre; the
flight home after the last iteration is not part of any estimate and is left out).

The survey baseline is not one survey refined by halving: for each budget it is the
survey whose line spacing fills that budget, and for each target the survey with the
fewest lines that reaches it (line counts scanned on a ladder, then bisected), per seed
— what an operator who knew the answer would fly.

Fields: ``authors`` (the paper's setting: the authors' generator, missions/paper.yaml),
``paper`` (the paper's eqs. 8-9), ``plume`` (3 narrow sources on a flat background) and
``front`` (a meandering sharp front and round islands).

Per planner and field it prints: the median distance to -10/-20/-30 dB (runs that got
there, and in how many seeds the planner got there in less distance than the best survey
for that seed), the MAE and the iso-line error at budgets, stalls, and for plumes the
sources missed (no sample within one sigma of a source centre). ``--threshold`` adds
threshold mapping: the adaptive planner given one target level (the middle of the true
range) against the survey's distance to the same iso-line error.

    python bench/efficiency.py --quick                      # 2 seeds, a smoke run
    python bench/efficiency.py --seeds 0:20 --markdown --json runs/efficiency.json
    python bench/efficiency.py --fields plume --planners adaptive --threshold
    python bench/efficiency.py --seeds 0:8 --planners 'adaptive,adaptive[batch_m=200]'

A planner written ``adaptive[key=value,...]`` is the adaptive planner with those settings
on top of ``--adaptive``: variants measured against the default in the same run.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import statistics
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from econdor_gcs.core.contours import contour_pieces  # noqa: E402
from econdor_gcs.core.geometry import path_length  # noqa: E402
from econdor_gcs.core.gp import kriging_reconstruct  # noqa: E402
from econdor_gcs.core.metrics import isoline_error  # noqa: E402
from econdor_gcs.core.spline import reconstruct  # noqa: E402
from econdor_gcs.core.uncertainty import resample_polyline  # noqa: E402
from econdor_gcs.dfc import Dfc, isoline_levels  # noqa: E402
from econdor_gcs.mission import Mission, parse_mission  # noqa: E402
from econdor_lab.inprocess import InProcessExecutor  # noqa: E402
from econdor_lab.study import parse_seeds  # noqa: E402

TARGETS_DB = (-10.0, -20.0, -30.0)
ISO_TARGET_M = 0.5
EVERY_M = 20.0
"""Threshold runs are also measured along the way: the estimate from the samples flown so
far, every this many metres of flight (the planner's and the survey's alike)."""
SURVEY_FROM = 0.5
"""... a survey from this fraction of its flight on (before, part of the area is unflown)."""
FIELDS: dict[str, dict[str, Any]] = {
    "authors": {"model": "authors"},
    "paper": {"model": "paper"},
    "plume": {"model": "plume", "sources": 3, "sigma_min_m": 3.0, "sigma_max_m": 6.0,
              "background": 10.0},
    "front": {"model": "front"},
}
LADDER = (2, 3, 4, 5, 6, 8, 10, 12, 15, 19, 24, 30, 38, 48, 60, 75, 95, 120, 150, 199)


def parse_settings(text: str) -> dict[str, Any]:
    """``"model=proxy,floor=20"`` -> ``{"model": "proxy", "floor": 20.0}``."""
    out: dict[str, Any] = {}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        if value in ("true", "false"):
            out[key] = value == "true"
            continue
        try:
            out[key] = int(value)
        except ValueError:
            try:
                out[key] = float(value)
            except ValueError:
                out[key] = value
    return out


def split_variant(planner: str) -> tuple[str, dict[str, Any]]:
    """``"adaptive[batch_m=200]"`` -> ``("adaptive", {"batch_m": 200})``.

    >>> split_variant("adaptive[batch_m=200,legs=0]")
    ('adaptive', {'batch_m': 200, 'legs': 0})
    >>> split_variant("no-sg")
    ('no-sg', {})
    """
    name, bracket, rest = planner.partition("[")
    if not bracket:
        return planner, {}
    if not rest.endswith("]"):
        raise ValueError(f"planner {planner!r}: settings must end with ']'")
    return name, parse_settings(rest[:-1])


def split_planners(text: str) -> list[str]:
    """Split ``--planners`` at the commas outside brackets.

    >>> split_planners("adaptive,adaptive[batch_m=200,legs=0],no-sg")
    ['adaptive', 'adaptive[batch_m=200,legs=0]', 'no-sg']
    """
    out, depth, item = [], 0, ""
    for ch in text:
        depth += {"[": 1, "]": -1}.get(ch, 0)
        if ch == "," and depth == 0:
            out.append(item)
            item = ""
        else:
            item += ch
    out.append(item)
    return out


def mission_for(field: str, budget_m: float, planner: str, reconstruction: str,
                target_levels: tuple[float, ...] = (), survey_lines: int = 0,
                adaptive: dict[str, Any] | None = None) -> Mission:
    """The benchmark mission: 100 x 100 m, one vehicle, the diagonals, a binding budget."""
    algo: dict[str, Any] = {
        "planner": planner, "max_iterations": 1000, "min_iterations": 1000,
        "flight_budget_m": budget_m, "reconstruction": reconstruction,
        "target_levels": list(target_levels), "max_idle_iterations": 2}
    raw: dict[str, Any] = {"name": f"efficiency-{field}", "field": FIELDS[field],
                           "vehicles": {"count": 1}, "algorithm": algo,
                           "adaptive": adaptive or {}}
    if survey_lines:
        width, height = 100.0, 100.0
        raw["lawnmower"] = {"budget_m": survey_lines * height + width}
        algo.update(max_iterations=1, min_iterations=1, flight_budget_m=0.0)
    return parse_mission(raw, base_dir=ROOT / "missions")


def mid_level(mission: Mission, seed: int) -> float:
    """The middle of the true field's range on the grid (the 50 % iso-line)."""
    xx, yy = mission.grid.mesh
    return isoline_levels(np.asarray(mission.build_field(seed)(xx, yy)), (0.5,))[0]


def sources_missed(field: Any, x_m: np.ndarray, y_m: np.ndarray) -> int:
    """Plume sources with no sample within one sigma of their centre."""
    centres = getattr(field, "centres_m", None)
    if centres is None or len(x_m) == 0:
        return 0
    d, _ = cKDTree(np.column_stack([x_m, y_m])).query(centres)
    return int(np.sum(d > field.sigmas_m))


def _row(rec: Any, flight_m: float) -> dict[str, Any]:
    iso = rec.isoline_error_m
    return {"flight_m": flight_m, "mae_db": rec.mae_db, "samples": rec.samples,
            "iso": [iso.get(k, math.nan) for k in ("p25", "p50", "p75")],
            "iso_target": iso.get("target", math.nan),
            "target_missed": iso.get("target_missed", math.nan)}


class _Executor(InProcessExecutor):
    """The in-process executor, counting the samples of the flight home (the DFC adds them
    to its last record, whose estimate is from before them)."""

    home_samples = 0

    def finish(self) -> list[Any]:
        reports = super().finish()
        self.home_samples = sum(len(r.samples) for r in reports)
        return reports


def sample_distances(flight_m: list[float], counts: list[int], x_m: np.ndarray,
                     y_m: np.ndarray, home: tuple[float, float]) -> np.ndarray:
    """The flight distance at each sample: within each flight (record), the path between
    its samples (from the last sample before it, or home), scaled so that the flight ends
    at its recorded distance (turns, searches and braking fly more than the chords)."""
    out = np.zeros(len(x_m))
    prev_n, prev_d = 0, 0.0
    px, py = home
    for d, n in zip(flight_m, counts, strict=True):
        if n > prev_n:
            xs = np.r_[px, x_m[prev_n:n]]
            ys = np.r_[py, y_m[prev_n:n]]
            cum = np.cumsum(np.hypot(np.diff(xs), np.diff(ys)))
            scale = (d - prev_d) / cum[-1] if cum[-1] > 0 else 0.0
            out[prev_n:n] = prev_d + cum * scale
            px, py = x_m[n - 1], y_m[n - 1]
        prev_n, prev_d = n, d
    return out


def first_within(mission: Mission, truth_grid: np.ndarray, level: float, x_m: np.ndarray,
                 y_m: np.ndarray, v: np.ndarray, dist_m: np.ndarray, from_m: float = 0.0
                 ) -> float:
    """The first flight distance (checked every EVERY_M from ``from_m``) at which the
    estimate from the samples so far has an iso-line error at ``level`` <= ISO_TARGET_M
    (the mission's reconstruction, as the DFC does it); nan if never."""
    grid = mission.grid
    method = mission.algorithm.reconstruction
    start = max(from_m, EVERY_M)
    for d in np.arange(start, dist_m[-1] + EVERY_M, EVERY_M) if len(dist_m) else ():
        n = int(np.searchsorted(dist_m, min(d, dist_m[-1]), side="right"))
        if n < 3:
            continue
        est = (kriging_reconstruct(x_m[:n], y_m[:n], v[:n], grid) if method == "kriging"
               else reconstruct(x_m[:n], y_m[:n], v[:n], grid, method=method))
        if isoline_error(truth_grid, est, grid, level) <= ISO_TARGET_M:
            return float(dist_m[n - 1])
    return math.nan


def run_planner(args: tuple[str, int, str, float, str, bool, dict[str, Any], bool]
                ) -> dict[str, Any]:
    """One budget-true run: per-iteration rows (flight home excluded), sources missed."""
    field, seed, label, budget_m, recon, threshold, adaptive, along_way = args
    planner, variant = split_variant(label)
    adaptive = {**adaptive, **variant}
    targets = (mid_level(mission_for(field, budget_m, planner, recon), seed),) if threshold else ()
    mission = mission_for(field, budget_m, planner, recon, targets, adaptive=adaptive)
    truth = mission.build_field(seed)
    t0 = time.perf_counter()
    executor = _Executor(mission, truth, seed=seed)
    res = Dfc(mission, executor, planner=planner, truth=truth, seed=seed).run()
    rows = []
    for i, rec in enumerate(res.records):
        last = i == len(res.records) - 1
        rows.append(_row(rec, rec.flight_distance_m - (res.return_m if last else 0.0)))
    s = res.samples
    for row in rows:
        n = row["samples"]
        row["missed"] = sources_missed(truth, s.x_m[:n], s.y_m[:n])
    along = math.nan
    if threshold and along_way and rows:
        counts = [r["samples"] for r in rows]
        counts[-1] -= executor.home_samples  # not the flight home
        n = counts[-1]
        dist = sample_distances([r["flight_m"] for r in rows], counts, s.x_m[:n], s.y_m[:n],
                                (mission.region.xmin, mission.region.ymin))
        xx, yy = mission.grid.mesh
        along = first_within(mission, np.asarray(truth(xx, yy)), targets[0], s.x_m[:n],
                             s.y_m[:n], s.value[:n], dist)
    return {"field": field, "seed": seed, "planner": label + (":threshold" if threshold else ""),
            "rows": rows, "stop": res.stop_reason, "wall_s": time.perf_counter() - t0,
            "target": targets[0] if targets else math.nan, "along_m": along}


def run_survey(mission: Mission, seed: int, lines: int, along_way: bool = False
               ) -> dict[str, Any]:
    """One survey of ``lines`` north-south lines; its single estimate (and, with
    ``along_way``, where along its flight the mid-level iso-line first met the target)."""
    truth = mission.build_field(seed)
    executor = _Executor(mission, truth, seed=seed)
    res = Dfc(mission, executor, planner="lawnmower", truth=truth, seed=seed).run()
    rec = res.records[0]
    s = res.samples
    row = _row(rec, rec.flight_distance_m)
    row["missed"] = sources_missed(truth, s.x_m, s.y_m)
    row["lines"] = lines
    if along_way and math.isfinite(row["iso"][1]) and row["iso"][1] <= ISO_TARGET_M:
        # the same survey measured along the way (only one that gets there at its end)
        n = rec.samples  # the survey's record: its samples, before the flight home
        dist = sample_distances([rec.flight_distance_m], [n], s.x_m[:n], s.y_m[:n],
                                (mission.region.xmin, mission.region.ymin))
        xx, yy = mission.grid.mesh
        row["along_m"] = first_within(mission, np.asarray(truth(xx, yy)), mid_level(mission, seed),
                                      s.x_m[:n], s.y_m[:n], s.value[:n], dist,
                                      SURVEY_FROM * rec.flight_distance_m)
    return row


class SurveyScan:
    """The best survey per budget and per target for one field and seed (memoised)."""

    def __init__(self, field: str, seed: int, recon: str, cache: Path | None,
                 along_way: bool = False) -> None:
        self.field, self.seed, self.recon = field, seed, recon
        self.along_way = along_way
        self.cache = cache
        self.runs: dict[int, dict[str, Any]] = {}

    def get(self, lines: int) -> dict[str, Any]:
        if lines not in self.runs:
            path = None
            if self.cache is not None:
                path = self.cache / f"survey-{self.field}-{self.recon}-{self.seed}-{lines}.json"
                if path.exists():
                    row = json.loads(path.read_text())
                    if (not self.along_way or "along_m" in row
                            or not row["iso"][1] <= ISO_TARGET_M):
                        self.runs[lines] = row
                        return row
            mission = mission_for(self.field, 0.0, "lawnmower", self.recon, survey_lines=lines)
            self.runs[lines] = run_survey(mission, self.seed, lines, self.along_way)
            if path is not None:
                path.write_text(json.dumps(self.runs[lines]))
        return self.runs[lines]

    def for_budget(self, budget_m: float) -> dict[str, Any] | None:
        """The survey that fills ``budget_m`` (most lines within it)."""
        n = int((budget_m - 100.0) // 100.0)
        while n >= 2:
            r = self.get(n)
            if r["flight_m"] <= budget_m:
                return r
            n -= 1
        return None

    def first_reaching(self, ok: Any, max_lines: int) -> dict[str, Any] | None:
        """The survey with the fewest lines for which ``ok(row)`` holds (ladder, then
        bisection between the last ladder count that failed and the first that passed)."""
        prev = 1
        for n in (k for k in LADDER if k <= max_lines):
            if ok(self.get(n)):
                lo, hi = prev, n  # ok fails at lo (or lo is below the ladder), holds at hi
                while hi - lo > 1:
                    mid = (lo + hi) // 2
                    if ok(self.get(mid)):
                        hi = mid
                    else:
                        lo = mid
                return self.get(hi)
            prev = n
        return None


def ideal_tracer(field: str, seed: int, recon: str, max_lines: int = 40, min_lines: int = 0
                 ) -> dict[str, Any]:
    """What a planner that knew where the iso-line is would fly: every piece of the true
    iso-line at the middle level (sampled every 0.8 m, as at 8 m/s and 10 Hz) after the
    fewest even survey lines (0, 1, 2, ...) with which the estimate's iso-line error is
    ≤ ISO_TARGET_M. Its distance counts the flight from the home corner to the first line,
    the lines, the pieces and the transits between them (nearest piece next, from the home
    corner or the survey's end), no search: a floor for planners that find the iso-line by
    flying on it, not a bound for all. With ``min_lines = 1``: the same after at least one
    line (the adaptive planner's start in threshold mode until it became the diagonal,
    which flew the same ~50 m from home to the line through the middle)."""
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
            return {"km": flown / 1000, "lines": lines, "iso": err}
    return {"km": math.nan, "lines": max_lines, "iso": math.nan}


def scan_survey(args: tuple[str, int, float, str, str | None, list[float], bool, bool]
                ) -> dict[str, Any]:
    field, seed, budget_m, recon, cache, budgets, threshold, along_way = args
    scan = SurveyScan(field, seed, recon, Path(cache) if cache else None, along_way)
    t0 = time.perf_counter()
    max_lines = int((budget_m - 100.0) // 100.0)
    out: dict[str, Any] = {"field": field, "seed": seed, "budget": {}, "to_db": {}}
    for b in budgets:
        out["budget"][str(b)] = scan.for_budget(b)
    for t in TARGETS_DB:
        r = scan.first_reaching(lambda row, t=t: row["mae_db"] <= t, max_lines)
        out["to_db"][str(t)] = r["flight_m"] if r else math.nan
    r = scan.first_reaching(lambda row: row["iso"][1] <= ISO_TARGET_M, max_lines)
    out["to_iso50"] = r["flight_m"] if r else math.nan
    # measured along the way: a survey of a few more lines may get there before its end
    out["to_iso50_along"] = math.nan
    if r and along_way:
        along = [scan.get(n).get("along_m", math.nan)
                 for n in range(r["lines"], min(r["lines"] + 3, max_lines) + 1)]
        along = [a for a in along if not math.isnan(a)]
        out["to_iso50_along"] = min(along) if along else math.nan
    if threshold:
        out["ideal"] = ideal_tracer(field, seed, recon)
        # the fewest lines >= 1 are the fewest lines when those are >= 1 already
        out["ideal_line"] = (out["ideal"] if out["ideal"]["lines"] >= 1 else
                             ideal_tracer(field, seed, recon, min_lines=1))
    for n in LADDER:  # the whole ladder within the budget: the survey's curve in the figures
        if n <= max_lines:
            scan.get(n)
    out["runs"] = len(scan.runs)
    out["scanned"] = sorted(scan.runs.values(), key=lambda r: r["lines"])
    out["wall_s"] = time.perf_counter() - t0
    return out


# -- summaries ----------------------------------------------------------------------------


def distance_to(rows: list[dict[str, Any]], ok: Any, budget_m: float = math.inf) -> float:
    """Flight distance of the first estimate for which ``ok`` holds, within the budget (a
    last batch that overran the budget does not count)."""
    for row in rows:
        if row["flight_m"] > budget_m:
            break
        if ok(row):
            return float(row["flight_m"])
    return math.nan


def at_budget(rows: list[dict[str, Any]], budget_m: float) -> dict[str, Any] | None:
    best = None
    for row in rows:
        if row["flight_m"] <= budget_m:
            best = row
    return best


def stalled(r: dict[str, Any]) -> bool:
    """Stopped by the stall rule, or improved < 1 dB over the second half of its flight
    while still worse than -30 dB."""
    rows = r["rows"]
    if r["stop"] == "stalled":
        return True
    if len(rows) < 3:
        return False
    half = at_budget(rows, rows[-1]["flight_m"] / 2)
    final = rows[-1]["mae_db"]
    return final > min(TARGETS_DB) and (half is None or half["mae_db"] - final < 1.0)


def med(values: list[float]) -> float:
    v = [x for x in values if not math.isnan(x)]
    return statistics.median(v) if v else math.nan


def fmt(x: float, spec: str = ".1f") -> str:
    return "—" if math.isnan(x) else format(x, spec)


def iso_mean(row: dict[str, Any] | None) -> float:
    if row is None:
        return math.nan
    v = [x for x in row["iso"] if not math.isnan(x)]
    return sum(v) / len(v) if v else math.nan


def table(field: str, planners: list[str], runs: list[dict[str, Any]],
          surveys: dict[int, dict[str, Any]], budgets: list[float], bar: str, md: bool) -> None:
    plume = field == "plume"
    head = ["planner", *[f"km to {t:.0f} dB (runs; beat survey)" for t in TARGETS_DB],
            *[f"MAE dB @{b / 1000:g} km" for b in budgets],
            *[f"iso m @{b / 1000:g} km" for b in budgets], "stalls"]
    if plume:
        head += [f"sources missed @{b / 1000:g} km" for b in (budgets[0], budgets[-1])]
    head.append("wall s/run")
    print(bar + bar.join(head) + bar)
    if md:
        print(bar + bar.join("---" for _ in head) + bar)
    seeds = sorted(surveys)
    for pl in [*planners, "best survey"]:
        cells = [pl]
        rs = [r for r in runs if r["field"] == field and r["planner"] == pl]
        for t in TARGETS_DB:
            sv = [surveys[s]["to_db"][str(t)] for s in seeds]
            if pl == "best survey":
                d = sv
                cells.append(f"{fmt(med(d) / 1000, '.2f')} ({sum(not math.isnan(x) for x in d)}/"
                             f"{len(d)})")
                continue
            d = [distance_to(r["rows"], lambda row, t=t: row["mae_db"] <= t, budgets[-1])
                 for r in rs]
            by_seed = {r["seed"]: x for r, x in zip(rs, d, strict=True)}
            wins = sum(1 for s in seeds if s in by_seed and not math.isnan(by_seed[s]) and (
                math.isnan(surveys[s]["to_db"][str(t)]) or by_seed[s] < surveys[s]["to_db"][str(t)]))
            cells.append(f"{fmt(med(d) / 1000, '.2f')} ({sum(not math.isnan(x) for x in d)}/"
                         f"{len(d)}; {wins})")
        for b in budgets:
            if pl == "best survey":
                v = [surveys[s]["budget"][str(b)] for s in seeds]
                cells.append(fmt(med([x["mae_db"] if x else math.nan for x in v])))
            else:
                cells.append(fmt(med([(at_budget(r["rows"], b) or {"mae_db": math.nan})["mae_db"]
                                      for r in rs])))
        for b in budgets:
            if pl == "best survey":
                cells.append(fmt(med([iso_mean(surveys[s]["budget"][str(b)]) for s in seeds]), ".2f"))
            else:
                cells.append(fmt(med([iso_mean(at_budget(r["rows"], b)) for r in rs]), ".2f"))
        cells.append("—" if pl == "best survey" else f"{sum(stalled(r) for r in rs)}/{len(rs)}")
        if plume:
            for b in (budgets[0], budgets[-1]):
                if pl == "best survey":
                    m = [(surveys[s]["budget"][str(b)] or {"missed": 3})["missed"] for s in seeds]
                else:
                    m = [(at_budget(r["rows"], b) or {"missed": 3})["missed"] for r in rs]
                cells.append(f"{sum(m)} of {3 * len(m)}")
        wall = [surveys[s]["wall_s"] / max(1, surveys[s]["runs"]) for s in seeds] if (
            pl == "best survey") else [r["wall_s"] for r in rs]
        cells.append(fmt(med(wall), ".0f"))
        print(bar + bar.join(cells) + bar)


def threshold_table(field: str, runs: list[dict[str, Any]], surveys: dict[int, dict[str, Any]],
                    budget_m: float, bar: str, md: bool) -> None:
    """Per threshold mapper: each seed's distance to iso <= ISO_TARGET_M against the best
    survey's and the ideal tracer's (see :func:`ideal_tracer`), then one summary line."""
    rs = [r for r in runs if r["field"] == field and r["planner"].endswith(":threshold")]
    labels = list(dict.fromkeys(r["planner"] for r in rs))
    along_way = any(not math.isnan(r.get("along_m", math.nan)) for r in rs)
    along_head = [f"km along the way (every {EVERY_M:g} m)", "survey km along",
                  "ratio along"] if along_way else []
    summary = []
    for label in labels:
        head = ["seed", "level", f"km to iso ≤ {ISO_TARGET_M} m", "survey km", "ratio",
                *along_head, "ideal tracer km (lines)", "ideal ratio", "final iso m", "pieces missed", "stop",
                "flown km"]
        print(f"\n### threshold mapping, field {field}: {label.removesuffix(':threshold')}\n")
        print(bar + bar.join(head) + bar)
        if md:
            print(bar + bar.join("---" for _ in head) + bar)
        ratios, ideal, ideal_line, alongs = [], [], [], []
        for r in sorted((r for r in rs if r["planner"] == label), key=lambda r: r["seed"]):
            d = distance_to(r["rows"], lambda row: row["iso_target"] <= ISO_TARGET_M, budget_m)
            sv = surveys[r["seed"]]
            to_iso = sv["to_iso50"]
            ratio = d / to_iso if to_iso and not math.isnan(to_iso) else math.nan
            ratios.append(ratio)
            along_m, sv_along = r.get("along_m", math.nan), sv.get("to_iso50_along", math.nan)
            alongs.append(along_m / sv_along if sv_along and not math.isnan(sv_along)
                          else math.nan)
            tracer = sv.get("ideal") or {"km": math.nan, "lines": -1}
            ideal.append(tracer["km"] * 1000 / to_iso if to_iso else math.nan)
            after_line = sv.get("ideal_line") or {"km": math.nan}
            ideal_line.append(after_line["km"] * 1000 / to_iso if to_iso else math.nan)
            last = r["rows"][-1]
            print(bar + bar.join([
                str(r["seed"]), fmt(r["target"]), fmt(d / 1000, ".2f"), fmt(to_iso / 1000, ".2f"),
                fmt(ratio, ".2f"),
                *([fmt(along_m / 1000, ".2f"), fmt(sv_along / 1000, ".2f"),
                   fmt(alongs[-1], ".2f")] if along_way else []),
                f"{fmt(tracer['km'], '.2f')} ({tracer['lines']})",
                fmt(ideal[-1], ".2f"), fmt(last["iso_target"], ".2f"),
                fmt(last["target_missed"], ".0f"), r["stop"],
                fmt(last["flight_m"] / 1000, ".2f")]) + bar)
        got = [x for x in ratios if not math.isnan(x)]
        got_along = [x for x in alongs if not math.isnan(x)]
        summary.append((label, med(ratios), len(got), len(ratios), sum(x <= 0.5 for x in got),
                        sum(x < 1.0 for x in got), med(ideal), med(ideal_line),
                        med(alongs), sum(x <= 0.5 for x in got_along)))
    if not summary:
        return
    print(f"\n### threshold mapping, field {field}: summary\n")
    head = ["mapper", "median ratio to the survey", "runs there", "ratio ≤ 0.5", "beat survey",
            "ideal tracer's median ratio", "... after one line",
            *([f"median ratio along the way (every {EVERY_M:g} m)", "ratio along ≤ 0.5"]
              if along_way else [])]
    print(bar + bar.join(head) + bar)
    if md:
        print(bar + bar.join("---" for _ in head) + bar)
    for label, ratio, got, n, half, won, ideal_ratio, line_ratio, along, half_along in summary:
        print(bar + bar.join([label.removesuffix(":threshold"), fmt(ratio, ".2f"), f"{got}/{n}",
                              str(half), str(won), fmt(ideal_ratio, ".2f"),
                              fmt(line_ratio, ".2f"),
                              *([fmt(along, ".3f"), str(half_along)] if along_way else [])
                              ]) + bar)


def figures(out: Path, fields: list[str], planners: list[str], runs: list[dict[str, Any]],
            surveys: list[dict[str, Any]], budget_m: float) -> list[Path]:
    """MAE against distance, median over the seeds, per field: every planner and the best
    survey for each distance (the lower envelope of the scanned surveys, per seed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    grid = np.linspace(0.0, budget_m, 201)
    paths = []
    for field in fields:
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
        for pl in [*planners, "best survey"]:
            curves = []
            if pl == "best survey":
                for sv in (s for s in surveys if s["field"] == field):
                    rows = sorted(sv["scanned"], key=lambda r: r["flight_m"])
                    best, curve, k = math.nan, [], 0
                    for d in grid:
                        while k < len(rows) and rows[k]["flight_m"] <= d:
                            best = min(best, rows[k]["mae_db"]) if not math.isnan(best) else (
                                rows[k]["mae_db"])
                            k += 1
                        curve.append(best)
                    curves.append(curve)
            else:
                for r in (r for r in runs if r["field"] == field and r["planner"] == pl):
                    curves.append([(at_budget(r["rows"], d) or {"mae_db": math.nan})["mae_db"]
                                   for d in grid])
            if not curves:
                continue
            arr = np.array(curves, dtype=float)
            ok = np.sum(np.isfinite(arr), axis=0) * 2 > arr.shape[0]  # most seeds have a value
            with warnings.catch_warnings():  # all-NaN columns are masked by ``ok``
                warnings.simplefilter("ignore", RuntimeWarning)
                median = np.where(ok, np.nanmedian(np.where(np.isfinite(arr), arr, np.nan), axis=0),
                                  np.nan)
            ax.plot(grid / 1000, median, label=pl, lw=2 if pl in ("adaptive", "best survey") else 1)
        for t in TARGETS_DB:
            ax.axhline(t, color="0.85", lw=0.8, zorder=0)
        ax.set_xlabel("flight distance (km), everything counted")
        ax.set_ylabel("MAE (dB), median over seeds")
        ax.set_title(f"{field}: MAE against distance")
        ax.legend()
        path = out / f"efficiency_{field}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="0:20")
    p.add_argument("--fields", default=",".join(FIELDS))
    p.add_argument("--planners", default="adaptive,econdor,no-sg")
    p.add_argument("--budget", type=float, default=10_000.0, help="flight budget per run (m)")
    p.add_argument("--reconstruction", default="auto", help="auto | kriging (all planners)")
    p.add_argument("--threshold", action="store_true",
                   help="add threshold mapping runs: each adaptive planner (variants too) of "
                        "--planners, or the default adaptive planner if there is none")
    p.add_argument("--threshold-only", action="store_true",
                   help="only the threshold mapping runs (implies --threshold)")
    p.add_argument("--along", action="store_true",
                   help="threshold runs measured along the way too: the estimate from the "
                        f"samples so far every {EVERY_M:g} m of flight, the planner's and the "
                        "survey's alike (slower)")
    p.add_argument("--adaptive", default="", help="adaptive settings, e.g. model=proxy,floor=20")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--cache", default=None, help="directory memoising survey runs")
    p.add_argument("--json", default=None, help="write every run's rows here")
    p.add_argument("--from-json", default=None, help="print tables (and figures) from a saved run")
    p.add_argument("--figures", default=None, help="draw MAE-against-distance figures here")
    p.add_argument("--quick", action="store_true", help="2 seeds, 3 km budget")
    p.add_argument("--markdown", action="store_true", help="print Markdown tables")
    a = p.parse_args()
    if a.quick:
        a.seeds, a.budget = "0:2", 3_000.0
    seeds = parse_seeds(a.seeds)
    fields = a.fields.split(",")
    unknown = [f for f in fields if f not in FIELDS]
    if unknown:
        p.error(f"--fields: unknown field {unknown[0]!r} (one of {', '.join(FIELDS)})")
    planners = [x for x in split_planners(a.planners) if x]
    try:
        for pl in planners:
            split_variant(pl)
    except ValueError as exc:
        p.error(f"--planners: {exc}")
    budgets = [b for b in (1_000.0, 2_000.0, 5_000.0, 10_000.0, 20_000.0) if b < a.budget]
    budgets.append(a.budget)
    if a.cache:
        Path(a.cache).mkdir(parents=True, exist_ok=True)
    settings = parse_settings(a.adaptive)
    a.threshold = a.threshold or a.threshold_only
    jobs: list[tuple[Any, ...]] = [] if a.threshold_only else [
        (f, s, pl, a.budget, a.reconstruction, False, settings, False)
        for f in fields for s in seeds for pl in planners]
    if a.threshold:
        mappers = [pl for pl in planners if split_variant(pl)[0] == "adaptive"] or ["adaptive"]
        jobs += [(f, s, pl, a.budget, a.reconstruction, True, settings, a.along)
                 for f in fields for s in seeds for pl in mappers]
    survey_jobs = [(f, s, a.budget, a.reconstruction, a.cache, budgets, a.threshold,
                    a.threshold and a.along)
                   for f in fields for s in seeds]
    t0 = time.perf_counter()
    if a.from_json:
        saved = json.loads(Path(a.from_json).read_text())
        runs, surveys = saved["runs"], saved["surveys"]
        jobs = [r for r in runs]
    else:
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")  # spawned workers: one BLAS thread each
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=a.workers, mp_context=ctx) as pool:
            survey_futs = [pool.submit(scan_survey, j) for j in survey_jobs]
            run_futs = [pool.submit(run_planner, j) for j in jobs]
            surveys = [f.result() for f in survey_futs]
            runs = [f.result() for f in run_futs]
    wall = time.perf_counter() - t0
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps({"args": vars(a), "runs": runs, "surveys": surveys},
                                           default=float))
    bar = "|" if a.markdown else " "
    print(f"# efficiency: {len(seeds)} seeds, budget {a.budget / 1000:g} km (binding), "
          f"reconstruction {a.reconstruction}, adaptive {settings or 'defaults'}, {len(jobs)} runs + "
          f"{sum(s['runs'] for s in surveys)} surveys in {wall:.0f} s on {a.workers} workers")
    for field in fields:
        print(f"\n## field: {field}\n")
        by_seed = {s["seed"]: s for s in surveys if s["field"] == field}
        if not a.threshold_only:
            table(field, planners, runs, by_seed, budgets, bar, a.markdown)
        threshold_table(field, runs, by_seed, a.budget, bar, a.markdown)
    if a.figures:
        for path in figures(Path(a.figures), fields, planners, runs, surveys, a.budget):
            print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
