"""Planners, fleet assignment and the level schedule of E-CONDOR."""

import math

import numpy as np
import pytest

from econdor_gcs.core.assignment import assign_jobs
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.planners import (
    ContourPlanner,
    LawnmowerPlanner,
    PlanContext,
    diagonal_jobs,
    lawnmower_lines_for_budget,
)
from econdor_gcs.core.sg import update_delta, update_kappa
from econdor_gcs.core.tasks import TraceTask, Waypoint

REGION = Region(0, 100, 0, 100)
GRID = Grid(REGION, 101, 101)


def ctx(estimate=None):
    return PlanContext(iteration=1, region=REGION, n_vehicles=1, grid=GRID, estimate=estimate)


def ramp():
    """A field whose values are spread evenly: g = x (0..100)."""
    xx, _ = GRID.mesh
    return xx.copy()


def test_contour_planner_follows_the_authors_schedule():
    p = ContourPlanner(m0=3, sg=True, lloyd_bins=None)
    b1 = p.next_batch(ctx(ramp()))
    assert b1.levels_planned == 3 and len(b1.levels) == 3
    np.testing.assert_allclose(b1.levels, [16.67, 50.0, 83.33], atol=0.6)
    assert p.delta == pytest.approx(np.min(np.diff(b1.levels)))
    assert len(b1.jobs) == 3  # one straight contour line per level
    p.observe(4.0)
    b2 = p.next_batch(ctx(ramp()))  # kappa stays 1, nothing dropped
    assert b2.levels_planned == 4 and len(b2.dropped) == 0 and b2.kappa == 1
    p.observe(1.6)
    delta_before = p.delta
    b3 = p.next_batch(ctx(ramp()))
    assert b3.kappa == update_kappa(1, 4.0, 1.6) == 3  # eq. (6)
    assert b3.levels_planned == 4 + 3
    assert b3.delta == pytest.approx(update_delta(delta_before, 4.0, 1.6))  # eq. (7)
    assert b3.forced == 0 and len(b3.levels) > 0 and len(b3.dropped) > 0
    traced = np.r_[b1.levels, b2.levels]
    for lv in b3.levels:  # kept levels are >= delta away from every traced level
        assert np.min(np.abs(traced - lv)) >= b3.delta
    for lv in b3.dropped:
        assert np.min(np.abs(traced - lv)) < b3.delta


def test_all_levels_redundant_flies_the_kappa_least_redundant():
    p = ContourPlanner(m0=3, sg=True, lloyd_bins=None)
    p.next_batch(ctx(ramp()))
    p.observe(1.0)
    p.next_batch(ctx(ramp()))
    p.observe(3.0)  # the learning error ROSE: eq. (7) grows delta a lot
    b = p.next_batch(ctx(ramp()))
    assert b.delta > 30  # every new level is within delta of a traced one
    assert b.forced == b.kappa == len(b.levels) > 0
    assert len(b.jobs) > 0


def test_no_sg_adds_one_level_and_retraces_all():
    p = ContourPlanner(m0=3, sg=False, lloyd_bins=None)
    ms = []
    for e in (5.0, 1.0, 0.5, 0.2):
        b = p.next_batch(ctx(ramp()))
        ms.append(b.levels_planned)
        assert len(b.levels) == b.levels_planned and len(b.dropped) == 0 and b.kappa == 1
        p.observe(e)
    assert ms == [3, 4, 5, 6]


def test_diagonal_jobs_split_evenly():
    for n in (1, 2, 3, 5):
        jobs = diagonal_jobs(REGION, n)
        assert len(jobs) == n
        on_diagonal = []
        for j in jobs:
            pts = [(t.x_m, t.y_m) for t in j.tasks]
            on_diagonal.append(sum(math.dist(a, b) for a, b in zip(pts[:-1], pts[1:], strict=True)
                                   if abs(abs(b[0] - a[0]) - abs(b[1] - a[1])) < 1e-9))
        assert sum(on_diagonal) == pytest.approx(2 * math.hypot(100, 100))
        assert max(on_diagonal) == pytest.approx(min(on_diagonal))
        assert all(isinstance(t, Waypoint) for j in jobs for t in j.tasks)


def test_assignment_is_balanced_complete_and_transit_aware():
    p = ContourPlanner(m0=9, sg=False, lloyd_bins=None)
    batch = p.next_batch(ctx(ramp()))
    plans = assign_jobs(batch.jobs, [(0.0, 0.0), (100.0, 0.0), (50.0, 100.0)])
    tasks = [t for plan in plans for t in plan]
    assert len(tasks) == len(batch.jobs) == 9
    assert len({t.piece_id for t in tasks}) == 9  # unique piece ids
    counts = [len(plan) for plan in plans]
    assert max(counts) - min(counts) <= 1  # nine equal 100 m lines over three vehicles
    # the vehicle starting at x=0 gets the western lines, the one at x=100 the eastern ones
    assert np.mean([t.level for t in plans[0]]) < np.mean([t.level for t in plans[1]])
    for plan in plans:
        assert all(isinstance(t, TraceTask) for t in plan)


def _assign_one_by_one(jobs, positions_m, search_radius_m=10.0, first_piece_id=0):
    """The assignment as first written (every remaining piece retargeted at every step):
    the reference the vectorised nearest-point search must match exactly."""
    n = len(positions_m)
    loads, ends, buckets = [0.0] * n, list(positions_m), [[] for _ in range(n)]
    for job in sorted(jobs, key=lambda j: -j.length_m):
        costs = [loads[v] + math.dist(ends[v], job.start_m) + job.length_m for v in range(n)]
        v = min(range(n), key=costs.__getitem__)
        loads[v], ends[v] = costs[v], job.end_m
        buckets[v].append(job)
    plans, piece_id = [], first_piece_id
    for v in range(n):
        pos, todo, tasks = positions_m[v], list(buckets[v]), []
        while todo:
            for j in todo:
                if j.piece is not None:
                    j.retarget(*pos, search_radius_m, j.tasks[0].max_length_m, piece_id)
            k = min(range(len(todo)), key=lambda i: math.dist(pos, todo[i].start_m))
            job = todo.pop(k)
            if job.piece is not None:
                job.retarget(*pos, search_radius_m, job.tasks[0].max_length_m, piece_id)
                piece_id += 1
            tasks.extend(job.tasks)
            pos = job.end_m
        plans.append(tasks)
    return plans


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_assignment_matches_the_one_by_one_search(seed):
    from econdor_gcs.core.fields import authors_field

    truth = authors_field(REGION, seed)
    xx, yy = GRID.mesh
    estimate = truth(xx, yy)
    positions = [(0.0, 0.0), (100.0, 0.0)] if seed else [(37.0, 61.0)]

    def batch():
        p = ContourPlanner(m0=12, sg=False, lloyd_bins=None)
        return p.next_batch(ctx(estimate)).jobs

    expected = _assign_one_by_one(batch(), positions, first_piece_id=1000)
    got = assign_jobs(batch(), positions, first_piece_id=1000)
    assert len(expected[0]) > 10
    assert got == expected


def test_lawnmower_refines_and_fits_budget():
    lm = LawnmowerPlanner(REGION, spacing_m=25.0)
    first = lm.next_batch(ctx())
    assert len(first.jobs) == 5 and first.survey_m == pytest.approx(500.0)
    second = lm.next_batch(ctx())
    xs = sorted(j.tasks[0].x_m for j in second.jobs)
    np.testing.assert_allclose(xs, [12.5, 37.5, 62.5, 87.5])  # the lines in between
    assert lawnmower_lines_for_budget(REGION, 1100.0) == 10
    budget = LawnmowerPlanner(REGION, budget_m=1100.0)
    b = budget.next_batch(ctx())
    assert len(b.jobs) == 10
    last = budget.next_batch(ctx())
    assert last.jobs == [] and last.done


def test_authors_lloyd_variant_moves_the_outer_levels_inward():
    textbook = ContourPlanner(m0=3, sg=True, lloyd_bins=200).next_batch(ctx(ramp()))
    authors = ContourPlanner(m0=3, sg=True, lloyd_bins=200, lloyd_variant="authors")
    b = authors.next_batch(ctx(ramp()))
    np.testing.assert_allclose(b.levels, [25.0, 50.0, 75.0], atol=1.0)  # k / (M + 1)
    np.testing.assert_allclose(textbook.levels, [16.67, 50.0, 83.33], atol=0.6)
    assert authors.delta == pytest.approx(25.0, abs=1.0)  # delta_0 = smallest gap
    with pytest.raises(ValueError, match="lloyd_variant"):
        ContourPlanner(lloyd_variant="matlab")


def test_a_level_within_the_noise_of_a_traced_one_is_redundant():
    """The SG redundancy test uses max(delta_n, noise_std): with noise, an iso-line
    within the noise of one already traced is that one again."""
    def third_batch(noise_std):
        p = ContourPlanner(m0=3, sg=True, lloyd_bins=None)
        c = PlanContext(iteration=1, region=REGION, n_vehicles=1, grid=GRID,
                        estimate=ramp(), noise_std=noise_std)
        p.next_batch(c)
        p.observe(4.0)
        p.next_batch(c)
        p.observe(1.6)
        return p.next_batch(c)

    exact, noisy = third_batch(0.0), third_batch(12.0)
    assert exact.delta == noisy.delta < 12.0
    assert len(noisy.dropped) > len(exact.dropped)
