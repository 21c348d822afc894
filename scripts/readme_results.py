#!/usr/bin/env python3
"""Write the README's "Results" block from the benchmarks' results files in docs/results.

The README never holds a number a benchmark did not write: each cell below is read from a
table of a stamped results file (by the file, the heading it sits under, its row and its
column), and the block between the README's ``<!-- results:begin -->`` and
``<!-- results:end -->`` markers is rewritten. ``--check`` exits 1 when the README is stale
(a test runs it).

    python scripts/readme_results.py            # rewrite the block
    python scripts/readme_results.py --check    # is it current?
"""

from __future__ import annotations

import argparse
import contextlib
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"


@dataclass(frozen=True)
class Cell:
    """One value of a results file: the table under the first heading that contains
    ``heading`` (after every heading that contains each of ``after``), the row whose
    first cell is ``row`` (and second ``row2``, if given), the column headed ``column`` (a
    prefix is enough)."""

    file: str
    heading: str
    row: str
    column: str
    after: tuple[str, ...] = ()
    row2: str = ""


def tables_under(text: str, heading: str, after: tuple[str, ...]) -> list[list[list[str]]]:
    """The Markdown tables between the heading that contains ``heading`` (found after the
    headings in ``after``, in order) and the next heading of the same or a higher rank."""
    lines = text.splitlines()
    i = 0
    for h in (*after, heading):
        while i < len(lines) and not (lines[i].startswith("#") and h in lines[i]):
            i += 1
        if i == len(lines):
            raise LookupError(f"no heading containing {h!r}")
        rank = len(lines[i]) - len(lines[i].lstrip("#"))
        i += 1
    tables: list[list[list[str]]] = []
    current: list[list[str]] = []
    for line in lines[i:]:
        if line.startswith("#") and len(line) - len(line.lstrip("#")) <= rank:
            break
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if not all(re.fullmatch(r":?-+:?", c) for c in cells):
                current.append(cells)
        elif current:
            tables.append(current)
            current = []
    if current:
        tables.append(current)
    return tables


def read(cell: Cell) -> str:
    path = RESULTS / cell.file
    for table in tables_under(path.read_text(encoding="utf-8"), cell.heading, cell.after):
        head = table[0]
        cols = [j for j, h in enumerate(head) if h.startswith(cell.column)]
        rows = [r for r in table[1:] if r and r[0] == cell.row
                and (not cell.row2 or (len(r) > 1 and r[1] == cell.row2))]
        if cols and rows:
            return rows[0][cols[0]]
    raise LookupError(f"{cell.file}: no cell {cell.row!r} / {cell.column!r} under "
                      f"{cell.heading!r}")


def stamp(file: str) -> str:
    """The command line a results file names as the one that wrote it."""
    m = re.search(r"^Command: `([^`]+)`", (RESULTS / file).read_text(encoding="utf-8"), re.M)
    if not m:
        raise LookupError(f"{file}: no 'Command:' stamp")
    return m.group(1)


FIELD_NAMES = (("paper", "paper field (eqs. 8–9)"), ("plume", "plumes"),
               ("authors", "authors' generator"))
"""The threshold results' fields, as the README names them."""


def conditions(file: str) -> Iterator[tuple[str, str, str, str]]:
    """The sensor conditions of the noise report: ``(field, heading, condition, seeds)``
    for each ``### <condition> (sensor ...; <seeds>)`` heading under ``## Field: <field>``."""
    field = ""
    for line in (RESULTS / file).read_text(encoding="utf-8").splitlines():
        if line.startswith("## Field: "):
            field = line.removeprefix("## Field: ").strip()
        elif field and line.startswith("### ") and "(sensor " in line:
            heading = line.removeprefix("### ")
            condition, rest = heading.split(" (sensor ", 1)
            yield field, heading, condition, rest.split("; ", 1)[1].rstrip(")")


def block() -> str:
    noise, thr = "noise.md", "threshold-fresh.md"
    out = [BEGIN, "<!-- written by scripts/readme_results.py from docs/results; do not edit -->",
           ""]
    out += ["**By field and sensor** — MAE in dB (lower is better) after 2 and 4 km of flight; "
            "the distance the adaptive planner needs to reach the best 4 km survey's MAE, and "
            "threshold mode's distance to a 0.5 m iso-line error, each as a multiple of the "
            "best survey's flown with the same sensor (stays reached; first reached in "
            "brackets; ∞: not reached within the budget), with the 90 % interval of each "
            "median (where the median over seeds not flown lies); and all threshold mode flew "
            "until it stopped by itself, over the same survey distance "
            "([results/noise.md](docs/results/noise.md)):", "",
            "| field, sensor, seeds | adaptive @2 km | adaptive @4 km | best survey @2 km "
            "| best survey @4 km | adaptive × survey | 90 % interval | threshold × survey "
            "| 90 % interval | threshold iso m | threshold to its stop |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for field, heading, condition, seeds in conditions(noise):
        def get(row: str, col: str, key: str = heading, f: str = field) -> str:
            return read(Cell(noise, key, row, col, after=(f"Field: {f}",)))
        label = f"{field}, {'perfect' if condition == 'noise 0' else condition}, {seeds}"
        try:
            cells = [get("adaptive", "MAE dB @2 km"), get("adaptive", "MAE dB @4 km"),
                     get("best survey", "MAE dB @2 km"), get("best survey", "MAE dB @4 km"),
                     get("adaptive", "× survey to its 4 km MAE"),
                     get("adaptive", "4 km MAE × survey: median's 90 % interval")]
        except LookupError:
            continue
        for col in ("× survey, stays", "iso × survey: median's 90 % interval", "final iso m",
                    "× survey, to its own stop"):
            try:
                cells.append(get("adaptive", col))
            except LookupError:
                cells.append("—")
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    out += ["", "**Threshold iso-line** (the middle level) — distance to a mean iso-line error "
            "≤ 0.5 m that stays reached, and all it flew until it stopped by itself, as "
            "multiples of the best survey's distance to that error, fresh seeds "
            "([results/threshold-fresh.md](docs/results/threshold-fresh.md)):", "",
            "| field | × best survey (median) | median's 90 % interval | runs ≤ 0.5× "
            "| to its stop (median) |",
            "|---|---|---|---|---|"]
    for field, name in FIELD_NAMES:
        under = (f"Field: {field}",)
        row = [read(Cell(thr, "Threshold mapping", field, "median × survey, stays", under)),
               read(Cell(thr, "Threshold mapping", field, "median's 90 % interval", under)),
               read(Cell(thr, "Threshold mapping", field, "≤ 0.5×, stays", under)),
               read(Cell(thr, "Threshold mapping", field, "median × survey, to its own stop",
                         under))]
        out.append(f"| {name} | " + " | ".join(row) + " |")
    out += end_probes(noise, thr)
    out += ["", "Made by `" + stamp(noise) + "` and `" + stamp(thr) + "`.", END]
    return "\n".join(out)


NO_END_PROBES = "adaptive[probes_at_end=false]"


def end_probes(noise: str, thr: str) -> list[str]:
    """Threshold mode with and without the probes left for the end
    (``adaptive.probes_at_end``), where both were flown."""
    rows = []
    for field, name in FIELD_NAMES:
        under = (f"Field: {field}",)
        with contextlib.suppress(LookupError):
            rows += [f"| {name}, noise-free, fresh seeds | {label} | " + " | ".join(
                read(Cell(thr, "Threshold mapping", field, col, under, mapper))
                for col in ("median × survey, stays", "median's 90 % interval",
                            "≤ 0.5×, stays", "median × survey, to its own stop")) + " |"
                     for mapper, label in (("adaptive", "default"), (NO_END_PROBES, "`false`"))]
    for field, heading, condition, seeds in conditions(noise):
        if condition != "noise 1":
            continue
        try:
            rows += [f"| {field}, noise 1, {seeds.split(' ')[0]} seeds | {label} | " + " | ".join(
                read(Cell(noise, heading, mapper, col, (f"Field: {field}",)))
                for col in ("× survey, stays", "iso × survey: median's 90 % interval",
                            "≤ 0.5×, stays", "× survey, to its own stop")) + " |"
                     for mapper, label in (("adaptive", "default"), (NO_END_PROBES, "`false`"))]
        except LookupError:
            continue
    if not rows:
        return []
    return ["", "**Threshold mode without the probes left for the end** "
            "(`adaptive.probes_at_end: false`: it stops once nowhere is left where an "
            "iso-line could be), against the default, as multiples of the best survey's "
            "distance:", "",
            "| field, sensor, seeds | `probes_at_end` | × survey, stays | median's 90 % "
            "interval | runs ≤ 0.5× | to its stop |", "|---|---|---|---|---|---|", *rows]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true", help="exit 1 if the README is stale")
    p.add_argument("--readme", type=Path, default=ROOT / "README.md")
    a = p.parse_args(argv)
    text = a.readme.read_text(encoding="utf-8")
    if BEGIN not in text or END not in text:
        print(f"{a.readme}: no {BEGIN} ... {END} block", file=sys.stderr)
        return 1
    before, rest = text.split(BEGIN, 1)
    _, after = rest.split(END, 1)
    new = before + block() + after
    if a.check:
        if new != text:
            print(f"{a.readme}: the results block is stale: run scripts/readme_results.py",
                  file=sys.stderr)
            return 1
        return 0
    a.readme.write_text(new, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
