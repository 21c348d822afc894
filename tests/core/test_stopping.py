"""The learning-error stop rule with noisy samples (econdor_gcs.core.stopping)."""

from __future__ import annotations

import numpy as np
import pytest

from econdor_gcs.core import metrics
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.spline import fit_field
from econdor_gcs.core.stopping import gamma_converged, noise_floor

GRID = Grid(Region(0.0, 60.0, 0.0, 60.0), 61, 61)


def _lines(xs: list[float], rng: np.random.Generator, noise: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """North-south lines sampled every 0.8 m over a plane, with noise."""
    y = np.arange(0.0, 60.0, 0.8)
    x = np.concatenate([np.full(y.size, xi) for xi in xs])
    yy = np.concatenate([y if i % 2 == 0 else y[::-1] for i in range(len(xs))])
    v = 10.0 + 0.05 * x + 0.02 * yy + rng.normal(0.0, noise, x.size)
    return x, yy, v


@pytest.mark.parametrize("noise", [0.5, 2.0])
def test_the_floor_is_what_noise_alone_moves_the_estimate_by(noise):
    """Over a plane (nothing left to learn) every change of the estimate when lines are
    added is the noise's: the learning error it makes is the floor, within a factor of 2
    either way, and it grows with the noise."""
    rng = np.random.default_rng(3)
    old = _lines([5.0, 15.0, 25.0, 35.0, 45.0, 55.0], rng, noise)
    new = _lines([10.0, 30.0, 50.0], rng, noise)
    x, y, v = (np.concatenate([a, b]) for a, b in zip(old, new, strict=True))
    before = fit_field(*old, GRID).values
    after = fit_field(x, y, v, GRID).values
    learning = metrics.learning_error(after, before)
    floor, sd_max = noise_floor(x, y, old[0].size, GRID, noise)
    assert 0.5 * floor < learning < 2.0 * floor, (learning, floor)
    assert 0 < floor < sd_max < noise


def test_no_floor_for_exact_samples_or_no_new_ones():
    x, y = np.array([1.0, 2.0, 3.0]), np.array([1.0, 1.0, 1.0])
    assert noise_floor(x, y, 2, GRID, 0.0) == (0.0, 0.0)
    assert noise_floor(x, y, 3, GRID, 1.0) == (0.0, 0.0)


def test_the_rule_does_not_fire_on_a_learning_error_at_its_noise_floor():
    """A learning error that has levelled off at what the noise makes is no convergence
    while what is left of it above the floor still falls; once the changes are all
    noise the field is learnt."""
    errors = [8.0, 2.0, 1.04, 1.02, 1.0]
    assert gamma_converged(errors, [0.0] * 5, 0.05, 90.0, 90.1)  # taken as it is
    floors = [0.0, 1.0, 1.0, 1.0, 1.0]
    assert not gamma_converged(errors, floors, 0.05, 90.0, 90.1)
    assert gamma_converged([*errors, 0.98, 0.99], [*floors, 1.0, 1.0], 0.05, 90.0, 90.1)


def test_the_span_may_move_by_what_the_noise_moves_it():
    errors, floors = [8.0, 1.0, 1.0, 1.0], [0.0] * 4
    assert not gamma_converged(errors, floors, 0.05, 90.0, 92.0)
    assert gamma_converged(errors, floors, 0.05, 90.0, 92.0, span_noise=1.5)
