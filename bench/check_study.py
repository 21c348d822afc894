"""An independent check of the threshold figures: ``econdor study``, as a user runs it, and
nothing but the ``study.csv`` files it writes.

It shares no code with ``bench/efficiency.py`` (its own missions, searches and counting);
from the package it takes only the true field's range, to set each seed's target level
at the middle of it (the bench's level: the middle of the true values on the 1 m grid).

Per field and seed:

* the adaptive planner in threshold mode, one study per seed (the level is the seed's):
  10 km budget, the iteration cap out of reach, one vehicle on the 100 x 100 m area;
* the best survey: ``lawnmower.lines`` = 2, 3, 4, ... flown as one study over every seed
  that no survey has got there for yet, until each has one (a survey's flight grows with
  its line count, so the first that gets there is the shortest);
* from study.csv: each row's ``flight_distance_m`` (the flight behind that estimate; the
  flight home is in no row) and ``isoline_target_m`` (the planner's) or ``isoline_p50_m``
  (the survey's: its error at the middle of the true span). The planner's distance is
  where the error first comes within 0.5 m ("first"), and where it does so for good, to
  the end of the run ("stays"); a run that never does is a loss at infinity.

    python bench/check_study.py --seeds 900:920 --fields authors,paper,plume --out docs/results/check-fresh.md
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
TARGET_M = 0.5
GOAL = 0.5
BUDGET_M = 10_000.0
MAX_LINES = 99
FIELDS = {
    "authors": {"model": "authors"},
    "paper": {"model": "paper"},
    "plume": {"model": "plume", "sources": 3, "sigma_min_m": 3.0, "sigma_max_m": 6.0,
              "background": 10.0},
    "front": {"model": "front"},
}


def mission(field: str, **sections: dict) -> dict:
    raw = {"name": f"check-{field}", "field": FIELDS[field], "area": {"width_m": 100, "height_m": 100},
           "vehicles": {"count": 1}}
    raw.update(sections)
    return raw


def mid_level(field: str, seed: int) -> float:
    sys.path.insert(0, str(ROOT))
    from econdor_gcs.config import parse_mission

    m = parse_mission(mission(field))
    xx, yy = np.meshgrid(np.arange(0.0, 100.5, 1.0), np.arange(0.0, 100.5, 1.0))
    v = np.asarray(m.build_field(seed)(xx, yy))
    return float(v.min() + 0.5 * (v.max() - v.min()))


def study(raw: dict, seeds: list[int], planner: str, out: Path) -> list[dict[str, str]]:
    out.mkdir(parents=True, exist_ok=True)
    path = out / "mission.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    cmd = [sys.executable, "-m", "econdor", "study", str(path), "--seeds",
           ",".join(map(str, seeds)), "--planner", planner, "--out", str(out / "study"),
           "--workers", "1", "--quiet", "--no-figures"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"econdor study failed ({shlex.join(cmd)}): {proc.stderr.strip()}")
    with (out / "study" / "study.csv").open(encoding="utf-8") as f:
        return list(csv.DictReader(f))


def first_and_stays(rows: list[dict[str, str]]) -> tuple[float, float]:
    d = [float(r["flight_distance_m"]) for r in rows]
    e = [float(r["isoline_target_m"]) for r in rows]
    good = [x <= TARGET_M and d_ <= BUDGET_M for x, d_ in zip(e, d, strict=True)]
    first = next((d_ for d_, g in zip(d, good, strict=True) if g), math.inf)
    stays = math.inf
    for d_, x in zip(reversed(d), reversed(e), strict=True):
        if x > TARGET_M:
            break
        stays = d_
    return first, stays if stays <= BUDGET_M else math.inf


def best_surveys(field: str, seeds: list[int], work: Path) -> dict[int, tuple[float, int]]:
    best: dict[int, tuple[float, int]] = {}
    for lines in range(2, MAX_LINES + 1):
        left = [s for s in seeds if s not in best]
        if not left:
            break
        raw = mission(field, algorithm={"planner": "lawnmower", "max_iterations": 8,
                                        "min_iterations": 1},
                      lawnmower={"lines": lines})
        for r in study(raw, left, "lawnmower", work / f"survey-{lines}"):
            flown = float(r["flight_distance_m"])
            if float(r["isoline_p50_m"]) <= TARGET_M and flown <= BUDGET_M:
                best[int(r["seed"])] = (flown, lines)
    return {s: best.get(s, (math.inf, 0)) for s in seeds}


def fmt(x: float, spec: str = ".3f") -> str:
    return "∞" if math.isinf(x) else format(x, spec)


def main() -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--seeds", default="900:920", help="A:B or a comma list")
    p.add_argument("--fields", default="authors,paper,plume")
    p.add_argument("--out", default=None, help="also write the report here (Markdown)")
    p.add_argument("--keep", default=None, help="keep the studies in this directory")
    a = p.parse_args()
    if ":" in a.seeds:
        lo, hi = a.seeds.split(":")
        seeds = list(range(int(lo), int(hi)))
    else:
        seeds = [int(s) for s in a.seeds.split(",")]
    work = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="check-study-"))
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True, check=False).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                           capture_output=True, text=True, check=False).stdout.strip()
    lines = ["# Threshold mapping, checked with `econdor study` alone", "",
             f"Command: `{shlex.join(['python', *sys.argv])}`  ",
             f"Commit: `{commit}`" + (" with changes not committed" if dirty else ""), "",
             f"The distance to a mean iso-line error ≤ {TARGET_M} m at the middle level, over "
             "the best survey's (every line count from 2 up); a run that never gets there is ∞.",
             "", "| field | seeds | median × survey, stays | ≤ 0.5×, stays | median × survey, "
             "first | ≤ 0.5×, first | never stays |", "|---|---|---|---|---|---|---|"]
    detail = []
    for field in a.fields.split(","):
        surveys = best_surveys(field, seeds, work / field)
        stays_r, first_r = [], []
        for seed in seeds:
            level = mid_level(field, seed)
            raw = mission(field, algorithm={
                "planner": "adaptive", "max_iterations": 1000, "min_iterations": 1000,
                "flight_budget_m": BUDGET_M, "target_levels": [level],
                "max_idle_iterations": 2})
            rows = study(raw, [seed], "adaptive", work / field / f"adaptive-{seed}")
            first, stays = first_and_stays(rows)
            sv, n = surveys[seed]
            r_first = math.inf if math.isinf(first) else first / sv
            r_stays = math.inf if math.isinf(stays) else stays / sv
            first_r.append(r_first)
            stays_r.append(r_stays)
            detail.append(f"| {field} | {seed} | {level:.2f} | {fmt(stays / 1000)} | "
                          f"{fmt(first / 1000)} | {fmt(sv / 1000)} ({n}) | {fmt(r_stays)} | "
                          f"{fmt(r_first)} |")
        lines.append(f"| {field} | {a.seeds} | {fmt(statistics.median(stays_r))} | "
                     f"{sum(x <= GOAL for x in stays_r)}/{len(seeds)} | "
                     f"{fmt(statistics.median(first_r))} | "
                     f"{sum(x <= GOAL for x in first_r)}/{len(seeds)} | "
                     f"{sum(math.isinf(x) for x in stays_r)} |")
        print(lines[-1], flush=True)
    lines += ["", "| field | seed | level | km, stays | km, first | survey km (lines) | "
              "× survey, stays | × survey, first |", "|---|---|---|---|---|---|---|---|",
              *detail]
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        Path(a.out).write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
