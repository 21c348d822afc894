"""A benchmark's rows kept on disk (JSON lines, gzip when the name ends in .gz): what
code they were flown with, and the check that lets rows flown with older code stand for
the current code.

Every row is stamped with the fingerprint of the code it ran (``code``) and the commit it
was flown at (``commit``). A change to that code makes every row stale, also where the
change cannot touch a row's flight (a mode the rows never use). :func:`restamp` lets such
rows stand: some of them are flown again, and only if every one comes out the same as the
saved row are the stale rows given the current fingerprint (``code``), with the commit at
which they were checked (``restamped``); the commit they were flown at stays.

>>> a = {"kind": "run", "rows": [{"mae": 0.5, "wall_s": 3.0}], "code": "a", "commit": "x"}
>>> same_flight(a, {**a, "rows": [{"mae": 0.5, "wall_s": 9.0}], "code": "b"})
True
>>> same_flight(a, {**a, "rows": [{"mae": 0.6, "wall_s": 3.0}]})
False
>>> same_flight({**a, "target": float("nan")}, {**a, "target": float("nan")})
True
"""

from __future__ import annotations

import gzip
import hashlib
import json
import math
import sys
from collections.abc import Callable, Sequence
from functools import cache
from pathlib import Path
from typing import Any

from report import tree_commit
from surveys import NOT_RUN_BY_A_SURVEY, SURVEY_SOURCES

ROOT = Path(__file__).resolve().parents[1]

NOT_RUN_BY_A_NOISY_SURVEY = (*NOT_RUN_BY_A_SURVEY, "econdor_gcs/core/levels.py",
                             "econdor_gcs/core/sg.py")
"""E-CONDOR's own modules are imported by a survey, never called either."""


@cache
def code_fingerprint(sources: tuple[str, ...] = SURVEY_SOURCES,
                     skip: tuple[str, ...] = NOT_RUN_BY_A_NOISY_SURVEY) -> str:
    """A hash of the source a survey runs (``surveys.SURVEY_SOURCES``), or of other
    ``sources`` but for ``skip``. What the noise bench adds to a survey is its sensor,
    which the cache key and every saved row hold."""
    h = hashlib.sha256()
    for entry in sources:
        p = ROOT / entry
        for f in sorted(p.rglob("*.py")) if p.is_dir() else [p]:
            rel = f.relative_to(ROOT).as_posix()
            if not rel.startswith(skip):
                h.update(rel.encode())
                h.update(f.read_bytes())
    return h.hexdigest()


RUN_SOURCES = ("econdor_gcs/core", "econdor_gcs/dfc", "econdor_gcs/config",
               "econdor_gcs/errors.py", "econdor_lab/inprocess.py", "sim_vehicle",
               "bench/runs.py", "bench/surveys.py")
"""The code a planner run runs: a saved run flown with other code is flown again
(a bench's ``--json``) and left out of its tables (a survey scan the same, by
:func:`survey_code`)."""


@cache
def run_code() -> str:
    """The fingerprint of ``RUN_SOURCES`` a row is stamped with (``code``)."""
    return code_fingerprint(RUN_SOURCES, ())[:16]


@cache
def survey_code() -> str:
    """The fingerprint of what a survey runs (:func:`code_fingerprint`) a scan is stamped
    with: a change to the planners or the tracer leaves scans current."""
    return code_fingerprint()[:16]


def code_of(kind: str) -> str:
    """The fingerprint a row of ``kind`` is stamped with: a survey scan's
    (:func:`survey_code`), or a planner run's (:func:`run_code`)."""
    return survey_code() if kind == "survey" else run_code()


def current_code(row: dict[str, Any]) -> bool:
    """Whether a saved row (a planner run, or a survey scan: ``kind``) was flown by this
    code."""
    return row.get("code") == code_of(str(row.get("kind")))


@cache
def commit() -> str:
    """The commit a row is flown at (``+`` when the tree held changes not committed)."""
    head, dirty = tree_commit()
    return head[:12] + ("+" if dirty else "")


VOLATILE = frozenset({"wall_s", "code", "commit", "restamped", "flown"})
"""Keys that are not the flight: timings, stamps, and how many survey runs came from a
cache (``flown``)."""


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows saved in ``path`` (JSON lines; gzip-compressed when it ends in .gz)."""
    if not path.exists():
        return []
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]


def load(names: str, current: Callable[[dict[str, Any]], bool], keep_stale: bool = False,
         stale_is: str = "flown with other code") -> list[dict[str, Any]]:
    """The rows of the comma-separated files ``names``; those not ``current`` are set
    aside, and said so on stderr with the commits they were flown at, unless
    ``keep_stale``."""
    rows = [r for name in names.split(",") for r in read_rows(Path(name))]
    stale = [r for r in rows if not current(r)]
    if stale and not keep_stale:
        print(f"{len(stale)} saved rows {stale_is} set aside (commits "
              f"{', '.join(sorted({str(r.get('commit')) for r in stale}))})",
              file=sys.stderr, flush=True)
        rows = [r for r in rows if current(r)]
    return rows


def append_row(path: Path, row: dict[str, Any]) -> None:
    """Add one row to ``path`` (a gzip file gets a member per row: still one stream)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "at", encoding="utf-8") as fh:
        fh.write(json.dumps(row, default=float) + "\n")


def superseded(rows: Sequence[dict[str, Any]], name: Callable[[dict[str, Any]], Any],
               current: Callable[[dict[str, Any]], bool] = current_code) -> list[bool]:
    """Per row: not ``current`` (flown with other code), and a current row of the same
    ``name`` replaces it."""
    replaced = {name(r) for r in rows if current(r)}
    return [not current(r) and name(r) in replaced for r in rows]


def drop_superseded(path: Path, name: Callable[[dict[str, Any]], Any],
                    current: Callable[[dict[str, Any]], bool] = current_code) -> int:
    """Remove from ``path`` the rows a current row replaces (:func:`superseded`); how many
    went."""
    rows = read_rows(path)
    kept = [r for r, gone in zip(rows, superseded(rows, name, current), strict=True)
            if not gone]
    if len(kept) < len(rows):
        write_rows(path, kept)
    return len(rows) - len(kept)


def write_rows(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Replace ``path`` with ``rows`` (written beside it first, then moved over it)."""
    tmp = path.with_name(path.name + ".tmp" + path.suffix)
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(tmp, "wt", encoding="utf-8") as fh:
        fh.writelines(json.dumps(row, default=float) + "\n" for row in rows)
    tmp.replace(path)


def _flight(v: Any) -> Any:
    """``v`` as JSON gives it back, without the :data:`VOLATILE` keys."""
    if isinstance(v, dict):
        return {k: _flight(x) for k, x in v.items() if k not in VOLATILE}
    if isinstance(v, list | tuple):
        return [_flight(x) for x in v]
    return v


FLOAT_RTOL = 1e-9
"""Relative difference of two numbers taken as the same: another machine's arithmetic
(its BLAS, its CPU's instructions) moves the last bits of a flight's figures (measured:
under 1e-11), never a flight's distance or samples."""


def same_flight(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Whether two rows hold the same flight: every value equal (as JSON keeps it) but the
    :data:`VOLATILE` ones, numbers within :data:`FLOAT_RTOL` of each other."""
    def plain(row: dict[str, Any]) -> Any:
        return _flight(json.loads(json.dumps(row, default=float)))

    return _same(plain(a), plain(b))


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if all(isinstance(x, int | float) and not isinstance(x, bool) for x in (a, b)):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return math.isclose(a, b, rel_tol=FLOAT_RTOL, abs_tol=FLOAT_RTOL)
    return type(a) is type(b) and a == b


def spread(rows: Sequence[dict[str, Any]], k: int) -> list[dict[str, Any]]:
    """``k`` of ``rows`` spread evenly over them in the order of their kind, field,
    condition, planner and seed (all when there are no more)."""
    order = sorted(rows, key=lambda r: (r["kind"], r["field"], r.get("noise", 0.0),
                                        r.get("variant", ""), r.get("planner", ""),
                                        r["seed"], r.get("job", "")))
    if len(order) <= k:
        return order
    return [order[(2 * i + 1) * len(order) // (2 * k)] for i in range(k)]


def restamp(path: Path, stale: Sequence[dict[str, Any]], k: int,
            fly: Callable[[list[dict[str, Any]]], list[dict[str, Any]]],
            code: Callable[[dict[str, Any]], str], commit: str) -> tuple[bool, str]:
    """Fly :func:`spread` ``k`` of the ``stale`` rows saved in ``path`` again (``fly``:
    the rows flown anew, in the same order); if each comes out as saved, give every stale
    row its current fingerprint (``code(row)``) and ``restamped = commit`` in ``path``.
    Returns whether it did, and a line saying what was found."""
    picked = spread(stale, k)
    again = fly(picked)
    for old, new in zip(picked, again, strict=True):
        if not same_flight(old, new):
            what = {key: old.get(key) for key in ("kind", "field", "noise", "variant",
                                                   "planner", "seed") if key in old}
            return False, f"flown again, {what} differs from the saved row: nothing restamped"
    rows = read_rows(path)
    keys = {_key(r) for r in stale}
    n = 0
    for row in rows:
        if _key(row) in keys:
            row.update(code=code(row), restamped=commit)
            n += 1
    write_rows(path, rows)
    return True, (f"{len(picked)} of {len(stale)} stale rows flown again came out as saved: "
                  f"{n} rows restamped at {commit}")


def restamped(rows: list[dict[str, Any]]) -> str:
    """What the report says of rows restamped (``--restamp``), if any."""
    at = sorted({str(r["restamped"]) for r in rows if r.get("restamped")})
    n = sum(1 for r in rows if r.get("restamped"))
    return (f" ({n} of them checked to fly the same with the code of {', '.join(at)}: "
            "a sample flown again came out as saved)") if at else ""


def _key(row: dict[str, Any]) -> tuple[Any, ...]:
    """What tells a saved row from the others: its job (``bench/efficiency.py``), or its
    kind, field, seed, planner and condition (``bench/noise.py``), and its code."""
    if "job" in row:
        return (row["job"], row.get("code"))
    return (row["kind"], row["field"], row["seed"], row.get("planner", ""), row["noise"],
            row["variant"], row.get("code"))
