"""How the efficiency bench counts (bench/summaries.py, surveys.py, report.py): every run
counts, a regression after a target was first met is not "stays reached", the best survey
is the shortest of every line count, and every results file names a command that runs."""

from __future__ import annotations

import doctest
import math
import re
import shlex
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.append(str(ROOT / "bench"))  # after the packages: bench/sim_vehicle.py is a script

import report  # noqa: E402
import runs  # noqa: E402
import summaries  # noqa: E402
import surveys  # noqa: E402
from summaries import first_reached, median, ratio, share_within, stays_reached  # noqa: E402


@pytest.mark.parametrize("module", [summaries, runs])
def test_docstring_examples(module):
    assert doctest.testmod(module).failed == 0


def _rows(errors, step_m=100.0):
    return [{"flight_m": step_m * (i + 1), "iso_target": e, "mae_db": e}
            for i, e in enumerate(errors)]


def test_a_target_met_and_then_lost_is_not_stays_reached():
    """Met at 200 m, lost at 300 m (the estimate moved), met again from 500 m on."""
    rows = _rows([0.9, 0.4, 5.6, 0.8, 0.3, 0.2])
    ok = lambda row: row["iso_target"] <= 0.5  # noqa: E731
    assert first_reached(rows, ok) == 200.0
    assert stays_reached(rows, ok) == 500.0
    assert stays_reached(rows[:3], ok) == math.inf  # the run ended above the target
    assert stays_reached(rows, ok, budget_m=450.0) == math.inf  # not within the budget
    assert first_reached(rows, ok, budget_m=150.0) == math.inf


def test_a_run_that_never_gets_there_is_a_loss_in_the_median():
    ratios = [ratio(d, 1000.0) for d in (300.0, 400.0, math.inf, math.inf, math.inf)]
    assert ratios[2:] == [math.inf] * 3
    assert median(ratios) == math.inf  # three losses of five: the median is lost
    assert share_within(ratios, 0.5) == (2, 5)
    with pytest.raises(ValueError, match="NaN"):
        median([0.3, math.nan])


class FakeScan(surveys.SurveyScan):
    """Surveys of made-up iso-line errors by line count (flight: 100 m per line + 100)."""

    def __init__(self, errors: dict[int, float]) -> None:
        super().__init__("plume", 0, "auto", None)
        self.errors = errors
        self.asked: list[int] = []

    def get(self, lines: int) -> dict:
        self.asked.append(lines)
        return {"lines": lines, "flight_m": 100.0 * lines + 100.0,
                "iso": [0.0, self.errors.get(lines, 9.0), 0.0]}


def test_the_best_survey_is_the_shortest_of_every_line_count():
    """Not monotone (plume seed 904): passes at 21 lines, fails at 19, 24 and 29. A ladder
    (..., 15, 19, 24, 30) then bisection finds 30 or misses it; every count finds 21."""
    errors = {n: 0.9 for n in range(2, 99)} | {21: 0.4, 30: 0.3}
    scan = FakeScan(errors)
    best = scan.shortest_reaching(lambda r: r["iso"][1] <= 0.5, 10_000.0)
    assert best is not None and best["lines"] == 21
    assert scan.asked == list(range(2, 22))
    never = FakeScan({}).shortest_reaching(lambda r: r["iso"][1] <= 0.5, 3_000.0)
    assert never is None  # counted as infinitely long, not dropped


def test_threshold_summary_counts_every_run():
    surveys_by_seed = {s: {"to_iso": {"flight_m": 1000.0, "lines": 9}} for s in (1, 2, 3)}
    rs = [{"field": "plume", "seed": 1, "planner": "adaptive:threshold", "target": 55.0,
           "stop": "planner_done", "rows": [{**r, "target_missed": 0} for r in
                                              _rows([0.9, 0.4, 0.3])]},
          {"field": "plume", "seed": 2, "planner": "adaptive:threshold", "target": 55.0,
           "stop": "planner_done", "rows": [{**r, "target_missed": 0} for r in
                                              _rows([0.9, 0.4, 5.6, 0.3])]},
          {"field": "plume", "seed": 3, "planner": "adaptive:threshold", "target": 55.0,
           "stop": "flight_budget", "rows": [{**r, "target_missed": 1} for r in
                                               _rows([0.9, 0.8])]}]
    _, summary = report.threshold_tables("plume", rs, surveys_by_seed, 10_000.0, md=True)
    (s,) = summary
    assert s["runs"] == 3 and s["never"] == 1
    assert s["median_first"] == pytest.approx(0.2)  # 0.2, 0.2, inf
    assert s["median_stays"] == pytest.approx(0.4)  # 0.2, 0.4, inf
    assert (s["half_stays"], s["half_first"]) == (2, 2)


def test_every_results_file_names_a_command_that_runs():
    """docs/results is written only by the benches: each file is stamped with the command
    (its script exists and takes those arguments) and the commit that wrote it."""
    files = sorted((ROOT / "docs" / "results").glob("*.md"))
    for path in files:
        text = path.read_text(encoding="utf-8")
        command = re.search(r"^Command: `([^`]+)`", text, re.MULTILINE)
        assert command, f"{path.name}: no Command: line"
        assert re.search(r"^Commit: `[0-9a-f]{40}`", text, re.MULTILINE), path.name
        argv = shlex.split(command.group(1))
        assert argv[0] == "python" and (ROOT / argv[1]).is_file(), argv
        if Path(argv[1]).name == "efficiency.py":
            import efficiency

            efficiency.parse_args(argv[2:])  # exits on arguments it does not take
