"""The Gaussian-process model: Matérn correlation, ML fit, kriging (global and tiled)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from econdor_gcs.core import metrics
from econdor_gcs.core.fields import authors_field
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.gp import (
    Kriging,
    MaternHyper,
    _profile_nll,
    fit_matern,
    kriging_reconstruct,
    matern,
    thin_samples,
)
from econdor_gcs.core.spline import reconstruct
from econdor_gcs.errors import ReconstructionError

REGION = Region(0, 100, 0, 100)
GRID = Grid(REGION, 101, 101)


def lines(spacing_m: float, step_m: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """Samples along north-south lines, as a survey takes them."""
    y = np.arange(0.0, 100.0 + 1e-9, step_m)
    xs = np.arange(0.0, 100.0 + 1e-9, spacing_m)
    return np.repeat(xs, y.size), np.tile(y, xs.size)


def test_matern_matches_the_closed_forms():
    r = np.array([0.0, 0.5, 2.0])
    np.testing.assert_allclose(matern(r, 0.5), np.exp(-r))
    s3 = math.sqrt(3) * r
    np.testing.assert_allclose(matern(r, 1.5), (1 + s3) * np.exp(-s3))
    s5 = math.sqrt(5) * r
    np.testing.assert_allclose(matern(r, 2.5), (1 + s5 + s5**2 / 3) * np.exp(-s5))
    with pytest.raises(ValueError, match="nu"):
        matern(r, 3.5)


def test_profile_likelihood_equals_scikit_learns_at_the_same_hyperparameters():
    sklearn_gp = pytest.importorskip("sklearn.gaussian_process")
    kernels = pytest.importorskip("sklearn.gaussian_process.kernels")
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 50, 80), rng.uniform(0, 50, 80)
    v = np.sin(x / 7) + np.cos(y / 5) + 3.0
    d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    nll, mean, amp = _profile_nll(math.log(9.0), d, v, 2.5, 1e-4)
    kernel = (kernels.ConstantKernel(amp**2, "fixed") * kernels.Matern(9.0, "fixed", nu=2.5)
              + kernels.WhiteKernel(1e-4 * amp**2, "fixed"))
    gp = sklearn_gp.GaussianProcessRegressor(kernel, optimizer=None).fit(
        np.column_stack([x, y]), v - mean)
    # scikit-learn adds a 1e-10 jitter to the diagonal: equal to ~1e-7
    assert -nll == pytest.approx(gp.log_marginal_likelihood_value_, rel=1e-6)


def test_fit_recovers_the_length_scale_of_a_sampled_process():
    rng = np.random.default_rng(4)
    x, y = rng.uniform(0, 60, 350), rng.uniform(0, 60, 350)
    d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    cov = 4.0 * matern(d / 8.0, 2.5) + 1e-8 * np.eye(x.size)
    v = 10.0 + np.linalg.cholesky(cov) @ rng.standard_normal(x.size)
    hyper = fit_matern(x, y, v, nu=2.5, max_points=350)
    assert 5.0 < hyper.length_m < 12.0
    assert 1.0 < hyper.amplitude < 4.0


def test_a_flat_background_with_rounding_noise_has_no_amplitude():
    # a plume's background far from every source: 10 to within a few ulps (the sum of
    # vanishing Gaussians), the samples of a 10 m step along a line
    y = np.arange(0.0, 60.0, 0.8)
    x = np.full_like(y, 50.0)
    v = 10.0 + 4e-15 * np.sin(7.0 * y)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the likelihood of rounding noise is not searched
        hyper = fit_matern(x, y, v)
    assert hyper.amplitude == 0.0
    assert hyper.mean == pytest.approx(10.0)
    assert fit_matern(x, y, 10.0 + 1e-6 * np.sin(y / 7.0)).amplitude > 0.0  # small is not flat


def test_fit_refuses_too_few_samples():
    with pytest.raises(ReconstructionError, match="at least 3"):
        fit_matern([0.0, 1.0], [0.0, 1.0], [1.0, 2.0])


def test_thinning_keeps_one_real_sample_per_cell():
    x, y = lines(5.0)
    idx = thin_samples(x, y, 2.0)
    assert 0 < idx.size < x.size
    cells = set(zip(np.floor(x[idx] / 2.0).astype(int), np.floor(y[idx] / 2.0).astype(int),
                    strict=True))
    assert len(cells) == idx.size


def test_kriging_interpolates_and_knows_where_it_is_uncertain():
    f = authors_field(REGION, 0)
    x, y = lines(10.0)
    model = Kriging(max_global=10_000).fit(x, y, f(x, y))
    mu, sd = model.predict(x[::37], y[::37], return_std=True)
    np.testing.assert_allclose(mu, f(x[::37], y[::37]), atol=1e-2)
    assert np.all(sd < 0.05 * model.hyper_.amplitude)
    _, sd_gap = model.predict(np.array([5.0]), np.array([50.0]), return_std=True)
    assert sd_gap[0] > 10 * float(np.median(sd))  # between lines, 5 m from every sample


def test_tiles_lose_little_against_one_exact_system():
    f = authors_field(REGION, 2)
    truth = f(*GRID.mesh)
    x, y = lines(5.0)
    v = f(x, y)
    exact = Kriging(max_global=100_000).fit(x, y, v)
    tiled = Kriging(max_global=500, hyper=exact.hyper_).fit(x, y, v)
    assert len(tiled.tiles_) > 1
    e_exact = metrics.mae(truth, exact.predict(*GRID.mesh))
    e_tiled = metrics.mae(truth, tiled.predict(*GRID.mesh))
    assert metrics.to_db(e_tiled) < metrics.to_db(e_exact) + 6.0


def test_kriging_beats_the_spline_on_survey_lines():
    """The reason kriging is offered: on a smooth field, 10 m survey lines."""
    f = authors_field(REGION, 0)
    truth = f(*GRID.mesh)
    x, y = lines(10.0)
    v = f(x, y)
    krig = metrics.mae(truth, kriging_reconstruct(x, y, v, GRID))
    spline = metrics.mae(truth, reconstruct(x, y, v, GRID))
    assert krig < 0.8 * spline


def test_unit_variance_is_within_zero_and_one():
    hyper = MaternHyper(0.0, 3.0, 6.0)
    x, y = lines(20.0)
    var = Kriging(hyper=hyper).fit(x, y, np.zeros_like(x)).unit_variance(*GRID.mesh)
    assert var.min() >= 0.0 and var.max() <= 1.0
    assert var.max() > 0.5  # halfway between lines 20 m apart, l = 6 m


def test_mission_reconstruction_kriging_is_what_the_dfc_estimates_with():
    """``algorithm.reconstruction: kriging``: the same flight (a 10-line survey of the paper's
    setting), reconstructed by the DFC with kriging and with the spline."""
    from pathlib import Path

    from econdor_gcs.config import parse_mission
    from econdor_gcs.dfc.loop import Dfc, IterationDone
    from econdor_lab.inprocess import InProcessExecutor

    raw = {"name": "krig", "field": {"model": "authors"}, "vehicles": {"count": 1},
           "algorithm": {"planner": "lawnmower", "max_iterations": 1, "min_iterations": 1},
           "lawnmower": {"budget_m": 10 * 100.0 + 100.0}}
    results, used = {}, {}
    for method in ("auto", "kriging"):
        raw["algorithm"]["reconstruction"] = method
        m = parse_mission(raw, base_dir=Path(__file__).resolve().parents[1] / "missions")
        field = m.build_field(0)
        counts: list[int] = []  # samples behind each estimate (before the flight home)
        results[method] = Dfc(m, InProcessExecutor(m, field, seed=0), planner="lawnmower",
                              truth=field, seed=0,
                              progress=lambda e, c=counts: c.append(e.record.samples)
                              if isinstance(e, IterationDone) else None).run()
        used[method] = counts[-1]
    spline, krig = results["auto"], results["kriging"]
    assert used["auto"] == used["kriging"]  # the same flight
    n, s = used["kriging"], krig.samples
    np.testing.assert_array_equal(spline.samples.x_m[:n], s.x_m[:n])
    expected = kriging_reconstruct(s.x_m[:n], s.y_m[:n], s.value[:n], krig.grid)
    np.testing.assert_allclose(krig.estimate, expected, atol=1e-6)
    assert krig.records[-1].mae == pytest.approx(metrics.mae(krig.truth, expected), rel=1e-6)
    assert krig.records[-1].mae < 0.9 * spline.records[-1].mae
