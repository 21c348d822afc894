"""A small end-to-end in-process study: the whole DFC loop with real tracing."""

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from econdor.cli import main
from econdor_gcs.config import Mission, load_mission
from econdor_gcs.dfc.loop import IterationRecord
from econdor_gcs.errors import EcondorError
from econdor_lab.inprocess import InProcessExecutor
from econdor_lab.study import parse_seeds, run_seed, run_study

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def demo():
    return load_mission(ROOT / "missions" / "demo.yaml").with_overrides(
        max_iterations=3, min_iterations=3)


def test_econdor_run_improves_at_every_iteration_with_real_tracing(demo, tmp_path):
    """Demo mission, seed 1, 3 iterations (measured: 17.3, -6.8, -27.7, -38.0 dB)."""
    r = run_seed(demo, 1, "econdor", str(tmp_path))
    rows = r["rows"]
    assert [row["iteration"] for row in rows] == [0, 1, 2, 3]
    maes = [row["mae"] for row in rows]
    assert maes[1] < maes[0] / 3  # tracing the first contours helps a lot
    assert all(b < a for a, b in zip(maes, maes[1:], strict=False))
    assert rows[-1]["mae_db"] < -30.0
    # cumulative distances and samples only grow; contour distance <= flown
    for a, b in zip(rows, rows[1:], strict=False):
        assert b["flight_distance_m"] >= a["flight_distance_m"]
        assert b["samples"] >= a["samples"]
    assert 0 < rows[-1]["contour_distance_m"] < rows[-1]["flight_distance_m"]
    s = r["summary"]
    # every sample is on disk; the last row's are those behind its estimate (not the way home)
    assert s["samples"] > rows[-1]["samples"]
    assert s["flight_distance_m"] == pytest.approx(rows[-1]["flight_distance_m"])
    assert s["final_mae"] == pytest.approx(maes[-1])
    run_dir = Path(r["run_dir"])
    with (run_dir / "samples.csv").open() as f:
        assert sum(1 for _ in f) - 1 == s["samples"]
    with (run_dir / "metrics.csv").open() as f:
        assert tuple(csv.DictReader(f).fieldnames) == IterationRecord.CSV_COLUMNS


def test_parse_seeds():
    assert parse_seeds("0:3") == [0, 1, 2]
    assert parse_seeds("4,7") == [4, 7]
    with pytest.raises(EcondorError, match="--seeds"):
        parse_seeds("a:b")


@pytest.mark.slow
def test_study_outputs_all_planners(demo, tmp_path):
    mission = demo.with_overrides(max_iterations=2, min_iterations=2)
    summary = run_study(mission, [3], ["econdor", "no-sg", "lawnmower"], tmp_path, workers=1)
    assert set(summary["by_planner"]) == {"econdor", "no-sg", "lawnmower"}
    with (tmp_path / "study.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["planner"] for r in rows} == {"econdor", "no-sg", "lawnmower"}
    assert len(rows) == 3 * 3
    for planner in ("econdor", "no-sg", "lawnmower"):
        maes = [float(r["mae"]) for r in rows if r["planner"] == planner]
        assert maes[-1] < maes[0], planner
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["seeds"] == [3]
    figs = sorted(p.name for p in (tmp_path / "figures").glob("*.png"))
    assert "fig7_mae_vs_distance.png" in figs and "fig3_mae_db_vs_levels.png" in figs
    assert any(n.startswith("fig9_maps_") for n in figs)
    for r in summary["runs"]:  # the 50 % contour is found by every planner, within metres
        assert 0.0 <= r["isoline_error_m"]["p50"] < 5.0, r["planner"]


def test_cli_study_and_errors(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("field: {model: paper}\nvehicles: {cont: 2}\n")
    assert main(["study", str(bad), "--seeds", "0:1", "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert err.strip().splitlines() == ["econdor: error: vehicles.cont: unknown key "
                                        "(allowed: altitude_m, count, max_accel_mps2, "
                                        "max_speed_mps, max_turn_rate_dps, noise_std, "
                                        "sample_rate_hz, sensor, speed_mps, speedup)"]
    with pytest.raises(SystemExit) as exc:
        main(["study", str(bad), "--workers", "0", "--out", "x"])
    assert exc.value.code == 2


def test_study_on_a_dask_cluster(demo, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    mission = demo.with_overrides(max_iterations=1, min_iterations=1)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=":0") as cluster:
        summary = run_study(mission, [5, 6], ["econdor"], tmp_path,
                            scheduler=cluster.scheduler_address, figures=False)
    assert [r["seed"] for r in summary["runs"]] == [5, 6]
    assert all(r["iterations"] == 1 for r in summary["runs"])
    with (tmp_path / "study.csv").open() as f:
        assert len(list(csv.DictReader(f))) == 4


def test_unreachable_scheduler_is_one_clear_error(demo, tmp_path):
    pytest.importorskip("dask.distributed")
    from econdor_gcs.errors import EcondorError

    with pytest.raises(EcondorError, match="cannot reach Dask scheduler"):
        run_study(demo, [1], ["econdor"], tmp_path, scheduler="tcp://127.0.0.1:1", figures=False,
                  connect_timeout_s=1.0)


def test_flight_budget_stops_the_run(demo):
    mission = demo.with_overrides(max_iterations=8, min_iterations=1, flight_budget_m=1500.0)
    r = run_seed(mission, 2, "no-sg", None)
    s = r["summary"]
    assert s["stop_reason"] == "flight_budget"
    # the budget is checked before each iteration: the last one started below it
    assert r["rows"][-2]["flight_distance_m"] < 1500.0 <= r["rows"][-1]["flight_distance_m"]


class FieldExecutor:
    """One vehicle that, whatever it is asked to fly, samples a smooth field at 300 random
    points (the stop rules see estimates that settle, cheaply)."""

    n_vehicles = 1

    def __init__(self, seed: int = 0, flown_m: dict[int, float] | None = None) -> None:
        self.rng = np.random.default_rng(seed)
        self.flown_m = flown_m or {}
        """What iteration n flew (m; 300 when not given)."""

    def positions(self):
        return [(0.0, 0.0)]

    def fly(self, plans, iteration, *, survey=False):
        from econdor_gcs.core.tasks import FlightReport, SampleLog

        x, y = self.rng.uniform(0.0, 100.0, (2, 300))
        value = 50.0 + 20.0 * np.sin(x / 30.0) * np.cos(y / 40.0) + self.rng.normal(0, 0.01, 300)
        from econdor_gcs.core.tasks import Phase

        phase = Phase.SURVEY if survey else Phase.TRANSIT
        log = SampleLog(np.arange(300) / 10.0, x, y, value, np.full(300, phase, np.int8),
                        np.zeros(300, np.int16))
        flown = self.flown_m.get(iteration, 300.0)
        return [FlightReport(0, log, flown, 0.0, [], float(x[-1]), float(y[-1]), 30.0)]

    def finish(self):
        return []


def _small(**algorithm):
    return load_mission(ROOT / "missions" / "demo.yaml").with_overrides(
        grid_spacing_m=4, **algorithm)


def test_gamma_rule_stops_when_learning_error_levels_off():
    """gamma_n = 3 E_n / (E_n + E_{n-1} + E_{n-2}) within 1 +- lambda (and a stable span)."""
    from econdor_gcs.dfc.loop import Dfc

    dfc = Dfc(_small(stop_lambda=0.05), FieldExecutor())
    dfc.records = [IterationRecord(i, 0, 0, 0, 0.0, e, 0, 0, 0, 0, 500.0 * (i + 1), 0)
                   for i, e in enumerate([math.nan, 1.0, 1.02, 0.99])]
    assert dfc._gamma_converged(50.0, 50.1)  # gamma = 0.99, span moved 0.2 %
    assert not dfc._gamma_converged(50.0, 55.0)  # span still moving
    dfc.records[-1].learning_error = 0.5  # still falling: gamma = 0.6
    assert not dfc._gamma_converged(50.0, 50.1)
    dfc.records = dfc.records[:3]  # fewer than three learning errors: never
    assert not dfc._gamma_converged(50.0, 50.0)


def test_gamma_rule_skips_starved_iterations():
    """The loop gives the rule what each iteration flew (its cumulative flight, less the
    previous row's): iterations that flew a few tens of metres after 500 m ones are not
    read as levelling off, however alike their learning errors."""
    from econdor_gcs.dfc.loop import Dfc

    dfc = Dfc(_small(stop_lambda=0.05), FieldExecutor())
    flown = [500.0, 1000.0, 1500.0, 1550.0, 1610.0, 1660.0]  # 500 m, then 50-60 m each
    dfc.records = [IterationRecord(i, 0, 0, 0, 0.0, e, 0, 0, 0, 0, f, 0)
                   for i, (e, f) in enumerate(zip([math.nan, 1.0, 0.01, 0.0101, 0.0099, 0.01],
                                                  flown, strict=True))]
    assert not dfc._gamma_converged(50.0, 50.1)
    dfc.records[-1].flight_distance_m = 2100.0  # the last one flew its share again
    dfc.records[-1].learning_error = 0.0099
    assert not dfc._gamma_converged(50.0, 50.1)  # 1.0, 0.01, 0.0099: still falling


def test_starved_iterations_do_not_count_against_max_iterations():
    """Iterations that flew under FAIR_SHARE of the largest one (here 20 m after 500 m
    ones) are not counted against ``max_iterations``, at most ``max_starved_iterations``
    of them; 0 counts every iteration."""
    from econdor_gcs.dfc.loop import Dfc

    flown = {1: 500.0, 2: 500.0, 3: 20.0, 4: 20.0, 5: 500.0, 6: 20.0, 7: 500.0, 8: 500.0}

    def iterations(**algorithm):
        result = Dfc(_small(max_iterations=5, min_iterations=1, **algorithm),
                     FieldExecutor(flown_m=flown), planner="no-sg").run()
        assert result.stop_reason == "max_iterations"
        # the summary says how many were not counted
        assert result.summary()["starved_iterations"] == len(result.records) - 1 - 5
        return [r.iteration for r in result.records[1:]]

    assert iterations(max_starved_iterations=0) == [1, 2, 3, 4, 5]
    assert iterations(max_starved_iterations=2) == [1, 2, 3, 4, 5, 6, 7]  # 3 and 4 free
    assert iterations(max_starved_iterations=5) == [1, 2, 3, 4, 5, 6, 7, 8]  # and 6
    # off unless the mission asks (the paper's iteration n); the demo asks for 2
    assert load_mission(ROOT / "missions" / "paper.yaml").algorithm.max_starved_iterations == 0
    assert iterations() == [1, 2, 3, 4, 5, 6, 7]


def test_run_stops_on_the_gamma_rule():
    """Through the whole loop: the run ends with ``learning_error_converged`` at the first
    iteration (>= min_iterations) whose gamma is within 1 +- lambda with a stable span."""
    from econdor_gcs.dfc.loop import Dfc

    lam = 0.3
    result = Dfc(_small(stop_lambda=lam, min_iterations=3, max_iterations=12), FieldExecutor(),
                 planner="no-sg").run()
    assert result.stop_reason == "learning_error_converged" and result.converged
    errs = [r.learning_error for r in result.records[1:]]
    gamma = 3 * errs[-1] / sum(errs[-3:])
    assert abs(gamma - 1.0) <= lam
    assert 3 <= len(result.records) - 1 < 12


def test_run_stalls_when_there_is_nothing_to_fly(monkeypatch):
    """A planner with nothing to fly for max_idle_iterations + 1 iterations: ``stalled``."""
    from econdor_gcs.core.planners import Batch
    from econdor_gcs.dfc import loop as dfc_module

    class Idle:
        name = "idle"

        def initiation(self, context):
            return None  # the mission's diagonals

        def next_batch(self, context):
            return Batch(jobs=[], levels_planned=0)

        def observe(self, learning_error, reports):
            pass

    monkeypatch.setitem(dfc_module.PLANNERS, "idle", lambda mission: Idle())
    result = dfc_module.Dfc(_small(max_iterations=10, min_iterations=1, max_idle_iterations=2),
                            FieldExecutor(), planner="idle").run()
    assert result.stop_reason == "stalled" and not result.converged
    # the initiation, then max_idle_iterations idle iterations recorded; the next one stalls
    assert [r.iteration for r in result.records] == [0, 1, 2]
    assert all(r.learning_error == 0.0 for r in result.records[1:])


def test_lawnmower_initiation_pattern(tmp_path):
    from dataclasses import replace

    from econdor_gcs.config import InitiationConfig
    from econdor_gcs.files.rundir import read_samples

    mission = load_mission(ROOT / "missions" / "demo.yaml")
    mission = replace(mission.with_overrides(max_iterations=1, min_iterations=1),
                      initiation=InitiationConfig("lawnmower", 20.0, 0))
    r = run_seed(mission, 1, "econdor", str(tmp_path))
    n0 = r["rows"][0]["samples"]
    s = read_samples(tmp_path / "runs" / "econdor-1" / "samples.csv")
    x, y = s.x_m[:n0], s.y_m[:n0]
    for line_x in (0, 20, 40, 60, 80, 100):  # every survey line flown end to end
        on = np.abs(x - line_x) < 0.5
        assert y[on].min() < 5 and y[on].max() > 95, line_x
    assert 600 <= r["rows"][0]["flight_distance_m"] <= 1200  # 600 m of lines + transit


def test_cli_study_takes_a_list_of_planners(demo, tmp_path, capsys):
    mission = tmp_path / "m.yaml"
    mission.write_text((ROOT / "missions" / "demo.yaml").read_text().replace(
        "max_iterations: 5", "max_iterations: 1").replace("min_iterations: 3",
                                                          "min_iterations: 1"))
    out = tmp_path / "o"
    assert main(["study", str(mission), "--seeds", "2", "--planner", "lawnmower,adaptive",
                 "--out", str(out), "--workers", "1", "--no-figures", "--quiet"]) == 0
    with (out / "study.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["planner"] for r in rows if r["iteration"] == "0"] == ["lawnmower", "adaptive"]
    assert "isoline_target_m" in rows[0]
    with pytest.raises(SystemExit) as exc:
        main(["study", str(mission), "--planner", "adaptive,nope", "--out", str(out)])
    assert exc.value.code == 2
    assert "unknown planner 'nope'" in capsys.readouterr().err


def test_levels_traced_counts_levels_actually_traced(demo):
    """Levels whose pieces were never found are planned, not traced."""
    from econdor_gcs.dfc.loop import Dfc

    mission = demo.with_overrides(max_iterations=1, min_iterations=1, search_radius_m=0.5)
    field = mission.build_field(1)
    res = Dfc(mission, InProcessExecutor(mission, field, seed=1), planner="no-sg", truth=field,
              seed=1).run()
    rec = res.records[1]
    assert rec.levels_planned == len(rec.levels) == 3  # three levels sent out
    assert rec.outcomes["not_found"] >= 1  # a 0.5 m search misses pieces
    assert 0 < rec.levels_traced < 3  # one level had no piece found: not traced


def test_samples_of_a_run_still_writing_are_read_up_to_the_last_whole_line(tmp_path):
    from econdor_gcs.files.rundir import SAMPLE_COLUMNS, read_samples

    path = tmp_path / "samples.csv"
    values = {"t_s": "1.5", "x_m": "2", "y_m": "3", "value": "4.25", "phase": "2",
              "vehicle": "0", "iteration": "1"}
    row = ",".join(values[c] for c in SAMPLE_COLUMNS)
    path.write_text(",".join(SAMPLE_COLUMNS) + "\n" + row + "\n" + row + "\n" + "3.0,4.",
                    encoding="utf-8")
    s = read_samples(path)
    assert len(s) == 2 and s.phase.tolist() == [2, 2] and s.value.tolist() == [4.25, 4.25]


def _survey_mission(vehicles: dict | None = None, **lawnmower) -> Mission:
    """The paper mission (8 iterations) flying one survey given by ``lawnmower``."""
    import yaml

    from econdor_gcs.config import parse_mission

    raw = yaml.safe_load((ROOT / "missions" / "paper.yaml").read_text(encoding="utf-8"))
    raw["algorithm"]["planner"] = "lawnmower"
    raw["lawnmower"] = lawnmower
    raw["vehicles"].update(vehicles or {})
    return parse_mission(raw, base_dir=ROOT / "missions")


def test_a_survey_sized_by_its_budget_ends_done_and_books_no_way_home(tmp_path):
    """In a mission of 8 iterations, a survey sized by ``lawnmower.budget_m`` is one row of
    study.csv and the run stops because the survey is complete (not after empty iterations,
    ``stalled``); the flight home is in no row and not in ``flight_distance_m``, so the
    summary, its median and the row agree."""
    mission = _survey_mission(budget_m=1100.0)
    assert mission.algorithm.max_iterations == 8
    summary = run_study(mission, [0], ["lawnmower"], tmp_path, workers=1, figures=False)
    with (tmp_path / "study.csv").open() as f:
        rows = list(csv.DictReader(f))
    run = summary["runs"][0]
    assert [int(r["iteration"]) for r in rows] == [0]
    assert run["stop_reason"] == "planner_done"
    flown = float(rows[0]["flight_distance_m"])
    assert 900.0 < flown <= 1100.0
    assert run["flight_distance_m"] == pytest.approx(flown)
    assert summary["by_planner"]["lawnmower"]["median_flight_distance_m"] == pytest.approx(flown)
    assert run["return_m"] > 100.0  # 9 lines end in the far corner
    assert run["total_flown_m"] == pytest.approx(flown + run["return_m"])
    assert int(rows[0]["samples"]) < run["samples"]  # the flight home sampled too, in no row


@pytest.mark.parametrize(("budget_m", "vehicles"), [
    (1000.0, {}), (2000.0, {}), (4000.0, {}),
    (2000.0, {"speed_mps": 12.0, "max_accel_mps2": 3.0, "max_turn_rate_dps": 90.0}),
])
def test_a_survey_sized_by_its_budget_flies_within_it(budget_m, vehicles):
    """The line-count rule counts the turns (the vehicle overshoots every corner): the
    survey flies within ``budget_m``, and not much less (the turns are charged, at most,
    twice what the vehicle flies beyond its corners)."""
    from econdor_gcs.dfc.loop import Dfc

    mission = _survey_mission(vehicles, budget_m=budget_m)
    field = mission.build_field(0)
    result = Dfc(mission, InProcessExecutor(mission, field, seed=0), planner="lawnmower",
                 truth=field, seed=0).run()
    flown = result.records[0].flight_distance_m
    assert 0.85 * budget_m < flown <= budget_m


def test_a_survey_of_given_lines(tmp_path):
    from econdor_gcs.dfc.loop import Dfc
    from econdor_gcs.errors import MissionError

    mission = _survey_mission(lines=12)
    field = mission.build_field(0)
    result = Dfc(mission, InProcessExecutor(mission, field, seed=0), planner="lawnmower",
                 truth=field, seed=0).run()
    assert len(result.records) == 1 and result.stop_reason == "planner_done"
    s = result.samples
    n = result.records[0].samples
    ends = np.sign(s.y_m[:n] - 50.0)[np.abs(s.y_m[:n] - 50.0) > 45.0]  # -1 south, +1 north
    assert np.count_nonzero(np.diff(ends)) == 12  # one end-to-end passage per line
    with pytest.raises(MissionError, match="lawnmower.lines: give lines or budget_m"):
        _survey_mission(lines=12, budget_m=2000.0)
    with pytest.raises(MissionError, match="lawnmower.lines"):
        _survey_mission(lines=1)
    with pytest.raises(MissionError, match="lawnmower.budget_m: 250 m holds no survey"):
        Dfc(_survey_mission(budget_m=250.0), InProcessExecutor(mission, field), planner="lawnmower")
