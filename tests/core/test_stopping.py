"""The learning-error stop rule with noisy samples (econdor_gcs.core.stopping)."""

from __future__ import annotations

import numpy as np
import pytest

from econdor_gcs.core import metrics
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.spline import fit_field
from econdor_gcs.core.stopping import gamma_converged, noise_floor, sampled_enough

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


# A SITL run of the demo mission (docs/experiments/2026-12-05-sitl-stop.md): what each
# iteration after the diagonals flew. Iterations 3 and 4 traced
# one level each (delta dropped the rest) and flew 49 and 66 m.
SITL_FLOWN_M = [835.3, 1539.8, 48.8, 66.1, 2225.9]


def test_starved_iterations_are_not_read_as_convergence():
    """Three iterations that each flew a few tens of metres learn little, so their
    learning errors are small and alike (gamma about 1): the map has not converged, the
    fleet has hardly sampled anything new."""
    starved_e = [6.6, 0.99, 0.0036, 0.0038, 0.0037]
    starved_m = [835.0, 1540.0, 49.0, 66.0, 58.0]
    floors = [0.0] * 5
    assert not gamma_converged(starved_e, floors, 0.05, 90.0, 90.1, flown_m=starved_m)
    # the same errors after iterations that flew their share: levelled off
    assert gamma_converged(starved_e, floors, 0.05, 90.0, 90.1,
                           flown_m=[835.0, 1540.0, 900.0, 1100.0, 1000.0])


def test_gamma_is_taken_over_the_iterations_that_sampled_enough():
    """Starved iterations between sampled ones are skipped, not read as zeros or as
    levelling off; the rule fires only right after an iteration that sampled enough."""
    assert sampled_enough(SITL_FLOWN_M) == [True, True, False, False, True]
    floors = [0.0] * 5
    # levelled off over the sampled ones (1.0, 1.02, 0.99), starved ones in between
    errors = [1.0, 1.02, 0.003, 0.004, 0.99]
    assert gamma_converged(errors, floors, 0.05, 90.0, 90.1, flown_m=SITL_FLOWN_M)
    # ... but not while the last iteration is a starved one
    assert not gamma_converged(errors[:4], floors[:4], 0.05, 90.0, 90.1,
                               flown_m=SITL_FLOWN_M[:4])
    # an iteration that flew nothing sampled nothing
    assert sampled_enough([0.0, 0.0]) == [False, False]
