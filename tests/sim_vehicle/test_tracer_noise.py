"""The tracer with a noisy or lagging sensor: the vehicle's own noise estimate and what the
crossing detector and the trace leg make of it (sim_vehicle.machine.noise)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from econdor_gcs.core.geometry import Region
from econdor_gcs.core.tasks import Phase, TraceTask, Waypoint
from sim_vehicle.body import SimBody
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
