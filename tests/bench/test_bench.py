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

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.append(str(ROOT / "bench"))  # after the packages: bench/sim_vehicle.py is a script

import report  # noqa: E402
import runs  # noqa: E402
import saved_rows  # noqa: E402
import summaries  # noqa: E402
import surveys  # noqa: E402
from summaries import (  # noqa: E402
    first_reached,
    median,
    median_interval,
    ratio,
    share_within,
    stays_reached,
)


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
    # all each flew until it stopped, over the survey's: 0.3, 0.4, 0.2 (the loss too)
    assert s["median_stop"] == pytest.approx(0.3)


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


def test_tables_from_saved_runs_of_several_files(tmp_path, capsys):
    """One field per saved file (each row written as it finished), printed as one report;
    a row is the run or scan of the job it names, flown by this code."""
    import efficiency

    argv = ["--fields", "plume,paper", "--seeds", "1:3", "--threshold-only", "--no-per-seed"]
    jobs, survey_jobs = efficiency.jobs_of(efficiency.parse_args(argv))
    names = []
    for field, seed in (("plume", 1), ("paper", 2)):
        run = {"field": field, "seed": seed, "planner": "adaptive:threshold", "target": 5.0,
               "stop": "planner_done",
               "rows": [{**r, "target_missed": 0} for r in _rows([0.9, 0.4])]}
        survey = {"field": field, "seed": seed, "runs": 9, "flown": 9, "budget": {},
                  "to_db": {}, "to_iso": {"flight_m": 1000.0, "lines": 9}, "scanned": []}
        path = tmp_path / f"{field}.jsonl"
        job, = [j for j in jobs if j[:2] == (field, seed)]
        scan, = [j for j in survey_jobs if j[:2] == (field, seed)]
        saved_rows.append_row(path, {"kind": "run", "job": efficiency.job_key("run", job),
                                     **run, "code": saved_rows.run_code()})
        saved_rows.append_row(path, {"kind": "survey", **survey, "code": saved_rows.survey_code(),
                                     "job": efficiency.job_key("survey", scan)})
        names.append(str(path))
    out = tmp_path / "t.md"
    assert efficiency.main(["--from-json", ",".join(names), *argv, "--out", str(out)]) == 0
    text = out.read_text()
    assert "## Field: plume" in text and "## Field: paper" in text
    assert "2 planner runs and 18 surveys" in text
    assert "Threshold mapping, every field" in text
    assert "4 of the 8 runs and survey scans asked for are not in the saved rows" in \
        capsys.readouterr().err


def test_the_survey_cache_key_names_code_that_exists():
    """A moved module must move in the key too: a path that is gone would fail every run
    with a cache (and one left out would let a changed survey come from the cache)."""
    for entry in surveys.SURVEY_SOURCES:
        assert (ROOT / entry).exists(), entry
    assert len(surveys.code_fingerprint()) == 64


def test_noise_rows_of_other_code_or_sensor_are_set_aside(tmp_path, capsys):
    """A saved noise-bench row counts only if flown by this code with its condition's
    sensor: one of other code, or whose sensor no longer matches, is left out of the
    tables (and would be flown again); ``--any-code`` keeps it and names its commit. The
    rows round-trip through a gzip file written a row at a time."""
    import noise
    import noise_flights

    def survey(seed: int) -> dict:
        row = {"kind": "survey", "field": "plume", "seed": seed, "noise": 1.0,
               "variant": "", "to_iso": {"flight_m": 1000.0, "lines": 9},
               "scanned": [{"flight_m": 900.0, "mae_db": -10.0, "iso": [0.4] * 3, "iso_mean": 0.4,
                            "lines": 9, "noise_std": 1.0}]}
        return {**row, **noise_flights.provenance("plume", 1.0, "", survey=True)}

    path = tmp_path / "rows.jsonl.gz"
    good, other_code, other_sensor = survey(1), survey(2), survey(3)
    other_code.update(code="0" * 16, commit="abc")
    other_sensor["sensor"] = {"noise_std": 2.0}
    for row in (good, other_code, other_sensor):
        saved_rows.append_row(path, row)
    assert [r["seed"] for r in saved_rows.read_rows(path)] == [1, 2, 3]
    assert [noise_flights.current(r) for r in saved_rows.read_rows(path)] == [True, False, False]
    assert noise_flights.current(good) and good["code"] == saved_rows.survey_code()
    # a planner run is stamped with the code a run runs (the tracer, the planners too)
    run = {"kind": "run", "field": "plume", "seed": 1, "noise": 1.0, "variant": "",
           **noise_flights.provenance("plume", 1.0, "")}
    assert noise_flights.current(run) and run["code"] == saved_rows.run_code() != saved_rows.survey_code()
    assert not noise_flights.current({**run, "code": saved_rows.survey_code()})

    noise.main(["--from-json", str(path), "--fields", "plume"])
    out = capsys.readouterr()
    assert "2 saved rows flown with other code or another sensor set aside" in out.err
    assert "0 planner runs and 1 survey scans" in out.out
    noise.main(["--from-json", str(path), "--fields", "plume", "--any-code"])
    text = capsys.readouterr().out
    assert "0 planner runs and 3 survey scans" in text and "abc" in text


def test_same_flight_takes_last_bits_as_the_same_and_any_count_or_key_as_not():
    """Figures within ``FLOAT_RTOL`` (another machine's arithmetic) and NaN beside NaN are
    the same flight; another sample count, a missing key or a timing-free figure moved by
    a millionth are not; timings and stamps never count."""
    a = {"kind": "run", "rows": [{"mae": 14.465390592845988, "iso": [8.131080983663978,
                                                                     float("nan")],
                                  "samples": 457}], "wall_s": 1.0, "commit": "c0"}
    same = {"kind": "run", "rows": [{"mae": 14.46539059284019, "iso": [8.131080983643963,
                                                                       float("nan")],
                                     "samples": 457}], "wall_s": 7.0, "commit": "c1"}
    assert saved_rows.same_flight(a, same)
    row = a["rows"][0]
    for other in ({**row, "samples": 458}, {**row, "mae": row["mae"] * (1 + 1e-6)},
                  {**row, "iso": [8.131080983663978, 0.0]}, {"mae": row["mae"]}):
        assert not saved_rows.same_flight(a, {**a, "rows": [other]})


def test_restamp_lets_stale_rows_stand_only_when_flown_again_they_come_out_the_same(tmp_path):
    """``--restamp``: of the stale rows, a spread sample is flown again; only if every one
    comes out as saved (timings and stamps aside) do they all get the current code, the
    commit they were flown at kept and the checking commit added; one that differs leaves
    the file as it was."""

    def row(seed: int, mae: float) -> dict:
        return {"kind": "run", "field": "plume", "seed": seed, "noise": 1.0, "variant": "",
                "planner": "adaptive", "rows": [{"mae": mae, "flight_m": 100.0}],
                "wall_s": 1.0, "code": "old", "commit": "c0"}

    path = tmp_path / "rows.jsonl.gz"
    stale = [row(s, 0.1 * s) for s in range(6)]
    for r in stale:
        saved_rows.append_row(path, r)
    flown: list[list[int]] = []

    def fly(picked, shift=0.0):
        flown.append([r["seed"] for r in picked])
        return [{**r, "rows": [{"mae": r["rows"][0]["mae"] + shift, "flight_m": 100.0}],
                 "wall_s": 9.0, "code": "new", "commit": "c1"} for r in picked]

    ok, line = saved_rows.restamp(path, stale, 2, lambda p: fly(p, 1e-6), lambda r: "new", "c1")
    assert not ok and "differs" in line
    assert saved_rows.read_rows(path) == stale
    # another machine's last bits of arithmetic are the same flight
    ok, line = saved_rows.restamp(path, stale, 2, lambda p: fly(p, 1e-13), lambda r: "new",
                                  "c1")
    assert ok and "6 rows restamped at c1" in line
    assert flown == [[1, 4], [1, 4]]  # spread over the rows, not the first ones
    back = saved_rows.read_rows(path)
    assert [(r["code"], r["commit"], r["restamped"]) for r in back] == [("new", "c0", "c1")] * 6
    assert [r["rows"] for r in back] == [r["rows"] for r in stale]


def test_efficiency_rows_are_named_by_their_job_and_set_aside_when_of_other_code(
        tmp_path, capsys):
    """The efficiency bench's saved rows (``--json``, JSON lines) are named by their job
    (a survey scan's without the cache directory, which changes no result); ``--from-json``
    sets aside a row of other code, says so, and says how many asked for are missing."""
    import efficiency

    scan = ("plume", 3, 10_000.0, "auto", "/tmp/a", [10_000.0], (), 0.5, False)
    assert efficiency.job_key("survey", scan) == efficiency.job_key(
        "survey", (*scan[:4], "/elsewhere", *scan[5:]))
    assert efficiency.job_key("survey", scan) != efficiency.job_key(
        "survey", ("plume", 4, *scan[2:]))
    run = ("plume", 3, "adaptive", 10_000.0, "auto", True, {})
    row = {"kind": "run", "job": efficiency.job_key("run", run), "code": "0" * 16,
           "commit": "abc"}
    assert not saved_rows.current_code(row)
    assert saved_rows.current_code({**row, "code": saved_rows.run_code()})
    path = tmp_path / "rows.jsonl.gz"
    saved_rows.append_row(path, row)
    efficiency.main(["--from-json", str(path), "--fields", "plume", "--seeds", "3",
                     "--threshold-only"])
    err = capsys.readouterr().err
    assert "1 saved rows flown with other code set aside (commits abc)" in err
    assert "2 of the 2 runs and survey scans asked for are not in the saved rows" in err


def test_rows_of_other_code_go_once_a_current_row_of_the_same_job_replaces_them(tmp_path):
    """``saved_rows.drop_superseded`` (both benches, after flying): a stale row whose job a
    current row now holds goes; a stale row nothing replaces stays, and so do current ones."""
    now, old = saved_rows.run_code(), "0" * 16
    rows = [{"kind": "run", "job": "a", "code": old}, {"kind": "run", "job": "b", "code": old},
            {"kind": "run", "job": "a", "code": now}, {"kind": "run", "job": "c", "code": now}]
    path = tmp_path / "rows.jsonl.gz"
    saved_rows.write_rows(path, rows)
    assert saved_rows.drop_superseded(path, lambda r: r["job"]) == 1
    assert saved_rows.read_rows(path) == rows[1:]
    assert saved_rows.drop_superseded(path, lambda r: r["job"]) == 0


def test_efficiency_appends_what_it_flies_and_drops_the_rows_it_replaces(
        tmp_path, monkeypatch, capsys):
    """``efficiency.py --json``: each row flown is appended as it comes in; then the rows of
    other code of the same jobs go, and a stale row of a job not flown stays."""
    import efficiency

    jobs, _ = efficiency.jobs_of(efficiency.parse_args(
        ["--fields", "plume", "--seeds", "3:5", "--threshold-only"]))
    todo = [(efficiency.job_key("run", j), "run", j) for j in jobs]
    path = tmp_path / "rows.jsonl.gz"
    stale = [{"kind": "run", "job": k, "code": "old"} for k, _, _ in todo]
    other = {"kind": "run", "job": "another", "code": "old"}
    for r in [*stale, other]:
        saved_rows.append_row(path, r)

    def fly(todo, workers):
        for key, kind, _ in todo:
            yield key, {"kind": kind, "job": key, "code": efficiency.code_of(kind)}

    monkeypatch.setattr(efficiency, "fly_jobs", fly)
    new = efficiency.fly_and_save(todo, 1, path)
    assert list(new) == [k for k, _, _ in todo]
    assert saved_rows.read_rows(path) == [other, *new.values()]
    assert f"{len(todo)} rows of other code replaced" in capsys.readouterr().err


@pytest.mark.parametrize("same", [True, False], ids=["as-saved", "differs"])
def test_efficiency_restamp_flies_a_spread_of_the_asked_for_stale_rows_again(
        tmp_path, monkeypatch, capsys, same):
    """``efficiency.py --restamp K``: of the asked-for rows of other code (not those of
    other fields), K spread over them are flown again by their jobs; the rows stand with the
    current code only if each comes out as saved."""
    import efficiency

    argv = ["--fields", "plume,paper", "--seeds", "3:6", "--threshold-only"]
    jobs, scans = efficiency.jobs_of(efficiency.parse_args(argv))
    path = tmp_path / "rows.jsonl.gz"
    saved = [{"kind": kind, "job": efficiency.job_key(kind, j), "field": j[0], "seed": j[1],
              "rows": [{"iso_target": 0.1 * j[1]}], "code": "old", "commit": "c0"}
             for kind, js in (("run", jobs), ("survey", scans)) for j in js]
    other = {**saved[0], "job": "another field's", "field": "front"}
    for r in [*saved, other]:
        saved_rows.append_row(path, r)
    flown: list[str] = []

    def fly(todo, workers):
        for key, kind, job in todo:
            flown.append(key)
            row = next(r for r in saved if r["job"] == key)
            yield key, {**row, "rows": [{"iso_target": 0.1 * job[1] + (0 if same else 1)}],
                        "code": efficiency.code_of(kind), "commit": "c1"}

    monkeypatch.setattr(efficiency, "fly_jobs", fly)
    code = efficiency.main([*argv, "--json", str(path), "--restamp", "3"])
    assert len(flown) == 3 and len(set(flown)) == 3 and other["job"] not in flown
    back = saved_rows.read_rows(path)
    err = capsys.readouterr().err
    if same:
        assert code == 0 and "12 rows restamped" in err
        assert [r["code"] == efficiency.code_of(r["kind"]) for r in back] == [True] * 12 + [False]
        assert [r["rows"] for r in back] == [r["rows"] for r in [*saved, other]]
    else:
        assert code == 1 and "differs" in err
        assert back == [*saved, other]


@pytest.mark.parametrize("n", [5, 10, 20, 40])
def test_the_median_interval_covers_the_median_of_what_the_runs_are_drawn_from(n):
    """The median's 90 % interval the reports give (``summaries.median_interval``) covers
    the true median of a skewed distribution with losses (exponential, a fifth of the draws
    ``inf``) at least 90 % of the time, and not by being far wider than it must (under 99 %)."""
    rng = np.random.default_rng(7)
    # P(X <= m) = 0.8 * (1 - exp(-m)) = 0.5 -> the true median
    true_median = -math.log(1.0 - 0.5 / 0.8)
    hits = 0
    trials = 4000
    for _ in range(trials):
        draws = rng.exponential(1.0, n)
        draws[rng.random(n) < 0.2] = math.inf
        lo, hi = median_interval(draws.tolist())
        hits += lo <= true_median <= hi
    assert 0.9 <= hits / trials < 0.99


@pytest.mark.slow
def test_every_bench_script_imports():
    """A bench whose imports moved away fails at once, not when someone next runs it
    (``bench/sensor.py`` took ``mid_level`` from a module that no longer had it): one
    process loads every script as its own ``__main__`` would, short of running it."""
    scripts = sorted(str(p) for p in (ROOT / "bench").glob("*.py"))
    code = ("import runpy, sys\n"
            "sys.path[0] = sys.argv[1]  # as `python bench/x.py` has it\n"
            "for path in sys.argv[2:]:\n"
            "    runpy.run_path(path, run_name='bench_import_check')\n")
    import subprocess

    proc = subprocess.run([sys.executable, "-c", code, str(ROOT / "bench"), *scripts], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_noise_again_flies_exactly_the_stale_saved_rows_and_replaces_them(
        tmp_path, monkeypatch, capsys):
    """``noise.py --again``: the selected saved rows of other code are flown again, each by
    its own job (not every job the selection names), appended as they come in, and the rows
    they replace dropped; a row already replaced (a cut-off run going on) is not flown."""
    import noise
    import noise_flights

    def row(seed: int, planner: str, code: str) -> dict:
        return {"kind": "run", "field": "plume", "seed": seed, "noise": 1.0, "variant": "",
                "planner": planner, "sensor": noise_flights.condition_sensor("plume", 1.0, ""),
                "rows": [{"mae_db": -1.0, "flight_m": 10.0}], "code": code, "commit": "c0"}

    now = saved_rows.run_code()
    path = tmp_path / "rows.jsonl.gz"
    saved = [row(900, "adaptive", "old"), row(901, "adaptive", "old"),
             row(901, "adaptive", now), row(902, "econdor", "old")]
    for r in saved:
        saved_rows.append_row(path, r)
    flown: list[tuple] = []

    def fly(jobs, workers):
        for i, (kind, job) in enumerate(jobs):
            assert kind == "run"
            flown.append(job)
            yield i, {**row(job[1], job[2], now), "rows": [{"mae_db": -2.0, "flight_m": 9.0}]}

    monkeypatch.setattr(noise, "fly", fly)
    argv = ["--json", str(path), "--fields", "plume", "--noise", "1", "--seeds", "900:903",
            "--planners", "adaptive", "--again"]
    assert noise.main(argv) == 0
    assert flown == [("plume", 900, "adaptive", 1.0, "")]
    back = saved_rows.read_rows(path)
    assert sorted((r["seed"], r["planner"], r["code"] == now) for r in back) == [
        (900, "adaptive", True), (901, "adaptive", True), (902, "econdor", False)]
    assert noise.main(argv) == 2  # nothing left of other code
    assert "no selected row of other code" in capsys.readouterr().err


def test_the_idealised_traces_cut_bends_and_read_the_bench_surveys(tmp_path: Path) -> None:
    """bench/threshold_bounds.py: a part flown with its bends cut (``--cuts``) is shorter
    than the part where it bends and as long where it is straight; the bench's best survey
    per seed is read from its saved rows (surveys only, of the field asked)."""
    import gzip
    import json

    import threshold_bounds as tb

    from econdor_gcs.core.contours import ContourPiece

    t = np.linspace(0.0, np.pi, 200)
    arc = ContourPiece(0.0, np.column_stack([50 + 30 * np.cos(t), 50 + 30 * np.sin(t)]), False)
    line = ContourPiece(0.0, np.column_stack([np.linspace(10, 90, 50), np.full(50, 5.0)]), False)
    none = np.zeros((0, 2))
    for piece, shorter in ((arc, True), (line, False)):
        _, whole = tb.parts_beyond([piece], none, 0.0)
        _, cut = tb.parts_beyond([piece], none, 0.0, cut_m=5.0)
        assert (cut < whole - 1.0) if shorter else math.isclose(cut, whole, rel_tol=1e-9)
    path = tmp_path / "rows.jsonl.gz"
    with gzip.open(path, "wt") as f:
        for r in ({"kind": "survey", "field": "authors", "seed": 900, "to_iso": {"flight_m": 921.0}},
                  {"kind": "survey", "field": "paper", "seed": 900, "to_iso": {"flight_m": 5.0}},
                  {"kind": "run", "field": "authors", "seed": 901}):
            f.write(json.dumps(r) + "\n")
    assert tb._bench_surveys(str(path), "authors") == {900: 921.0}
