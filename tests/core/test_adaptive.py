"""The adaptive planner: uncertainty, candidates, greedy selection, threshold mapping, and
whole runs through the DFC loop with the real onboard tracer."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from econdor_gcs.config import load_mission
from econdor_gcs.core.adaptive import (
    AdaptiveParams,
    AdaptivePlanner,
    adaptive_planner,
    greedy_plan,
    perimeter_batch,
    sweep_spacing_m,
)
from econdor_gcs.core.assignment import assign_jobs
from econdor_gcs.core.candidates import (
    Candidate,
    CandidateKind,
    contour_candidates,
    extremum_probes,
    level_crossings,
    line_candidates,
    mark_crossings,
    probe_reach,
    sweep_candidates,
)
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.planners import PlanContext
from econdor_gcs.core.tasks import Phase, SampleLog, TraceTask, Waypoint
from econdor_gcs.core.uncertainty import (
    Footprints,
    UncertaintyMap,
    expected_error,
    resample_polyline,
)
from econdor_gcs.dfc import loop as dfc
from econdor_lab.inprocess import InProcessExecutor

ROOT = Path(__file__).resolve().parents[2]
REGION = Region(0, 100, 0, 100)
GRID = Grid(REGION, 101, 101)
PLAN = Grid.with_spacing(REGION, 2.0)


def uniform_map(variance: np.ndarray | None = None) -> UncertaintyMap:
    xx, yy = PLAN.mesh
    n = xx.size
    v = np.ones(n) if variance is None else variance
    return UncertaintyMap(xx.ravel(), yy.ravel(), v, np.ones(n), np.zeros(n), "proxy", 5.0,
                          None, PLAN)


def mae_value(umap: UncertaintyMap):
    return lambda var, near, cells: expected_error(umap.amplitude[cells], var, 2.0)


def samples_along(points: list[tuple[float, float]], field, step_m: float = 0.8) -> SampleLog:
    xs, ys = [], []
    for (ax, ay), (bx, by) in zip(points[:-1], points[1:], strict=True):
        n = max(2, int(math.hypot(bx - ax, by - ay) / step_m))
        xs.append(np.linspace(ax, bx, n))
        ys.append(np.linspace(ay, by, n))
    x, y = np.concatenate(xs), np.concatenate(ys)
    return SampleLog(np.arange(x.size) * 0.1, x, y, np.asarray(field(x, y), dtype=float),
                     np.full(x.size, Phase.SURVEY, dtype=np.int8), np.zeros(x.size, np.int16))


def after_diagonals(seed: int, positions: list[tuple[float, float]], budget_left_m: float
                    ) -> PlanContext:
    """The context of iteration 1 on plume field ``seed``: the diagonals flown."""
    from econdor_gcs.core.spline import reconstruct

    field = load_mission(ROOT / "missions" / "plume.yaml").build_field(seed)
    s = samples_along([(0, 0), (100, 100), (100, 0), (0, 100)], field)
    est = reconstruct(s.x_m, s.y_m, s.value, GRID)
    return PlanContext(iteration=1, region=REGION, n_vehicles=len(positions), grid=GRID,
                       estimate=est, samples=s, positions_m=positions,
                       budget_left_m=budget_left_m)


def test_contour_pieces_are_cut_and_oriented_for_the_tracer():
    xx, _ = GRID.mesh
    ramp = xx.copy()  # g = x: iso-lines run north-south, higher values to the east
    cands = contour_candidates(ramp, GRID, np.array([30.0, 70.0]), piece_m=30.0, min_piece_m=4.0)
    assert len(cands) == 8  # two 100 m lines, four pieces each
    for c in cands:
        assert c.kind == CandidateKind.TRACE and c.length_m <= 30.0 + 1e-6
        # the tracer keeps higher values on its left: walking a g = x line means going south
        assert c.points_m[0, 1] > c.points_m[-1, 1]


def test_greedy_flies_where_the_uncertainty_is_and_keeps_to_the_budget():
    var = np.ones(PLAN.nx * PLAN.ny)
    xx, _ = PLAN.mesh
    var[xx.ravel() < 50] = 0.01  # the west half is known already
    umap = uniform_map(var)
    cands = line_candidates(REGION, 2.0, "ns")
    picks, after = greedy_plan(cands, Footprints(umap, [c.points_m for c in cands]), var,
                               mae_value(umap), [(50.0, 0.0)], [350.0])
    route = picks[0]
    assert 2 <= len(route) <= 3
    assert all(p.path_m[0, 0] > 50 for p in route)  # only the uncertain east half
    flown = sum(p.transit_m + p.candidate.length_m for p in route)
    assert flown <= 350.0
    assert after.sum() < var.sum()


def test_redundancy_is_judged_in_space():
    umap = uniform_map()
    leg = np.array([[20.0, 50.0], [50.0, 50.0]])
    twins = [Candidate(CandidateKind.LEG, leg, reversible=True),
             Candidate(CandidateKind.LEG, leg + [0.0, 0.5], reversible=True),
             Candidate(CandidateKind.LEG, leg + [40.0, 30.0], reversible=True)]
    # room for two of them: the second is the far leg, not the twin of the first
    picks, _ = greedy_plan(twins, Footprints(umap, [c.points_m for c in twins]), umap.variance,
                           mae_value(umap), [(20.0, 50.0)], [100.0])
    chosen = [p.candidate for p in picks[0]]
    assert len(chosen) == 2 and chosen[1] is twins[2]


def test_the_fleet_shares_the_work():
    umap = uniform_map()
    cands = line_candidates(REGION, 4.0, "ns")
    picks, _ = greedy_plan(cands, Footprints(umap, [c.points_m for c in cands]), umap.variance,
                           mae_value(umap), [(0.0, 0.0), (100.0, 0.0)], [300.0, 300.0])
    assert len(picks[0]) >= 2 and len(picks[1]) >= 2
    assert np.mean([p.path_m[0, 0] for p in picks[0]]) < np.mean([p.path_m[0, 0] for p in picks[1]])


def test_planner_routes_its_jobs_and_the_assignment_keeps_them():
    ctx = after_diagonals(0, [(0.0, 100.0), (100.0, 0.0)], 5000.0)
    batch = adaptive_planner(AdaptiveParams(batch_m=300.0)).next_batch(ctx)
    assert batch.jobs and all(j.vehicle in (0, 1) for j in batch.jobs)
    plans = assign_jobs(batch.jobs, ctx.positions_m, first_piece_id=7000)
    for v in (0, 1):  # each vehicle flies its own jobs, in the planner's order
        expected = [t for j in batch.jobs if j.vehicle == v for t in j.tasks]
        assert len(plans[v]) == len(expected)
        for got, want in zip(plans[v], expected, strict=True):
            assert type(got) is type(want) and (got.x_m, got.y_m) == (want.x_m, want.y_m)
    ids = [t.piece_id for plan in plans for t in plan if isinstance(t, TraceTask)]
    assert ids == sorted(set(ids)) and (not ids or ids[0] == 7000)
    # never more than the batch, except the first pick of a vehicle
    for v in (0, 1):
        assert sum(j.length_m for j in batch.jobs if j.vehicle == v) <= 300.0 + 150.0


def test_trace_tasks_carry_their_estimated_contour_for_stock_autopilots():
    """A vehicle without the tracer flies a contour piece as its waypoint polyline: every
    trace task of the adaptive planner carries its route, from its start point."""
    from econdor_gcs.core.waypoints import task_waypoints

    ctx = after_diagonals(0, [(0.0, 100.0), (100.0, 0.0)], 5000.0)
    batch = adaptive_planner(AdaptiveParams(batch_m=300.0)).next_batch(ctx)
    traces = [t for j in batch.jobs for t in j.tasks if isinstance(t, TraceTask)]
    assert traces
    for t in traces:
        assert len(t.route_m) >= 2 and t.route_m[0] == (t.x_m, t.y_m)
        wps = task_waypoints(t, 1.0)
        assert (wps[0].x_m, wps[0].y_m) == (t.x_m, t.y_m)


def test_planner_never_plans_beyond_the_budget_left():
    ctx = after_diagonals(1, [(0.0, 100.0)], 120.0)
    batch = adaptive_planner().next_batch(ctx)
    assert len(batch.jobs) == 1  # one pick may overrun a tiny remainder; no second one


def test_perimeter_is_split_over_the_fleet():
    ctx = PlanContext(iteration=0, region=REGION, n_vehicles=3)
    batch = perimeter_batch(ctx)
    assert [j.vehicle for j in batch.jobs] == [0, 1, 2]
    assert batch.survey_m == pytest.approx(4 * 99.0, rel=1e-6)
    assert all(isinstance(t, Waypoint) for j in batch.jobs for t in j.tasks)


def test_threshold_mode_is_done_when_nothing_straddles():
    """A constant field far from the level, sampled everywhere: nowhere to look."""
    pts = []
    for x in np.arange(0.0, 100.1, 5.0):
        pts += [(x, 0.0), (x, 100.0)] if int(x / 5) % 2 == 0 else [(x, 100.0), (x, 0.0)]
    s = samples_along(pts, lambda x, y: np.full(np.shape(x), 10.0) + 0.01 * np.asarray(x))
    est = np.full(GRID.shape, 10.0) + 0.01 * GRID.mesh[0]
    ctx = PlanContext(iteration=3, region=REGION, n_vehicles=1, grid=GRID, estimate=est,
                      samples=s, positions_m=[(0.0, 0.0)])
    planner = adaptive_planner(AdaptiveParams(target_levels=(55.0,)))
    batch = planner.next_batch(ctx)
    assert batch.done and not batch.jobs and planner.open_cells == 0
    # the same with a gap nobody flew: not done
    far = SampleLog(s.t_s[s.x_m < 60], s.x_m[s.x_m < 60], s.y_m[s.x_m < 60],
                    s.value[s.x_m < 60], s.phase[s.x_m < 60], s.vehicle[s.x_m < 60])
    ctx2 = PlanContext(iteration=3, region=REGION, n_vehicles=1, grid=GRID, estimate=est,
                       samples=far, positions_m=[(0.0, 0.0)])
    batch2 = adaptive_planner(AdaptiveParams(target_levels=(55.0,))).next_batch(ctx2)
    assert not batch2.done and batch2.jobs
    assert all(t.x_m > 40 for j in batch2.jobs for t in j.tasks)


def test_adaptive_is_registered_and_configured_from_the_mission():
    m = load_mission(ROOT / "missions" / "threshold.yaml")
    planner = dfc.build_planner("adaptive", m)
    assert isinstance(planner, AdaptivePlanner)
    assert planner.params.target_levels == (55.0,)
    assert planner.params.model == "gp" and planner.params.fit_length  # "auto"
    with pytest.raises(ValueError, match="model"):
        adaptive_planner(AdaptiveParams(model="nope"))


@pytest.mark.slow
def test_adaptive_run_maps_a_plume_field_to_a_stated_error():
    """A whole in-process run with the real tracer: 3 km of flight on plume seed 3 (the
    16-line survey start, 1.7 km, then adaptive plans)."""
    m = load_mission(ROOT / "missions" / "plume.yaml").with_overrides(flight_budget_m=3000.0)
    field = m.build_field(3)
    flown: list[type] = []

    def progress(event: dfc.DfcEvent) -> None:
        if isinstance(event, dfc.IterationPlanned):
            flown.extend(type(t) for plan in event.plans for t in plan)

    result = dfc.Dfc(m, InProcessExecutor(m, field, seed=3), planner="adaptive", truth=field,
                     seed=3, progress=progress).run()
    assert result.stop_reason == "flight_budget"
    assert 3000.0 <= result.flight_distance_m < 3000.0 + 400.0  # the way home not counted
    print(f"plume seed 3: {result.records[0].mae_db:.1f} dB after the survey start, "
          f"{result.records[-1].mae_db:.1f} dB at 3 km")
    assert result.records[-1].mae_db < -25.0
    assert result.records[-1].mae_db < result.records[0].mae_db - 10.0
    # ordinary mission items: trace tasks (traced onboard) and waypoint legs
    assert set(flown) == {TraceTask, Waypoint}


@pytest.mark.slow
def test_threshold_study_finds_every_piece_and_stops_when_nothing_is_left(tmp_path):
    """``econdor study missions/threshold.yaml``: the diagonals miss pieces of the iso-line at
    55; the planner finds them, traces them and stops (``planner_done``) before the budget
    does; study.csv reports the iso-line error at the target and the pieces missed."""
    import csv
    import json

    from econdor.cli import main

    out = tmp_path / "study"
    assert main(["study", str(ROOT / "missions" / "threshold.yaml"), "--seeds", "5",
                 "--planner", "adaptive", "--out", str(out), "--workers", "1", "--no-figures",
                 "--quiet"]) == 0
    run = json.loads((out / "summary.json").read_text())["runs"][0]
    assert run["stop_reason"] == "planner_done"
    assert run["flight_distance_m"] < 3000.0  # the budget did not stop it (the way home apart)
    assert run["isoline_error_m"]["target@55"] == run["isoline_error_m"]["target"] < 0.5
    with (out / "study.csv").open() as f:
        rows = list(csv.DictReader(f))
    first, last = rows[0], rows[-1]
    assert float(first["isoline_target_missed"]) >= 1  # the diagonals alone miss a piece
    assert float(first["isoline_target_m"]) > 2.0
    assert float(last["isoline_target_missed"]) == 0
    assert float(last["isoline_target_m"]) < 0.5
    errors = [float(r["isoline_target_m"]) for r in rows]
    assert all(e == e for e in errors)  # a number in every row, never NaN


def test_level_crossings_come_from_survey_and_transit_samples_only():
    x = np.arange(0.0, 10.0, 0.5)
    value = x.copy()  # crosses 4.25 once, between x = 4.0 and 4.5
    for phase, found in ((Phase.SURVEY, 1), (Phase.TRANSIT, 1), (Phase.TRACE, 0)):
        s = SampleLog(x, x, np.zeros_like(x), value, np.full(x.size, phase, dtype=np.int8),
                      np.zeros(x.size, np.int16))
        pts, lv = level_crossings(s, np.array([4.25, 50.0]))
        assert len(pts) == found and lv.tolist() == [4.25] * found
        if found:
            assert pts[0].tolist() == pytest.approx([4.25, 0.0])
    # consecutive samples of two vehicles, or far apart, do not make a crossing
    two = SampleLog(x, x, np.zeros_like(x), value, np.full(x.size, Phase.SURVEY, dtype=np.int8),
                    (x > 4.2).astype(np.int16))
    assert len(level_crossings(two, np.array([4.25]))[0]) == 0
    # survey samples 0.5 m apart: a pair farther apart than max_step_m is no crossing
    survey = SampleLog(x, x, np.zeros_like(x), value, np.full(x.size, Phase.SURVEY, np.int8),
                       np.zeros(x.size, np.int16))
    assert len(level_crossings(survey, np.array([4.25]), max_step_m=1.0)[0]) == 1
    assert len(level_crossings(survey, np.array([4.25]), max_step_m=0.1)[0]) == 0
    # a sample exactly on the level: one crossing there (the pair arriving at it)
    on = level_crossings(survey, np.array([4.0]))[0]
    assert on.tolist() == [[4.0, 0.0]]


def test_crossings_first_traces_a_sampled_crossing_before_anything_else():
    """A ring iso-line crossed by one survey leg: its component is picked first, entered at
    the crossing; once traced there it is an ordinary candidate again."""
    xx, yy = GRID.mesh
    def field(x, y):
        return 100.0 * np.exp(-((np.asarray(x) - 70) ** 2 + (np.asarray(y) - 30) ** 2) / 200.0)

    est = field(xx, yy)
    s = samples_along([(0.0, 30.0), (100.0, 30.0)], field)  # west-east through the bump
    ring = contour_candidates(est, GRID, np.array([50.0]), 30.0, 4.0, whole=True)
    assert len(ring) == 1 and ring[0].closed
    marked = mark_crossings(ring, s, np.array([50.0]), band_m=3.0)
    c = marked[0]
    assert c.first and c.entry_m is not None
    assert abs(c.entry_m[1] - 30.0) < 1e-9 and abs(abs(c.entry_m[0] - 70.0) - 11.77) < 0.1
    umap = uniform_map()
    legs = line_candidates(REGION, 4.0, "ns")
    cands = [*legs, c]
    picks, _ = greedy_plan(cands, Footprints(umap, [k.points_m for k in cands]), umap.variance,
                           mae_value(umap), [(0.0, 0.0)], [400.0])
    assert picks[0][0].candidate is c  # before every line the greedy would prefer
    batch = adaptive_planner()._batch(picks, np.array([50.0]))
    first = batch.jobs[0].tasks[0]
    assert isinstance(first, TraceTask) and (first.x_m, first.y_m) == tuple(c.entry_m)
    assert first.max_length_m == pytest.approx(max(2 * c.length_m, 60.0))  # capped
    # traced (samples of the TRACE phase along the ring): no longer first
    loop = ring[0].points_m
    n = len(loop)
    traced = SampleLog(np.r_[s.t_s, 100.0 + np.arange(n)], np.r_[s.x_m, loop[:, 0]],
                       np.r_[s.y_m, loop[:, 1]], np.r_[s.value, np.full(n, 50.0)],
                       np.r_[s.phase, np.full(n, Phase.TRACE)].astype(np.int8),
                       np.r_[s.vehicle, np.zeros(n)].astype(np.int16))
    again = mark_crossings(contour_candidates(est, GRID, np.array([50.0]), 30.0, 4.0, whole=True),
                           traced, np.array([50.0]), band_m=3.0)
    assert not any(k.first for k in again)


def test_traces_through_crossings_go_before_probes_even_when_a_probe_is_nearer():
    """Of the candidates that go first, a trace through a sampled crossing (the iso-line is
    there) is picked before a probe (it may be), whatever the distances; ``nearest`` picks
    the nearest. With room for one only (the first pick may overrun the batch), that one is
    the whole plan; with room for both, both are flown, in the order with less transit."""
    ring = Candidate(CandidateKind.TRACE, np.array([[80.0, 80.0], [90.0, 80.0], [90.0, 90.0],
                                                    [80.0, 90.0], [80.0, 80.0]]),
                     closed=True, level=50.0, first=True)
    probe = Candidate(CandidateKind.LEG, np.array([[5.0, 0.0], [5.0, 20.0]]), reversible=True,
                      first=True)
    umap = uniform_map()
    cands = [probe, ring]
    fp = Footprints(umap, [k.points_m for k in cands])
    for order, head in ((True, ring), (False, probe)):
        picks, _ = greedy_plan(cands, fp, umap.variance, mae_value(umap), [(0.0, 0.0)], [30.0],
                               traces_before_legs=order)
        assert [p.candidate for p in picks[0]] == [head]
        picks, _ = greedy_plan(cands, fp, umap.variance, mae_value(umap), [(0.0, 0.0)], [400.0],
                               traces_before_legs=order)
        assert [p.candidate for p in picks[0]] == [probe, ring]


def test_threshold_planner_is_not_done_while_a_sampled_crossing_is_untraced():
    """Every cell closed (``band_m`` covers the area), but a survey leg crossed the ring
    iso-line and no trace has flown it: the planner traces it before it says ``done``;
    once it is traced, it is done."""
    def field(x, y):
        return 100.0 * np.exp(-((np.asarray(x) - 70) ** 2 + (np.asarray(y) - 30) ** 2) / 200.0)

    xx, yy = GRID.mesh
    est = field(xx, yy)
    s = samples_along([(0.0, 30.0), (100.0, 30.0)], field)
    params = AdaptiveParams(target_levels=(50.0,), band_m=1000.0, model="proxy", probes=False)
    planner = adaptive_planner(params)

    def ctx(samples: SampleLog) -> PlanContext:
        return PlanContext(iteration=1, region=REGION, n_vehicles=1, grid=GRID, estimate=est,
                           samples=samples, positions_m=[(100.0, 30.0)])

    batch = planner.next_batch(ctx(s))
    assert planner.open_cells == 0 and not batch.done
    task = batch.jobs[0].tasks[0]
    assert isinstance(task, TraceTask) and task.level == 50.0
    loop = contour_candidates(est, GRID, np.array([50.0]), 30.0, 4.0, whole=True)[0].points_m
    n = len(loop)
    traced = SampleLog(np.r_[s.t_s, 100.0 + np.arange(n)], np.r_[s.x_m, loop[:, 0]],
                       np.r_[s.y_m, loop[:, 1]], np.r_[s.value, np.full(n, 50.0)],
                       np.r_[s.phase, np.full(n, Phase.TRACE)].astype(np.int8),
                       np.r_[s.vehicle, np.zeros(n)].astype(np.int16))
    after = planner.next_batch(ctx(traced))
    assert after.done and not after.jobs


def _survey(xs: list[float], field) -> SampleLog:
    pts: list[tuple[float, float]] = []
    for i, x in enumerate(xs):
        pts += [(x, 0.0), (x, 100.0)] if i % 2 == 0 else [(x, 100.0), (x, 0.0)]
    return samples_along(pts, field)


def test_threshold_coverage_floor_is_measured_in_metres_not_through_the_model():
    """A smooth plane far below the level: the GP fits a length of ~100 m, so its variance
    is small everywhere; still, with lines 30 m apart, places 15 m from every sample are
    farther than ``explore_m`` (10 m) and the planner flies there before it is done. Lines
    8 m apart leave nothing farther than 4 m: done."""
    def plane(x, y):
        return 10.0 + 0.1 * np.asarray(x) + 0.0 * np.asarray(y)

    xx, yy = GRID.mesh
    assert AdaptiveParams().explore_m < 15.0
    for xs, done in (([15.0, 45.0, 75.0], False), (list(np.arange(4.0, 100.0, 8.0)), True)):
        planner = adaptive_planner(AdaptiveParams(target_levels=(50.0,)))
        batch = planner.next_batch(PlanContext(
            iteration=1, region=REGION, n_vehicles=1, grid=GRID, estimate=plane(xx, yy),
            samples=_survey(xs, plane), positions_m=[(50.0, 50.0)]))
        assert planner.hyper is not None and planner.hyper.length_m > 50.0
        assert batch.done is done and (planner.open_cells == 0) is done
        if not done:  # the first leg goes through a gap between two lines
            (x0, _), (x1, _) = batch.jobs[0].start_m, batch.jobs[0].end_m
            far = planner.params.explore_m
            assert min(abs(x0 - x) for x in xs) > far or min(abs(x1 - x) for x in xs) > far


def test_threshold_planner_is_done_when_no_flight_would_lower_what_is_left(monkeypatch):
    """Open cells are left, but the greedy finds no candidate that would lower their score
    (at the area's edge the model can know more than a pass 0.5 m inside adds): the
    planner says ``done`` instead of planning nothing until the run stalls (``explore:
    legs``; with ``lines`` what is left once every place is covered is planned so too)."""
    from econdor_gcs.core.adaptive import base

    def plane(x, y):
        return 10.0 + 0.1 * np.asarray(x) + 0.0 * np.asarray(y)

    xx, yy = GRID.mesh
    ctx = PlanContext(iteration=1, region=REGION, n_vehicles=1, grid=GRID,
                      estimate=plane(xx, yy), samples=_survey([50.0], plane),
                      positions_m=[(50.0, 100.0)])
    planner = adaptive_planner(AdaptiveParams(target_levels=(50.0,), explore="legs"))
    batch = planner.next_batch(ctx)
    assert planner.open_cells > 0 and batch.jobs and not batch.done
    monkeypatch.setattr(base, "greedy_plan",  # the greedy of the plan both planners share
                        lambda cands, fp, var, *a, **k: ([[]], var))
    batch = planner.next_batch(ctx)
    assert planner.open_cells > 0 and not batch.jobs and batch.done


def _peak(cx: float, cy: float, height: float, sigma: float = 4.0):
    def field(x, y):
        r2 = (np.asarray(x) - cx) ** 2 + (np.asarray(y) - cy) ** 2
        return 10.0 + height * np.exp(-r2 / (2 * sigma ** 2))
    return field


def _join(*logs: SampleLog) -> SampleLog:
    t0 = 0.0
    cols: dict[str, list[np.ndarray]] = {k: [] for k in ("t_s", "x_m", "y_m", "value", "phase",
                                                         "vehicle")}
    for log in logs:
        for k in cols:
            cols[k].append(getattr(log, k) + (t0 if k == "t_s" else 0))
        t0 += 1000.0
    return SampleLog(*(np.concatenate(cols[k]) for k in ("t_s", "x_m", "y_m", "value", "phase",
                                                           "vehicle")))


def test_a_peak_beside_the_track_is_probed_across_it():
    """A line passes 10 m from a peak that reaches the level: the samples peak where the
    line is closest, and the probe crosses the track there, over the peak."""
    field = _peak(50.0, 40.0, 90.0)
    line = samples_along([(0.0, 50.0), (100.0, 50.0)], field)
    probes = extremum_probes(line, np.array([55.0]), REGION, 30.0, 1e-4, 3.0)
    assert len(probes) == 1
    p = probes[0]
    assert p.first and p.kind == CandidateKind.LEG and p.reversible
    assert np.allclose(p.points_m[:, 0], 50.0, atol=0.5)  # across the west-east track
    assert sorted(p.points_m[:, 1].tolist()) == pytest.approx([35.0, 65.0], abs=0.5)
    # a minimum above the level is probed the same way; a maximum above it is a crossing
    dip = samples_along([(0.0, 50.0), (100.0, 50.0)],
                        lambda x, y: 110.0 - _peak(50.0, 40.0, 90.0)(x, y) + 10.0)
    assert len(extremum_probes(dip, np.array([55.0]), REGION, 30.0, 1e-4, 3.0)) == 1
    over = samples_along([(0.0, 40.0), (100.0, 40.0)], field)
    assert extremum_probes(over, np.array([55.0]), REGION, 30.0, 1e-4, 3.0) == []
    # with nothing to reach (the level below the maximum seen) or nothing standing out
    assert extremum_probes(line, np.array([5.0]), REGION, 30.0, 1e-4, 3.0) == []
    far = samples_along([(0.0, 99.0), (100.0, 99.0)], _peak(50.0, 10.0, 90.0, sigma=3.0))
    assert np.ptp(far.value) < 1e-12  # nothing there to stand out
    assert extremum_probes(far, np.array([55.0]), REGION, 30.0, 1e-4, 3.0) == []


def test_a_peak_that_cannot_reach_the_level_within_the_probe_is_not_probed():
    """probe_reach: a sharp peak 10 m beside the line can rise to the level within the
    probe; a broad low bump, as flat across as along, cannot (55 is far above its top)."""
    levels = np.array([55.0])
    sharp = samples_along([(0.0, 50.0), (100.0, 50.0)], _peak(50.0, 40.0, 90.0))
    broad = samples_along([(0.0, 50.0), (100.0, 50.0)], _peak(50.0, 40.0, 20.0, sigma=15.0))
    for flown in (sharp, broad):
        assert len(extremum_probes(flown, levels, REGION, 30.0, 1e-4, 3.0)) == 1
    assert len(extremum_probes(sharp, levels, REGION, 30.0, 1e-4, 3.0, reach=1.5)) == 1
    assert extremum_probes(broad, levels, REGION, 30.0, 1e-4, 3.0, reach=1.5) == []
    # the bound itself: the broad bump's top (30) is within it, the level is not
    j = int(np.argmax(broad.value))
    prominence = broad.value[j] - max(broad.value[0], broad.value[-1])
    top = broad.value[j] + probe_reach(broad, np.arange(len(broad)), j, 1.0, prominence, 15.0)
    assert 30.0 - 1.0 < top < 55.0


def test_probing_climbs_to_the_peak_and_stops_there():
    """A peak short of the level: the first probe finds the peak's row, the second (parallel
    to the first line) runs through the peak, and there the climb ends (the extremum of
    the second was sampled across by the first)."""
    field = _peak(50.0, 40.0, 40.0)  # 50 at the top, the level 55 is never reached
    levels = np.array([55.0])
    flown = samples_along([(0.0, 52.0), (100.0, 52.0)], field)
    seen = []
    for _ in range(4):
        probes = extremum_probes(flown, levels, REGION, 30.0, 1e-4, 3.0)
        seen.append(len(probes))
        if not probes:
            break
        a, b = probes[0].points_m
        flown = _join(flown, samples_along([tuple(a), tuple(b)], field))
    assert seen == [1, 1, 0]
    # without the climb (probe_climb: false) the first probe's own extremum is not probed
    first = extremum_probes(samples_along([(0.0, 52.0), (100.0, 52.0)], field), levels, REGION,
                            30.0, 1e-4, 3.0)[0].points_m
    after_first = _join(samples_along([(0.0, 52.0), (100.0, 52.0)], field),
                        samples_along([tuple(first[0]), tuple(first[1])], field))
    assert len(extremum_probes(after_first, levels, REGION, 30.0, 1e-4, 3.0)) == 1
    assert extremum_probes(after_first, levels, REGION, 30.0, 1e-4, 3.0, not_on=[first]) == []
    # the second probe ran west-east through the peak
    assert np.min(np.hypot(flown.x_m - 50.0, flown.y_m - 40.0)) < 0.5


def test_threshold_mode_flies_its_probes_first():
    """After the diagonals on plume seed 1 (both pieces of the iso-line at 55 missed) the
    plan starts with a probe across a diagonal; without probes it does not."""
    ctx = after_diagonals(1, [(0.0, 100.0)], 5000.0)
    with_probes = adaptive_planner(AdaptiveParams(target_levels=(55.0,))).next_batch(ctx)
    first = with_probes.jobs[0]
    assert all(isinstance(t, Waypoint) for t in first.tasks)
    a, b = (np.array((t.x_m, t.y_m)) for t in first.tasks)
    d = b - a
    # a diagonal runs along (1, 1) or (1, -1): a probe across it along the other one
    assert abs(abs(d[0]) - abs(d[1])) < 1.0 and 25.0 < np.hypot(*d) <= 30.0 + 1e-6
    probes = extremum_probes(ctx.samples, np.array([55.0]), REGION, 30.0, 1e-4, 3.0)
    assert any(np.allclose(sorted(map(tuple, p.points_m)), sorted([tuple(a), tuple(b)]))
               for p in probes)
    without = adaptive_planner(AdaptiveParams(target_levels=(55.0,), probes=False)).next_batch(ctx)
    assert [j.start_m for j in without.jobs] != [j.start_m for j in with_probes.jobs]


@pytest.mark.parametrize("at_end", [True, False], ids=["probes-at-end", "stop"])
def test_threshold_mode_flies_the_probes_left_at_the_end_only_when_asked(at_end):
    """No cell left to score (the coverage floor set beyond the area, an estimate far from
    the level) after a line beside a peak short of it: a probe is still on offer. By
    default it is flown before ``done``; ``probes_at_end: false`` stops there. A sampled
    crossing left untraced is traced either way (the iso-line is known to be there)."""
    field = _peak(50.0, 40.0, 40.0)  # 50 at the top: the level 55 is never reached
    flown = samples_along([(0.0, 52.0), (100.0, 52.0)], field)
    assert extremum_probes(flown, np.array([55.0]), REGION, 30.0, 1e-4, 3.0)
    xx, yy = GRID.mesh
    params = AdaptiveParams(target_levels=(55.0,), explore_m=200.0, model="proxy",
                            probes_at_end=at_end)
    ctx = PlanContext(iteration=1, region=REGION, n_vehicles=1, grid=GRID,
                      estimate=np.full(xx.shape, 10.0), samples=flown,
                      positions_m=[(100.0, 52.0)])
    planner = adaptive_planner(params)
    batch = planner.next_batch(ctx)
    assert planner.open_cells == 0
    assert batch.done != at_end
    if at_end:  # the probe: across the line, through the peak's row
        a, b = (np.array((t.x_m, t.y_m)) for t in batch.jobs[0].tasks)
        assert abs(a[0] - 50.0) < 1.0 and abs(b[0] - 50.0) < 1.0 and abs(a[1] - b[1]) > 25.0
    # the crossing rule stands: the ring at 50 on a field that reaches it, crossed by the
    # line and untraced, is traced before done with the probes off too
    ring = _peak(50.0, 52.0, 80.0, sigma=10.0)
    crossed = samples_along([(0.0, 52.0), (100.0, 52.0)], ring)
    crossing = adaptive_planner(dataclasses.replace(params, target_levels=(50.0,))).next_batch(
        dataclasses.replace(ctx, estimate=ring(xx, yy), samples=crossed))
    assert not crossing.done and isinstance(crossing.jobs[0].tasks[0], TraceTask)


def test_a_whole_piece_at_the_edge_is_entered_at_an_end_or_at_its_crossing():
    """A straight iso-line across the area: one whole candidate, 2 m inside the edges at
    both ends, flown from either end; through a sampled crossing it goes first, entered
    at the crossing (``open_entry: crossing``) or still at an end (``end``)."""
    xx, _ = GRID.mesh
    est = xx.astype(float)  # the iso-line at 40 is the line x = 40
    (c,) = contour_candidates(est, GRID, np.array([40.0]), 30.0, 4.0, whole=True)
    assert c.whole and not c.closed and c.reversible
    ys = sorted([c.points_m[0, 1], c.points_m[-1, 1]])
    assert ys == pytest.approx([2.0, 98.0], abs=1e-6)
    s = samples_along([(0.0, 60.0), (100.0, 60.0)], lambda x, y: np.asarray(x, dtype=float))
    (at_crossing,) = mark_crossings([c], s, np.array([40.0]), band_m=3.0)
    assert at_crossing.first and at_crossing.entry_m.tolist() == pytest.approx([40.0, 60.0])
    (c2,) = contour_candidates(est, GRID, np.array([40.0]), 30.0, 4.0, whole=True)
    (at_end,) = mark_crossings([c2], s, np.array([40.0]), band_m=3.0, open_at_end=True)
    assert at_end.first and at_end.entry_m is None
    picks, _ = greedy_plan([at_end], Footprints(uniform_map(), [at_end.points_m]),
                           uniform_map().variance, mae_value(uniform_map()), [(40.0, 100.0)],
                           [400.0])
    assert picks[0][0].path_m[0].tolist() == pytest.approx([40.0, 98.0])  # the nearer end


def test_open_entry_auto_enters_at_a_known_end_or_at_the_crossing_nearest_the_head():
    """``open_entry: auto`` on the iso-line x = 40 of the field x: the tracer heads south
    first (higher values on its left), so the south end is the head.

    - One crossing in the middle: entered there, with the flight back from the south
      edge counted (``detour_m``), and listed so it ends at the north end, where the
      vehicle finishes.
    - Two crossings: the one nearer the head (the shorter flight back).
    - A crossing 3 m from the head end: entered at that end, no flight back.
    - ... unless a trace or search was flown there already: then at the crossing."""
    xx, _ = GRID.mesh
    est = xx.astype(float)

    def field(x, y):
        return np.asarray(x, dtype=float)

    def entered(samples: SampleLog):
        (c,) = contour_candidates(est, GRID, np.array([40.0]), 30.0, 4.0, whole=True)
        assert c.points_m[-1, 1] < c.points_m[0, 1]  # the head is the south end
        (c,) = mark_crossings([c], samples, np.array([40.0]), band_m=3.0, end_m=6.0)
        assert c.first and not c.reversible
        return c

    middle = samples_along([(0.0, 60.0), (100.0, 60.0)], field)
    c = entered(middle)
    assert c.entry_m.tolist() == pytest.approx([40.0, 60.0])
    assert c.detour_m == pytest.approx(58.0, abs=0.5)
    assert c.points_m[-1].tolist() == pytest.approx([40.0, 98.0])
    south = samples_along([(0.0, 20.0), (100.0, 20.0)], field)
    c = entered(_join(middle, south))
    assert c.entry_m.tolist() == pytest.approx([40.0, 20.0])
    assert c.detour_m == pytest.approx(18.0, abs=0.5)
    at_end = samples_along([(0.0, 5.0), (100.0, 5.0)], field)
    c = entered(_join(middle, at_end))
    assert c.entry_m is None and c.detour_m == 0.0
    assert c.points_m[0].tolist() == pytest.approx([40.0, 2.0])
    tried = samples_along([(40.5, 0.5), (40.5, 1.5)], field)
    tried.phase[:] = Phase.SEARCH
    c = entered(_join(middle, at_end, tried))
    assert c.entry_m.tolist() == pytest.approx([40.0, 5.0])  # the crossing nearest the head


@pytest.mark.parametrize("planner", [True, False], ids=["planner-spacing", "2-explore_m"])
def test_sweeps_strips_narrower_than_twice_explore_m_reach_the_corners(planner):
    """Swept over the whole area, strips 2 x ``explore_m`` (20 m) wide leave the corner
    cells 10.01 m from the nearest leg (the legs stay 0.5 m inside the area), so they stay
    open for ever; the planner's strips (:func:`sweep_spacing_m`) reach every cell."""
    p = AdaptiveParams(target_levels=(1.0,))
    spacing_m = sweep_spacing_m(p) if planner else 2.0 * p.explore_m
    u = uniform_map()
    everything = np.ones(u.x_m.size, dtype=bool)
    legs = sweep_candidates(u, everything, REGION, spacing_m)
    flown = np.vstack([resample_polyline(c.points_m, 0.25) for c in legs])
    d, _ = cKDTree(flown).query(np.column_stack([u.x_m, u.y_m]))
    assert (d.max() <= p.explore_m) == planner  # every cell within explore_m of a leg


def test_threshold_mode_plans_its_own_batch_size():
    ctx = after_diagonals(0, [(0.0, 100.0)], 5000.0)
    planned = {}
    for batch_m in (100.0, 400.0):
        params = AdaptiveParams(target_levels=(55.0,), threshold_batch_m=batch_m, batch_m=999.0)
        jobs = adaptive_planner(params).next_batch(ctx).jobs
        planned[batch_m] = sum(j.length_m for j in jobs)
    assert planned[100.0] <= 100.0 + 100.0  # one pick may overrun what is left
    assert planned[400.0] > 2 * planned[100.0]


def test_survey_start_flies_even_strips_over_the_fleet_then_plans():
    """``start: survey``: the first flight is ``start_lines`` north-south lines at the
    strip centres, shared by the fleet; the adaptive plans follow within the budget."""
    m = load_mission(ROOT / "missions" / "paper.yaml").with_overrides(flight_budget_m=1400.0)
    m = dataclasses.replace(m, adaptive=dataclasses.replace(m.adaptive, start="survey",
                                                            start_lines=8))
    field = m.build_field(0)
    plans: dict[int, list[list[object]]] = {}

    def progress(event: dfc.DfcEvent) -> None:
        if isinstance(event, dfc.IterationPlanned):
            plans[event.iteration] = event.plans

    result = dfc.Dfc(m, InProcessExecutor(m, field, seed=0), planner="adaptive", truth=field,
                     seed=0, progress=progress).run()
    first = plans[0]
    assert sum(1 for plan in first if plan) == min(m.vehicles.count, 8)
    r = m.region
    xs = sorted({t.x_m for plan in first for t in plan if isinstance(t, Waypoint)})
    assert xs == pytest.approx([r.xmin + (k + 0.5) * r.width_m / 8 for k in range(8)])
    assert result.records[0].flight_distance_m >= 8 * r.height_m
    assert len(result.records) >= 2 and 1 in plans
    assert result.stop_reason == "flight_budget"
    with pytest.raises(ValueError, match="start"):
        adaptive_planner(AdaptiveParams(start="zigzag"))
    with pytest.raises(ValueError, match="explore"):
        adaptive_planner(AdaptiveParams(explore="spiral"))
    with pytest.raises(ValueError, match="line_weight"):
        adaptive_planner(AdaptiveParams(line_weight="q"))


def test_start_auto_is_a_survey_of_16_lines_for_the_field_and_1_for_thresholds():
    ctx = PlanContext(iteration=0, region=REGION, n_vehicles=1)
    first = adaptive_planner().initiation(ctx)
    assert first is not None and len(first.jobs) == 16
    # threshold mode, one vehicle: one line from where the vehicle is through the centre,
    # flown in steps (from the home corner: the diagonal)
    # (no position known yet: from the home corner)
    for pos, start, heading in (((0.0, 0.0), (0.5, 0.5), (1.0, 1.0)),
                                (None, (0.5, 0.5), (1.0, 1.0)),
                                ((50.0, 0.0), (50.0, 0.5), (0.0, 1.0)),
                                ((100.0, 30.0), (99.5, 30.0), (-49.5, 20.0))):
        at = PlanContext(iteration=0, region=REGION, n_vehicles=1,
                         positions_m=[pos] if pos else [])
        one = adaptive_planner(AdaptiveParams(target_levels=(55.0,))).initiation(at)
        assert one is not None and len(one.jobs) == 1
        (job,) = one.jobs
        assert job.start_m == pytest.approx(start)
        step = np.subtract(job.end_m, job.start_m)
        assert step[0] * heading[1] - step[1] * heading[0] == pytest.approx(0.0, abs=1e-9)
        assert float(np.dot(step, heading)) > 0.0 and job.length_m <= 5.0
    # a fleet flies the north-south line through the middle whole
    fleet = PlanContext(iteration=0, region=REGION, n_vehicles=2)
    one = adaptive_planner(AdaptiveParams(target_levels=(55.0,))).initiation(fleet)
    assert one is not None and [j.start_m for j in one.jobs] == [(50.0, 0.0)]  # the middle
    diagonals = AdaptiveParams(target_levels=(55.0,), start="diagonals")
    assert adaptive_planner(diagonals).initiation(ctx) is None  # the mission's pattern
    # a budget that holds fewer lines gets fewer (lines plus the cross-track legs)
    small = PlanContext(iteration=0, region=REGION, n_vehicles=1, budget_left_m=700.0)
    first = adaptive_planner().initiation(small)
    assert first is not None and len(first.jobs) == 6


# -- threshold mode: the start line in steps, lines through uncovered ground ----------------


def _bump(x, y):
    """A round bump at (50, 45): its iso-line at 50 is a ring of radius ~11.8 m."""
    return 100.0 * np.exp(-((np.asarray(x) - 50.0) ** 2 + (np.asarray(y) - 45.0) ** 2) / 200.0)


def _context(s: SampleLog, iteration: int, pos: tuple[float, float]) -> PlanContext:
    from econdor_gcs.core.spline import reconstruct

    est = reconstruct(s.x_m, s.y_m, s.value, GRID)
    return PlanContext(iteration=iteration, region=REGION, n_vehicles=1, grid=GRID, estimate=est,
                       samples=s, positions_m=[pos], budget_left_m=3000.0)


def _concat(*logs: SampleLog) -> SampleLog:
    out = SampleLog.concat(list(logs))
    out.t_s = np.arange(len(out)) * 0.1
    return out


def test_the_start_line_is_flown_in_steps_and_a_crossing_is_traced_before_the_next_step():
    """``start_step_m``: the start line is an iteration per step; a crossing a step sampled
    is traced (whole, allowed to run the perimeter) before the next step. What is left of
    the line goes on from where the last step ended, not from where the line was first left
    open; after the trace it competes with the lines through uncovered ground."""
    params = AdaptiveParams(target_levels=(50.0,), start_step_m=30.0, explore="lines")
    planner = adaptive_planner(params)
    first = planner.initiation(PlanContext(iteration=0, region=REGION, n_vehicles=1,
                                           positions_m=[(50.0, 0.0)]))
    assert first is not None and len(first.jobs) == 1
    assert [(w.x_m, w.y_m) for w in first.jobs[0].tasks] == [(50.0, 0.5), (50.0, 30.5)]
    step1 = samples_along([(0.0, 0.0), (50.0, 0.0), (50.0, 30.5)], _bump)  # along the edge first
    second = planner.next_batch(_context(step1, 1, (50.0, 30.5)))
    (leg,) = second.jobs
    ys = [w.y_m for w in leg.tasks]
    assert ys[0] == pytest.approx(32.0, abs=1.0) and ys[-1] == pytest.approx(ys[0] + 30.0)
    step2 = _concat(step1, samples_along([(50.0, ys[0]), (50.0, ys[-1])], _bump))
    third = planner.next_batch(_context(step2, 2, (50.0, ys[-1])))
    (trace,) = third.jobs
    task = trace.tasks[0]
    assert isinstance(task, TraceTask) and task.level == 50.0
    assert math.hypot(task.x_m - 50.0, task.y_m - 45.0) == pytest.approx(11.8, abs=1.0)
    assert task.max_length_m >= 400.0  # the perimeter: the estimate's ring is from a line
    # the ring traced (its samples read the level) from the crossing nearest the vehicle, a
    # gap left open at y = 5-15 on the line (as if a gust had thrown the vehicle off): the
    # next step still goes on north
    ring = np.array([[50.0 + 11.8 * math.cos(t), 45.0 + 11.8 * math.sin(t)]
                     for t in np.linspace(0.0, 2 * math.pi, 120)])
    traced = SampleLog(np.zeros(len(ring)), ring[:, 0], ring[:, 1], np.full(len(ring), 50.0),
                       np.full(len(ring), Phase.TRACE, dtype=np.int8),
                       np.zeros(len(ring), np.int16))
    holed = _concat(step2, traced)
    keep = ~((holed.x_m > 49.0) & (holed.y_m > 5.0) & (holed.y_m < 15.0))
    holed = SampleLog(holed.t_s[keep], holed.x_m[keep], holed.y_m[keep], holed.value[keep],
                      holed.phase[keep], holed.vehicle[keep])
    holed_xy = np.column_stack([holed.x_m, holed.y_m])
    rest = planner._route.rest(holed_xy)
    assert rest is not None and rest[:, 0].tolist() == [50.0, 50.0]
    assert rest[0, 1] == pytest.approx(ys[-1] + 2.0, abs=1.0) and rest[1, 1] > rest[0, 1]
    fourth = planner.next_batch(_context(holed, 3, (50.0, 56.8)))  # the loop closed here
    (leg,) = fourth.jobs
    pts = np.array([(w.x_m, w.y_m) for w in leg.tasks])
    assert leg.length_m <= 30.0 + 1e-9  # a step of the line that won
    assert not np.any((np.abs(pts[:, 0] - 50.0) < 1.0) & (pts[:, 1] < 20.0))  # not the gap
    # the rest of the start line was weighed against the other lines: the step is of the
    # best of them per metre (here through the unflown west, entered beside the vehicle)
    assert pts[0, 0] == pytest.approx(50.0, abs=1.0) and pts[-1, 0] < 25.0
    # one vehicle only: a fleet flies the start survey whole
    fleet = adaptive_planner(params).initiation(PlanContext(iteration=0, region=REGION,
                                                           n_vehicles=2))
    assert fleet is not None and fleet.jobs[0].length_m == pytest.approx(100.0)


def test_the_start_line_is_flown_in_steps_where_the_model_is_blind_beside_the_track():
    """``explore: auto`` where the GP cannot see beside the track (a flat background: no
    amplitude) still flies the start line in steps to its end: what the model sees is not
    told from a fit to the line's first metres, and a crossing further on is traced as soon
    as a step samples it."""
    def flat(x, y):
        return np.full(np.shape(x), 10.0)

    planner = adaptive_planner(AdaptiveParams(target_levels=(50.0,), start_step_m=10.0))
    first = planner.initiation(PlanContext(iteration=0, region=REGION, n_vehicles=1,
                                           positions_m=[(50.0, 0.0)]))
    assert first is not None
    path = [(50.0, 0.0)] + [(w.x_m, w.y_m) for w in first.jobs[0].tasks]
    s = samples_along(path, flat)
    for it in range(1, 4):
        ctx = _context(s, it, path[-1])
        assert planner._blind_beside(ctx)  # no GP yet, then one with no amplitude
        (step,) = planner.next_batch(ctx).jobs
        assert step.length_m == pytest.approx(10.0, abs=1e-6)  # a step, not the rest
        pts = [(w.x_m, w.y_m) for w in step.tasks]
        assert pts[0][0] == pytest.approx(50.0) and pts[0][1] > path[-1][1]  # on north
        s = _concat(s, samples_along(pts, flat))
        path = pts


def test_lines_mode_flies_the_line_through_the_most_uncovered_ground_until_none_is_left():
    """``explore: lines``: with the start line flown and no crossing, the next flight is a
    step along the line through the most uncovered ground per metre (the middle of an
    unflown half, not beside the line flown; with ``rays``, a line from the vehicle itself
    into that half, with no transit to it); with every place within ``explore_m`` of a
    sample the planner is done."""
    def low(x, y):
        return 10.0 + 0.01 * np.asarray(x) + 0.02 * np.asarray(y)  # never reaches 50

    line = samples_along([(0.0, 0.0), (50.0, 0.0), (50.0, 100.0)], low)  # flown whole
    legs = {}
    for rays in (0, 32):
        params = AdaptiveParams(target_levels=(50.0,), start_step_m=30.0, explore="lines",
                                probes=False, rays=rays)
        planner = adaptive_planner(params)
        assert planner.initiation(PlanContext(iteration=0, region=REGION, n_vehicles=1,
                                              positions_m=[(50.0, 0.0)]))
        (legs[rays],) = planner.next_batch(_context(line, 1, (50.0, 100.0))).jobs
        assert legs[rays].length_m <= 30.0 + 1e-9  # a step of it
    xs = {round(w.x_m, 1) for w in legs[0].tasks}
    assert len(xs) == 1 and 15.0 <= abs(xs.pop() - 50.0) <= 35.0  # north-south, mid-half
    assert legs[0].tasks[0].y_m == pytest.approx(99.5)  # from its end nearer the vehicle
    a, b = ((w.x_m, w.y_m) for w in legs[32].tasks)
    # from the vehicle (past the ground its own samples already cover)
    assert math.hypot(a[0] - 50.0, a[1] - 100.0) < 4.0
    # ... down into one unflown half, away from the line flown
    assert abs(b[0] - 50.0) >= 10.0 and b[1] < a[1] and abs(b[0] - 50.0) < 30.0
    covered = samples_along([(x, 0.0 if k % 2 else 100.0) for k, x in
                             enumerate(np.arange(2.5, 100.0, 5.0)) for _ in (0, 1)], low)
    done = planner.next_batch(_context(_concat(line, covered), 2, (97.5, 0.0)))
    assert done.done and not done.jobs


def test_lines_mode_probes_first_only_where_the_model_cannot_see_beside_the_track():
    """A GP with a long fitted length (a smooth field) predicts what lies a probe's reach
    beside the track, so the lines weighted by it look there; a short one, or one that
    learnt no amplitude (every sample alike: a flat background), cannot, so the track's
    extrema are probed."""
    from econdor_gcs.core.gp import MaternHyper

    planner = adaptive_planner(AdaptiveParams(target_levels=(50.0,), explore="lines"))
    s = samples_along([(0.0, 10.0), (100.0, 10.0)], lambda x, y: 10.0 + 0.3 * np.asarray(x))
    ctx = PlanContext(iteration=1, region=REGION, n_vehicles=1, samples=s)
    assert planner._blind_beside(ctx)  # no GP yet
    for length, amplitude, blind in ((30.0, 10.0, False), (12.0, 10.0, True),
                                     (30.0, 0.1, True)):
        planner.hyper = MaternHyper(mean=20.0, amplitude=amplitude, length_m=length)
        assert planner._blind_beside(ctx) is blind
    flat = samples_along([(0.0, 10.0), (100.0, 10.0)], lambda x, y: np.full(np.shape(x), 10.0))
    planner.hyper = MaternHyper(mean=10.0, amplitude=0.0, length_m=200.0)  # as fitted to it
    assert planner._blind_beside(PlanContext(iteration=1, region=REGION, n_vehicles=1,
                                             samples=flat))
    planner = adaptive_planner(AdaptiveParams(target_levels=(50.0,), explore="lines",
                                             probe_length_m=0.0))
    planner.hyper = MaternHyper(mean=20.0, amplitude=10.0, length_m=30.0)
    assert planner._blind_beside(ctx)


def test_a_vehicle_a_trace_took_away_from_its_line_weighs_the_rest_against_other_lines():
    """``explore: lines``: the start line is flown to y = 62, then a trace ends 37 m from
    where the line was left. Going back there is no longer a given: the rest of the line
    (from either end) competes with the lines through uncovered ground, and here a line
    through the unflown west, entered near the vehicle, covers more per metre (``rays: 0``:
    the lines from the vehicle itself, which would win here too, are left out)."""
    def low(x, y):
        return 10.0 + 0.01 * np.asarray(x) + 0.02 * np.asarray(y)

    planner = adaptive_planner(AdaptiveParams(target_levels=(50.0,), start_step_m=30.0,
                                             explore="lines", probes=False, rays=0))
    assert planner.initiation(PlanContext(iteration=0, region=REGION, n_vehicles=1,
                                          positions_m=[(50.0, 0.0)]))
    s1 = samples_along([(0.0, 0.0), (50.0, 0.0), (50.0, 30.0)], low)
    planner.next_batch(_context(s1, 1, (50.0, 30.0)))
    away = [(50.0, 62.0), (75.0, 70.0), (60.0, 99.0)]  # the trace's track
    s2 = _concat(s1, samples_along([(50.0, 31.0), (50.0, 62.0)], low), samples_along(away, low))
    (leg,) = planner.next_batch(_context(s2, 2, (60.0, 99.0))).jobs
    start = leg.tasks[0]
    assert math.hypot(start.x_m - 50.0, start.y_m - 63.0) > 10.0  # not back to the line
    assert start.x_m < 50.0 and start.y_m == pytest.approx(99.5)  # the west, from the top


def test_a_mission_without_an_adaptive_section_gets_the_planners_own_defaults(tmp_path):
    """The mission schema takes the adaptive defaults from ``AdaptiveParams``: a mission
    that sets none flies the planner as the planner's defaults say (a default written
    twice had left missions and the bench on an old value)."""
    path = tmp_path / "bare.yaml"
    path.write_text("field: {model: paper}\n")
    mission = load_mission(path)
    assert AdaptiveParams(**dataclasses.asdict(mission.adaptive)) == AdaptiveParams()
    # and a key the mission sets is the mission's
    path.write_text("field: {model: paper}\nadaptive: {start_step_m: 7.5}\n")
    assert load_mission(path).adaptive.start_step_m == 7.5


def test_a_trace_spent_at_once_is_not_planned_to_begin_there_again():
    """A trace that found the level and ended closed (on a track traced before) or at the
    edge within 10 m was spent where it began: no trace is planned to begin within 5 m of
    it again (paper seed 98 planned one there 99 times over, to its flight budget, each
    ending after a few metres). A trace that found nothing, or traced on, counts not."""
    from econdor_gcs.core.tasks import FlightReport, TaskOutcome

    def report(task: TraceTask, status: str, traced_m: float) -> FlightReport:
        return FlightReport(0, SampleLog.concat([]), 10.0, traced_m,
                            [TaskOutcome(task, status, 10.0, traced_m)], 0.0, 0.0, 1.0)

    def trace(x: float, y: float, entry: tuple[float, float] | None = None) -> Candidate:
        pts = np.array([[x, y], [x - 20.0, y + 20.0]])
        return Candidate(CandidateKind.TRACE, pts, 50.0, whole=True,
                         entry_m=None if entry is None else np.array(entry))

    planner = adaptive_planner(AdaptiveParams(target_levels=(50.0,)))
    planner.observe(0.0, [report(TraceTask(50.0, 99.0, 58.0, 3.0, 275.0, 0), "closed", 2.5),
                          report(TraceTask(50.0, 20.0, 20.0, 3.0, 275.0, 0), "not_found", 0.0),
                          report(TraceTask(50.0, 50.0, 80.0, 3.0, 275.0, 0), "closed", 90.0)])
    near, entered_near = trace(98.0, 60.0), trace(70.0, 70.0, entry=(97.0, 56.0))
    kept = [trace(20.0, 21.0), trace(50.0, 79.0), trace(90.0, 58.0),
            Candidate(CandidateKind.LEG, np.array([[99.0, 58.0], [99.0, 0.0]]))]
    assert planner._unspent([near, entered_near, *kept]) == kept
    planner.observe(0.0, [report(TraceTask(50.0, 20.0, 20.0, 3.0, 275.0, 0), "boundary", 4.0)])
    assert planner._unspent(kept) == kept[1:]


def test_threshold_not_done_on_noise_over_a_flat_background() -> None:
    """Issue 32: noisy samples of a flat background (the start diagonal and one line past a
    plume they all miss) leave the GP no amplitude, its length at the bound and a nugget
    of millions; a line then lowers its variance nowhere. The coverage floor is in metres:
    with most of the area farther than ``explore_m`` from every sample the planner is not
    done, and flies over that uncovered ground."""
    from econdor_gcs.core.spline import fit_field

    region = Region(0.0, 100.0, 0.0, 100.0)
    grid = Grid.with_spacing(region, 1.0)
    rng = np.random.default_rng(920)
    diag = np.linspace(0.0, 93.0, 420)
    line = np.linspace(93.0, 1.0, 420)
    x = np.r_[diag, np.full(line.size, 93.0)]
    y = np.r_[diag, line]
    v = 10.0 + rng.normal(0.0, 1.0, x.size)
    rec = fit_field(x, y, v, grid)
    assert rec.noise.noise_std > 0.5  # the station sees the noise
    samples = SampleLog(t_s=np.arange(x.size) / 10.0, x_m=x, y_m=y, value=v,
                        phase=np.zeros(x.size, dtype=np.int8),
                        vehicle=np.zeros(x.size, dtype=np.int16))
    planner = adaptive_planner(AdaptiveParams(target_levels=(55.0,)), seed=920)
    ctx = PlanContext(iteration=24, region=region, n_vehicles=1, grid=grid,
                      estimate=rec.values, samples=samples, positions_m=[(93.0, 1.0)],
                      noise_std=float(rec.noise.noise_std))
    batch = planner.next_batch(ctx)
    assert planner.hyper is not None and planner.hyper.amplitude < 0.05  # the model sees noise
    assert not batch.done
    assert batch.jobs
    # what it flies reaches ground farther than explore_m from every sample
    flown = np.array([(t.x_m, t.y_m) for job in batch.jobs for t in job.tasks
                      if isinstance(t, Waypoint)])
    far = cKDTree(np.column_stack([x, y])).query(flown)[0]
    assert far.max() > planner.params.explore_m
