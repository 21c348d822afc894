"""The best survey for each budget and each target, per field and seed: every line count
tried, each run cached on disk.

A survey's error is not monotone in its number of lines: the lines move when their number
changes, and a feature that one count straddles the next may miss (plume seed 901: an
iso-line error of 0.61 m with 15 lines, 3.09 m with 17, 0.27 m with 18). A search that
assumes it is (a ladder of counts, then bisection) can miss the shortest survey that
reaches a target, and so flatter whatever is compared with it. So:

* **for a target** (an MAE in dB, the iso-line error at the middle level): every line
  count from 2 up is flown until one reaches it. Its flight is the shortest of any survey
  that reaches the target, since a survey's flight grows with its line count (by about
  a line per line: :func:`shortest_reaching` checks it over the counts flown);
* **for a budget**: every line count whose survey fits is flown, and the best estimate
  among them is the survey's figure at that budget (and its curve in the figures).

Each survey is the DFC's run of the ``lawnmower`` planner with ``lawnmower.lines``, on the
same field, vehicle and reconstruction as the planners. Runs are memoised in ``--cache``,
one JSON file per run, under a key made of the mission (field, vehicle, reconstruction,
grid), the seed, the line count and the source code a survey runs (the station's
numerical core but the adaptive planner's own modules, the DFC, the mission, the
in-process executor, the simulated vehicle, these bench modules): change any of them and
the survey is flown again.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any

from runs import ROOT, max_survey_lines, mission_raw, run_survey

SURVEY_SOURCES = ("econdor_gcs/core", "econdor_gcs/dfc/loop.py", "econdor_gcs/config",
                  "econdor_gcs/errors.py", "econdor_lab/inprocess.py", "sim_vehicle",
                  "bench/runs.py", "bench/surveys.py")
"""The code a survey runs (its cache key)."""
NOT_RUN_BY_A_SURVEY = ("econdor_gcs/core/adaptive", "econdor_gcs/core/candidates.py",
                       "econdor_gcs/core/uncertainty.py", "econdor_gcs/core/routes.py",
                       "sim_vehicle/machine/leg.py")
"""... but for the adaptive planner's own modules and the tracer's trace leg: imported,
never called by a survey."""


@cache
def code_fingerprint() -> str:
    """A hash of the source files a survey runs (``SURVEY_SOURCES``)."""
    h = hashlib.sha256()
    for entry in SURVEY_SOURCES:
        p = ROOT / entry
        files = sorted(p.rglob("*.py")) if p.is_dir() else [p]
        for f in files:
            rel = f.relative_to(ROOT).as_posix()
            if rel.startswith(NOT_RUN_BY_A_SURVEY):
                continue
            h.update(rel.encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def survey_key(field: str, recon: str) -> str:
    """What, beside the seed and the line count, makes a survey run what it is."""
    mission = mission_raw(field, 0.0, "lawnmower", recon, survey_lines=2)
    mission["lawnmower"] = {}
    text = json.dumps({"mission": mission, "code": code_fingerprint()}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


class SurveyScan:
    """The surveys of one field and seed, by line count (flown once, then from the cache)."""

    def __init__(self, field: str, seed: int, recon: str, cache_dir: Path | None) -> None:
        self.field, self.seed, self.recon = field, seed, recon
        self.dir = cache_dir / survey_key(field, recon) if cache_dir is not None else None
        self.runs: dict[int, dict[str, Any]] = {}
        self.flown = 0
        """Surveys flown here (not read from the cache)."""

    def get(self, lines: int) -> dict[str, Any]:
        if lines in self.runs:
            return self.runs[lines]
        path = self.dir / f"{self.field}-{self.seed}-{lines}.json" if self.dir else None
        if path is not None and path.exists():
            row = json.loads(path.read_text())
        else:
            row = self.fly(lines)
            self.flown += 1
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(".tmp")
                tmp.write_text(json.dumps(row))
                tmp.replace(path)
        self.runs[lines] = row
        return row

    def fly(self, lines: int) -> dict[str, Any]:
        """Fly the survey of ``lines`` lines (what the cache keeps)."""
        return run_survey(self.field, self.seed, lines, self.recon)

    def all_within(self, budget_m: float) -> list[dict[str, Any]]:
        """Every survey whose planned flight fits ``budget_m`` (2 lines up)."""
        return [self.get(n) for n in range(2, max_survey_lines(budget_m) + 1)]

    def shortest_reaching(self, ok: Callable[[dict[str, Any]], bool], budget_m: float
                          ) -> dict[str, Any] | None:
        """The shortest survey for which ``ok`` holds, within ``budget_m``: every line
        count from 2 up, until one does."""
        flown: list[dict[str, Any]] = []
        for n in range(2, max_survey_lines(budget_m) + 1):
            row = self.get(n)
            if flown and row["flight_m"] <= flown[-1]["flight_m"]:
                raise RuntimeError(f"{self.field} seed {self.seed}: {n} lines flew "
                                   f"{row['flight_m']:.0f} m, not more than {n - 1} lines")
            flown.append(row)
            if row["flight_m"] > budget_m:
                return None
            if ok(row):
                return row
        return None


def best_within(rows: list[dict[str, Any]], budget_m: float, key: str
                ) -> dict[str, Any] | None:
    """Of the surveys flown within ``budget_m``, the one with the lowest ``key``."""
    fit = [r for r in rows if r["flight_m"] <= budget_m and not math.isnan(r[key])]
    return min(fit, key=lambda r: r[key]) if fit else None


def scan_survey(args: tuple[str, int, float, str, str | None, list[float], tuple[float, ...],
                            float, bool]) -> dict[str, Any]:
    """The best surveys of one field and seed: for each budget in ``budgets`` (with
    ``whole``: every line count within the budget flown), for each MAE target (dB) and
    for the iso-line target (m) at the middle level."""
    field, seed, budget_m, recon, cache_dir, budgets, targets_db, iso_m, whole = args
    scan = SurveyScan(field, seed, recon, Path(cache_dir) if cache_dir else None)
    t0 = time.perf_counter()
    out: dict[str, Any] = {"field": field, "seed": seed, "budget": {}, "to_db": {}}

    def reached(row: dict[str, Any] | None) -> dict[str, Any]:
        return ({"flight_m": row["flight_m"], "lines": row["lines"]} if row
                else {"flight_m": math.inf, "lines": 0})

    for t in targets_db:
        row = scan.shortest_reaching(lambda r, t=t: r["mae_db"] <= t, budget_m)
        out["to_db"][str(t)] = reached(row)
    out["to_iso"] = reached(scan.shortest_reaching(lambda r: r["iso"][1] <= iso_m, budget_m))
    if whole:
        rows = scan.all_within(budget_m)
        for b in budgets:
            out["budget"][str(b)] = {"mae_db": best_within(rows, b, "mae_db"),
                                     "iso": best_within(rows, b, "iso_mean"),
                                     "missed": best_within(rows, b, "missed")}
    out["scanned"] = sorted(scan.runs.values(), key=lambda r: r["lines"])
    out["runs"] = len(scan.runs)
    out["flown"] = scan.flown
    out["wall_s"] = time.perf_counter() - t0
    return out
