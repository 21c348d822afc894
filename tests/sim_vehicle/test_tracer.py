"""Contour search / trace on analytic fields, and the in-process executor."""

from __future__ import annotations

import math
from collections.abc import Generator

import numpy as np
import pytest

from econdor_gcs.core.geometry import Region, path_length
from econdor_gcs.core.tasks import Phase, Task, TaskOutcome, TraceTask, Waypoint
from sim_vehicle.body import Sample, SimBody
from sim_vehicle.executor import run_plan, run_task
from sim_vehicle.tracer import TracerParams, fly_to, run_task_batch, trace_contour

REGION = Region(0.0, 100.0, 0.0, 100.0)
SIGMA_M = 25.0


def gaussian(cx_m: float, cy_m: float):
    """Radial Gaussian bump of height 100 (vectorised, like the project's field models)."""

    def field(x, y):
        return 100.0 * np.exp(-((x - cx_m) ** 2 + (y - cy_m) ** 2) / (2.0 * SIGMA_M**2))

    return field


def level_at(r_m: float) -> float:
    return 100.0 * math.exp(-(r_m**2) / (2.0 * SIGMA_M**2))


def drain(gen: Generator[Sample, None, TaskOutcome]) -> tuple[list[Sample], TaskOutcome]:
    samples: list[Sample] = []
    while True:
        try:
            samples.append(next(gen))
        except StopIteration as stop:
            return samples, stop.value


def trace_circle(noise_std: float = 0.0, seed: int = 0, angle_rad: float = 0.4,
                 offset_m: float = 4.0):
    field = gaussian(50.0, 50.0)
    body = SimBody(field, REGION, 5.0, 5.0, noise_std=noise_std,
                   rng=np.random.default_rng(seed))
    r = 20.0 + offset_m
    task = TraceTask(level_at(20.0), 50.0 + r * math.cos(angle_rad),
                     50.0 + r * math.sin(angle_rad), 10.0, 0.0, 7)
    events: list[str] = []
    samples, outcome = drain(trace_contour(body, task, TracerParams(speed_mps=8.0),
                                           events.append))
    arr = np.array([(s.x_m, s.y_m, s.phase) for s in samples])
    trace = arr[arr[:, 2] == Phase.TRACE]
    dist = np.abs(np.hypot(trace[:, 0] - 50.0, trace[:, 1] - 50.0) - 20.0)
    return samples, outcome, events, dist


def test_trace_circle_noise_free() -> None:
    samples, outcome, events, dist = trace_circle()
    assert outcome.status == "closed"
    assert events[0] == "contour found" and events[-1] == "loop closed"
    # measured at 8 m/s, 10 Hz: max ~0.37 m, mean ~0.06 m, length error ~+1 %
    assert dist.max() < 0.6
    assert dist.mean() < 0.12
    assert outcome.traced_m == pytest.approx(2.0 * math.pi * 20.0, rel=0.03)
    phases = [s.phase for s in samples]
    # transit, then search, then trace, in that order
    assert phases[0] == Phase.TRANSIT
    first_search = phases.index(Phase.SEARCH)
    first_trace = phases.index(Phase.TRACE)
    assert first_search < first_trace
    assert Phase.TRANSIT not in phases[first_search:]
    flown = path_length(np.array([5.0] + [s.x_m for s in samples]),
                        np.array([5.0] + [s.y_m for s in samples]))
    # the odometer integrates the sub-steps, the samples are one chord per tick
    assert outcome.flown_m == pytest.approx(flown, rel=1e-3)
    assert outcome.flown_m >= flown


@pytest.mark.parametrize("angle_rad, offset_m", [(2.0, 4.0), (4.0, -4.0)])
def test_trace_circle_other_starts(angle_rad: float, offset_m: float) -> None:
    _, outcome, _, dist = trace_circle(angle_rad=angle_rad, offset_m=offset_m)
    assert outcome.status == "closed"
    assert dist.max() < 0.8
    assert outcome.traced_m == pytest.approx(2.0 * math.pi * 20.0, rel=0.05)


@pytest.mark.parametrize("seed", [1, 2])
def test_trace_circle_with_noise(seed: int) -> None:
    _, outcome, _, dist = trace_circle(noise_std=0.05, seed=seed)
    assert outcome.status == "closed"
    # measured: max ~0.4 m, mean ~0.08 m
    assert dist.max() < 0.8
    assert dist.mean() < 0.2
    assert outcome.traced_m == pytest.approx(2.0 * math.pi * 20.0, rel=0.05)


@pytest.mark.parametrize("noise_std", [2.0, 3.0])
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_noisy_trace_goes_round_once_without_orbiting(noise_std: float, seed: int) -> None:
    """Readings whose noise is about a metre of offset (the gradient at the circle is
    2.3 per metre): the trace goes once round the circle and closes at its start. It
    must neither circle on the spot (a run of noise can drive the curvature's integral
    round into circles a metre across when the trace slows in a bend) nor take such a
    circle's passes over its own track for the loop's closure."""
    _, outcome, _, _ = trace_circle(noise_std=noise_std, seed=seed)
    circle = 2.0 * math.pi * 20.0
    assert outcome.status == "closed"
    # measured: 1.05-1.21 x the circle
    assert 0.95 * circle <= outcome.traced_m <= 1.25 * circle


def test_contour_leaving_area_traces_both_arcs() -> None:
    # circle of radius 20 centred 5 m inside the east edge: the inside arc spans
    # angles 75.5 deg .. 284.5 deg (through 180 deg), 72.9 m long
    field = gaussian(95.0, 50.0)
    body = SimBody(field, REGION, 50.0, 50.0)
    task = TraceTask(level_at(20.0), 71.0, 52.0, 10.0, 0.0, 1)
    events: list[str] = []
    samples, outcome = drain(trace_contour(body, task, on_event=events.append))
    assert outcome.status == "boundary"
    assert "boundary reached, tracing other direction" in events
    arr = np.array([(s.x_m, s.y_m, s.phase) for s in samples])
    assert all(REGION.contains(x, y) for x, y, _ in arr)
    trace = arr[arr[:, 2] == Phase.TRACE]
    ang = np.degrees(np.arctan2(trace[:, 1] - 50.0, trace[:, 0] - 95.0)) % 360.0
    assert ang.min() < 85.0 and ang.max() > 275.0  # both ends near the edge
    dist = np.abs(np.hypot(trace[:, 0] - 95.0, trace[:, 1] - 50.0) - 20.0)
    assert dist.max() < 0.8
    arc_m = 20.0 * 2.0 * (math.pi - math.acos(5.0 / 20.0))
    assert outcome.traced_m == pytest.approx(arc_m, rel=0.1)


def test_max_length_respected() -> None:
    body = SimBody(gaussian(50.0, 50.0), REGION, 50.0, 20.0)
    task = TraceTask(level_at(20.0), 74.0, 50.0, 10.0, 40.0, 2)
    events: list[str] = []
    _, outcome = drain(trace_contour(body, task, on_event=events.append))
    assert outcome.status == "length_limit"
    assert events[-1] == "length limit"
    step_m = 8.0 * body.dt_s
    assert 40.0 <= outcome.traced_m <= 40.0 + step_m + 1e-6


@pytest.mark.parametrize("level", [150.0, level_at(45.0)])
def test_level_not_nearby_gives_not_found(level: float) -> None:
    body = SimBody(gaussian(50.0, 50.0), REGION, 50.0, 20.0)
    task = TraceTask(level, 74.0, 50.0, 10.0, 0.0, 3)
    events: list[str] = []
    samples, outcome = drain(trace_contour(body, task, on_event=events.append))
    assert outcome.status == "not_found"
    assert events == ["contour not found"]
    assert outcome.traced_m == 0.0
    search = [s for s in samples if s.phase == Phase.SEARCH]
    assert search, "the vehicle must have searched"
    dists = [math.hypot(s.x_m - 74.0, s.y_m - 50.0) for s in search]
    assert max(dists) < 10.0 + 3.0
    # budget: about the area of the search disc / spiral spacing, plus slack
    assert len(samples) < 600


def test_spiral_searches_a_disc_smaller_than_its_spacing() -> None:
    """A flat field around the start (the plane fit has no gradient to descend) and a cone
    east of it, off the probe legs, its level 0.9-3.9 m from the start: only the fallback
    spiral can find it. With a 3 m search radius (the adaptive planner's) and the 3 m
    spiral spacing, the spiral used to end before its first point: the task came back
    ``not_found``."""

    def cone(x, y):  # flat at 10, a cone of radius 2 m rising to 30 at (52.4, 50)
        r = np.hypot(np.asarray(x) - 52.4, np.asarray(y) - 50.0)
        return 10.0 + 20.0 * np.clip(1.0 - r / 2.0, 0.0, 1.0)

    body = SimBody(cone, REGION, 50.0, 20.0)  # arrives from the south: probes go west, north
    task = TraceTask(15.0, 50.0, 50.0, 3.0, 3.0, 1)  # the level 1.5 m from the cone's top
    events: list[str] = []
    samples, outcome = drain(trace_contour(body, task, on_event=events.append))
    assert "contour found" in events
    assert outcome.status != "not_found"
    search = [s for s in samples if s.phase == Phase.SEARCH]
    assert max(math.hypot(s.x_m - 50.0, s.y_m - 50.0) for s in search) <= 3.0 + 0.5
    assert any(s.x_m > 51.0 for s in search)  # it went round: the probes stay at x <= 50
    # a search radius of 0 has no disc to spiral in: not found, at once
    body = SimBody(cone, REGION, 50.0, 20.0)
    _, outcome = drain(trace_contour(body, TraceTask(15.0, 50.0, 50.0, 0.0, 3.0, 1)))
    assert outcome.status == "not_found"


def test_senses_only_at_own_position() -> None:
    inner = gaussian(50.0, 50.0)
    holder: dict[str, SimBody] = {}
    calls = [0]

    def spy(x, y):
        body = holder["body"]
        assert float(x) == body.x_m and float(y) == body.y_m
        calls[0] += 1
        return inner(x, y)

    body = SimBody(spy, REGION, 5.0, 5.0, noise_std=0.05, rng=np.random.default_rng(3))
    holder["body"] = body
    samples, outcome = drain(trace_contour(body, TraceTask(level_at(20.0), 74.0, 50.0, 10.0,
                                                           60.0, 0)))
    assert outcome.status == "length_limit"
    assert calls[0] == len(samples) == body.ticks


def test_fly_to_reaches_target() -> None:
    body = SimBody(gaussian(50.0, 50.0), REGION, 10.0, 10.0)
    samples, outcome = drain(fly_to(body, 80.0, 30.0, tolerance_m=0.5))
    assert outcome.status == "reached"
    assert outcome.task == Waypoint(80.0, 30.0)
    assert math.hypot(body.x_m - 80.0, body.y_m - 30.0) <= 0.5
    assert all(s.phase == Phase.TRANSIT for s in samples)
    assert max(math.hypot(s.x_m - 10.0, s.y_m - 10.0) for s in samples) < 73.0  # no overshoot


def test_run_task_dispatch() -> None:
    body = SimBody(gaussian(50.0, 50.0), REGION, 10.0, 10.0)
    _, out = drain(run_task(body, Waypoint(20.0, 10.0)))
    assert out.status == "reached" and out.task == Waypoint(20.0, 10.0)
    with pytest.raises(TypeError):
        drain(run_task(body, "not a task"))  # type: ignore[arg-type]


def test_run_plan_collects_samples() -> None:
    body = SimBody(gaussian(50.0, 50.0), REGION, 5.0, 5.0, t_s=100.0)
    tasks: list[Task] = [Waypoint(30.0, 30.0), TraceTask(level_at(20.0), 74.0, 50.0, 10.0, 0.0, 4),
             Waypoint(60.0, 20.0)]
    report = run_plan(body, tasks, vehicle=3, return_to=(5.0, 5.0))
    log = report.samples
    assert report.vehicle == 3
    assert len(log) > 100
    assert np.all(np.diff(log.t_s) > 0.0)
    assert np.all(log.vehicle == 3)
    assert set(np.unique(log.phase)) == {Phase.TRANSIT, Phase.SEARCH, Phase.TRACE}
    assert [o.status for o in report.outcomes] == ["reached", "closed", "reached"]
    assert report.outcomes[1].task is tasks[1]
    flown = path_length(np.r_[5.0, log.x_m], np.r_[5.0, log.y_m])
    assert report.flown_m == pytest.approx(flown, rel=1e-3)
    assert report.flown_m >= flown
    assert report.flown_m >= sum(o.flown_m for o in report.outcomes)
    assert report.traced_m == pytest.approx(report.outcomes[1].traced_m)
    assert report.sim_s == pytest.approx(len(log) * body.dt_s)
    assert log.t_s[-1] == pytest.approx(100.0 + report.sim_s)
    assert math.hypot(report.end_x_m - 5.0, report.end_y_m - 5.0) <= 1.0
    assert (report.end_x_m, report.end_y_m) == (log.x_m[-1], log.y_m[-1])


@pytest.mark.parametrize("noise_std", [0.0, 0.05])
def test_wavy_open_contour(noise_std: float) -> None:
    # g = 5 sin(x / 10) + 0.5 y: the level 25 is y = 50 - 10 sin(x / 10), an open wavy
    # line across the whole area (curvature up to 0.1 1/m, gradient 0.5 .. 0.7 /m)
    def field(x, y):
        return 5.0 * np.sin(x / 10.0) + 0.5 * y

    def contour_y(x):
        return 50.0 - 10.0 * np.sin(x / 10.0)

    body = SimBody(field, REGION, 10.0, 10.0, noise_std=noise_std,
                   rng=np.random.default_rng(5))
    task = TraceTask(25.0, 55.0, float(contour_y(55.0)) + 4.0, 10.0, 0.0, 0)
    samples, outcome = drain(trace_contour(body, task))
    assert outcome.status == "boundary"
    trace = np.array([(s.x_m, s.y_m) for s in samples if s.phase == Phase.TRACE])
    xx = np.linspace(0.0, 100.0, 20001)
    yy = contour_y(xx)
    dist = np.array([np.min(np.hypot(xx - x, yy - y)) for x, y in trace])
    assert dist.max() < 1.0
    assert trace[:, 0].min() < 2.0 and trace[:, 0].max() > 98.0  # both edges reached
    true_len = path_length(xx, yy)
    assert outcome.traced_m == pytest.approx(true_len, rel=0.1)


@pytest.mark.parametrize("x0, back", [(2.0, False), (98.0, True), (50.0, True)],
                         ids=["tail-end", "head-end", "middle"])
def test_open_contour_entered_at_the_edge_is_not_flown_back(x0: float, back: bool) -> None:
    """The wavy line of the test above: the tracer heads east first (higher values on its
    left). Entered 2 m from the west edge, it traces to the east edge and ends there: the
    few metres west of the start are not worth the flight back across (``edge_skip_m``).
    Entered at the east end or in the middle, it flies back to the entry and traces the
    other way. The whole line is traced every time."""
    def field(x, y):
        return 5.0 * np.sin(x / 10.0) + 0.5 * y

    y0 = 50.0 - 10.0 * math.sin(x0 / 10.0)
    body = SimBody(field, REGION, x0, y0 + 2.0)
    events: list[str] = []
    samples, outcome = drain(trace_contour(body, TraceTask(25.0, x0, y0 + 2.0, 10.0, 0.0, 0),
                                           on_event=events.append))
    assert outcome.status == "boundary"
    trace = np.array([(s.x_m, s.y_m) for s in samples if s.phase == Phase.TRACE])
    assert trace[:, 0].min() < 3.0 and trace[:, 0].max() > 98.0
    assert ("boundary reached, tracing other direction" in events) == back
    # measured: 132 m flown from the west end (231 m before edge_skip_m), 133 m from the
    # east end, 183 m from the middle, for 121-123 m traced
    flown_back = outcome.flown_m - outcome.traced_m
    assert (flown_back > 40.0) == (x0 == 50.0)
    assert flown_back < 15.0 or x0 == 50.0


@pytest.mark.parametrize(
    "field, level, status, where",
    [
        # flat field exactly at the level, noisy: every point is "on" it; it runs to an edge
        # (where the edge walk reads the level again in the noise, traces from there and
        # may come back round to its start: closed)
        (lambda x, y: 0.0 * x + 5.0, 5.0, ("boundary", "closed"), None),
        # a 2 m radius contour on a sharp peak: too tight for 8 m/s, lost twice and taken up
        # again slowly; going round it, the trace is never 8 m from its start (the start's
        # closure), but it comes back onto its own track (measured: 34 m traced, 90 % of
        # it within 0.45 m of the contour; "lost" after 38 m without the rejoin)
        (lambda x, y: 100.0 * np.exp(-((x - 50) ** 2 + (y - 50) ** 2) / 50.0), 92.0, "closed",
         (47.0, 53.0, 47.0, 53.0)),
        # a near-discontinuity: followed along x = 50 from edge to edge
        (lambda x, y: 10.0 * np.tanh((x - 50.0) / 0.3), 0.0, "boundary", (49.5, 50.5, 0.0, 100.0)),
    ],
    ids=["flat", "tight-peak", "step"],
)
def test_pathological_fields_terminate(field, level: float, status: str | tuple[str, ...],
                                       where: tuple[float, float, float, float] | None) -> None:
    body = SimBody(field, REGION, 10.0, 10.0, noise_std=0.1, rng=np.random.default_rng(0))
    samples, outcome = drain(trace_contour(body, TraceTask(level, 52.0, 48.0, 10.0, 0.0, 0)))
    assert outcome.status in ((status,) if isinstance(status, str) else status)
    # hard budget: 4 region perimeters at half cruise speed plus transit/search
    assert len(samples) < 5000
    traced = np.array([(s.x_m, s.y_m) for s in samples if s.phase == Phase.TRACE])
    assert len(traced) > 0
    if where is not None:  # the traced samples stay on the feature
        xmin, xmax, ymin, ymax = where
        assert xmin <= traced[:, 0].min() and traced[:, 0].max() <= xmax
        assert ymin <= traced[:, 1].min() and traced[:, 1].max() <= ymax
    if status == "boundary":  # from one edge of the area to the other
        assert traced[:, 1].min() < 2.0 and traced[:, 1].max() > 98.0


def _gaussian_sum_field():
    from econdor_gcs.core.fields import GaussianSumField

    return GaussianSumField(REGION, np.array([[50.0, 50.0]]), np.array([SIGMA_M]),
                            np.array([1.0]), scale=100.0)


def test_compiled_sensor_reads_the_field_exactly() -> None:
    # a Gaussian-sum field is read inside the compiled tracer: every sample is bit for bit
    # the field model at the sample's position (no interpolated truth)
    field = _gaussian_sum_field()
    body = SimBody(field, REGION, 5.0, 5.0)
    assert body.field_terms[0] == 1  # the compiled path
    rows, outcome = run_task_batch(body, TraceTask(level_at(20.0), 74.0, 50.0, 10.0, 0.0, 1),
                                   TracerParams(speed_mps=8.0))
    assert outcome.status == "closed"
    np.testing.assert_array_equal(rows[:, 3], field(rows[:, 1], rows[:, 2]))
    # and it traces the same circle as the Python callable of the same formula
    dist = np.abs(np.hypot(rows[:, 1] - 50.0, rows[:, 2] - 50.0) - 20.0)[rows[:, 4] == Phase.TRACE]
    assert dist.max() < 0.6


def test_raster_field_is_traced_on_the_exact_slow_path() -> None:
    # a raster is not compiled: the machine pauses every tick for scipy's interpolator
    from econdor_gcs.core.fields import RasterField

    xs = np.linspace(0.0, 100.0, 201)
    xx, yy = np.meshgrid(xs, xs)
    raster = RasterField(REGION, gaussian(50.0, 50.0)(xx, yy))
    body = SimBody(raster, REGION, 5.0, 5.0)
    assert body.field_terms[0] == 0
    rows, outcome = run_task_batch(body, TraceTask(level_at(20.0), 74.0, 50.0, 10.0, 0.0, 1),
                                   TracerParams(speed_mps=8.0))
    assert outcome.status == "closed"
    np.testing.assert_array_equal(rows[:, 3], raster(rows[:, 1], rows[:, 2]))
    trace = rows[rows[:, 4] == Phase.TRACE]
    assert np.abs(np.hypot(trace[:, 1] - 50.0, trace[:, 2] - 50.0) - 20.0).max() < 0.6


def test_generators_and_batches_fly_the_same_samples() -> None:
    # one machine: one tick per next() (the MAVLink vehicle) or thousands per call
    # (in-process studies) give the same samples and outcome, noise included
    task = TraceTask(level_at(20.0), 74.0, 50.0, 10.0, 0.0, 1)
    params = TracerParams(speed_mps=8.0)

    def body():
        return SimBody(_gaussian_sum_field(), REGION, 5.0, 5.0, noise_std=0.05,
                       rng=np.random.default_rng(11))

    b1, b2 = body(), body()
    samples, out1 = drain(trace_contour(b1, task, params))
    rows, out2 = run_task_batch(b2, task, params)
    np.testing.assert_array_equal(np.array([tuple(s) for s in samples]), rows)
    assert (out1.status, out1.flown_m, out1.traced_m) == (out2.status, out2.flown_m,
                                                          out2.traced_m)
    assert b1.odometer_m == b2.odometer_m and b1.t_s == b2.t_s


def test_one_compiled_signature_for_every_kind_of_use() -> None:
    # compiled and Python fields, noise or not, generator or batch: the same machine code
    # (a second signature would mean a second compilation in every process)
    from sim_vehicle import machine

    task = TraceTask(level_at(20.0), 74.0, 50.0, 10.0, 30.0, 1)
    for field in (_gaussian_sum_field(), gaussian(50.0, 50.0)):
        for noise in (0.0, 0.05):
            body = SimBody(field, REGION, 5.0, 5.0, noise_std=noise)
            run_task_batch(body, task)
            drain(trace_contour(body, task))
    assert len(machine.advance.signatures) == 1


@pytest.mark.parametrize("recover_m", [20.0, 0.0], ids=["recovers", "without-recovery"])
def test_a_contour_lost_at_a_saddle_is_taken_up_where_it_was_last_held(
        recover_m: float) -> None:
    """Paper field, seed 0, at the middle of its range: coming down from the north the
    iso-line turns west beside a saddle, far more sharply than 8 m/s allows. The tracer
    overshoots into the saddle and loses it. Going back to where the iso-line was last
    held and on slowly follows it to the west edge, then traces the other way from the
    entry to the north edge. Searching where the vehicle is instead (``recover_m = 0``,
    the tracer before) loses it for good after ~70 m; the trace then goes back to its
    entry and traces the other way, to the north edge, and the west is left untraced
    (with the two searches in a row that tracer had: given four, it searches on in the
    saddle until it meets its own track, 76 m traced, and the trace ends there).
    (Without the edge walk, so that the trace ends at the west edge: with it, it walks
    on to the next piece.)"""
    from econdor_gcs.config import parse_mission
    from econdor_gcs.dfc.loop import isoline_levels

    mission = parse_mission({"name": "saddle", "field": {"model": "paper"},
                             "vehicles": {"count": 1}})
    truth = mission.build_field(0)
    xx, yy = mission.grid.mesh
    level = isoline_levels(np.asarray(truth(xx, yy)), (0.5,))[0]
    body = SimBody(truth, mission.region, 50.0, 75.5)  # arriving from the south
    events: list[str] = []
    samples, outcome = drain(trace_contour(body, TraceTask(level, 50.0, 80.5, 3.0, 0.0, 0),
                                           TracerParams(recover_m=recover_m, edge_walk_m=0.0,
                                                        max_reacquire=4 if recover_m else 2),
                                           events.append))
    assert outcome.status == "boundary"
    traced = np.array([(s.x_m, s.y_m, s.value) for s in samples if s.phase == Phase.TRACE])
    assert traced[:, 1].max() > 95.0  # the north edge, the other way
    if recover_m == 0.0:
        # measured: lost after 70 m, 117 m traced in all
        assert "contour lost, tracing other direction" in events
        assert outcome.traced_m < 130.0
        assert traced[:, 0].min() > 20.0  # never at the west edge
        return
    assert "contour lost, tracing other direction" not in events
    # measured: 135 m traced for 218 m flown (70 m traced, then lost, without the recovery)
    assert outcome.traced_m > 120.0
    # reached the west edge on the branch it was on (y ~ 40 there), not the other branch
    # of the saddle, which meets that edge at y ~ 18 ...
    west = traced[traced[:, 0] < 2.0]
    assert len(west) > 0 and west[:, 1].min() > 38.0 and west[:, 1].max() < 44.0
    # on the iso-line, not wandering: 90 % of the traced samples within 1 % of the range
    span = float(np.ptp(truth(xx, yy)))
    assert np.quantile(np.abs(traced[:, 2] - level), 0.9) < 0.01 * span


@pytest.mark.parametrize("rejoin_m, status", [(20.0, "closed"), (0.0, "length_limit")],
                         ids=["rejoin", "start-only"])
def test_a_trace_round_a_loop_past_a_saddle_ends_where_it_rejoins_its_track(
        rejoin_m: float, status: str) -> None:
    """Paper field, seed 80, at the middle of its range (a real run's first trace):
    entered in the south-west, the iso-line runs east, round the eastern hump and west
    along a neck to a saddle near (25, 75), where the tracer turns into the small lobe to
    the north instead of on south. Round the lobe it comes back to the saddle, which its
    start does not lie on. Ending where it comes back onto its own track, it stops after
    one round (measured: 253 m traced); closed only at its start, it went round the lobe
    until its 400 m limit."""
    from econdor_gcs.config import parse_mission
    from econdor_gcs.dfc.loop import isoline_levels

    mission = parse_mission({"name": "saddle", "field": {"model": "paper"},
                             "vehicles": {"count": 1}})
    truth = mission.build_field(80)
    xx, yy = mission.grid.mesh
    level = isoline_levels(np.asarray(truth(xx, yy)), (0.5,))[0]
    body = SimBody(truth, mission.region, 0.0, 0.0)
    rows, outcome = run_task_batch(body, TraceTask(level, 11.0, 13.0, 3.0, 400.0, 0),
                                   TracerParams(rejoin_min_m=rejoin_m))
    assert outcome.status == status
    trace = rows[rows[:, 4] == Phase.TRACE]
    north_end = (trace[:, 1] < 30.0) & (trace[:, 2] > 90.0)  # the lobe's: y ~ 95, x ~ 20
    rounds = np.count_nonzero(np.diff(north_end.astype(int)) == 1)
    if rejoin_m > 0:
        assert 220.0 < outcome.traced_m < 300.0
        assert rounds == 1
        assert math.hypot(*(trace[-1, 1:3] - (27.0, 76.0))) < 6.0  # back at the saddle
    else:
        assert outcome.traced_m == pytest.approx(400.0, abs=2.0)
        assert rounds >= 2


@pytest.mark.parametrize("rejoin_m", [20.0, 0.0], ids=["rejoin", "start-only"])
def test_a_trace_ends_where_it_comes_onto_a_track_traced_before_at_its_level(
        rejoin_m: float) -> None:
    """A first trace of the 20 m circle, entered in the east, stops at its 50 m length
    limit (143 degrees round, counterclockwise); a second one of the same level, entered
    in the west (180 degrees), comes onto the first one's track half the circle on, where
    the first began, goes back to its entry and traces the other way, to where the first
    one ended: the 37 degrees between them, which neither had traced. Closed only at its
    own start, the second one goes round it all. A trace of another level is not stopped
    by the track."""
    circle_m = 2.0 * math.pi * 20.0
    body = SimBody(gaussian(50.0, 50.0), REGION, 70.0, 50.0)
    params = TracerParams(rejoin_min_m=rejoin_m)
    _, first = run_task_batch(body, TraceTask(level_at(20.0), 74.0, 50.0, 10.0, 50.0, 0),
                              params)
    assert first.status == "length_limit"
    rows, second = run_task_batch(body, TraceTask(level_at(20.0), 26.0, 50.0, 10.0, 0.0, 0),
                                  params)
    trace = rows[rows[:, 4] == Phase.TRACE]
    assert second.status == "closed"
    if rejoin_m > 0:
        assert second.traced_m == pytest.approx(circle_m * (180.0 + 37.0) / 360.0, abs=4.0)
        angle = np.degrees(np.arctan2(trace[:, 2] - 50.0, trace[:, 1] - 50.0))
        assert np.abs(angle).min() < 10.0  # on to where the first trace began (0 deg) ...
        # ... and the other way, to where it ended (measured: 156 deg; the rejoin is
        # within the closure radius, 3 m or 9 degrees, of its track)
        assert 143.0 < angle[-1] < 160.0
    else:
        assert second.traced_m == pytest.approx(circle_m, rel=0.05)
    _, other = run_task_batch(body, TraceTask(level_at(15.0), 35.0, 50.0, 10.0, 0.0, 0),
                              params)
    assert other.status == "closed"
    assert other.traced_m == pytest.approx(2.0 * math.pi * 15.0, rel=0.05)
    if rejoin_m == 0:  # (no track kept)
        return
    # the tracks are part of the body's checkpoint (a resumed run ends its traces alike)
    import json

    again = SimBody(gaussian(50.0, 50.0), REGION, 0.0, 0.0)
    again.restore(json.loads(json.dumps(body.checkpoint())))
    for level in (level_at(20.0), level_at(15.0)):
        assert len(body.traced_track(level)) > 0
        np.testing.assert_array_equal(again.traced_track(level), body.traced_track(level))


RIDGE_SY_M = 6.0


def _ridge(x, y):
    """A ridge of height 100 along y = 50, its top 10 m beyond the east edge: the level
    50 is an ellipse with semi-axes 47 m (x) and 7.1 m (y), cut by the edge, whose inside
    arc runs from (100, 43.1) round the west tip (63, 50) to (100, 56.9)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    return 100.0 * np.exp(-((x - 110.0) ** 2 / (2.0 * 40.0**2)
                            + (y - 50.0) ** 2 / (2.0 * RIDGE_SY_M**2)))


def _ridge_arc_m() -> float:
    t = np.linspace(0.0, 2.0 * math.pi, 20001)
    a, b = 40.0 * math.sqrt(2.0 * math.log(2.0)), RIDGE_SY_M * math.sqrt(2.0 * math.log(2.0))
    x, y = 110.0 + a * np.cos(t), 50.0 + b * np.sin(t)
    inside = x <= 100.0
    return float(np.sum(np.hypot(np.diff(x), np.diff(y))[inside[:-1] & inside[1:]]))


@pytest.mark.parametrize("walk_m", [100.0, 0.0], ids=["walk", "no-walk"])
def test_edge_walk_finds_where_the_iso_line_comes_back_in(walk_m: float) -> None:
    """Entered on the ridge's south flank, the tracer heads east (higher values on its
    left) to the east edge. Walking north along the edge inside the ridge, it finds the
    iso-line coming back in 14 m on and traces it back round the west tip to its start
    (closed); without the walk it flies 30 m back to the entry and traces the other way
    to the edge. The same arc is traced either way."""
    y0 = 50.0 - RIDGE_SY_M * math.sqrt(2.0 * math.log(2.0) - (70.0 - 110.0) ** 2 / 40.0**2)
    body = SimBody(_ridge, REGION, 70.0, y0 - 5.0)
    events: list[str] = []
    samples, outcome = drain(trace_contour(body, TraceTask(50.0, 70.0, y0, 5.0, 0.0, 0),
                                           TracerParams(edge_walk_m=walk_m),
                                           on_event=events.append))
    trace = np.array([(s.x_m, s.y_m, s.value) for s in samples if s.phase == Phase.TRACE])
    assert outcome.traced_m == pytest.approx(_ridge_arc_m(), rel=0.1)
    assert np.quantile(np.abs(trace[:, 2] - 50.0), 0.9) < 2.0
    assert trace[:, 0].min() < 65.0 and trace[:, 1].max() > 55.0  # the tip, the north side
    overhead_m = outcome.flown_m - outcome.traced_m
    if walk_m > 0:
        assert outcome.status == "closed"
        assert "contour found along the edge" in events
        assert "boundary reached, tracing other direction" not in events
        # measured: 28 m flown besides the trace (the flight to the entry, the search,
        # the walk), 52 m without the walk
        walk = np.array([(s.x_m, s.y_m) for s in samples if s.phase == Phase.SEARCH
                         and s.x_m > 97.0])
        assert walk[:, 1].min() < 45.0 and walk[:, 1].max() > 55.0
        assert overhead_m < 35.0
    else:
        assert outcome.status == "boundary"
        assert "boundary reached, tracing other direction" in events
        assert overhead_m > 40.0


def test_edge_walk_gives_up_on_a_plateau() -> None:
    """A straight front across the area (a step 2 m wide on a faint slope): along the
    edge the high side never comes back down. Past the top of what it reads, the walk
    expects the level no nearer than a parabola through that top would bring it, farther
    than the flight back: it gives up a few metres on, flies back to the entry and traces
    the other way, edge to edge."""
    def front(x, y):
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return 10.0 * np.tanh((x - 50.0) / 2.0) - 0.005 * y

    body = SimBody(front, REGION, 45.0, 30.0)
    events: list[str] = []
    samples, outcome = drain(trace_contour(body, TraceTask(-0.15, 50.0, 30.0, 5.0, 0.0, 0),
                                           on_event=events.append))
    assert outcome.status == "boundary"
    assert "boundary reached, walking the edge" in events
    assert "boundary reached, tracing other direction" in events
    trace = np.array([(s.x_m, s.y_m) for s in samples if s.phase == Phase.TRACE])
    assert trace[:, 1].min() < 2.0 and trace[:, 1].max() > 98.0
    walk = np.array([(s.x_m, s.y_m) for s in samples if s.phase == Phase.SEARCH
                     and (s.y_m < 2.0 or s.y_m > 98.0)])
    # measured: the walk gave up 14.5 m along the edge (the flight back was 70 m; still
    # rising, it goes on while twice the distance walked is within that)
    assert path_length(walk[:, 0], walk[:, 1]) < 20.0
