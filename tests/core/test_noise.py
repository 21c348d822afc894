"""Reconstruction from noisy samples: the noise estimate, the smoothing, what the DFC records.

Statistics over many samples, not single values: each check is a property the product
relies on (an estimate within a few per cent of the noise, none for exact samples, a map
better than interpolating the noise, more samples no worse than fewer).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from econdor_gcs.core import metrics
from econdor_gcs.core.fields import paper_field, plume_field
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.gp import Kriging, fit_matern
from econdor_gcs.core.noise import NOISE_FLOOR_REL, estimate_noise
from econdor_gcs.core.smoothing import (
    SmoothingParams,
    _Selection,
    _solve_smoothing,
    denoise,
    smooth_samples,
)
from econdor_gcs.core.spline import BiharmonicSpline, FastBiharmonicSpline, fit_field, reconstruct

REGION = Region(0.0, 100.0, 0.0, 100.0)
GRID = Grid(REGION, 101, 101)
BENCH_DATA = Path(__file__).resolve().parents[2] / "bench" / "data"


def survey(spacing_m: float, step_m: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """A boustrophedon survey in the order it is flown: north-south lines, alternately up
    and down, samples ``step_m`` apart along them."""
    y = np.arange(0.0, 100.0 + 1e-9, step_m)
    xs = np.arange(0.0, 100.0 + 1e-9, spacing_m)
    return (np.repeat(xs, y.size),
            np.concatenate([y if i % 2 == 0 else y[::-1] for i in range(xs.size)]))


def plume(seed: int = 3):
    return plume_field(REGION, seed, sources=3, sigma_min_m=3.0, sigma_max_m=6.0,
                       background=10.0)


# -- the noise estimate ---------------------------------------------------------------------
@pytest.mark.parametrize("sigma", [0.3, 1.0, 3.0])
@pytest.mark.parametrize("field", ["paper", "plume"])
def test_noise_is_estimated_within_a_few_percent_along_survey_lines(field, sigma):
    f = paper_field(REGION, 5) if field == "paper" else plume()
    x, y = survey(5.0)
    v = f(x, y) + np.random.default_rng(7).normal(0.0, sigma, x.size)
    est = estimate_noise(x, y, v)
    assert est.n_differences > 0.9 * x.size  # all but the windows across a turn
    assert est.noise_std == pytest.approx(sigma, rel=0.05)


def test_exact_samples_have_no_noise_even_where_the_track_weaves():
    """A vehicle weaving about its line (a 0.3 m zigzag every few samples) moves across the
    field's gradient between samples: that change is the field's, not noise."""
    f = paper_field(REGION, 5)
    x, y = survey(5.0)
    x = x + 0.3 * np.sin(np.arange(x.size) * 1.7)
    est = estimate_noise(x, y, f(x, y))
    assert est.noise_std == 0.0
    assert est.raw_std < 0.5 * NOISE_FLOOR_REL * est.spread


@pytest.mark.parametrize("name", ["paper-s0", "demo-mavlink", "threshold-paper-s9"])
def test_recorded_noise_free_runs_have_no_noise(name):
    """In process (tracing, searching, edge walks) and over MAVLink (float32 values,
    positions to the centimetre)."""
    with np.load(BENCH_DATA / f"{name}.npz") as d:
        est = estimate_noise(d["x_m"], d["y_m"], d["value"])
    assert est.n_differences > 1000
    assert est.noise_std == 0.0
    assert est.raw_std < 0.2 * NOISE_FLOOR_REL * est.spread


def test_scattered_samples_give_no_estimate():
    """Consecutive samples far apart are not along a track: nothing is estimated from them
    (and nothing smoothed)."""
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0, 100, 3000), rng.uniform(0, 100, 3000)
    v = paper_field(REGION, 1)(x, y) + rng.normal(0.0, 1.0, x.size)
    est = estimate_noise(x, y, v)
    assert est.n_differences < 30 and est.noise_std == 0.0 and math.isnan(est.raw_std)


def test_jumps_between_tracks_are_left_out():
    """Two vehicles' samples one after the other: the windows across the jump from one's
    last sample to the other's first are not used."""
    f = paper_field(REGION, 2)
    x1, y1 = survey(10.0)
    x2, y2 = x1[::-1] + 5.0, y1[::-1]
    x, y = np.r_[x1, x2], np.r_[y1, y2]
    v = f(x, y) + np.r_[np.zeros(x1.size), 1e3 * (x2 > 80)]  # a jump of 1000 at the seam
    est = estimate_noise(x, y, v)
    assert est.noise_std == 0.0


# -- the smoothing ----------------------------------------------------------------------------
def test_smoothing_shrinks_the_noise_and_keeps_a_plume_peak():
    f = plume()
    x, y = survey(2.5)
    truth = f(x, y)
    v = truth + np.random.default_rng(1).normal(0.0, 1.0, x.size)
    s = smooth_samples(x, y, v, 1.0)
    err_raw = np.abs(v - truth)
    err = np.abs(s.values - truth)
    assert err.mean() < 0.3 * err_raw.mean()
    peak = truth > truth.min() + 0.5 * np.ptp(truth)
    assert peak.any() and err[peak].mean() < err_raw[peak].mean()
    assert s.damping_m2.max() > 1e3 * s.damping_m2.min()  # flat background vs peaks


def test_the_selection_and_the_bordered_solve_give_the_same_smoothing_spline():
    """Two ways to the same values (eigendecomposition projected off the plane; the
    bordered system), with cell counts as weights."""
    from econdor_gcs.core.greens import _Blocks

    rng = np.random.default_rng(4)
    pts = rng.uniform(0, 20, (120, 2))
    v = np.sin(pts[:, 0] / 3) + rng.normal(0.0, 0.3, 120)
    weight = rng.integers(1, 4, 120).astype(float)
    blocks = _Blocks()
    sel = _Selection(blocks, pts, v, weight)
    from econdor_gcs.core.smoothing import _choose_damping

    lam = float(_choose_damping([sel], 0.3, np.array([0.5, 5.0, 50.0]), 1.0)[0])
    np.testing.assert_allclose(sel.fitted(lam), _solve_smoothing(blocks, pts, v, weight, lam),
                               atol=1e-8)


def test_exact_samples_are_interpolated_as_before():
    """No noise found: the samples go to the interpolation untouched, so the estimate is
    bit for bit the one taking them as exact."""
    f = paper_field(REGION, 3)
    x, y = survey(4.0)
    v = f(x, y)
    rec = fit_field(x, y, v, GRID)
    assert rec.noise_std == 0.0
    np.testing.assert_array_equal(rec.values, reconstruct(x, y, v, GRID, noise_std=0.0))
    d = denoise(x, y, v)
    assert not d.smoothed and d.x is x and d.v is v


@pytest.mark.parametrize("sigma", [1.0, 3.0])
def test_noisy_survey_maps_beat_interpolation_and_improve_with_more_lines(sigma):
    """The issue's complaint: the survey that flew twice as far made a worse map."""
    f = plume()
    truth = f(*GRID.mesh)
    maes = {}
    for spacing in (5.0, 2.5):
        x, y = survey(spacing)
        v = f(x, y) + np.random.default_rng(2).normal(0.0, sigma, x.size)
        rec = fit_field(x, y, v, GRID)
        assert rec.noise_std == pytest.approx(sigma, rel=0.1)
        maes[spacing] = metrics.mae(truth, rec.values)
        interpolated = metrics.mae(truth, reconstruct(x, y, v, GRID, noise_std=0.0))
        assert maes[spacing] < 0.6 * interpolated
    assert maes[2.5] < maes[5.0]


def test_the_estimators_smooth_and_say_what_noise_they_assumed():
    f = plume()
    x, y = survey(5.0)
    v = f(x, y) + np.random.default_rng(5).normal(0.0, 1.0, x.size)
    fast = FastBiharmonicSpline().fit(x, y, v)
    assert fast.noise_std_ == pytest.approx(1.0, rel=0.1) and fast.damping_m2_.size > 0
    assert fast.n_samples_ == x.size
    exact = BiharmonicSpline(noise_std=0.0).fit(x[:900], y[:900], v[:900])
    assert exact.noise_std_ == 0.0
    np.testing.assert_allclose(exact.predict(x[:900], y[:900]), v[:900], atol=1e-6)
    with pytest.raises(ValueError, match="noise_std"):
        BiharmonicSpline(noise_std=-1.0).fit(x, y, v)


def test_smoothing_params_reject_impossible_values():
    with pytest.raises(ValueError, match="overlap"):
        SmoothingParams(overlap_m=6.0, margin_m=5.0)
    with pytest.raises(ValueError, match="damping"):
        SmoothingParams(damping_range_m2=(10.0, 1.0))


# -- kriging ----------------------------------------------------------------------------------
@pytest.mark.slow
def test_kriging_fits_with_the_estimated_noise_and_its_std_shows_it():
    f = paper_field(REGION, 6)
    x, y = survey(10.0)
    v = f(x, y)
    noisy = v + np.random.default_rng(3).normal(0.0, 1.0, x.size)
    exact = Kriging().fit(x, y, v)
    model = Kriging().fit(x, y, noisy)
    assert exact.noise_std_ == 0.0 and exact.counts_ is None
    assert model.noise_std_ == pytest.approx(1.0, rel=0.1)
    h = model.hyper_
    assert h.amplitude * math.sqrt(h.nugget) == pytest.approx(model.noise_std_, rel=1e-9)
    _, sd_exact = exact.predict(x[::50], y[::50], return_std=True)
    _, sd = model.predict(x[::50], y[::50], return_std=True)
    # on a sample the exact model is sure; the noisy one only as sure as a few
    # neighbouring samples' mean
    assert np.median(sd) > 10 * np.median(sd_exact) and 0.1 < np.median(sd) < 1.0
    truth = f(*GRID.mesh)
    rec = fit_field(x, y, noisy, GRID, method="kriging", return_std=True)
    assert rec.std is not None and rec.std.shape == GRID.shape
    assert metrics.mae(truth, rec.values) < 0.5 * metrics.mae(
        truth, Kriging(noise_std=0.0).fit(x, y, noisy).predict(*GRID.mesh))


def test_fit_matern_with_known_noise_finds_the_length_scale():
    rng = np.random.default_rng(8)
    x, y = rng.uniform(0, 60, 500), rng.uniform(0, 60, 500)
    d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    from econdor_gcs.core.gp import matern

    c = 4.0 * matern(d / 8.0, 2.5) + 1e-8 * np.eye(x.size)
    v = 3.0 + np.linalg.cholesky(c) @ rng.normal(size=x.size) + rng.normal(0, 0.5, x.size)
    h = fit_matern(x, y, v, max_points=500, noise_std=0.5)
    assert h.length_m == pytest.approx(8.0, rel=0.3)
    assert h.amplitude == pytest.approx(2.0, rel=0.3)
    assert h.amplitude**2 * h.nugget == pytest.approx(0.25, rel=1e-9)


# -- the DFC ------------------------------------------------------------------------------------
@pytest.mark.parametrize("noise", [0.0, 1.0])
def test_the_dfc_records_the_noise_it_estimated(noise):
    from econdor_gcs.config import parse_mission
    from econdor_gcs.dfc.loop import Dfc
    from econdor_lab.inprocess import InProcessExecutor

    raw = {"name": "noisy", "field": {"model": "plume", "sources": 3, "sigma_min_m": 3.0,
                                      "sigma_max_m": 6.0, "background": 10.0},
           "vehicles": {"count": 1, "noise_std": noise},
           "algorithm": {"planner": "lawnmower", "max_iterations": 1, "min_iterations": 1},
           "lawnmower": {"budget_m": 1100.0}}
    m = parse_mission(raw, base_dir=Path(__file__).resolve().parents[2] / "missions")
    field = m.build_field(1)
    result = Dfc(m, InProcessExecutor(m, field, seed=1), planner="lawnmower", truth=field,
                 seed=1).run()
    estimates = [r.noise_std for r in result.records]
    if noise == 0.0:
        assert estimates == [0.0] * len(estimates)
    else:
        assert estimates[-1] == pytest.approx(noise, rel=0.1)
    assert result.summary()["noise_std"] == estimates[-1]


@pytest.mark.parametrize("name", ["plume-noise1-s900", "plume-noise3-s900", "paper-noise1-s0",
                                  "paper-noise3-s0"])
def test_recorded_noisy_runs_have_their_sensor_noise_estimated(name):
    """Real runs with noise (the adaptive planner's and E-CONDOR's traces, searches,
    transits): the estimate is within a few per cent of the sensor's noise."""
    import json

    with np.load(BENCH_DATA / f"{name}.npz") as d:
        est = estimate_noise(d["x_m"], d["y_m"], d["value"])
        sensor = json.loads(str(d["meta"]))["noise_std"]
    assert est.noise_std == pytest.approx(sensor, rel=0.05)


def test_fit_matern_started_from_a_previous_optimum_finds_the_same_one():
    """A planner refits after each flight from the last optimum: one descent from there
    finds what three searches from afar find."""
    rng = np.random.default_rng(9)
    x, y = rng.uniform(0, 60, 600), rng.uniform(0, 60, 600)
    d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    from econdor_gcs.core.gp import matern

    c = 4.0 * matern(d / 8.0, 2.5) + 1e-8 * np.eye(x.size)
    v = 3.0 + np.linalg.cholesky(c) @ rng.normal(size=x.size) + rng.normal(0, 0.5, x.size)
    before = fit_matern(x[:300], y[:300], v[:300], max_points=300, noise_std=0.5)
    cold = fit_matern(x, y, v, max_points=600, noise_std=0.5)
    warm = fit_matern(x, y, v, max_points=600, noise_std=0.5, start=before)
    assert warm.length_m == pytest.approx(cold.length_m, rel=0.02)
    assert warm.amplitude == pytest.approx(cold.amplitude, rel=0.02)
    # a start far from the optimum still descends to it
    far = dataclasses.replace(before, length_m=60.0, amplitude=0.1)
    assert fit_matern(x, y, v, max_points=600, noise_std=0.5, start=far).length_m == \
        pytest.approx(cold.length_m, rel=0.05)


def test_the_planner_fits_its_gp_to_noisy_samples_again_only_as_they_grow(monkeypatch):
    from econdor_gcs.core.adaptive import AdaptiveParams, adaptive_planner, base
    from econdor_gcs.core.planners import PlanContext
    from econdor_gcs.core.spline import reconstruct
    from econdor_gcs.core.tasks import SampleLog

    calls: list[tuple[int, object]] = []

    def counted(x, y, v, **kw):
        calls.append((len(x), kw.get("start")))
        return fit_matern(x, y, v, **kw)

    monkeypatch.setattr(base, "fit_matern", counted)
    rng = np.random.default_rng(3)
    x, y = rng.uniform(0, 100, 1400), rng.uniform(0, 100, 1400)
    v = np.sin(x / 15.0) + np.cos(y / 20.0) + rng.normal(0, 0.1, x.size)
    planner = adaptive_planner(AdaptiveParams(model="gp"))

    def plan(n: int, noise: float) -> None:
        s = SampleLog(np.arange(n) * 0.1, x[:n], y[:n], v[:n], np.zeros(n, np.int8),
                      np.zeros(n, np.int16))
        est = reconstruct(s.x_m, s.y_m, s.value, GRID, noise_std=noise)
        planner.uncertainty(PlanContext(iteration=n, region=REGION, n_vehicles=1, grid=GRID,
                                        estimate=est, samples=s, noise_std=noise))

    plan(300, 0.1)
    first = planner.hyper
    assert first is not None and calls == [(300, None)]
    plan(330, 0.2)  # grown by a tenth: the last fit, its nugget of the new noise
    assert len(calls) == 1 and planner.hyper is not None
    assert planner.hyper.length_m == first.length_m
    assert planner.hyper.nugget == pytest.approx((0.2 / first.amplitude) ** 2)
    plan(380, 0.1)  # by more than a fifth: one descent from the last optimum
    assert len(calls) == 2 and calls[1][0] == 380 and calls[1][1] == first
    plan(700, 0.1)  # doubled since the search from afar: searched from afar again
    assert calls[2] == (700, None)
    plan(760, 0.0)  # exact samples: the length alone, searched every plan
    plan(770, 0.0)
    assert [n for n, _ in calls[3:]] == [760, 770]
