"""The uncertainty model the adaptive planner scores paths with (core/uncertainty.py)."""

from __future__ import annotations

import numpy as np
import pytest

from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.gp import MaternHyper
from econdor_gcs.core.uncertainty import (
    Footprints,
    line_variance,
    resample_polyline,
    uncertainty_map,
)

REGION = Region(0, 100, 0, 100)
GRID = Grid(REGION, 101, 101)
PLAN = Grid.with_spacing(REGION, 2.0)


def diagonal_samples(field) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 100.0, 251)
    x, y = np.r_[t, t], np.r_[t, 100.0 - t]
    return x, y, field(x, y)


def test_proxy_variance_is_one_minus_exp_of_the_distance_to_the_nearest_sample():
    x, y = np.array([10.0, 80.0]), np.array([10.0, 40.0])
    umap = uncertainty_map(x, y, np.array([0.0, 1.0]), np.zeros(GRID.shape), GRID, PLAN,
                           model="proxy", length_m=5.0)
    d = np.min(np.hypot(umap.x_m[:, None] - x, umap.y_m[:, None] - y), axis=1)
    np.testing.assert_allclose(umap.variance, 1.0 - np.exp(-(d / 5.0) ** 2), atol=1e-12)
    at_sample = (umap.x_m == 10.0) & (umap.y_m == 10.0)
    assert umap.variance[at_sample] == pytest.approx(0.0)
    assert umap.variance.max() == pytest.approx(1.0)


def test_amplitude_is_the_floor_plus_the_steepness_nearby():
    xx, _ = GRID.mesh
    # flat at 0 west of x = 60, a ramp of slope 2 per metre east of it
    est = np.where(xx < 60.0, 0.0, 2.0 * (xx - 60.0))
    x, y, v = diagonal_samples(lambda x, y: np.where(x < 60.0, 0.0, 2.0 * (x - 60.0)))
    umap = uncertainty_map(x, y, v, est, GRID, PLAN, model="proxy", gradient_gain_m=5.0)
    floor = 0.2 * float(np.ptp(v))  # default s0: a fifth of the sampled range
    west = umap.x_m < 50.0  # farther than the 7 m window from the ramp
    east = umap.x_m > 70.0
    np.testing.assert_allclose(umap.amplitude[west], floor)
    np.testing.assert_allclose(umap.amplitude[east], floor + 5.0 * 2.0, rtol=1e-6)
    # an explicit floor replaces the default; the expected error is a sqrt(v)
    low = uncertainty_map(x, y, v, est, GRID, PLAN, model="proxy", floor=1.0)
    np.testing.assert_allclose(low.amplitude[west], 1.0)
    np.testing.assert_allclose(low.sigma(), low.amplitude * np.sqrt(low.variance))


def test_gp_variance_falls_where_samples_are_and_needs_hyperparameters():
    x, y, v = diagonal_samples(lambda x, y: np.sin(x / 9.0) + np.cos(y / 7.0))
    hyper = MaternHyper(0.0, 1.0, 6.0, 1e-4, 2.5)
    umap = uncertainty_map(x, y, v, np.zeros(GRID.shape), GRID, PLAN, model="gp", hyper=hyper)
    on_diag = np.abs(umap.x_m - umap.y_m) < 1e-9
    corner = np.hypot(umap.x_m - 50.0, umap.y_m - 0.0) < 1e-9  # 35 m from both diagonals
    assert umap.variance[on_diag].max() < 0.02
    assert umap.variance[corner][0] > 0.95
    assert umap.amplitude.min() == pytest.approx(hyper.amplitude)  # floor: sigma_f
    with pytest.raises(ValueError, match="hyperparameters"):
        uncertainty_map(x, y, v, np.zeros(GRID.shape), GRID, PLAN, model="gp")
    with pytest.raises(ValueError, match="model"):
        uncertainty_map(x, y, v, np.zeros(GRID.shape), GRID, PLAN, model="kriging")


@pytest.mark.parametrize("model", ["proxy", "gp"])
def test_line_variance_rises_with_distance(model):
    hyper = MaternHyper(0.0, 1.0, 5.0, 1e-4, 2.5) if model == "gp" else None
    d = np.linspace(0.0, 30.0, 61)
    v = line_variance(d, model, 5.0, hyper)
    assert v[0] < 0.01 and v[-1] > 0.95
    assert np.all(np.diff(v) >= -1e-12)


def test_footprints_hold_the_cells_near_each_path_and_their_distances():
    x, y, v = diagonal_samples(lambda x, y: x)
    umap = uncertainty_map(x, y, v, np.zeros(GRID.shape), GRID, PLAN, model="proxy")
    line = np.array([[50.0, 0.0], [50.0, 100.0]])
    dot = np.array([[10.0, 90.0], [10.0, 90.0]])
    fp = Footprints(umap, [line, dot])
    r = fp.radius_m
    assert 5.0 < r <= 25.0
    cells = fp.cells[fp.start[0]:fp.start[1]]
    dist = fp.dist_m[fp.start[0]:fp.start[1]]
    np.testing.assert_allclose(dist, np.abs(umap.x_m[cells] - 50.0), atol=1e-9)
    within = np.flatnonzero(np.abs(umap.x_m - 50.0) < r)
    assert set(cells.tolist()) == set(within.tolist())  # every cell within reach, no other
    assert np.all(fp.owner[fp.start[1]:] == 1)
    np.testing.assert_allclose(fp.line_var, umap.line_variance(fp.dist_m))


def test_resample_polyline_spaces_points_along_every_segment():
    p = resample_polyline(np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]]), 1.0)
    steps = np.hypot(*np.diff(p, axis=0).T)
    assert np.all(steps <= 1.0 + 1e-9) and steps.sum() == pytest.approx(7.0)
    assert p[0].tolist() == [0.0, 0.0] and p[-1].tolist() == [4.0, 3.0]


def test_noisy_gp_map_keeps_a_flown_place_worth_flying_again():
    """With the noise as the GP's nugget, a second pass over a line adds what averaging
    the noise down is worth; with exact samples it adds nothing."""
    x, y, v = diagonal_samples(lambda x, y: np.sin(x / 9.0) + np.cos(y / 7.0))
    rng = np.random.default_rng(3)
    noisy = v + rng.normal(0.0, 0.3, v.size)
    hyper = MaternHyper(0.0, 1.0, 6.0, 0.09, 2.5)  # nugget: (0.3 / 1.0) ** 2
    umap = uncertainty_map(x, y, noisy, np.zeros(GRID.shape), GRID, PLAN, model="gp",
                           hyper=hyper, noise_std=0.3)
    assert umap.noisy
    on_diag = np.abs(umap.x_m - umap.y_m) < 1e-9
    # the noise leaves a floor on the flown line that exact samples would not
    assert umap.variance[on_diag].min() > 0.002
    line = umap.line_variance(np.zeros(1))
    before = umap.variance[on_diag]
    after = umap.combine(before, np.full(before.shape, line[0]))
    assert np.all(after < before)
    exact = uncertainty_map(x, y, v, np.zeros(GRID.shape), GRID, PLAN, model="gp",
                            hyper=hyper)
    assert not exact.noisy
    np.testing.assert_array_equal(exact.combine(before, np.full(before.shape, line[0])),
                                  np.minimum(before, line[0]))
