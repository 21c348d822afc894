"""The station's correction for a known sensor lag (:mod:`econdor_gcs.core.lag`), on
samples of simulated flights with a lagging sensor and on synthetic tracks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from econdor_gcs.config import parse_mission
from econdor_gcs.core.lag import (
    LagCorrection,
    LagEstimate,
    correct_lag,
    estimate_lag,
    noise_std,
    track_derivative,
)
from econdor_gcs.core.tasks import SampleLog, TraceTask
from econdor_gcs.files.checkpoint import read_checkpoint
from econdor_lab.inprocess import run_inprocess
from sim_vehicle.sensor import SensorModel
from tests.helpers.sensor import fly


def lagged_flight(lag_s: float, noise: float = 0.0, seed: int = 0):
    """A lawnmower of three legs over a Gaussian bump (sigma 6 m) with a lagging sensor:
    the raw and the corrected samples, and the truth at each sample's position."""
    def bump(x, y):
        return 100.0 * np.exp(-((np.asarray(x) - 1000.0) ** 2
                                + (np.asarray(y) - 1000.0) ** 2) / 72.0)

    _, s = fly(SensorModel(lag_s=lag_s, noise_std=noise), field=bump, seed=seed,
               start=(950.0, 996.0),
               legs=((1050.0, 996.0), (1050.0, 1000.0), (950.0, 1000.0), (950.0, 1004.0),
                     (1050.0, 1004.0)))
    fixed = correct_lag(s, lag_s)
    return s, fixed, bump(fixed.x_m, fixed.y_m)


def test_deconvolution_puts_the_bump_back_where_it_is():
    raw, fixed, truth = lagged_flight(1.0)
    assert np.array_equal(truth, raw_truth(raw))
    before = np.abs(raw.value - truth).max()
    after = np.abs(fixed.value - truth).max()
    assert before > 40.0  # 8 m late on a 6 m bump
    assert after < 0.02 * before
    assert np.array_equal(fixed.x_m, raw.x_m) and np.array_equal(fixed.t_s, raw.t_s)


def raw_truth(s: SampleLog) -> np.ndarray:
    return 100.0 * np.exp(-((s.x_m - 1000.0) ** 2 + (s.y_m - 1000.0) ** 2) / 72.0)


def test_deconvolution_does_not_amplify_the_noise():
    """With noise 1, the naive inverse y + tau * dy/dt (central differences) would add
    noise tau / dt / sqrt(2) ~ 7 times the sensor's; the adaptive window keeps the corrected
    samples' error near the noise itself, and still removes most of the lag's error."""
    raw, fixed, truth = lagged_flight(1.0, noise=1.0, seed=2)
    quiet = truth < 0.01  # away from the bump: only noise
    assert np.std(fixed.value[quiet] - truth[quiet]) < 1.5
    raw_err = np.sqrt(np.mean((raw.value - raw_truth(raw)) ** 2))
    err = np.sqrt(np.mean((fixed.value - truth) ** 2))
    assert err < 0.3 * raw_err


def test_noise_estimate_from_lagged_readings():
    _, raw = fly(SensorModel(lag_s=1.0, noise_std=2.0), seed=5)
    assert noise_std(raw.value) == pytest.approx(2.0, rel=0.1)
    clean, _, _ = lagged_flight(1.0)
    assert noise_std(clean.value) < 0.01


def test_track_derivative_exact_where_clean_and_smooth_where_noisy():
    t = np.arange(0.0, 20.0, 0.1)
    assert np.allclose(track_derivative(t, np.sin(t), 0.0)[1:-1], np.cos(t[1:-1]), atol=2e-3)
    rng = np.random.default_rng(0)
    y = 2.0 * t + rng.normal(0.0, 1.0, len(t))
    d = track_derivative(t, y, noise_std(y))
    naive = np.gradient(y, t)
    assert np.std(d - 2.0) < 0.2 * np.std(naive - 2.0)


def test_vehicles_and_stretches_are_corrected_apart():
    """Interleaved samples of two vehicles, and a pause (hover) in one vehicle's samples,
    are corrected as separate tracks: the same result as each alone."""
    t = np.arange(0.0, 20.0, 0.1)
    one = SampleLog(t, 8.0 * t, np.zeros_like(t), 16.0 * t - 16.0,
                    np.zeros(len(t), dtype=np.int8), np.zeros(len(t), dtype=np.int16))
    t2 = np.r_[np.arange(0.0, 8.0, 0.1), np.arange(30.0, 40.0, 0.1)]
    two = SampleLog(t2, np.r_[np.zeros(80), np.full(100, 50.0)], 3.0 * t2, 5.0 * t2 ** 2,
                    np.zeros(len(t2), dtype=np.int8), np.ones(len(t2), dtype=np.int16))
    both = SampleLog.concat([one, two])
    order = np.argsort(both.t_s, kind="stable")  # interleaved in time, as received
    mixed = SampleLog(*(getattr(both, f)[order] for f in ("t_s", "x_m", "y_m", "value",
                                                          "phase", "vehicle")))
    fixed = correct_lag(mixed, 1.0)
    for alone in (one, two):
        want = correct_lag(alone, 1.0)
        mine = fixed.vehicle == alone.vehicle[0]
        assert np.allclose(fixed.value[mine], want.value)
    assert np.allclose(correct_lag(one, 1.0).value, 16.0 * t)
    # the pause: 5 t^2 with a 1 s lag has slope 10 t; the stretch after the pause is not
    # fitted across the gap (its first sample's slope is from its own samples)
    got = correct_lag(two, 1.0).value
    assert got[80] == pytest.approx(5 * 30.0 ** 2 + 10 * 30.0, rel=1e-3)


def test_zero_lag_or_none_changes_nothing():
    raw, _, _ = lagged_flight(1.0, noise=0.5)
    for lag, how in ((0.0, LagCorrection.DECONVOLVE), (1.0, LagCorrection.NONE)):
        out = correct_lag(raw, lag, how)
        assert np.array_equal(out.value, raw.value) and np.array_equal(out.x_m, raw.x_m)
    with pytest.raises(ValueError, match="lag_s"):
        correct_lag(raw, -1.0)


def _lagging_mission(correction: str = "deconvolve", *, lag_s: float = 1.0,
                     iterations: int = 1):
    return parse_mission({
        "name": "lagging", "seed": 3, "field": {"model": "paper", "n1": 4, "n2": 4},
        "vehicles": {"count": 2, "sensor": {"noise_std": 0.3, "lag_s": lag_s,
                                            "lag_correction": correction}},
        "algorithm": {"planner": "econdor", "max_iterations": iterations,
                      "min_iterations": 1, "grid_spacing_m": 2.0,
                      "max_trace_length_m": 150.0},
    })


def test_the_station_uses_each_flight_corrected_and_records_it_as_received(tmp_path):
    """The DFC corrects each flight's samples of each vehicle (the same code for the
    MAVLink and the in-process executors: it is the DFC's); ``samples.csv`` keeps what was
    received; without the correction the station uses the samples as received."""
    result = run_inprocess(_lagging_mission(), tmp_path / "run")
    rows = np.loadtxt(tmp_path / "run" / "samples.csv", delimiter=",", skiprows=1, ndmin=2)
    keys = rows[:, [6, 5]]  # iteration, vehicle: one flight of one vehicle
    starts = np.r_[0, np.flatnonzero(np.any(np.diff(keys, axis=0) != 0, axis=1)) + 1,
                   len(rows)]
    assert len(starts) > 3
    want = []
    for a, b in zip(starts[:-1], starts[1:], strict=True):
        r = rows[a:b]
        flight = SampleLog(r[:, 0], r[:, 1], r[:, 2], r[:, 3], r[:, 4].astype(np.int8),
                           r[:, 5].astype(np.int16))
        want.append(correct_lag(flight, 1.0).value)
    assert np.array_equal(result.samples.value, np.concatenate(want))
    assert np.array_equal(result.samples.x_m, rows[:, 1])
    assert not np.allclose(result.samples.value, rows[:, 3])
    plain = run_inprocess(_lagging_mission("none"), tmp_path / "plain")
    received = np.loadtxt(tmp_path / "plain" / "samples.csv", delimiter=",", skiprows=1)
    assert np.array_equal(plain.samples.value, received[:, 3])


def test_a_broad_field_is_not_mistaken_for_noise():
    """On a broad, smooth field the lagged readings' curvature is signal: the correction
    stays at its narrowest window (a smoothing window would bend the field)."""
    def broad(x, y):
        return 50.0 + 30.0 * np.sin(np.asarray(x) / 9.0) * np.cos(np.asarray(y) / 13.0)

    legs = [(1100.0, 900.0 + 4.0 * k) if k % 2 == 0 else (900.0, 900.0 + 4.0 * k)
            for k in range(6)]
    _, s = fly(SensorModel(lag_s=1.0), field=broad, start=(900.0, 900.0), legs=legs)
    truth = broad(s.x_m, s.y_m)
    fixed = correct_lag(s, 1.0)
    assert np.sqrt(np.mean((s.value - truth) ** 2)) > 5.0
    assert np.sqrt(np.mean((fixed.value - truth) ** 2)) < 0.02


def _slope(x, y):
    return 50.0 + 2.0 * np.asarray(x) + 0.5 * np.asarray(y)


def _lawnmower(lag_s: float, noise: float, seed: int, field=_slope, cross: bool = True):
    """Six legs 4 m apart flown east and west by turns; with ``cross``, a leg south across
    all of them at the end (the crossovers an estimate needs)."""
    legs = [(1100.0, 900.0 + 4.0 * k) if k % 2 == 0 else (900.0, 900.0 + 4.0 * k)
            for k in range(6)]
    if cross:
        legs += [(1000.0, 920.0), (1000.0, 880.0)]
    _, s = fly(SensorModel(lag_s=lag_s, noise_std=noise), field=field, seed=seed,
               start=(900.0, 900.0), legs=legs)
    return s


@pytest.mark.parametrize("lag_s", [0.5, 1.0, 2.0])
@pytest.mark.parametrize("noise", [0.0, 1.0, 3.0])
def test_the_lag_is_estimated_from_the_crossovers(lag_s, noise):
    """Legs flown both ways over a slope, crossed by one leg: over four seeds the estimate
    is within 10 % of the sensor's time constant (median; each within 15 % + 0.05 s), noise
    or not (the rates' own noise taken out, it is not pulled toward 0), and each is firm
    enough to be used."""
    got = [estimate_lag(_lawnmower(lag_s, noise, seed)) for seed in range(4)]
    assert all(e.usable for e in got)
    assert np.median([e.lag_s for e in got]) == pytest.approx(lag_s, rel=0.1)
    assert max(abs(e.lag_s - lag_s) for e in got) < 0.15 * lag_s + 0.05


def test_no_lag_is_estimated_as_none():
    e = estimate_lag(_lawnmower(0.0, 1.0, 0))
    assert e.usable and e.lag_s < 0.05


def test_crossovers_on_flat_ground_or_none_at_all_give_no_estimate():
    """A plume's background says nothing of the lag (the differences of rate there are
    the noise's); neither does a flight that never comes back over its own track."""
    flat = estimate_lag(_lawnmower(1.0, 1.0, 0, field=lambda x, y: 10.0 + 0.0 * np.asarray(x)))
    assert not flat.usable and np.isnan(flat.lag_s) and flat.crossovers > 100
    _, once = fly(SensorModel(lag_s=1.0, noise_std=1.0), field=_slope, seed=0,
                  start=(900.0, 900.0), legs=((1100.0, 900.0), (1100.0, 1000.0)))
    uncrossed = estimate_lag(once)
    assert not uncrossed.usable and uncrossed.crossovers < 30


def test_a_corrected_flight_with_the_estimate_is_as_good_as_with_the_known_lag():
    s = _lawnmower(1.0, 1.0, 1)
    truth = _slope(s.x_m, s.y_m)
    est = estimate_lag(s)
    rms = [float(np.sqrt(np.mean((correct_lag(s, lag).value - truth) ** 2)))
           for lag in (0.0, est.lag_s, 1.0)]
    assert rms[0] > 10.0  # 8 m late on a slope of 2 per metre
    assert rms[1] < 1.1 * rms[2] + 0.05


def test_the_station_estimates_the_lag_when_told_to(tmp_path):
    """``lag_correction: estimate``: the station corrects every sample for the lag its
    crossovers give (recorded per iteration as ``lag_s``), not for the mission's ``lag_s``,
    and ``samples.csv`` still keeps the samples as received."""
    result = run_inprocess(_lagging_mission("estimate"), tmp_path / "run")
    lag = result.records[-1].lag_s
    assert lag == pytest.approx(1.0, rel=0.15) and lag != 1.0
    received = np.loadtxt(tmp_path / "run" / "samples.csv", delimiter=",", skiprows=1)
    raw = SampleLog(received[:, 0], received[:, 1], received[:, 2], received[:, 3],
                    received[:, 4].astype(np.int8), received[:, 5].astype(np.int16))
    final = estimate_lag(raw)  # the flight home's samples too
    assert final.usable and final.lag_s == pytest.approx(lag, abs=0.05)
    np.testing.assert_array_equal(result.samples.value, correct_lag(raw, final.lag_s).value)
    assert result.summary()["lag_s"] == lag
    known = run_inprocess(_lagging_mission(), tmp_path / "known")
    assert all(r.lag_s == 1.0 for r in known.records)


@pytest.mark.parametrize(("correction", "lag_s"), [("estimate", 1.0), ("deconvolve", 1.0),
                                                   ("none", 1.0), ("deconvolve", 0.0)])
def test_the_trace_tasks_carry_the_lag_the_station_corrects_for(tmp_path, correction, lag_s):
    """Every trace task is flown with the lag the station corrects the samples for when it
    is planned (``TraceTask.sensor_lag_s``): the known one; the estimate once one is usable
    (the estimate of the samples the plan was made from, recorded with the iteration
    before), a lag of unknown size before (``lag_unknown``); never a lag left in or a zero
    one, whose runs plan and record (``flights.jsonl``) their tasks as they always did."""
    result = run_inprocess(_lagging_mission(correction, lag_s=lag_s, iterations=3),
                           tmp_path / "run")
    flights = read_checkpoint(tmp_path / "run")
    told: list[tuple[float | None, bool]] = []
    for flight in flights:
        tasks = [t for plan in flight.plans for t in plan if isinstance(t, TraceTask)]
        tasks += [o.task for r in flight.reports for o in r.outcomes
                  if isinstance(o.task, TraceTask)]
        if not tasks:
            continue
        before = result.records[flight.iteration - 1].lag_s
        want = {"estimate": (before, False) if math.isfinite(before) else (0.0, True),
                "deconvolve": (lag_s or None, False), "none": (None, False)}[correction]
        assert {(t.sensor_lag_s, t.lag_unknown) for t in tasks} == {want}
        told.append(want)
    assert len(told) >= 2
    if correction == "estimate":  # of unknown size before the first usable estimate
        assert told[0] == (0.0, True)
        assert all(lag == pytest.approx(1.0, rel=0.15) for lag, _ in told[1:])
    if not any(lag or unknown for lag, unknown in told):
        assert "sensor_lag_s" not in (tmp_path / "run" / "flights.jsonl").read_text()


def test_an_estimated_lag_of_zero_is_told_as_known(tmp_path, monkeypatch):
    """With the lag estimated, a usable estimate of exactly 0 is told to the tracer as a
    known lag of 0 (``sensor_lag_s = 0``, not ``lag_unknown``, not left untold): a MAVLink
    tracer told of a lag of unknown size before would otherwise go on tracing as if its
    sensor lagged."""
    import econdor_gcs.dfc.loop as loop

    monkeypatch.setattr(loop, "estimate_lag", lambda raw: LagEstimate(0.0, 0.0, 100))
    run_inprocess(_lagging_mission("estimate", lag_s=1.0, iterations=3), tmp_path / "run")
    told = {(t.sensor_lag_s, t.lag_unknown) for flight in read_checkpoint(tmp_path / "run")
            for plan in flight.plans for t in plan if isinstance(t, TraceTask)}
    assert told == {(0.0, False)}
