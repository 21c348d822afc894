"""The efficiency bench's tables (plain text or Markdown) and the stamp of a results file.

Counting rules: :mod:`summaries` (every run counts, a run that never gets there is a loss
at infinity; "stays reached" is the headline, "first reached" beside it in brackets).
"""

from __future__ import annotations

import math
import shlex
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from runs import ROOT
from summaries import (
    first_reached,
    fmt,
    fmt_interval,
    median,
    median_measured,
    ratio,
    share_within,
    stays_reached,
    stop_ratio,
)

TARGETS_DB = (-10.0, -20.0, -30.0)
ISO_TARGET_M = 0.5
"""Threshold mapping's target: a mean iso-line error at the target level at most this."""
GOAL = 0.5
"""Threshold mapping's goal: at most this fraction of the best survey's distance."""


class Table:
    """Rows of cells printed as plain columns or as a Markdown table."""

    def __init__(self, head: Sequence[str]) -> None:
        self.head = list(head)
        self.rows: list[list[str]] = []

    def add(self, cells: Sequence[str]) -> None:
        self.rows.append(list(cells))

    def lines(self, md: bool) -> list[str]:
        if md:
            out = ["| " + " | ".join(self.head) + " |", "|" + "---|" * len(self.head)]
            return out + ["| " + " | ".join(r) + " |" for r in self.rows]
        widths = [max(len(c) for c in col) for col in zip(self.head, *self.rows, strict=True)]
        return ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
                for r in (self.head, *self.rows)]


def tree_commit() -> tuple[str, bool]:
    """The commit checked out, and whether the working tree holds changes to tracked files
    not committed (outside docs/: a report and the rows it keeps are written there, they
    change no result)."""
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              check=False).stdout.strip()

    return (git("rev-parse", "HEAD") or "unknown",
            bool(git("status", "--porcelain", "--untracked-files=no", "--", ".", ":!docs")))


def stamp(argv: Sequence[str]) -> list[str]:
    """Where a results file came from: the exact command and the commit (with a note when
    the working tree held changes not committed)."""
    commit, dirty = tree_commit()
    script = Path(argv[0]).resolve()
    if script.is_relative_to(ROOT):  # as run from the repository's root
        script = script.relative_to(ROOT)
    command = shlex.join(["python", script.as_posix(), *argv[1:]])
    return [f"<!-- written by {script.as_posix()}; do not edit: run the command again -->",
            f"Command: `{command}`  ",
            f"Commit: `{commit}`" + (" with changes not committed" if dirty else "") + "  ",
            f"Python {sys.version.split()[0]}"]


def at_budget(rows: list[dict[str, Any]], budget_m: float) -> dict[str, Any] | None:
    """The last estimate made within ``budget_m``."""
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


def field_tables(field: str, planners: list[str], runs: list[dict[str, Any]],
                 surveys: dict[int, dict[str, Any]], budgets: list[float], budget_m: float,
                 md: bool) -> list[str]:
    """Mapping the whole field: distance to each MAE target against the best survey's,
    then the estimates at each budget."""
    seeds = sorted(surveys)
    out = [f"Distance to each MAE target (km, median over {len(seeds)} seeds; a run that "
           "never stays there counts as ∞): stays reached (first reached); × the best "
           "survey for that seed and target (0 where no survey gets there within the "
           "budget); runs that stay there / runs ahead of the survey.", ""]
    head = ["planner"]
    for t in TARGETS_DB:
        head += [f"km to {t:.0f} dB", f"× survey to {t:.0f} dB", f"there / ahead ({t:.0f} dB)"]
    table = Table(head)
    for pl in planners:
        rs = [r for r in runs if r["field"] == field and r["planner"] == pl]
        cells = [pl]
        for t in TARGETS_DB:
            def ok(row: dict[str, Any], t: float = t) -> bool:
                return row["mae_db"] <= t
            stays = [stays_reached(r["rows"], ok, budget_m) for r in rs]
            first = [first_reached(r["rows"], ok, budget_m) for r in rs]
            sv = [surveys[r["seed"]]["to_db"][str(t)]["flight_m"] for r in rs]
            rs_stays = [ratio(d, s) for d, s in zip(stays, sv, strict=True)]
            rs_first = [ratio(d, s) for d, s in zip(first, sv, strict=True)]
            cells += [f"{fmt(median(stays) / 1000, '.2f')} ({fmt(median(first) / 1000, '.2f')})",
                      f"{fmt(median(rs_stays), '.2f')} ({fmt(median(rs_first), '.2f')})",
                      f"{sum(math.isfinite(d) for d in stays)}/{len(rs)} / "
                      f"{sum(x < 1.0 for x in rs_stays)}"]
        table.add(cells)
    cells = ["best survey"]
    for t in TARGETS_DB:
        sv = [surveys[s]["to_db"][str(t)]["flight_m"] for s in seeds]
        cells += [fmt(median(sv) / 1000, ".2f"), "1", f"{sum(math.isfinite(d) for d in sv)}"
                  f"/{len(sv)}"]
    table.add(cells)
    out += table.lines(md)
    plume = field == "plume"
    head = ["planner", *[f"MAE dB @{b / 1000:g} km" for b in budgets],
            *[f"iso m @{b / 1000:g} km" for b in budgets], "stalls"]
    if plume:
        head += [f"sources missed @{b / 1000:g} km" for b in (budgets[0], budgets[-1])]
    head.append("wall s/run")
    table = Table(head)
    for pl in [*planners, "best survey"]:
        cells = [pl]
        rs = [r for r in runs if r["field"] == field and r["planner"] == pl]

        def best(b: float, key: str) -> list[dict[str, Any] | None]:
            return [surveys[s]["budget"][str(b)][key] for s in seeds]

        for b in budgets:
            got = best(b, "mae_db") if pl == "best survey" else [at_budget(r["rows"], b)
                                                                for r in rs]
            cells.append(fmt(median_measured([x["mae_db"] if x else math.nan for x in got])))
        for b in budgets:
            got = best(b, "iso") if pl == "best survey" else [at_budget(r["rows"], b)
                                                             for r in rs]
            cells.append(fmt(median_measured([x["iso_mean"] if x else math.nan for x in got]), ".2f"))
        cells.append("—" if pl == "best survey" else f"{sum(stalled(r) for r in rs)}/{len(rs)}")
        if plume:
            for b in (budgets[0], budgets[-1]):
                got = best(b, "missed") if pl == "best survey" else [at_budget(r["rows"], b)
                                                                    for r in rs]
                m = [(x or {"missed": 3})["missed"] for x in got]
                cells.append(f"{sum(m)} of {3 * len(m)}")
        wall = ([surveys[s]["wall_s"] / max(1, surveys[s]["runs"]) for s in seeds]
                if pl == "best survey" else [r["wall_s"] for r in rs])
        cells.append(fmt(median_measured(wall), ".1f"))
        table.add(cells)
    out += ["", "The estimate at each budget (the last one made within it; the best survey: the "
            "best of every line count that fits), median over the seeds; iso m: the mean "
            "iso-line error at 25/50/75 % of the true span.", "", *table.lines(md)]
    return out


def threshold_tables(field: str, runs: list[dict[str, Any]], surveys: dict[int, dict[str, Any]],
                     budget_m: float, md: bool, per_seed: bool = True
                     ) -> tuple[list[str], list[dict[str, Any]]]:
    """Threshold mapping against the best survey to the same iso-line error: per seed,
    then a summary line per mapper (also returned, for the headline)."""
    rs = [r for r in runs if r["field"] == field and r["planner"].endswith(":threshold")]
    labels = list(dict.fromkeys(r["planner"] for r in rs))
    out: list[str] = []
    summary = []

    def ok(row: dict[str, Any]) -> bool:
        return row["iso_target"] <= ISO_TARGET_M

    for label in labels:
        mine = sorted((r for r in rs if r["planner"] == label), key=lambda r: r["seed"])
        table = Table(["seed", "level", "km, stays", "km, first", "survey km (lines)",
                       "× survey, stays", "× survey, first", "final iso m", "pieces missed",
                       "stop", "flown km"])
        stays_r, first_r, stays_km, survey_km, stop_r = [], [], [], [], []
        for r in mine:
            sv = surveys[r["seed"]]["to_iso"]
            stays = stays_reached(r["rows"], ok, budget_m)
            first = first_reached(r["rows"], ok, budget_m)
            stays_r.append(ratio(stays, sv["flight_m"]))
            first_r.append(ratio(first, sv["flight_m"]))
            stays_km.append(stays / 1000)
            survey_km.append(sv["flight_m"] / 1000)
            last = r["rows"][-1]
            stop_r.append(stop_ratio(last["flight_m"], sv["flight_m"]))
            table.add([str(r["seed"]), fmt(r["target"]), fmt(stays / 1000, ".3f"),
                       fmt(first / 1000, ".3f"),
                       f"{fmt(sv['flight_m'] / 1000, '.3f')} ({sv['lines']})",
                       fmt(stays_r[-1], ".3f"), fmt(first_r[-1], ".3f"),
                       fmt(last["iso_target"], ".2f"), fmt(last["target_missed"], ".0f"),
                       r["stop"], fmt(last["flight_m"] / 1000, ".2f")])
        name = label.removesuffix(":threshold")
        if per_seed:
            out += ["", f"Per seed, {name}:", "", *table.lines(md)]
        half_stays, n = share_within(stays_r, GOAL)
        half_first, _ = share_within(first_r, GOAL)
        summary.append({"field": field, "mapper": name, "runs": n,
                        "median_stays": median(stays_r), "half_stays": half_stays,
                        "median_first": median(first_r), "half_first": half_first,
                        "ahead": sum(x < 1.0 for x in stays_r),
                        "never": sum(math.isinf(x) for x in stays_r),
                        "median_km": median(stays_km), "survey_km": median(survey_km),
                        "interval_stays": fmt_interval(stays_r, ".3f"),
                        "median_stop": median_measured(stop_r)})
    table = Table(["field", "mapper", "runs", "median × survey, stays",
                   f"≤ {GOAL}×, stays", "median × survey, first", f"≤ {GOAL}×, first",
                   "ahead of survey, stays", "never stays ≤ target", "median km, stays",
                   "median survey km", "median's 90 % interval, stays",
                   "median × survey, to its own stop"])
    for s in summary:
        table.add([s["field"], s["mapper"], str(s["runs"]), fmt(s["median_stays"], ".3f"),
                   f"{s['half_stays']}/{s['runs']}", fmt(s["median_first"], ".3f"),
                   f"{s['half_first']}/{s['runs']}", f"{s['ahead']}/{s['runs']}",
                   str(s["never"]), fmt(s["median_km"], ".3f"), fmt(s["survey_km"], ".3f"),
                   s["interval_stays"], fmt(s["median_stop"], ".2f")])
    head = [f"Threshold mapping: the distance to a mean iso-line error ≤ {ISO_TARGET_M} m at the "
            "middle level, as a multiple of the best survey's for that seed (the shortest "
            "survey, of every line count, whose estimate gets there). Stays: from that "
            "estimate on, every later one to the end of the run is ≤ the target too; first: "
            "the first estimate that is. A run that never gets there counts as ∞. The "
            "median's 90 % interval: where the median over seeds not flown lies, with at "
            "least 90 % confidence (from the order statistics, whatever the distribution). "
            "To its own stop: all it flew until it stopped by itself (it does not know when "
            "the error is within the target), over the same survey distance.",
            "",
            *table.lines(md)]
    return head + out, summary
