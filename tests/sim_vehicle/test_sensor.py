"""The sensor model (noise, lag, GNSS position error) of the simulated vehicles, in the
mission. The station's lag correction is in ``test_lag.py``.

What a sample holds is checked by statistics over many samples against the model
(:mod:`sim_vehicle.sensor`): the noise's standard deviation within a confidence band, the
lag as the time constant fitted to a step response and as the offset on a ramp, the
position error's standard deviation and correlation time. The in-process body here; the
MAVLink vehicle in ``test_sensor_mavlink.py``.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from econdor_gcs.config import load_mission, parse_mission
from econdor_gcs.core.tasks import Phase, SampleLog, TraceTask, Waypoint
from econdor_gcs.errors import MissionError
from econdor_lab.inprocess import InProcessExecutor, sensor_model
from sim_vehicle.body import SimBody
from sim_vehicle.executor import run_plan
from sim_vehicle.sensor import SensorModel
from sim_vehicle.state import VehicleSettings, VehicleState
from tests.helpers.sensor import BIG, LIMITS, fly, ramp_x

ROOT = Path(__file__).resolve().parents[2]
def cruising(s: SampleLog, speed_mps: float = 8.0) -> np.ndarray:
    """Samples at full speed on the straight (no acceleration, no braking)."""
    v = np.hypot(np.gradient(s.x_m, s.t_s), np.gradient(s.y_m, s.t_s))
    return np.abs(v - speed_mps) < 0.05


# --------------------------------------------------------------------------- the model

def test_the_default_sensor_is_perfect():
    body, s = fly(SensorModel())
    assert np.array_equal(s.value, s.x_m)
    assert body.true_x_m == body.x_m


def test_model_rejects_impossible_values():
    for bad in ({"noise_std": -1.0}, {"lag_s": math.nan}, {"position_std_m": -0.1},
                {"position_tau_s": 0.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            SensorModel(**bad)
    with pytest.raises(ValueError, match="noise_std given twice"):
        SimBody(ramp_x, BIG, 0.0, 0.0, noise_std=1.0, sensor=SensorModel(noise_std=2.0))


def test_noise_is_white_gaussian_with_its_std():
    sigma = 0.7
    _, s = fly(SensorModel(noise_std=sigma), legs=((1900.0, 1000.0), (100.0, 1000.0)))
    r = s.value - s.x_m
    n = len(r)
    assert n > 4000
    # the sample std of n normal values: relative standard error 1 / sqrt(2n)
    assert abs(r.std() / sigma - 1.0) < 4.0 / math.sqrt(2 * n)
    assert abs(r.mean()) < 4.0 * sigma / math.sqrt(n)
    lag1 = np.corrcoef(r[1:], r[:-1])[0, 1]
    assert abs(lag1) < 4.0 / math.sqrt(n)
    # Gaussian: the fraction beyond 2 sigma
    beyond = np.mean(np.abs(r) > 2 * sigma)
    assert abs(beyond - 0.0455) < 4.0 * math.sqrt(0.0455 * 0.9545 / n)


@pytest.mark.parametrize("lag_s", [0.5, 1.0, 3.0])
def test_lag_is_the_time_constant_of_a_step_response(lag_s):
    def step(x, y):
        return np.where(np.asarray(x) > 1000.0, 100.0, 0.0) + 0.0 * np.asarray(y)

    _, s = fly(SensorModel(lag_s=lag_s), field=step)
    after = s.x_m > 1000.0
    t0 = s.t_s[after][0]
    t, v = s.t_s[after], s.value[after]
    keep = (v < 99.0) & (t - t0 < 5 * lag_s)
    # 100 - v = A exp(-(t - t0) / tau): the fitted slope of the log is -1 / tau
    slope = np.polyfit(t[keep] - t0, np.log(100.0 - v[keep]), 1)[0]
    assert -1.0 / slope == pytest.approx(lag_s, rel=0.01)
    assert np.all(s.value[~after] == 0.0)


def test_lag_on_a_ramp_is_speed_times_lag():
    _, s = fly(SensorModel(lag_s=1.0))
    c = cruising(s)
    c[: np.argmax(c) + 150] = False  # settled: many time constants after the acceleration
    assert c.sum() > 1000
    assert np.allclose(s.x_m[c] - s.value[c], 8.0 * 1.0, atol=1e-3)


def test_lag_and_noise_together_noise_on_top():
    _, s = fly(SensorModel(lag_s=1.0, noise_std=0.5), seed=3)
    c = cruising(s)
    c[: np.argmax(c) + 150] = False
    r = s.x_m[c] - 8.0 - s.value[c]
    assert abs(r.std() / 0.5 - 1.0) < 4.0 / math.sqrt(2 * c.sum())


def position_errors(std_m: float, tau_s: float, seed: int, axis: int = 0) -> np.ndarray:
    """The GNSS error along ``axis`` of one long flight, read from its samples: the field is
    that coordinate, so a sample's value is the true one and its position the believed."""
    def field(x, y):
        return np.asarray(y if axis else x, dtype=float) + 0.0 * np.asarray(x)

    legs = [(1900.0, 1900.0), (100.0, 100.0)] * 8
    _, s = fly(SensorModel(position_std_m=std_m, position_tau_s=tau_s), field=field,
               legs=legs, seed=seed, start=(100.0, 100.0))
    return (s.y_m if axis else s.x_m) - s.value


@pytest.mark.slow
def test_position_error_std_and_correlation_time():
    std_m, tau_s = 1.0, 10.0
    errors = [position_errors(std_m, tau_s, seed, axis=seed % 2) for seed in range(6)]
    e = np.concatenate(errors)
    total_s = len(e) * 0.1
    n_eff = total_s / (2.0 * tau_s)  # independent stretches of a Gauss-Markov process
    assert n_eff > 300
    assert abs(e.std() / std_m - 1.0) < 4.0 / math.sqrt(2 * n_eff)
    assert abs(e.mean()) < 4.0 * std_m / math.sqrt(n_eff)
    # the AR(1) coefficient per tick gives the correlation time
    phi = sum(float(np.dot(x[1:], x[:-1])) for x in errors) / \
        sum(float(np.dot(x[:-1], x[:-1])) for x in errors)
    assert -0.1 / math.log(phi) == pytest.approx(tau_s, rel=0.15)
    # the autocorrelation at one correlation time is 1/e
    k = int(tau_s / 0.1)
    rho = sum(float(np.dot(x[k:], x[:-k])) for x in errors) / \
        sum(float(np.dot(x, x)) for x in errors)
    assert rho == pytest.approx(math.exp(-1.0), abs=0.12)


def test_the_vehicle_flies_its_believed_position_on_a_smooth_true_path():
    body, s = fly(SensorModel(position_std_m=2.0, position_tau_s=5.0),
                  legs=((1000.0, 1000.0),), seed=1)
    # it ends where its GNSS says the waypoint is, and is truly off by the GNSS error
    assert math.hypot(body.x_m - 1000.0, body.y_m - 1000.0) < 1.0
    err = math.hypot(body.x_m - body.true_x_m, body.y_m - body.true_y_m)
    assert err > 0.0
    assert err == pytest.approx(math.hypot(*(body.sensor[0][k] for k in ("ex_m", "ey_m"))))
    # the odometer is the smooth true path (the believed one jitters with the error)
    believed = float(np.sum(np.hypot(np.diff(s.x_m), np.diff(s.y_m))))
    assert body.odometer_m < believed
    assert body.odometer_m == pytest.approx(900.0, rel=0.01)


def test_draws_are_seeded_per_vehicle_and_noise_kept_when_position_error_is_added():
    a = fly(SensorModel(noise_std=1.0, lag_s=0.5, position_std_m=1.0), seed=4)[1]
    b = fly(SensorModel(noise_std=1.0, lag_s=0.5, position_std_m=1.0), seed=4)[1]
    c = fly(SensorModel(noise_std=1.0, lag_s=0.5, position_std_m=1.0), seed=5)[1]
    assert np.array_equal(a.value, b.value) and np.array_equal(a.x_m, b.x_m)
    assert not np.array_equal(a.value, c.value)
    # the reading noise comes from its own stream: adding a GNSS error leaves it as it was
    plain = fly(SensorModel(noise_std=1.0), seed=4)[1]
    located = fly(SensorModel(noise_std=1.0, position_std_m=1.0), seed=4)[1]
    n = min(len(plain), len(located))
    truth_err = located.x_m[:n] - located.value[:n]  # noise minus the GNSS error
    assert not np.allclose(truth_err, plain.x_m[:n] - plain.value[:n])


def test_python_ticks_and_compiled_ticks_sense_alike():
    """The body's own ticks (the MAVLink vehicle's hover) run the same sensor model as
    the compiled tracer: a body that hovers with lag reads the settled value."""
    body = SimBody(ramp_x, BIG, 500.0, 500.0, limits=LIMITS,
                   sensor=SensorModel(lag_s=1.0, position_std_m=1.0),
                   rng=np.random.default_rng(0))
    run_plan(body, [Waypoint(600.0, 500.0)])
    readings = [body.hold(Phase.TRANSIT).value for _ in range(300)]
    # at rest the lagged reading converges on the field at the (drifting) true position
    assert readings[-1] == pytest.approx(body.true_x_m, abs=0.2)


def test_a_rebuilt_body_keeps_its_sensor_state():
    settings = VehicleSettings(lag_s=2.0, position_std_m=1.0, seed=3)
    st = VehicleState(ramp_x, BIG, load_mission(ROOT / "missions" / "demo.yaml").origin,
                      settings, (47.397742, 8.545594, 488.0))
    for _ in range(30):
        st.body.tick(8.0, 0.0, Phase.TRANSIT)
    before = (st.body.x_m, st.body.true_x_m, float(st.body.sensor[0]["y"]))
    st.params["SAMPLE_HZ"] = 20.0
    st.rebuild_body(st.body.t_s)
    assert (st.body.x_m, st.body.true_x_m, float(st.body.sensor[0]["y"])) == before
    assert st.body.dt_s == 0.05


def test_in_process_executor_carries_the_missions_sensor():
    m = load_mission(ROOT / "missions" / "plume-noisy.yaml")
    assert sensor_model(m) == SensorModel(noise_std=1.0, lag_s=0.5, position_std_m=1.0,
                                          position_tau_s=10.0)
    ex = InProcessExecutor(m, m.build_field(), seed=2)
    assert all(b.sensor_model == sensor_model(m) for b in ex.bodies)


# --------------------------------------------------------------------------- the mission

BASE = {"field": {"model": "paper"}}


def test_mission_sensor_keys_and_the_noise_alias():
    m = parse_mission({**BASE, "vehicles": {"sensor": {"noise_std": 1.5, "lag_s": 0.5,
                                                       "position_std_m": 1.0,
                                                       "position_tau_s": 20.0}}})
    s = m.vehicles.sensor
    assert (s.noise_std, s.lag_s, s.position_std_m, s.position_tau_s) == (1.5, 0.5, 1.0, 20.0)
    assert m.vehicles.noise_std == 1.5 and s.lag_correction == "deconvolve"
    old = parse_mission({**BASE, "vehicles": {"noise_std": 2.0}})
    assert old.vehicles.sensor.noise_std == 2.0 and old.vehicles.noise_std == 2.0
    default = parse_mission(BASE).vehicles.sensor
    assert (default.noise_std, default.lag_s, default.position_std_m) == (0.0, 0.0, 0.0)
    # overrides: the noise either way, sensor keys one by one
    assert old.with_vehicles(noise_std=0.5).vehicles.sensor.noise_std == 0.5
    lagged = m.with_vehicles(sensor={"lag_s": 2.0})
    assert lagged.vehicles.sensor.lag_s == 2.0 and lagged.vehicles.noise_std == 1.5
    assert m.with_vehicles(noise_std=0.0).vehicles.sensor.noise_std == 0.0
    assert dataclasses.replace(old.vehicles, count=2).sensor.noise_std == 2.0


@pytest.mark.parametrize(("vehicles", "message"), [
    ({"noise_std": 1.0, "sensor": {"noise_std": 1.0}},
     r"^vehicles\.noise_std: given twice, also as vehicles\.sensor\.noise_std \(keep one\)$"),
    ({"sensor": {"lag": 1.0}}, r"^vehicles\.sensor\.lag: unknown key \(allowed: lag_correction, "
                               r"lag_s, noise_std, position_std_m, position_tau_s\)$"),
    ({"sensor": {"lag_s": -1.0}},
     r"^vehicles\.sensor\.lag_s: must be >= 0 \(a sensor.s response time\), got -1\.0$"),
    ({"sensor": {"position_tau_s": 0}}, r"^vehicles\.sensor\.position_tau_s: must be > 0"),
    ({"sensor": {"lag_correction": "wiener"}}, r"^vehicles\.sensor\.lag_correction: must be "
                                               r"one of deconvolve, estimate, none"),
    ({"sensor": [1, 2]}, r"^vehicles\.sensor: expected a mapping, got list$"),
    ({"sensr": {}}, r"^vehicles\.sensr: unknown key \(allowed: .*sample_rate_hz, sensor, "),
])
def test_bad_sensor_keys_are_one_clear_error(vehicles, message):
    with pytest.raises(MissionError, match=message):
        parse_mission({**BASE, "vehicles": vehicles})


def test_plume_noisy_mission():
    m = load_mission(ROOT / "missions" / "plume-noisy.yaml")
    plume = load_mission(ROOT / "missions" / "plume.yaml")
    s = m.vehicles.sensor
    assert (s.noise_std, s.lag_s, s.position_std_m, s.position_tau_s) == (1.0, 0.5, 1.0, 10.0)
    assert m.field_params == plume.field_params and m.algorithm == plume.algorithm


def test_a_noise_only_sensor_draws_what_it_always_drew():
    """``noise_std`` alone: the readings carry the body generator's normal draws in order,
    as before the sensor model existed (noisy runs of earlier versions reproduce)."""
    _, s = fly(SensorModel(noise_std=0.7), seed=11)
    want = np.random.default_rng(11).normal(0.0, 0.7, size=len(s))
    assert np.array_equal(s.value - s.x_m, (s.x_m + want) - s.x_m)


@pytest.mark.parametrize(("correction", "known"), [("deconvolve", 0.5), ("estimate", 0.0),
                                                   ("none", 0.0)])
def test_the_mavlink_vehicles_tracer_knows_the_lag_when_the_station_does(correction, known):
    """As in the in-process mode, the onboard tracer is set up with the sensor's lag when
    the station corrects for the one it is told; an estimated lag reaches it with the trace
    tasks (``sensor_lag_s``, below), one left in never does."""
    from sim_vehicle.mavlink_vehicle import MavlinkVehicle

    m = load_mission(ROOT / "missions" / "plume-noisy.yaml").with_vehicles(
        sensor={"lag_correction": correction})
    v = MavlinkVehicle.from_mission(m, connect="udpin:127.0.0.1:0")
    try:
        assert v.autopilot.navigator.tracer_params().sensor_lag_s == known
    finally:
        v.close()
    assert InProcessExecutor(m, m.build_field(0), seed=0).params.sensor_lag_s == known


def test_a_trace_tasks_lag_overrides_the_executors():
    """A trace task that carries the station's lag (``sensor_lag_s``) is traced with it,
    whatever the executor was set up with: an executor that was told no lag flies it
    exactly as one told that lag flies the task without it; without it, the same task is
    flown otherwise."""
    m = load_mission(ROOT / "missions" / "plume-noisy.yaml")
    field = m.build_field(0)

    def executor(correction: str) -> InProcessExecutor:
        return InProcessExecutor(m.with_vehicles(sensor={"lag_correction": correction}),
                                 field, seed=0)

    task = TraceTask(54.9, 61.0, 11.0, 15.0, 80.0, 1)  # around the highest plume's top
    told = dataclasses.replace(task, sensor_lag_s=0.5)
    knew, = executor("deconvolve").fly([[task]], 1)
    was_told, = executor("estimate").fly([[told]], 1)
    untold, = executor("estimate").fly([[task]], 1)
    assert knew.outcomes[0].traced_m > 20.0
    for col in ("t_s", "x_m", "y_m", "value", "phase"):
        assert np.array_equal(getattr(knew.samples, col), getattr(was_told.samples, col))
    assert was_told.outcomes[0].task == told and was_told.outcomes[0].traced_m == \
        knew.outcomes[0].traced_m
    assert len(untold.samples) != len(knew.samples) or \
        not np.array_equal(untold.samples.x_m, knew.samples.x_m)
