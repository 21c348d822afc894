"""How the benches count: distances to a target, ratios to the best survey, medians.

Every run counts. A run that never reaches a target within the budget is a loss: its
distance and its ratio to the survey are infinite, never a NaN that drops out of a
median. A target can be reached in two senses:

* **first reached** — the first estimate (row) that meets it;
* **stays reached** — the first estimate from which every later one, to the end of the
  run, meets it. An estimate that goes back above the target after meeting it does not
  count: this is the headline measure.

A survey has one estimate, at its end, so for a survey the two are the same. Distances
are the DFC's rows (``flight_distance_m``): everything flown behind that estimate, never
the flight home after the last one (the DFC books it in no row).

>>> rows = [{"flight_m": 100.0, "e": 0.9}, {"flight_m": 200.0, "e": 0.4},
...         {"flight_m": 300.0, "e": 0.7}, {"flight_m": 400.0, "e": 0.3}]
>>> ok = lambda row: row["e"] <= 0.5
>>> first_reached(rows, ok), stays_reached(rows, ok)
(200.0, 400.0)
>>> stays_reached(rows[:3], ok)
inf
>>> ratio(400.0, 800.0), ratio(math.inf, 800.0), ratio(400.0, math.inf)
(0.5, inf, 0.0)
>>> median([0.4, math.inf, 0.6])
0.6
>>> share_within([0.4, math.inf, 0.5, 0.7], 0.5)
(2, 4)
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Sequence
from typing import Any

Row = dict[str, Any]
Check = Callable[[Row], bool]


def first_reached(rows: Sequence[Row], ok: Check, budget_m: float = math.inf) -> float:
    """Flight distance of the first row for which ``ok`` holds, within ``budget_m`` (a
    last batch that overran the budget does not count); ``inf`` if none."""
    for row in rows:
        if row["flight_m"] > budget_m:
            break
        if ok(row):
            return float(row["flight_m"])
    return math.inf


def stays_reached(rows: Sequence[Row], ok: Check, budget_m: float = math.inf) -> float:
    """Flight distance of the first row from which ``ok`` holds for every later row to
    the end of the run (rows beyond the budget included: a run that ends above the
    target never stayed there), if that row is within ``budget_m``; ``inf`` if none."""
    since = math.inf
    for row in reversed(rows):
        if not ok(row):
            break
        since = float(row["flight_m"])
    return since if since <= budget_m else math.inf


def ratio(distance_m: float, survey_m: float) -> float:
    """A run's distance over the best survey's: ``inf`` when the run never got there
    (a loss whatever the survey did), 0 when it did and no survey did."""
    if math.isinf(distance_m) or math.isnan(distance_m):
        return math.inf
    if math.isinf(survey_m) or math.isnan(survey_m):
        return 0.0
    return distance_m / survey_m


def median(values: Sequence[float]) -> float:
    """The median over every run, losses (``inf``) included; NaN for no runs."""
    if any(math.isnan(v) for v in values):
        raise ValueError("median: a NaN among the values (every run must count)")
    return statistics.median(values) if values else math.nan


def median_measured(values: Sequence[float]) -> float:
    """The median over the values measured (NaN: not measured, left out); NaN for none.

    >>> median_measured([1.0, math.nan, 3.0])
    2.0
    """
    measured = [v for v in values if not math.isnan(v)]
    return statistics.median(measured) if measured else math.nan


def stop_ratio(flown_m: float, survey_m: float) -> float:
    """All a run flew to its own stop over the best survey's distance; NaN (not measured)
    where no survey got there."""
    return flown_m / survey_m if math.isfinite(survey_m) else math.nan


def median_interval(values: Sequence[float], level: float = 0.9) -> tuple[float, float]:
    """A distribution-free interval for the median of what the runs are drawn from (the
    median over seeds not flown): ``[x_(k), x_(n+1-k)]`` of the sorted values, ``k`` the
    largest with ``P(B < k) <= (1 - level) / 2`` for ``B ~ Binomial(n, 1/2)``, so that it
    covers that median with probability at least ``level`` whatever the distribution
    (Conover, *Practical Nonparametric Statistics*, 3rd ed., §3.2). Losses (``inf``)
    count as the largest values. ``(nan, nan)`` when there are too few runs for ``level``.

    >>> median_interval(range(1, 21))   # n = 20: the 6th and 15th (covers 95.9 %)
    (6, 15)
    >>> median_interval([1.0, 2.0, 3.0])
    (nan, nan)
    """
    x = sorted(values)
    n = len(x)
    tail, k = 0.0, 0
    while k < n:
        tail += math.comb(n, k) / 2.0**n  # P(B <= k)
        if tail > (1.0 - level) / 2.0:
            break
        k += 1
    if k == 0:
        return math.nan, math.nan
    return x[k - 1], x[n - k]


def share_within(ratios: Sequence[float], goal: float) -> tuple[int, int]:
    """How many of ``ratios`` are ``<= goal``, of how many."""
    return sum(r <= goal for r in ratios), len(ratios)


def fmt_interval(values: Sequence[float], spec: str = ".2f") -> str:
    """:func:`median_interval` of ``values`` for a table: ``lo–hi``, ``—`` when too few."""
    lo, hi = median_interval(values)
    return "—" if math.isnan(lo) else f"{fmt(lo, spec)}–{fmt(hi, spec)}"


def fmt(x: float, spec: str = ".1f") -> str:
    """A figure for a table: ``∞`` for a loss, ``—`` for nothing measured."""
    if math.isnan(x):
        return "—"
    if math.isinf(x):
        return "∞"
    return format(x, spec)
