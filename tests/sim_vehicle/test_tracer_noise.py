"""The tracer with a noisy or lagging sensor: the vehicle's own noise estimate and what the
crossing detector and the trace leg make of it (sim_vehicle.machine.noise)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from econdor_gcs.core.geometry import Region
from econdor_gcs.core.tasks import Phase, TraceTask, Waypoint
from sim_vehicle.body import SimBody
from sim_vehicle.machine import fits
from sim_vehicle.machine import noise as onboard
from sim_vehicle.sensor import SensorModel
from sim_vehicle.tracer import TracerParams, run_task_batch

REGION = Region(0.0, 100.0, 0.0, 100.0)
SIGMA_M = 25.0


def _field(x, y):
    return 100.0 * np.exp(-((x - 50.0) ** 2 + (y - 50.0) ** 2) / (2.0 * SIGMA_M**2))


def _level_at(r_m: float) -> float:
    return 100.0 * math.exp(-(r_m**2) / (2.0 * SIGMA_M**2))


def _estimate(body: SimBody) -> float:
    return float(onboard.noise_std(body.state[0]))


@pytest.mark.parametrize("noise_std", [0.5, 2.0])
def test_the_vehicle_estimates_its_noise_in_transit_and_tracing(noise_std: float) -> None:
    body = SimBody(_field, REGION, 5.0, 5.0, sensor=SensorModel(noise_std=noise_std),
                   rng=np.random.default_rng(3))
    run_task_batch(body, Waypoint(90.0, 60.0))  # across the bump, in transit
    assert _estimate(body) == pytest.approx(noise_std, rel=0.15)
    task = TraceTask(_level_at(20.0), 74.0, 50.0, 10.0, 0.0, 0)
    run_task_batch(body, task, TracerParams(speed_mps=8.0))
    # the estimate forgets at 1/1000 per reading (the vehicle keeps it across tasks)
    assert _estimate(body) == pytest.approx(noise_std, rel=0.1)


def test_noise_free_readings_are_not_taken_for_noise() -> None:
    # the path's kinks and the field's shape leave a small residual in the differences,
    # not white: the estimate stays 0 and the tracer keeps its tuned, noise-free behaviour
    body = SimBody(_field, REGION, 5.0, 5.0)
    run_task_batch(body, Waypoint(90.0, 60.0))
    run_task_batch(body, TraceTask(_level_at(20.0), 74.0, 50.0, 10.0, 0.0, 0),
                   TracerParams(speed_mps=8.0))
    st = body.state[0]
    assert st["noise_n"] > 400 and st["noise_var"] > 0.0  # a residual there is
    assert _estimate(body) == 0.0
    assert onboard.filter_gain(st) == 1.0


def test_filter_gain_falls_with_the_noise_against_the_signal() -> None:
    rec = np.zeros(1, dtype=SimBody(_field, REGION, 0.0, 0.0).state.dtype)[0]
    rec["noise_n"] = 1000
    rec["noise_var"] = rec["noise_var5"] = 1.0
    gains = []
    for signal in (10.0, 0.3, 0.1):  # rms change per reading: the noise adds 2 sigma^2
        rec["diff_var"] = signal**2 + 2.0
        gains.append(onboard.filter_gain(rec))
    assert gains[0] == 1.0
    assert 1.0 > gains[1] > gains[2] >= 0.05


def test_alpha_beta_gains_are_the_tuned_ones_without_noise() -> None:
    assert onboard.alpha_beta_gains(0.0, 2.0, 0.1) == (1.0, 2.0)
    a1, b1 = onboard.alpha_beta_gains(0.01, 2.0, 0.1)
    a2, b2 = onboard.alpha_beta_gains(1.0, 2.0, 0.1)
    assert 1.0 > a1 > a2 > 0.0 and b1 > b2 > 0.0


def _trace_circle(noise_std: float, seed: int, lag_s: float = 0.0):
    body = SimBody(_field, REGION, 5.0, 5.0, sensor=SensorModel(noise_std=noise_std,
                                                                 lag_s=lag_s),
                   rng=np.random.default_rng(seed))
    task = TraceTask(_level_at(20.0), 50.0 + 24.0 * math.cos(0.4),
                     50.0 + 24.0 * math.sin(0.4), 10.0, 0.0, 7)
    rows, outcome = run_task_batch(body, task, TracerParams(speed_mps=8.0,
                                                            sensor_lag_s=lag_s))
    trace = rows[rows[:, 4] == int(Phase.TRACE)]
    dist = np.abs(np.hypot(trace[:, 1] - 50.0, trace[:, 2] - 50.0) - 20.0)
    return outcome, dist


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_noisy_circle_is_traced_and_closed(seed: int) -> None:
    # noise 1 on a gradient of 2.3 /m: 0.43 m of offset per reading
    outcome, dist = _trace_circle(1.0, seed)
    assert outcome.status == "closed"
    assert np.percentile(dist, 90) < 1.2


@pytest.mark.parametrize("noise_std", [0.0, 1.0])
def test_a_lag_of_unknown_size_changes_only_a_noisy_traces_filter(noise_std: float) -> None:
    """``lag_unknown`` (the station estimates the lag and has no estimate yet) sets the
    trace leg's filter as a told lag does, compensating none: a noisy trace is flown
    otherwise than with no lag told, and still closed; a noise-free one exactly as before
    (the filter's gains are the tuned ones there either way)."""

    def trace(unknown: bool) -> tuple[np.ndarray, str]:
        body = SimBody(_field, REGION, 5.0, 5.0, sensor=SensorModel(noise_std=noise_std),
                       rng=np.random.default_rng(4))
        task = TraceTask(_level_at(20.0), 74.0, 50.0, 10.0, 0.0, 0)
        rows, outcome = run_task_batch(body, task, TracerParams(speed_mps=8.0,
                                                                lag_unknown=unknown))
        return rows, outcome.status

    (told, status), (untold, _) = trace(True), trace(False)
    assert status == "closed"
    assert np.array_equal(told, untold) == (noise_std == 0.0)


def _line_fit(rng: np.random.Generator, noise_std: float, sigma: float, across_m: float = 0.03
              ) -> tuple[float, float]:
    """A plane fit through 20 noisy readings of the plane ``1.5 x + 0.5 y`` taken every
    0.8 m along the x axis, the track wandering ``across_m`` (rms) across it."""
    buf = np.zeros((20, 3))
    buf[:, 0] = 0.8 * np.arange(20)
    buf[:, 1] = across_m * rng.standard_normal(20)
    buf[:, 2] = 1.5 * buf[:, 0] + 0.5 * buf[:, 1] + noise_std * rng.standard_normal(20)
    gx, gy, _ = fits.fit_gradient(buf, 0, 20, 20, 1e-4, sigma)
    return gx, gy


def _fits(noise_std: float, sigma: float, across_m: float = 0.03) -> np.ndarray:
    rng = np.random.default_rng(5)
    return np.array([_line_fit(rng, noise_std, sigma, across_m) for _ in range(300)])


def test_a_gradient_fitted_along_a_straight_track_keeps_little_of_the_noise_across_it() -> None:
    raw, shrunk = _fits(1.0, 0.0), _fits(1.0, 1.0)
    steep_raw = np.hypot(raw[:, 0], raw[:, 1]) / 1.5
    steep = np.hypot(shrunk[:, 0], shrunk[:, 1]) / 1.5
    # the plain fit: the slope across the track is the noise over a few centimetres, and
    # most crossings on a straight line get a gradient more than twice the true one
    assert np.median(np.abs(raw[:, 1])) > 3.0 and np.mean(steep_raw > 2.0) > 0.6
    # shrunk for the noise: a quarter of the slope across, half as many twice too steep,
    # the slope along the track as it was
    assert np.median(np.abs(shrunk[:, 1])) < 0.3 * np.median(np.abs(raw[:, 1]))
    assert np.mean(steep > 2.0) < 0.5 * np.mean(steep_raw > 2.0)
    assert np.median(np.abs(shrunk[:, 0] - 1.5)) < 0.1


def test_a_gradient_fitted_over_samples_that_span_both_ways_is_kept() -> None:
    """Samples a few metres across the track (a turn) measure both components: the
    shrinkage leaves them."""
    raw, shrunk = _fits(0.3, 0.0, across_m=3.0), _fits(0.3, 0.3, across_m=3.0)
    assert np.median(np.abs(shrunk[:, 1] - 0.5)) < 0.1
    assert np.median(np.abs(shrunk - raw)) < 0.02


def test_noise_free_readings_are_fitted_as_they_are() -> None:
    """sigma 0: the slope across the track too (less what the fit's ridge of 1e-4 m^2
    takes from a spread of 0.03 m)."""
    rng = np.random.default_rng(5)
    assert _line_fit(rng, 0.0, 0.0) == pytest.approx((1.5, 0.5), rel=0.15)
