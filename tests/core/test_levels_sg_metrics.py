"""Every equation of the paper against a hand-computed case."""

import math

import numpy as np
import pytest
from scipy import stats

from econdor_gcs.core import metrics
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.levels import lloyd_max
from econdor_gcs.core.sg import (
    drop_redundant,
    initial_delta,
    normalised_gradient,
    update_delta,
    update_kappa,
)


def test_lloyd_max_uniform_gives_even_levels():
    v = np.linspace(0.0, 10.0, 200_001)
    np.testing.assert_allclose(lloyd_max(v, 5, bins=None), [1, 3, 5, 7, 9], atol=1e-3)
    np.testing.assert_allclose(lloyd_max(v, 5, bins=500), [1, 3, 5, 7, 9], atol=0.02)


def test_lloyd_max_standard_normal_two_levels():
    # Max (1960): the optimal 2-level quantiser of N(0,1) has levels +-sqrt(2/pi) = +-0.798
    v = stats.norm.ppf(np.linspace(0.5 / 400_000, 1 - 0.5 / 400_000, 400_000))
    lv = lloyd_max(v, 2, bins=None)
    np.testing.assert_allclose(lv, [-math.sqrt(2 / math.pi), math.sqrt(2 / math.pi)], atol=2e-3)


def test_lloyd_max_standard_normal_four_levels():
    # Max (1960) table: N = 4 output levels +-0.4528, +-1.510
    v = stats.norm.ppf(np.linspace(0.5 / 400_000, 1 - 0.5 / 400_000, 400_000))
    lv = lloyd_max(v, 4, bins=None, iterations=1000)
    np.testing.assert_allclose(lv, [-1.510, -0.4528, 0.4528, 1.510], atol=5e-3)


def test_lloyd_max_levels_are_centroids_of_midpoint_cells():
    rng = np.random.default_rng(3)
    v = rng.gamma(2.0, 3.0, 50_000)
    lv = lloyd_max(v, 4, bins=None, iterations=1000)
    edges = np.r_[-np.inf, 0.5 * (lv[1:] + lv[:-1]), np.inf]  # eq. (5)
    for i in range(4):
        cell = v[(v >= edges[i]) & (v < edges[i + 1])]
        assert lv[i] == pytest.approx(cell.mean(), rel=1e-3)  # eq. (4)


def test_lloyd_max_rejects_bad_input():
    with pytest.raises(ValueError, match="m:"):
        lloyd_max([1.0, 2.0], 0)
    with pytest.raises(ValueError, match="values"):
        lloyd_max([np.nan], 2)


def test_kappa_eq6_hand_computed():
    # E_{n-2}=4, E_{n-1}=2: ceil(1 + 2*2/6) = ceil(1.667) = 2
    assert update_kappa(1, 4.0, 2.0) == 3
    # error rising 1 -> 3: ceil(1 + 2*2/4) = 2
    assert update_kappa(2, 1.0, 3.0) == 4
    # equal errors: ceil(1) = 1
    assert update_kappa(5, 2.0, 2.0) == 6


def test_delta_eq7_hand_computed():
    # 0.9 * |1 - 2*(4-2)/(4+2)| = 0.9/3
    assert update_delta(0.9, 4.0, 2.0) == pytest.approx(0.3)
    # rising error grows delta: |1 - 2*(1-3)/4| = 2
    assert update_delta(0.5, 1.0, 3.0) == pytest.approx(1.0)


def test_zero_denominator_is_handled():
    assert normalised_gradient(0.0, 0.0) == 0.0
    assert update_kappa(3, 0.0, 0.0) == 4
    assert update_delta(0.7, 0.0, 0.0) == pytest.approx(0.7)
    assert normalised_gradient(None, 1.0) == 0.0


def test_initial_delta_and_dropping():
    assert initial_delta([10.0, 14.0, 15.5]) == pytest.approx(1.5)
    keep, drop = drop_redundant([1.0, 2.0, 3.0, 4.0], [2.05, 3.9], 0.2)
    np.testing.assert_array_equal(keep, [1.0, 3.0])
    np.testing.assert_array_equal(drop, [2.0, 4.0])
    keep, drop = drop_redundant([1.0, 2.0], [], 5.0)
    np.testing.assert_array_equal(keep, [1.0, 2.0])


def test_learning_error_mae_db_span():
    a = np.array([[1.0, 2.0], [3.0, 4.0]])
    b = np.array([[1.5, 2.0], [2.0, 4.0]])
    assert metrics.learning_error(a, b) == pytest.approx((0.5 + 1.0) / 4)  # eq. 3
    assert metrics.mae(a, b) == pytest.approx(0.375)  # eq. 10
    assert metrics.to_db(0.01) == pytest.approx(-40.0)  # eq. 11
    assert metrics.to_db(0.0) == -math.inf
    assert metrics.span_ratio(b, a) == pytest.approx(2.5 / 3.0)


def test_isoline_error_of_shifted_plane():
    region = Region(0, 100, 0, 100)
    g = Grid(region, 101, 101)
    xx, _ = g.mesh
    truth = xx.copy()
    est = xx - 2.0  # the 50-contour moves 2 m east
    assert metrics.isoline_error(truth, est, g, 50.0) == pytest.approx(2.0, abs=1e-6)
    assert metrics.isoline_error(truth, truth, g, 50.0) == pytest.approx(0.0, abs=1e-9)
    assert math.isnan(metrics.isoline_error(truth, est, g, 500.0))


def test_lloyd_max_authors_variant_tends_to_k_over_m_plus_one():
    """Lloyd_Max_2.m recomputes the outer thresholds: on a uniform law levels -> k/(M+1)."""
    v = np.linspace(0.0, 1.0, 100_001)
    lv = lloyd_max(v, 4, bins=None, iterations=3000, variant="authors")
    np.testing.assert_allclose(lv, [0.2, 0.4, 0.6, 0.8], atol=2e-3)
    textbook = lloyd_max(v, 4, bins=None)
    assert np.min(np.diff(lv)) < np.min(np.diff(textbook))  # smaller delta_0 (eq. 7's start)
    with pytest.raises(ValueError, match="variant"):
        lloyd_max(v, 4, variant="matlab")


def test_isoline_pieces_missed():
    grid = Grid(Region(0, 100, 0, 100), 101, 101)
    xx, yy = grid.mesh
    two = np.exp(-((xx - 25) ** 2 + (yy - 50) ** 2) / 50) + np.exp(
        -((xx - 75) ** 2 + (yy - 50) ** 2) / 50)
    one = np.exp(-((xx - 25) ** 2 + (yy - 50) ** 2) / 50)
    assert metrics.isoline_components_missed(two, two, grid, 0.5) == (0, 2)
    assert metrics.isoline_components_missed(two, one, grid, 0.5) == (1, 2)
    assert metrics.isoline_components_missed(two, np.zeros_like(two), grid, 0.5) == (2, 2)
