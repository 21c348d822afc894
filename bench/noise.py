"""Planners with a real sensor: noise, lag and position error, against the best survey
flown with the same sensor.

Every run is in process on the benchmark missions of ``bench/efficiency.py`` (100 x 100 m,
one vehicle at 8 m/s, 10 Hz), with the sensor of the condition (``vehicles.sensor``:
:mod:`sim_vehicle.sensor`); the station is told the lag where it is "known" and nothing
else (it estimates the noise itself). Every planner and every survey of a condition flies
the same fields with the same sensor, the same reconstruction and the same accounting
(:mod:`runs`: everything flown behind an estimate, never the flight home).

Planners: ``adaptive`` (the whole field), ``econdor``, ``threshold`` (the adaptive
planner given the middle of the true range as its one target level; it stops when no
place is left where the iso-line could be, within a 10 km safety budget) and the best
survey (:mod:`surveys`: every line count from 2 up, with the condition's sensor, cached).

Conditions: ``--noise`` levels (plume field units; another field gets the same fraction
of its span: ``SPAN``) with a sensor that only has noise, and the ``--sensors`` variants
(lag known or not, GNSS error) at each of ``--sensor-noise``.

For each field and condition the report gives, medians over the seeds:

* the MAE (dB) at 1, 2, 3 and 4 km (the last estimate within each), the seeds whose 4 km
  estimate is no worse than their 2 km one, and whether the medians fall at every step;
* the distance to the best survey's 4 km MAE (per seed: the best MAE of every survey that
  fits 4 km) as a multiple of the survey's own distance to it, stays reached (first
  reached); a run that never gets there is a loss at infinity;
* the iso-line error (m) at the middle level at 2 and 4 km;
* threshold mode: the distance to an iso-line error <= 0.5 m at its level, as a multiple
  of the shortest survey's that gets there (stays, first), its final iso-line error and
  how it stopped;
* for both multiples, the 90 % interval of the median (``summaries.median_interval``:
  where the median over seeds not flown lies, whatever the distribution).

    python bench/noise.py --fields plume --noise 1 --planners adaptive --seeds 900:903
    python bench/noise.py --seeds 900:910 --cache runs/noise-surveys \\
        --json docs/results/data/noise.jsonl.gz
    python bench/noise.py --from-json docs/results/data/noise.jsonl.gz --fresh 920:940 \\
        --markdown --out docs/results/noise.md   # the tables again, fresh seeds apart

The rows behind ``docs/results/noise.md`` are kept beside it, in
``docs/results/data/noise.jsonl.gz``: the report can be made again, and the rows still
current need not be flown again after a change.

``--json`` is appended to as runs finish (gzip-compressed when it ends in .gz); runs
already there are not flown again. Every row carries the sensor, the fingerprint of the code
it ran (``RUN_SOURCES``; a survey scan: only what a survey runs) and the commit: a row of
other code is flown again and left out of the tables (``--any-code`` keeps it, and the
report names the commits it was flown at). ``--restamp K`` lets the selected stale rows
stand after a change that cannot touch them: K of them are flown again, and only if every
one comes out as saved are they all stamped with the current code
(:func:`saved_rows.restamp`; the report names the commits they were checked at).
``--again`` flies the selected stale rows again, each its own job, and drops the rows it
replaced (cut off, it goes on from the rows already flown). A
planner written ``adaptive[key=value,...]`` is the adaptive planner with those settings
(variants measured against the default in the same run).
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from noise_flights import (  # noqa: E402
    BUDGET_M,
    ISO_TARGET_M,
    SENSORS,
    SPAN,
    THRESHOLD_BUDGET_M,
    condition_name,
    condition_sensor,
    current,
    fly,
    fly_in_order,
    job_again,
    selected,
)
from report import Table, at_budget, stamp  # noqa: E402
from runs import FIELDS, max_survey_lines, split_planners, split_variant  # noqa: E402
from saved_rows import (  # noqa: E402
    append_row,
    code_of,
    commit,
    drop_superseded,
    load,
    read_rows,
    restamp,
    restamped,
    superseded,
)
from summaries import (  # noqa: E402
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
from surveys import best_within  # noqa: E402

from econdor_lab.study import parse_seeds  # noqa: E402

CURVE_KM = (1.0, 2.0, 3.0, 4.0)
GOAL_MAP = 0.6
"""The adaptive planner's goal: the best survey's 4 km MAE in at most this share of the
survey's distance to it (noise 1, plumes)."""
GOAL_THRESHOLD = 0.5
"""Threshold mode's goal: an iso-line error <= 0.5 m in at most this share of the best
survey's distance to it."""
# -- tables ----------------------------------------------------------------------------------


def best_mae_within(survey: dict[str, Any], budget_m: float) -> dict[str, Any] | None:
    return best_within(survey["scanned"], budget_m, "mae_db")


def survey_to(survey: dict[str, Any], mae_db: float) -> float:
    """The shortest survey whose MAE is at most ``mae_db`` (of those scanned)."""
    ok = [r["flight_m"] for r in survey["scanned"] if r["mae_db"] <= mae_db + 1e-9]
    return min(ok) if ok else math.inf


def falls(medians: list[float]) -> bool:
    """Whether the medians (NaN where a planner has no estimate yet) fall at every step.

    >>> falls([math.nan, -6.0, -9.0, -9.5]), falls([-6.0, -9.0, -8.0, -10.0])
    (True, False)
    """
    m = [x for x in medians if not math.isnan(x)]
    return all(b <= a for a, b in zip(m, m[1:], strict=False))


def map_table(runs: list[dict[str, Any]], surveys: dict[int, dict[str, Any]],
              planners: list[str], md: bool) -> tuple[list[str], list[dict[str, Any]]]:
    """Mapping the whole field under one condition (module docstring)."""
    seeds = sorted(surveys)
    head = ["planner", *[f"MAE dB @{k:g} km" for k in CURVE_KM], "4 km ≤ 2 km", "falls",
            "× survey to its 4 km MAE, stays (first)", f"≤ {GOAL_MAP}×, stays",
            "iso m @2 km", "iso m @4 km", "noise found",
            "4 km MAE × survey: median's 90 % interval"]
    table = Table(head)
    summary = []
    for pl in [*planners, "best survey"]:
        if pl == "best survey":
            got = {k: [best_mae_within(surveys[s], k * 1000) for s in seeds] for k in CURVE_KM}
            meds = [median_measured([r["mae_db"] if r else math.nan for r in got[k]])
                    for k in CURVE_KM]
            no_worse = sum(1 for a, b in zip(got[2.0], got[4.0], strict=True)
                           if a and b and b["mae_db"] <= a["mae_db"])
            iso2 = median_measured([r["iso"][1] if r else math.nan for r in
                               (best_within(surveys[s]["scanned"], 2000, "iso_mean")
                                for s in seeds)])
            iso4 = median_measured([r["iso"][1] if r else math.nan for r in
                               (best_within(surveys[s]["scanned"], 4000, "iso_mean")
                                for s in seeds)])
            noise = median_measured([surveys[s]["scanned"][-1]["noise_std"] for s in seeds])
            table.add([pl, *[fmt(m) for m in meds], f"{no_worse}/{len(seeds)}",
                       "yes" if falls(meds) else "no",
                       "1", "—", fmt(iso2, ".2f"), fmt(iso4, ".2f"), fmt(noise, ".3f"), "—"])
            continue
        rs = [r for r in runs if r["planner"] == pl and r["seed"] in surveys]
        if not rs:
            continue
        at = {k: [at_budget(r["rows"], k * 1000) for r in rs] for k in CURVE_KM}
        meds = [median_measured([x["mae_db"] if x else math.nan for x in at[k]]) for k in CURVE_KM]
        no_worse = sum(1 for a, b in zip(at[2.0], at[4.0], strict=True)
                       if a and b and b["mae_db"] <= a["mae_db"])
        stays_r, first_r = [], []
        for r in rs:
            best = best_mae_within(surveys[r["seed"]], BUDGET_M)
            if best is None:
                continue
            target = best["mae_db"]
            sv = survey_to(surveys[r["seed"]], target)

            def ok(row: dict[str, Any], t: float = target) -> bool:
                return bool(row["mae_db"] <= t + 1e-9)

            stays_r.append(ratio(stays_reached(r["rows"], ok, BUDGET_M), sv))
            first_r.append(ratio(first_reached(r["rows"], ok, BUDGET_M), sv))
        within, n = share_within(stays_r, GOAL_MAP)
        iso = [median_measured([x["iso"][1] if x else math.nan for x in at[k]]) for k in (2.0, 4.0)]
        noise = median_measured([r["rows"][-1]["noise_std"] for r in rs])
        table.add([pl, *[fmt(m) for m in meds], f"{no_worse}/{len(rs)}",
                   "yes" if falls(meds) else "no",
                   f"{fmt(median(stays_r), '.2f')} ({fmt(median(first_r), '.2f')})",
                   f"{within}/{n}", fmt(iso[0], ".2f"), fmt(iso[1], ".2f"), fmt(noise, ".3f"),
                   fmt_interval(stays_r)])
        summary.append({"planner": pl, "mae_db": meds, "no_worse": no_worse, "runs": len(rs),
                        "ratio_stays": median(stays_r), "ratio_first": median(first_r)})
    return table.lines(md), summary


def threshold_table(runs: list[dict[str, Any]], surveys: dict[int, dict[str, Any]],
                    mappers: list[str], md: bool) -> list[str]:
    """Threshold mode under one condition against the shortest survey to 0.5 m."""
    table = Table(["mapper", "runs", "× survey, stays (first)", f"≤ {GOAL_THRESHOLD}×, stays",
                   "km, stays", "survey km", "final iso m", "pieces missed", "stops",
                   "iso × survey: median's 90 % interval", "× survey, to its own stop"])

    def ok(row: dict[str, Any]) -> bool:
        return bool(row["iso_target"] <= ISO_TARGET_M)

    for m in mappers:
        rs = [r for r in runs if r["planner"] == m and r["seed"] in surveys]
        if not rs:
            continue
        stays_r, first_r, km, skm, final, missed, stop_r = [], [], [], [], [], [], []
        stops: dict[str, int] = {}
        for r in rs:
            sv = surveys[r["seed"]]["to_iso"]["flight_m"]
            stays = stays_reached(r["rows"], ok, THRESHOLD_BUDGET_M)
            stays_r.append(ratio(stays, sv))
            first_r.append(ratio(first_reached(r["rows"], ok, THRESHOLD_BUDGET_M), sv))
            km.append(stays / 1000)
            skm.append(sv / 1000)
            final.append(r["rows"][-1]["iso_target"])
            stop_r.append(stop_ratio(r["rows"][-1]["flight_m"], sv))
            missed.append(r["rows"][-1]["target_missed"])
            stops[r["stop"]] = stops.get(r["stop"], 0) + 1
        within, n = share_within(stays_r, GOAL_THRESHOLD)
        table.add([m.removesuffix(":threshold"), str(len(rs)),
                   f"{fmt(median(stays_r), '.3f')} ({fmt(median(first_r), '.3f')})",
                   f"{within}/{n}", fmt(median(km), ".2f"), fmt(median(skm), ".2f"),
                   fmt(median_measured(final), ".2f"), fmt(sum(missed), ".0f"),
                   ", ".join(f"{k} {v}" for k, v in sorted(stops.items())),
                   fmt_interval(stays_r, ".3f"), fmt(median_measured(stop_r), ".2f")])
    return table.lines(md)


def report(runs: list[dict[str, Any]], surveys: list[dict[str, Any]], md: bool,
           fresh: frozenset[int] = frozenset()) -> list[str]:
    """The tables per field and condition, the tuning seeds apart from the ``fresh`` ones
    (never looked at while the design was tuned)."""
    out: list[str] = []
    fields = sorted({s["field"] for s in surveys}, key=list(SPAN).index)
    order = ["", *SENSORS]
    # noisy conditions first, by noise, then the sensor variants in SENSORS' order, and
    # the perfect sensor last
    conditions = sorted(dict.fromkeys((s["noise"], s["variant"]) for s in surveys),
                        key=lambda c: (c[0] == 0.0, order.index(c[1]) if c[1] in order
                                       else len(order), c[0]))
    planners = list(dict.fromkeys(r["planner"] for r in runs
                                  if not r["planner"].endswith(":threshold")))
    mappers = list(dict.fromkeys(r["planner"] for r in runs
                                 if r["planner"].endswith(":threshold")))
    for field in fields:
        out += ["", f"## Field: {field}"]
        for noise, variant in conditions:
            for group in ("tuned", "fresh"):
                sv = {s["seed"]: s for s in surveys if s["field"] == field
                      and s["noise"] == noise and s["variant"] == variant
                      and (s["seed"] in fresh) == (group == "fresh")}
                rs = [r for r in runs if r["field"] == field and r["noise"] == noise
                      and r["variant"] == variant and r["seed"] in sv]
                if not sv:
                    continue
                seeds = sorted(sv)
                sensor = condition_sensor(field, noise, variant)
                # records carried over from an earlier code (``measured_at``) say so
                older = sorted({str(r["measured_at"]) for r in [*rs, *sv.values()]
                                if r.get("measured_at")})
                note = f"; measured at {', '.join(older)}" if older else ""
                out += ["", f"### {condition_name(noise, variant)} (sensor {sensor}; "
                        f"{group} seeds {fmt_seeds(seeds)}, {len(seeds)}{note})", ""]
                text, _ = map_table(rs, sv, planners, md)
                out += text
                if mappers:
                    out += ["", *threshold_table(rs, sv, mappers, md)]
    return out


# -- main ------------------------------------------------------------------------------------


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--seeds", default="900:910")
    p.add_argument("--fields", default="plume,paper")
    p.add_argument("--planners", default="adaptive,econdor,threshold",
                   help="adaptive, econdor, no-sg, threshold (the adaptive planner given the "
                        "middle level), variants written adaptive[key=value]")
    p.add_argument("--noise", default="0,1,3", help="noise levels, in the plume's units")
    p.add_argument("--sensors", default="",
                   help=f"sensor variants at --sensor-noise (of {', '.join(SENSORS)}; "
                        "'all' for every one)")
    p.add_argument("--sensor-noise", default="1")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--cache", default=None, help="directory memoising survey runs")
    p.add_argument("--json", default=None,
                   help="append every run and survey scan here; what is there is not flown again")
    p.add_argument("--from-json", default=None,
                   help="the tables of saved runs (comma-separated files; .gz read as gzip)")
    p.add_argument("--any-code", action="store_true",
                   help="keep saved rows flown with other code (the report names their commits)")
    p.add_argument("--restamp", type=int, default=0, metavar="K",
                   help="with --json: fly K of the selected rows of other code again and, if "
                        "each comes out as saved, stamp them all with this code")
    p.add_argument("--again", action="store_true",
                   help="with --json: fly every selected saved row of other code again (its "
                        "own job, nothing else), then drop the rows this replaced")
    p.add_argument("--fresh", default="",
                   help="seeds reported apart as fresh (not looked at while tuning), e.g. 920:940")
    p.add_argument("--markdown", action="store_true")
    p.add_argument("--figures", default=None,
                   help="draw MAE-against-distance figures (noise_<field>.png) here")
    p.add_argument("--out", default=None, help="also write the report here, stamped")
    a = p.parse_args(argv)
    for f in a.fields.split(","):
        if f not in FIELDS or f not in SPAN:
            p.error(f"--fields: unknown field {f!r} (one of {', '.join(SPAN)})")
    # a variant's name may hold ", " ("lag 1 s, unknown"): only a bare comma separates
    a.variants = (list(SENSORS) if a.sensors == "all"
                  else [v for v in re.split(r",(?! )", a.sensors) if v])
    for v in a.variants:
        if v not in SENSORS:
            p.error(f"--sensors: unknown sensor {v!r} (one of {', '.join(SENSORS)})")
    try:
        for pl in split_planners(a.planners):
            split_variant(pl)
    except ValueError as exc:
        p.error(f"--planners: {exc}")
    return a


Selection = tuple[list[int], list[str], list[tuple[float, str]], list[str]]


def selection(a: argparse.Namespace) -> Selection:
    """The seeds, fields, conditions (noise, sensor variant) and planner labels asked for."""
    conditions = [(float(n), "") for n in a.noise.split(",") if n] + [
        (float(n), v) for n in a.sensor_noise.split(",") if n for v in a.variants]
    labels = []
    for pl in split_planners(a.planners):
        labels.append("adaptive:threshold" if pl == "threshold" else
                      pl.replace("threshold", "adaptive", 1) + ":threshold"
                      if pl.startswith("threshold[") else pl)
    return parse_seeds(a.seeds), a.fields.split(","), conditions, labels


def _name(r: dict[str, Any]) -> tuple[Any, ...]:
    return r["kind"], r["field"], r["seed"], r.get("planner", ""), r["noise"], r["variant"]


def stale_rows(path: Path, sel: Selection) -> list[dict[str, Any]]:
    """The selected rows saved in ``path`` that were flown with other code (its sensor the
    same), but for those a current row already replaces."""
    rows = read_rows(path)
    return [r for r, gone in zip(rows, superseded(rows, _name, current), strict=True)
            if not gone and not current(r)
            and r.get("sensor") == condition_sensor(r["field"], r["noise"], r["variant"])
            and selected(r, *sel)]


def fly_again(path: Path, stale: list[dict[str, Any]], cache: str | None,
              workers: int) -> int:
    """``--again``: fly each of the ``stale`` rows' own job again, appending the new row
    as it comes in (a run cut off goes on from there), then drop from ``path`` every row
    of other code that a current row replaces."""
    print(f"{len(stale)} saved rows of other code to fly again", file=sys.stderr, flush=True)
    for _, r in fly([job_again(r, cache) for r in stale], workers):
        append_row(path, r)
        last = r["rows"][-1] if r["kind"] == "run" else r["scanned"][-1]
        print(f"{r['field']} {condition_name(r['noise'], r['variant'])} seed {r['seed']} "
              f"{r.get('planner', 'survey')}: {last['mae_db']:.1f} dB at "
              f"{last['flight_m']:.0f} m", file=sys.stderr, flush=True)
    print(f"{drop_superseded(path, _name, current)} rows of other code replaced", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    a = parse_args(argv)
    md = a.markdown or a.out is not None
    saved: list[dict[str, Any]] = []
    src = a.from_json or a.json
    if src:
        saved = load(src, current, a.any_code, "flown with other code or another sensor")
    t0 = time.perf_counter()
    if a.restamp or a.again:
        if not a.json:
            print(f"noise.py: --{'restamp' if a.restamp else 'again'} needs --json (the "
                  "saved rows)", file=sys.stderr)
            return 2
        stale = stale_rows(Path(a.json), selection(a))
        if not stale:
            print("noise.py: no selected row of other code", file=sys.stderr)
            return 2
        if a.again:
            return fly_again(Path(a.json), stale, a.cache, a.workers)
        ok, line = restamp(Path(a.json), stale, a.restamp,
                           lambda picked: fly_in_order([job_again(r, a.cache) for r in picked], a.workers),
                           lambda r: code_of(r["kind"]),
                           commit())
        print(line, file=sys.stderr)
        return 0 if ok else 1
    if not a.from_json:
        seeds, fields, conditions, labels = selection(a)
        have = {(r["kind"], r["field"], r["seed"], r.get("planner", ""), r["noise"],
                 r["variant"]) for r in saved}
        jobs: list[tuple[str, tuple[Any, ...]]] = []
        for f in fields:
            for noise, variant in conditions:
                for s in seeds:
                    if ("survey", f, s, "", noise, variant) not in have:
                        jobs.append(("survey", (f, s, noise, variant, a.cache)))
                    jobs += [("run", (f, s, pl, noise, variant)) for pl in labels
                             if ("run", f, s, pl, noise, variant) not in have]
        print(f"{len(saved)} saved, {len(jobs)} to fly", file=sys.stderr, flush=True)
        for _, r in fly(jobs, a.workers):
            saved.append(r)
            if r["kind"] == "run":
                last = r["rows"][-1]
                print(f"{r['field']} {condition_name(r['noise'], r['variant'])} seed "
                      f"{r['seed']} {r['planner']}: {last['mae_db']:.1f} dB at "
                      f"{last['flight_m']:.0f} m, iso {last['iso_target']:.2f}, "
                      f"{r['stop']}, {r['wall_s']:.0f} s", file=sys.stderr, flush=True)
            if a.json:
                append_row(Path(a.json), r)
        saved = [r for r in saved if selected(r, seeds, fields, conditions, labels)]
    runs = [r for r in saved if r["kind"] == "run"]
    surveys = [r for r in saved if r["kind"] == "survey"]
    wall = time.perf_counter() - t0
    seeds_all = sorted({r["seed"] for r in saved})
    lines = ["# Planners with a noisy, lagging, mispositioned sensor (issue 32)", "",
             *(stamp(sys.argv) if a.out else []), "",
             f"{len(runs)} planner runs and {len(surveys)} survey scans (every line count "
             f"from 2 to {max_survey_lines(BUDGET_M)}, and on to the first that maps the "
             f"middle iso-line to {ISO_TARGET_M} m), seeds {fmt_seeds(seeds_all)}; "
             f"{wall:.0f} s; flown at {', '.join(sorted({str(r.get('commit')) for r in saved}))}"
             f"{restamped(saved)}. Distances: everything flown behind an estimate, never the flight "
             "home. MAE in dB (20 log10 of the mean absolute error on the 101 x 101 grid). "
             "'× survey to its 4 km MAE': the distance to the best 4 km survey's MAE over "
             "the survey's own distance to it (stays reached; first reached in brackets; a "
             "run that never gets there is ∞). 'iso m': the iso-line error at the middle "
             "level (the survey: of its best 2 / 4 km estimate by mean iso-line error). "
             "Threshold mode: distance to an iso-line error ≤ 0.5 m at the middle level over "
             "the shortest survey's that maps it so. 'Median's 90 % interval': where the "
             "median over seeds not flown lies, with at least 90 % confidence (from the order "
             "statistics of the seeds' ratios, whatever their distribution). 'To its own stop': "
             "all threshold mode flew until it stopped by itself (it does not know when the "
             "error is within the target), over the same survey distance.",
             *report(runs, surveys, md,
                     frozenset(parse_seeds(a.fresh)) if a.fresh else frozenset())]
    if a.figures:
        shown = figures(Path(a.figures), runs, surveys, frozenset(parse_seeds(a.fresh))
                        if a.fresh else frozenset())
        rel = Path(a.out).parent if a.out else Path(".")
        lines += ["", "## Figures", ""] + [f"![{p.stem}]({os.path.relpath(p, rel)})"
                                           for p in shown]
    text = "\n".join(lines) + "\n"
    print(text, end="")
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(text, encoding="utf-8")
    return 0


def figures(out: Path, runs: list[dict[str, Any]], surveys: list[dict[str, Any]],
            fresh: frozenset[int]) -> list[Path]:
    """Per field: median MAE against distance for the adaptive planner and the best survey
    of each distance, one colour per noise level (plain sensors only, tuned seeds)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    out.mkdir(parents=True, exist_ok=True)
    grid = np.linspace(250.0, BUDGET_M, 32)
    paths = []
    for field in sorted({r["field"] for r in surveys}):
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        noises = sorted({r["noise"] for r in surveys if r["field"] == field and not r["variant"]})
        for i, noise in enumerate(noises):
            colour = f"C{i}"
            sv = [r for r in surveys if r["field"] == field and r["noise"] == noise
                  and not r["variant"] and r["seed"] not in fresh]
            rs = [r for r in runs if r["field"] == field and r["noise"] == noise
                  and not r["variant"] and r["planner"] == "adaptive"
                  and r["seed"] not in fresh]
            for label, curves, style in (
                    ("adaptive", [[(at_budget(r["rows"], d) or {"mae_db": math.nan})["mae_db"]
                                   for d in grid] for r in rs], "-"),
                    ("best survey", [[(best_mae_within(r, d) or {"mae_db": math.nan})["mae_db"]
                                      for d in grid] for r in sv], "--")):
                if not curves:
                    continue
                arr = np.array(curves, dtype=float)
                ok = np.sum(np.isfinite(arr), axis=0) * 2 > arr.shape[0]
                med = [median_measured(list(col)) if k else math.nan
                       for col, k in zip(arr.T, ok, strict=True)]
                ax.plot(grid / 1000, med, style, color=colour,
                        label=f"{label}, noise {noise:g} ({len(curves)} seeds)")
        ax.set_xlabel("flight distance (km), all but the flight home")
        ax.set_ylabel("MAE (dB), median over seeds")
        ax.set_title(f"{field}: the map against the distance flown, by sensor noise")
        ax.legend(fontsize=7)
        path = out / f"noise_{field}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths


def fmt_seeds(seeds: list[int]) -> str:
    """``[900, 901, 902, 920]`` -> ``"900–902, 920"``."""
    out, i = [], 0
    while i < len(seeds):
        j = i
        while j + 1 < len(seeds) and seeds[j + 1] == seeds[j] + 1:
            j += 1
        out.append(f"{seeds[i]}–{seeds[j]}" if j > i else str(seeds[i]))
        i = j + 1
    return ", ".join(out)


if __name__ == "__main__":
    sys.exit(main())
