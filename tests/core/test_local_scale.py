"""Plateaus averaged over their whole extent, slopes and peaks left to the spline.

Statistics over many samples: each check is a property the noisy reconstruction relies on.
"""

from __future__ import annotations

import numpy as np
import pytest

from econdor_gcs.core import metrics
from econdor_gcs.core.fields import paper_field, plume_field
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.local_scale import ScaleParams, widen_on_plateaus
from econdor_gcs.core.samples import _block_mean_counts
from econdor_gcs.core.smoothing import SmoothingParams, denoise, smooth_samples
from econdor_gcs.core.spline import fit_field

REGION = Region(0.0, 100.0, 0.0, 100.0)
GRID = Grid(REGION, 101, 101)


def survey(spacing_m: float, step_m: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    y = np.arange(0.0, 100.0 + 1e-9, step_m)
    xs = np.arange(spacing_m / 2, 100.0, spacing_m)
    return (np.repeat(xs, y.size),
            np.concatenate([y if i % 2 == 0 else y[::-1] for i in range(xs.size)]))


def plume(seed: int = 3):
    return plume_field(REGION, seed, sources=3, sigma_min_m=3.0, sigma_max_m=6.0,
                       background=10.0)


def smoothed_survey(field, sigma: float, spacing_m: float = 4.0, seed: int = 1):
    x, y = survey(spacing_m)
    v = field(x, y) + np.random.default_rng(seed).normal(0.0, sigma, x.size)
    xm, ym, vm, counts = _block_mean_counts(x, y, v, 0.5)
    spline = smooth_samples(xm, ym, vm, sigma, SmoothingParams(local_scale=None), counts).values
    return xm, ym, vm, counts, spline, field(xm, ym)


def test_a_plateau_is_averaged_over_its_extent_and_a_plume_keeps_the_spline():
    xm, ym, vm, counts, spline, truth = smoothed_survey(plume(), 1.0)
    out = widen_on_plateaus(xm, ym, vm, counts, spline, 1.0)
    flat = truth < 10.0 + 1e-3
    assert flat.mean() > 0.3
    err_spline = np.abs(spline - truth)
    err = np.abs(out.values - truth)
    # the background: several times better than one plane per tile
    assert err[flat].mean() < 0.4 * err_spline[flat].mean()
    assert np.median(out.half_width_m[flat]) >= 20.0
    # the plumes' upper halves: the spline's values, untouched
    peak = truth > 10.0 + 0.5 * (np.max(truth) - 10.0)
    assert peak.sum() > 50
    np.testing.assert_array_equal(out.values[peak], spline[peak])


def test_a_field_without_plateaus_is_left_to_the_spline():
    """On the paper's smooth field the samples alike in value are a narrow band along an
    iso-line: the plateau rule leaves almost every value as the spline made it, and the
    map no worse."""
    f = paper_field(REGION, 5)
    xm, ym, vm, counts, spline, truth = smoothed_survey(f, 1.0)
    out = widen_on_plateaus(xm, ym, vm, counts, spline, 1.0)
    changed = out.values != spline
    assert changed.mean() < 0.05
    assert np.abs(out.values - truth).mean() <= 1.01 * np.abs(spline - truth).mean()


def test_without_the_plateau_rule_a_slope_is_flattened():
    """The rule is what protects slopes: with ``plateau_share`` 0 the band's means replace
    the spline on the paper field and the map is worse (the test above can fail)."""
    f = paper_field(REGION, 5)
    xm, ym, vm, counts, spline, truth = smoothed_survey(f, 1.0)
    loose = widen_on_plateaus(xm, ym, vm, counts, spline, 1.0, ScaleParams(plateau_share=0.0))
    assert (loose.values != spline).mean() > 0.2
    assert np.abs(loose.values - truth).mean() > 1.05 * np.abs(spline - truth).mean()


@pytest.mark.parametrize("sigma", [1.0, 3.0])
def test_the_noisy_map_of_a_plume_is_better_with_plateaus(sigma):
    f = plume()
    truth = f(*GRID.mesh)
    x, y = survey(4.0)
    v = f(x, y) + np.random.default_rng(2).normal(0.0, sigma, x.size)
    with_plateaus = fit_field(x, y, v, GRID).values
    d = denoise(x, y, v, params=SmoothingParams(local_scale=None))
    from econdor_gcs.core.spline import reconstruct
    without = reconstruct(d.x, d.y, d.v, GRID, noise_std=0.0)
    assert metrics.mae(truth, with_plateaus) < 0.8 * metrics.mae(truth, without)


def test_exact_samples_never_reach_the_plateau_rule():
    f = plume()
    x, y = survey(5.0)
    v = f(x, y)
    d = denoise(x, y, v)
    assert not d.smoothed and d.v is v


def test_scale_params_reject_impossible_values():
    for bad in (dict(half_widths_m=(5.0,)), dict(half_widths_m=(10.0, 5.0)),
                dict(similar_sd=0.0), dict(gamma=-1.0), dict(plateau_share=1.5),
                dict(bins_per_half_width=0), dict(max_cells=10)):
        with pytest.raises(ValueError, match="ScaleParams"):
            ScaleParams(**bad)
    with pytest.raises(ValueError, match="noise_std"):
        widen_on_plateaus(np.zeros(3), np.zeros(3), np.zeros(3), np.ones(3), np.zeros(3), 0.0)
