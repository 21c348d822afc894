"""How much flying each planner needs, with budgets that bind and the best survey as baseline.

Budget-true: every planner flies until the flight budget is spent (the iteration cap is
far beyond reach), on the same fields, with the same reconstruction and the same cost
accounting (:mod:`runs`: everything flown behind an estimate counts — initiation,
transits, searches, traces, lines — and never the flight home after the last iteration,
which no estimate uses; the DFC books it in no row, for the surveys as for the planners).

The baseline is the best survey, per seed (:mod:`surveys`): for a target, the shortest
survey that reaches it, found by flying every line count from 2 up (a survey's error is
not monotone in its line count); for a budget, the best of every line count that fits.

Every run counts (:mod:`summaries`): a run that never gets to a target within the budget
is a loss at infinity in the medians. A target is "stays reached" from the first
estimate after which every estimate to the end of the run meets it (the headline), and
"first reached" at the first that does (in brackets).

Per planner and field it prints the distance to -10/-20/-30 dB and its ratio to the best
survey's, the MAE and the iso-line error at budgets, stalls, and for plumes the sources
missed (no sample within one sigma of a source centre). ``--threshold`` adds threshold
mapping: the adaptive planner given one target level (the middle of the true range)
against the best survey's distance to the same iso-line error, per seed and summed up.

    python bench/efficiency.py --quick                      # 2 seeds, a smoke run
    python bench/efficiency.py --seeds 0:20 --cache runs/surveys --out docs/results/efficiency.md
    python bench/efficiency.py --fields plume --planners adaptive --threshold-only
    python bench/efficiency.py --seeds 0:8 --planners 'adaptive,adaptive[batch_m=200]'

A planner written ``adaptive[key=value,...]`` is the adaptive planner with those settings
on top of ``--adaptive``: variants measured against the default in the same run.
``--out FILE`` writes the report as Markdown, stamped with the command and the commit.

``--json FILE`` keeps every planner run and survey scan as a JSON line (gzip when it ends
in .gz), appended as each finishes, stamped with the job, the fingerprint of the code it
ran and the commit (:mod:`saved_rows`); a job already there, flown by this code, is not
flown again. ``--from-json`` makes the report from such files alone: rows of other code
are set aside unless ``--any-code`` (the report names the commits every row was flown
at). ``--restamp K`` lets the asked-for rows of other code stand after a change that cannot
touch their flights (a refactor): K of them, spread over fields, kinds and seeds, are flown
again, and only if every one comes out as saved are they all stamped with the current code
(:func:`saved_rows.restamp`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from report import (  # noqa: E402
    ISO_TARGET_M,
    TARGETS_DB,
    Table,
    at_budget,
    field_tables,
    stamp,
    threshold_tables,
)
from runs import (  # noqa: E402
    FIELDS,
    max_survey_lines,
    parse_settings,
    run_planner,
    split_planners,
    split_variant,
)
from saved_rows import (  # noqa: E402
    append_row,
    code_of,
    commit,
    current_code,
    drop_superseded,
    load,
    read_rows,
    restamp,
    restamped,
)
from summaries import fmt  # noqa: E402
from surveys import scan_survey  # noqa: E402

from econdor_lab.study import parse_seeds  # noqa: E402
from econdor_lab.workers import WorkerPool  # noqa: E402


def figures(out: Path, fields: list[str], planners: list[str], runs: list[dict[str, Any]],
            surveys: list[dict[str, Any]], budget_m: float) -> list[Path]:
    """MAE against distance, median over the seeds, per field: every planner and the best
    survey for each distance (the lower envelope of every survey flown, per seed)."""
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
                    best, curve, k = math.inf, [], 0
                    for d in grid:
                        while k < len(rows) and rows[k]["flight_m"] <= d:
                            best = min(best, rows[k]["mae_db"])
                            k += 1
                        curve.append(best if math.isfinite(best) else math.nan)
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
                med = np.where(ok, np.nanmedian(arr, axis=0), np.nan)
            ax.plot(grid / 1000, med, label=pl, lw=2 if pl in ("adaptive", "best survey") else 1)
        for t in TARGETS_DB:
            ax.axhline(t, color="0.85", lw=0.8, zorder=0)
        ax.set_xlabel("flight distance (km), all but the flight home")
        ax.set_ylabel("MAE (dB), median over seeds")
        ax.set_title(f"{field}: MAE against distance")
        ax.legend()
        path = out / f"efficiency_{field}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
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
    p.add_argument("--adaptive", default="", help="adaptive settings, e.g. model=proxy,floor=20")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--cache", default=None, help="directory memoising survey runs")
    p.add_argument("--json", default=None,
                   help="append every run and survey scan here (JSON lines, .gz: gzip); "
                        "what is there, flown by this code, is not flown again")
    p.add_argument("--from-json", default=None,
                   help="print tables (and figures) from saved rows alone: --json files, "
                        "comma-separated")
    p.add_argument("--any-code", action="store_true",
                   help="keep saved rows flown with other code (the report names the "
                        "commits every row was flown at)")
    p.add_argument("--restamp", type=int, default=0, metavar="K",
                   help="with --json: fly K of the asked-for rows of other code again and, "
                        "if each comes out as saved, stamp them all with this code")
    p.add_argument("--figures", default=None, help="draw MAE-against-distance figures here")
    p.add_argument("--quick", action="store_true", help="2 seeds, 3 km budget")
    p.add_argument("--markdown", action="store_true", help="print Markdown tables")
    p.add_argument("--out", default=None,
                   help="also write the report here as Markdown, stamped with the command "
                        "and the commit (docs/results/<name>.md)")
    p.add_argument("--no-per-seed", action="store_true",
                   help="threshold mapping: the summary only, not a row per seed")
    a = p.parse_args(argv)
    if a.quick:
        a.seeds, a.budget = "0:2", 3_000.0
    a.threshold = a.threshold or a.threshold_only
    unknown = [f for f in a.fields.split(",") if f not in FIELDS]
    if unknown:
        p.error(f"--fields: unknown field {unknown[0]!r} (one of {', '.join(FIELDS)})")
    try:
        for pl in split_planners(a.planners):
            split_variant(pl)
    except ValueError as exc:
        p.error(f"--planners: {exc}")
    return a


Job = tuple[Any, ...]


@dataclass(frozen=True)
class Asked:
    """What the arguments ask for."""

    seeds: list[int]
    fields: list[str]
    planners: list[str]
    budgets: list[float]
    settings: dict[str, Any]


def asked(a: argparse.Namespace) -> Asked:
    """The seeds, fields, planners, budgets and adaptive settings ``a`` asks for."""
    budgets = [b for b in (1_000.0, 2_000.0, 5_000.0, 10_000.0, 20_000.0) if b < a.budget]
    return Asked(parse_seeds(a.seeds), a.fields.split(","),
                 [x for x in split_planners(a.planners) if x], [*budgets, a.budget],
                 parse_settings(a.adaptive))


def jobs_of(a: argparse.Namespace) -> tuple[list[Job], list[Job]]:
    """The planner runs' and the survey scans' jobs the arguments ask for."""
    q = asked(a)
    jobs: list[Job] = [] if a.threshold_only else [
        (f, s, pl, a.budget, a.reconstruction, False, q.settings)
        for f in q.fields for s in q.seeds for pl in q.planners]
    if a.threshold:
        mappers = [pl for pl in q.planners if split_variant(pl)[0] == "adaptive"] or ["adaptive"]
        jobs += [(f, s, pl, a.budget, a.reconstruction, True, q.settings)
                 for f in q.fields for s in q.seeds for pl in mappers]
    survey_jobs = [(f, s, a.budget, a.reconstruction, a.cache, q.budgets,
                    () if a.threshold_only else TARGETS_DB, ISO_TARGET_M, not a.threshold_only)
                   for f in q.fields for s in q.seeds]
    return jobs, survey_jobs


def main(argv: list[str] | None = None) -> int:
    a = parse_args(argv)
    q = asked(a)
    seeds, fields, planners, budgets, settings = (q.seeds, q.fields, q.planners, q.budgets,
                                                   q.settings)
    if a.cache:
        Path(a.cache).mkdir(parents=True, exist_ok=True)
    jobs, survey_jobs = jobs_of(a)
    t0 = time.perf_counter()
    keyed = {job_key("survey", j): ("survey", j) for j in survey_jobs}
    keyed.update({job_key("run", j): ("run", j) for j in jobs})
    if a.restamp:
        return restamp_rows(a, keyed)
    saved: dict[str, dict[str, Any]] = {}
    src = a.from_json or a.json
    if src:
        saved = {r["job"]: r for r in load(src, current_code, a.any_code) if r.get("job") in keyed}
    todo = [] if a.from_json else [(k, kind, j) for k, (kind, j) in keyed.items()
                                   if k not in saved]
    saved.update(fly_and_save(todo, a.workers, Path(a.json) if a.json else None))
    missing = [k for k in keyed if k not in saved]
    if missing:
        print(f"{len(missing)} of the {len(keyed)} runs and survey scans asked for are not "
              "in the saved rows: left out of the tables", file=sys.stderr, flush=True)
    surveys = [saved[k] for k, (kind, _) in keyed.items() if kind == "survey" and k in saved]
    runs = [saved[k] for k, (kind, _) in keyed.items() if kind == "run" and k in saved]
    wall = time.perf_counter() - t0
    md = a.markdown or a.out is not None
    lines = [f"# Efficiency: {len(seeds)} seeds ({a.seeds}), budget {a.budget / 1000:g} km",
             "", *(stamp(sys.argv) if a.out else []), "",
             f"{len(runs)} planner runs and {sum(s['runs'] for s in surveys)} surveys "
             f"({sum(s.get('flown', 0) for s in surveys)} flown, the rest from the cache) "
             + (f"read from {a.from_json}" if a.from_json else
                f"in {wall:.0f} s on {a.workers} workers")
             + f", flown at {', '.join(sorted({str(r.get('commit')) for r in runs + surveys}))}"
             + restamped(runs + surveys)
             + f"; reconstruction {a.reconstruction}, "
             f"adaptive settings {settings or 'the defaults'}. Surveys: every line count from 2 "
             f"up to {max_survey_lines(a.budget)}. Distances: everything flown behind an "
             "estimate, never the flight home."]
    headline = []
    for field in fields:
        lines += ["", f"## Field: {field}", ""]
        by_seed = {s["seed"]: s for s in surveys if s["field"] == field}
        if not a.threshold_only:
            lines += field_tables(field, planners, runs, by_seed, budgets, a.budget, md)
        if a.threshold:
            tables, summary = threshold_tables(field, runs, by_seed, a.budget, md,
                                               per_seed=not a.no_per_seed)
            lines += ["", "### Threshold mapping", "", *tables]
            headline += summary
    if len(headline) > 1:
        table = Table(["field", "mapper", "runs", "median × survey, stays", "≤ 0.5×, stays",
                       "median × survey, first", "≤ 0.5×, first", "never"])
        for s in headline:
            table.add([s["field"], s["mapper"], str(s["runs"]), fmt(s["median_stays"], ".3f"),
                       f"{s['half_stays']}/{s['runs']}", fmt(s["median_first"], ".3f"),
                       f"{s['half_first']}/{s['runs']}", str(s["never"])])
        lines += ["", "## Threshold mapping, every field", "", *table.lines(md)]
    if a.figures:
        for path in figures(Path(a.figures), fields, planners, runs, surveys, a.budget):
            lines.append(f"\n![{path.stem}]({os.path.relpath(path, Path(a.out).parent)})"
                         if a.out else f"wrote {path}")
    text = "\n".join(lines) + "\n"
    print(text, end="")
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(text, encoding="utf-8")
    return 0


def fly_and_save(todo: list[tuple[str, str, Job]], workers: int, path: Path | None
                 ) -> dict[str, dict[str, Any]]:
    """Fly ``todo`` (:func:`fly_jobs`), each row appended to ``path`` as it comes in (a run
    cut off goes on from there); then drop from ``path`` the rows of other code the new
    ones replace. The new rows by key."""
    t0 = time.perf_counter()
    asked = {k: (kind, j) for k, kind, j in todo}
    rows: dict[str, dict[str, Any]] = {}
    for n, (k, row) in enumerate(fly_jobs(todo, workers), 1):
        rows[k] = row
        if path is not None:
            append_row(path, row)
        kind, j = asked[k]
        what = (f"surveys {j[0]} {j[1]}" if kind == "survey" else
                f"{j[2]}{':threshold' if j[5] else ''} {j[0]} {j[1]}")
        print(f"[{n}/{len(todo)}] {what} {time.perf_counter() - t0:.0f} s",
              file=sys.stderr, flush=True)
    if path is not None and todo:
        gone = drop_superseded(path, lambda r: r.get("job"))
        print(f"{gone} rows of other code replaced", file=sys.stderr, flush=True)
    return rows


def fly_jobs(todo: list[tuple[str, str, Job]], workers: int
             ) -> Iterator[tuple[str, dict[str, Any]]]:
    """Fly ``todo`` (key, kind, job) on ``workers`` spawned processes; each row (stamped
    with its code and the commit) with its key, as it finishes."""
    if not todo:
        return
    with WorkerPool(workers) as pool:
        fly: dict[str, Callable[[Any], dict[str, Any]]] = {"survey": scan_survey,
                                                            "run": run_planner}
        futs = {pool.submit(fly[kind], j): (k, kind) for k, kind, j in todo}
        for fut in as_completed(futs):
            k, kind = futs[fut]
            yield k, {"kind": kind, "job": k, **fut.result(), "code": code_of(kind),
                      "commit": commit()}


def restamp_rows(a: argparse.Namespace, keyed: dict[str, tuple[str, Job]]) -> int:
    """``--restamp``: the asked-for rows in ``--json`` of other code stand if ``--restamp``
    of them, flown again, come out as saved (:func:`saved_rows.restamp`)."""
    if not a.json:
        print("efficiency.py: --restamp needs --json (the rows to check)", file=sys.stderr)
        return 2
    stale = [r for r in read_rows(Path(a.json))
             if r.get("job") in keyed and not current_code(r)]
    if not stale:
        print("efficiency.py: no asked-for row of other code to restamp", file=sys.stderr)
        return 2

    def again(picked: list[dict[str, Any]]) -> list[dict[str, Any]]:
        todo = [(r["job"], *keyed[r["job"]]) for r in picked]
        flown = dict(fly_jobs(todo, a.workers))
        return [flown[r["job"]] for r in picked]

    ok, line = restamp(Path(a.json), stale, a.restamp, again,
                       lambda r: code_of(str(r["kind"])), commit())
    print(line, file=sys.stderr)
    return 0 if ok else 1


def job_key(kind: str, job: tuple[Any, ...]) -> str:
    """A run's or survey scan's job as a saved row names it: a survey scan's without the
    cache directory, which changes no result."""
    if kind == "survey":
        job = job[:4] + job[5:]
    return json.dumps([kind, *job], default=float, sort_keys=True)


if __name__ == "__main__":
    sys.exit(main())
