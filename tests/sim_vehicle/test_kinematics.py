"""Point-mass kinematics and the simulated body's clock and sensor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from econdor_gcs.core.geometry import Region, path_length
from sim_vehicle.body import Sample, SimBody
from sim_vehicle.kinematics import (
    TURN_LIMIT_MIN_SPEED_MPS,
    PointMass,
    VehicleLimits,
    wrap_angle_rad,
)

LIMITS = VehicleLimits(max_speed_mps=10.0, max_accel_mps2=5.0, max_turn_rate_dps=90.0)


def _random_flight(n_steps: int, dt_s: float, seed: int) -> tuple[PointMass, np.ndarray]:
    """Fly random, often infeasible commands; return the mass and (x, y, vx, vy) history."""
    rng = np.random.default_rng(seed)
    pm = PointMass(3.0, -2.0, LIMITS)
    hist = [(pm.x_m, pm.y_m, pm.vx_mps, pm.vy_mps)]
    cmd = (0.0, 0.0)
    for k in range(n_steps):
        if k % 7 == 0:
            cmd = tuple(rng.uniform(-20.0, 20.0, size=2))
        pm.step(dt_s, *cmd)
        hist.append((pm.x_m, pm.y_m, pm.vx_mps, pm.vy_mps))
    return pm, np.array(hist)


def test_speed_limit_and_reaches_it() -> None:
    pm = PointMass(0.0, 0.0, LIMITS)
    speeds = []
    for _ in range(100):
        pm.step(0.05, 100.0, 0.0)
        speeds.append(pm.speed_mps)
    assert max(speeds) <= LIMITS.max_speed_mps + 1e-9
    assert speeds[-1] == pytest.approx(LIMITS.max_speed_mps)
    # from rest it takes max_speed / max_accel seconds to get there
    assert speeds[int(1.0 / 0.05) - 1] == pytest.approx(5.0, abs=1e-9)


def test_accel_and_turn_rate_limits_on_random_commands() -> None:
    dt_s = 0.02
    _, hist = _random_flight(3000, dt_s, seed=4)
    v = hist[:, 2:4]
    speed = np.hypot(v[:, 0], v[:, 1])
    dv = np.hypot(*np.diff(v, axis=0).T)
    assert speed.max() <= LIMITS.max_speed_mps + 1e-9
    assert dv.max() <= LIMITS.max_accel_mps2 * dt_s + 1e-9
    assert dv.max() > 0.99 * LIMITS.max_accel_mps2 * dt_s  # limit actually active
    moving = (speed[:-1] >= TURN_LIMIT_MIN_SPEED_MPS) & (speed[1:] > 1e-9)
    heading = np.arctan2(v[:, 1], v[:, 0])
    turn = np.abs([wrap_angle_rad(h1 - h0) for h0, h1 in zip(heading[:-1], heading[1:],
                                                              strict=True)])
    max_turn = math.radians(LIMITS.max_turn_rate_dps) * dt_s
    assert turn[moving].max() <= max_turn + 1e-9
    assert turn[moving].max() > 0.99 * max_turn


def test_odometer_equals_path_length() -> None:
    pm, hist = _random_flight(2000, 0.05, seed=9)
    assert pm.odometer_m > 100.0
    assert pm.odometer_m == pytest.approx(path_length(hist[:, 0], hist[:, 1]), rel=1e-9)


def test_reverse_command_brakes_before_turning() -> None:
    pm = PointMass(0.0, 0.0, LIMITS)
    for _ in range(40):
        pm.step(0.05, 8.0, 0.0)
    assert pm.speed_mps == pytest.approx(8.0)
    speeds = []
    for _ in range(200):
        pm.step(0.05, -8.0, 0.0)
        speeds.append(pm.speed_mps)
    # braking at max_accel: speed decreases monotonically first, ends up flying -x
    assert speeds[10] < speeds[0] < 8.0
    assert pm.vx_mps == pytest.approx(-8.0, abs=1e-6)
    assert abs(pm.vy_mps) < 1e-6


def test_invalid_inputs() -> None:
    pm = PointMass(0.0, 0.0, LIMITS)
    with pytest.raises(ValueError):
        pm.step(0.0, 1.0, 0.0)
    with pytest.raises(ValueError):
        pm.step(0.1, math.nan, 0.0)
    with pytest.raises(ValueError):
        VehicleLimits(max_speed_mps=-1.0)


def test_body_tick_clock_and_own_position_sensing() -> None:
    calls: list[tuple[float, float]] = []
    region = Region(0.0, 100.0, 0.0, 100.0)

    def field(x: float, y: float) -> float:
        assert isinstance(x, np.float64) and isinstance(y, np.float64)
        calls.append((float(x), float(y)))
        return np.float64(2.0 * x + y)

    body = SimBody(field, region, 10.0, 20.0, sample_rate_hz=20.0, t_s=5.0)
    assert body.dt_s == pytest.approx(0.05)
    samples: list[Sample] = []
    for k in range(100):
        samples.append(body.tick(6.0, -3.0, 2) if k < 40 else body.hold(1))
        assert calls[-1] == (body.x_m, body.y_m)
        assert samples[-1].x_m == body.x_m and samples[-1].y_m == body.y_m
    assert len(calls) == 100
    t = np.array([s.t_s for s in samples])
    assert t[0] == pytest.approx(5.05)
    assert np.allclose(np.diff(t), 0.05)
    assert all(s.value == pytest.approx(2.0 * s.x_m + s.y_m) for s in samples)
    assert samples[0].phase == 2 and samples[-1].phase == 1
    assert body.speed_mps < 1e-9  # hold() brakes to a stop
    xs = np.array([10.0] + [s.x_m for s in samples])
    ys = np.array([20.0] + [s.y_m for s in samples])
    assert body.odometer_m == pytest.approx(path_length(xs, ys))


def test_body_noise_is_gaussian_with_given_std() -> None:
    body = SimBody(lambda x, y: 0.0 * x + 7.0, Region(0, 10, 0, 10), 5.0, 5.0,
                   noise_std=0.5, rng=np.random.default_rng(0))
    vals = np.array([body.hold(0).value for _ in range(4000)])
    assert vals.mean() == pytest.approx(7.0, abs=0.05)
    assert vals.std() == pytest.approx(0.5, rel=0.05)
