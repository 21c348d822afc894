"""Onboard contour search and tracing for a simulated vehicle.

Everything here steers a :class:`~sim_vehicle.body.SimBody` with velocity commands
and learns about the field **only from the samples the body returns** (one per
tick, taken at the vehicle's own position). The generators yield every sample and
return a :class:`~econdor_gcs.core.tasks.TaskOutcome`.

Search
    After flying to the task's start point the vehicle takes a short probe leg
    across its arrival direction, fits a plane to its recent samples and flies down
    (or up) the estimated gradient toward the level, slowing as the predicted
    distance shrinks. If that fails (flat field, wrong way, left the search disc) it
    flies an Archimedean spiral around the start point out to ``search_radius_m``, its
    turns ``spiral_spacing_m`` apart, or half the radius apart in a smaller disc.
    The level is found as soon as two consecutive samples bracket it.

Trace
    A PID controller on the signed lateral offset ``d = (value - level) / |grad|``
    steers the heading of a constant-speed velocity command (higher values kept on
    the left, or on the right on the return leg). The integral term is the path
    curvature, which is also used to slow down in tight bends. ``|grad|`` is
    re-estimated from a plane fit over the recent trace samples whenever they are
    spread enough across the track. Loop closure, the region boundary, the length
    limit, loss of the contour and a hard tick budget end the trace. At the boundary
    the vehicle first walks along it, the higher values still on its left (inside the
    region the trace kept there), for where an iso-line comes back in: the same one
    when the region only bulges over the edge. Found, it is traced on the same way,
    often back round to the entry (closed). The walk goes no farther than the flight
    back to the entry it would save, and gives up sooner when the field along the edge
    shows no sign of coming back down to the level; then the vehicle returns to the
    entry point and traces the other way. A lost contour (a bend
    too sharp for the cruise speed, a saddle where the gradient vanishes) is searched
    for again where the trace last held it, and the next ``recover_m`` are traced at
    ``recover_speed_mps``; ``max_reacquire`` losses in a row end the trace.

The logic itself is the compiled state machine of :mod:`sim_vehicle.machine` (one
implementation for the MAVLink vehicle and the in-process studies). This module is its
Python face: :func:`fly_to` and :func:`trace_contour` are generators that advance it one
tick per sample (what the MAVLink vehicle needs), :func:`run_task_batch` runs a task to
its end thousands of ticks per call (what the in-process executor needs).
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass, fields
from enum import StrEnum

import numpy as np

from econdor_gcs.core.tasks import Phase, Task, TaskOutcome, TraceTask, Waypoint

from . import machine as m
from .body import Sample, SimBody


class TracerEvent(StrEnum):
    """Notable moments of a trace task (passed to ``on_event``; the text is for people)."""

    FOUND = "contour found"
    NOT_FOUND = "contour not found"
    LOST_SEARCHING = "contour lost, searching"
    REACQUIRED = "contour reacquired"
    BOUNDARY_OTHER_DIRECTION = "boundary reached, tracing other direction"
    BUDGET_EXHAUSTED = "trace budget exhausted"
    CLOSED = "loop closed"
    BOUNDARY = "boundary reached"
    LENGTH_LIMIT = "length limit"
    LOST = "contour lost"
    FENCE = "stopped at the fence"
    EDGE_WALK = "boundary reached, walking the edge"
    EDGE_FOUND = "contour found along the edge"
    LOST_OTHER_DIRECTION = "contour lost, tracing other direction"
    PRIOR_OTHER_DIRECTION = "came onto an earlier trace, tracing other direction"


_EVENTS = {m.EV_FOUND: TracerEvent.FOUND, m.EV_NOT_FOUND: TracerEvent.NOT_FOUND,
           m.EV_LOST_SEARCHING: TracerEvent.LOST_SEARCHING,
           m.EV_REACQUIRED: TracerEvent.REACQUIRED,
           m.EV_BOUNDARY_OTHER: TracerEvent.BOUNDARY_OTHER_DIRECTION,
           m.EV_BUDGET: TracerEvent.BUDGET_EXHAUSTED, m.EV_CLOSED: TracerEvent.CLOSED,
           m.EV_BOUNDARY: TracerEvent.BOUNDARY, m.EV_LENGTH_LIMIT: TracerEvent.LENGTH_LIMIT,
           m.EV_LOST: TracerEvent.LOST, m.EV_FENCE: TracerEvent.FENCE,
           m.EV_EDGE_WALK: TracerEvent.EDGE_WALK, m.EV_EDGE_FOUND: TracerEvent.EDGE_FOUND,
           m.EV_LOST_OTHER: TracerEvent.LOST_OTHER_DIRECTION,
           m.EV_PRIOR_OTHER: TracerEvent.PRIOR_OTHER_DIRECTION}

EventCallback = Callable[[TracerEvent], None]


@dataclass(frozen=True)
class TracerParams:
    """Tuning of the onboard search and trace controller.

    Parameters
    ----------
    speed_mps
        Cruise speed while tracing (clipped to the vehicle's speed limit).
    transit_speed_mps
        Speed of transit legs; None means the vehicle's ``max_speed_mps``.
    closure_radius_m
        The loop is closed when the vehicle passes within this distance of the point
        where tracing began, after having been at least ``closure_min_away_m`` away.
    closure_min_away_m
        How far from the trace start the vehicle must have been before closure counts.
    search_speed_mps
        Top speed while searching.
    approach_speed_mps
        Minimum search speed, reached when the predicted distance to the level is small.
    approach_gain_hz
        Search speed = this gain * predicted distance to the level (clipped).
    probe_leg_m
        Length of each probe leg flown at the start of the search.
    spiral_spacing_m
        Distance between successive turns of the fallback search spiral (at most half
        the search radius: a 3 m disc still gets a turn from 1.5 to 3 m).
    trace_bandwidth_rps
        Closed-loop bandwidth of the lateral controller (triple pole at ``-p``); capped
        at ``0.3 * sample_rate_hz`` so the loop stays well inside the sample rate.
    trace_accel_mps2
        Tangential acceleration used to ramp the trace speed.
    lateral_accel_fraction
        Fraction of ``max_accel_mps2`` the trace controller may use for turning.
    filter_alpha, filter_beta
        Gains of the alpha-beta filter on the lateral offset and its rate.
    gradient_window
        Number of recent samples used for plane (gradient) fits.
    min_spread_m
        Minimum cross-track spread (std, m) of the window to trust a gradient fit.
    boundary_margin_m
        Stop tracing when the region boundary is this close along the heading.
    lost_offset_m
        Lateral offset (m) beyond which the contour is considered lost ...
    lost_time_s
        ... if it persists this long.
    reacquire_radius_m
        Radius of the local search used to reacquire a lost contour.
    max_reacquire
        Maximum number of reacquisition attempts in a row (a trace that held the
        contour for 40 m since its last loss gets them afresh; with ``recover_m = 0``
        per task).
    min_loop_radius_m
        A full turn of the heading within ``2 pi`` times this path length (without the
        loop closing) is taken as orbiting off the contour, i.e. the contour is lost.
    budget_factor
        Trace tick budget: this many region perimeters (plus ``max_length_m``) at
        half the cruise speed.
    edge_skip_m
        An iso-line found this close to the area's edge, along its other sense of tracing,
        is traced one way only: at the far edge the trace ends instead of flying back to
        the start for the few metres left on the near side.
    recover_speed_mps
        Speed of the trace after a lost contour was found again.
    recover_m
        How far the trace goes on at ``recover_speed_mps``. The search for a lost contour
        starts where the trace last held it (within 1 m). 0: the search starts where the
        vehicle is, the trace goes on at cruise speed and ``max_reacquire`` counts per
        task.
    edge_walk_m
        At the area's boundary, before flying back to the entry, the trace walks along
        the edge (at ``search_speed_mps``, ``boundary_margin_m`` inside, counterclockwise
        round the area: the higher values stay on its left) for up to this far, and
        never farther than the flight back it would save, for where the field falls
        through the level again: an iso-line comes in there, traced on the same way.
        Past the highest value it read, the walk takes the field along the edge for a
        parabola through that top and gives up when that would reach the level beyond
        its length (a plateau, as beside a front, never comes back down). At most six
        walks a task. 0: no walk.
    rejoin_min_m
        The loop is also closed when the trace comes back within ``closure_radius_m`` of
        its own track, flown at least this far before in the same direction (within 60
        degrees), away from where tracing began: past a saddle, where the level runs
        close to itself, a trace can turn into a loop that does not pass its start and
        would otherwise go round it until its length limit. The vehicle also keeps the
        tracks of its traces, by level: a later trace of the same level ends where it
        comes within ``closure_radius_m`` of one, flown either way (that stretch is
        traced). 0: only the start closes the loop, and no track is kept.
    sensor_lag_s
        The sensor's first-order time constant as the vehicle is told it (s; as the
        station is told ``vehicles.sensor.lag_s``); 0: the readings are taken as
        instantaneous. The trace leg brings its filtered offset forward by this lag, a
        search puts the crossing back to where the vehicle was this long before.
        The readings' noise is not a parameter: the vehicle estimates it itself
        (:mod:`sim_vehicle.machine.noise`).
    lag_unknown
        The sensor lags by an amount not known yet (the station estimates it): the trace
        leg's offset filter keeps the gains it has with a told lag (a lag takes the loop's
        margin, and a filter set for noise alone would take it twice), and nothing is
        compensated (``sensor_lag_s`` is 0).
    """

    speed_mps: float = 8.0
    transit_speed_mps: float | None = None
    closure_radius_m: float = 3.0
    closure_min_away_m: float = 8.0
    search_speed_mps: float = 5.0
    approach_speed_mps: float = 1.5
    approach_gain_hz: float = 1.0
    probe_leg_m: float = 2.0
    spiral_spacing_m: float = 3.0
    trace_bandwidth_rps: float = 2.5
    trace_accel_mps2: float = 2.0
    lateral_accel_fraction: float = 0.8
    filter_alpha: float = 0.85
    filter_beta: float = 0.5
    gradient_window: int = 20
    min_spread_m: float = 0.3
    boundary_margin_m: float = 1.0
    lost_offset_m: float = 6.0
    lost_time_s: float = 3.0
    reacquire_radius_m: float = 8.0
    max_reacquire: int = 4
    min_loop_radius_m: float = 3.0
    budget_factor: float = 4.0
    edge_skip_m: float = 4.0
    recover_speed_mps: float = 2.0
    recover_m: float = 20.0
    edge_walk_m: float = 100.0
    rejoin_min_m: float = 20.0
    sensor_lag_s: float = 0.0
    lag_unknown: bool = False


# ----------------------------------------------------------------------------- the machine

_BATCH_TICKS = 4096


class _TaskRun:
    """One task on a body: the compiled machine's state and buffers, advanced on demand."""

    def __init__(self, body: SimBody, task: Task, params: TracerParams,
                 speed_mps: float | None = None, tolerance_m: float = 1.0,
                 phase: int = Phase.TRANSIT) -> None:
        self.body = body
        self.task = task
        self.state = np.zeros(1, dtype=m.STATE)
        p = self.state[0]["params"]
        for f in fields(TracerParams):
            value = getattr(params, f.name)
            if value is not None:
                p[f.name] = value
        p["transit_speed_mps"] = params.transit_speed_mps or body.limits.max_speed_mps
        t = self.state[0]["task"]
        t["task_x_m"], t["task_y_m"] = float(task.x_m), float(task.y_m)
        self.recent = np.zeros((m.RECENT_SAMPLES, 3))
        self.window = np.zeros((max(1, params.gradient_window), 3))
        self.events = np.zeros((64, 2), dtype=np.int64)
        self.traced_m = 0.0
        if isinstance(task, TraceTask):
            t["kind"] = m.KIND_TRACE
            t["level"] = task.level
            t["search_radius_m"] = task.search_radius_m
            t["max_length_m"] = task.max_length_m
            n_ticks = m.trace_tick_budget(body.state, self.state) + 2
            self.turns = np.zeros((n_ticks, 2))
            self.track = np.zeros((n_ticks, 5))
            self.prior = body.traced_track(task.level)
        else:
            t["kind"] = m.KIND_FLY_TO
            t["wp_phase"] = int(phase)
            t["wp_tolerance_m"] = tolerance_m
            t["wp_speed_mps"] = body.limits.max_speed_mps if speed_mps is None else speed_mps
            self.turns = np.zeros((1, 2))
            self.track = np.zeros((1, 5))
            self.prior = np.zeros((0, 5))
        m.start_task(body.state, self.state)
        self._ctl = self.state[0]["ctl"]
        self._remembered = False

    @property
    def done(self) -> bool:
        return int(self._ctl["pc"]) == m.PC_DONE and not self._ctl["await_value"]

    def advance(self, n: int) -> tuple[np.ndarray, list[tuple[TracerEvent, int]]]:
        """Up to ``n`` ticks: their ``(t_s, x_m, y_m, value, phase)`` rows and the events
        with the number of rows before each."""
        body = self.body
        kind, cx, cy, inv, w, scale, offset = body.field_terms
        fence_verts, fence_rings, fence_circles = body.fence_terms
        out = np.empty((n, 5))
        events: list[tuple[TracerEvent, int]] = []
        done = 0
        value = 0.0
        while done < n and not self.done:
            noise = body.noise_ahead(n - done)
            k, n_ev, used = m.advance(body.state, self.state, kind, cx, cy, inv, w, scale,
                                      offset, fence_verts, fence_rings, fence_circles,
                                      self.recent, self.window, self.turns, self.track,
                                      self.prior, out[done:],
                                      noise, body.sensor, value, self.events)
            body.noise_used(used)
            events.extend((_EVENTS[int(c)], done + int(i)) for c, i in self.events[:n_ev])
            done += k
            if self._ctl["await_value"]:  # a field the compiled code cannot read
                value = float(body._field(np.float64(body.true_x_m),
                                          np.float64(body.true_y_m)))
        if self.done and isinstance(self.task, TraceTask) and not self._remembered:
            self._remembered = True
            body.remember_track(self.task.level,
                                self.track[: int(self.state[0]["track"]["len"])])
        return out[:done], events

    def outcome(self) -> TaskOutcome:
        ctl = self._ctl
        status = m.STATUS_NAMES[int(ctl["status"])]
        flown_m = self.body.odometer_m - float(ctl["odo0_m"])
        if isinstance(self.task, TraceTask):
            return TaskOutcome(self.task, status, flown_m, float(ctl["traced_m"]))
        return TaskOutcome(self.task, status, flown_m)

    def samples(self, on_event: EventCallback | None
                ) -> Generator[Sample, None, TaskOutcome]:
        """The task one tick per ``next()``, events replayed between the samples."""
        while not self.done:
            rows, events = self.advance(1)
            for event, _ in events:
                if on_event is not None:
                    on_event(event)
            for t_s, x_m, y_m, value, phase in rows.tolist():
                yield Sample(t_s, x_m, y_m, value, int(phase))
        return self.outcome()


def fly_to(
    body: SimBody,
    x_m: float,
    y_m: float,
    phase: int = Phase.TRANSIT,
    tolerance_m: float = 1.0,
    speed_mps: float | None = None,
) -> Generator[Sample, None, TaskOutcome]:
    """Fly straight to a point with a braking profile, sampling every tick.

    Parameters
    ----------
    body
        The simulated vehicle.
    x_m, y_m
        Target position.
    phase
        Phase tag of the samples.
    tolerance_m
        Arrival radius.
    speed_mps
        Cruise speed; None means the vehicle's maximum speed.

    Yields
    ------
    Sample
        One sample per tick.

    Returns
    -------
    TaskOutcome
        Status ``"reached"`` (or ``"unreachable"`` if a generous tick budget ran out).
    """
    run = _TaskRun(body, Waypoint(float(x_m), float(y_m)), TracerParams(),
                   speed_mps=None if speed_mps is None else float(speed_mps),
                   tolerance_m=tolerance_m, phase=phase)
    return (yield from run.samples(None))


def trace_contour(
    body: SimBody,
    task: TraceTask,
    params: TracerParams = TracerParams(),  # noqa: B008 - frozen, immutable default
    on_event: EventCallback | None = None,
) -> Generator[Sample, None, TaskOutcome]:
    """Fly to the task start, search for the level nearby and trace the iso-line.

    Parameters
    ----------
    body
        The simulated vehicle; its region bounds the trace.
    task
        Level, start point, search radius and maximum trace length (0 = unlimited).
    params
        Controller tuning.
    on_event
        Called with a :class:`TracerEvent` at notable events.

    Yields
    ------
    Sample
        One sample per tick (phases TRANSIT, SEARCH, TRACE).

    Returns
    -------
    TaskOutcome
        Status ``"closed"``, ``"boundary"``, ``"length_limit"``, ``"not_found"`` or
        ``"lost"``; ``flown_m`` includes transit, ``traced_m`` only TRACE ticks.
    """
    return (yield from _TaskRun(body, task, params).samples(on_event))


def run_task_batch(
    body: SimBody,
    task: Task,
    params: TracerParams = TracerParams(),  # noqa: B008 - frozen, immutable default
) -> tuple[np.ndarray, TaskOutcome]:
    """Run one task to its end in as few compiled calls as possible.

    Parameters
    ----------
    body
        The simulated vehicle.
    task
        A :class:`Waypoint` (flown at ``params.transit_speed_mps``, None = the vehicle's
        maximum) or a :class:`TraceTask`.
    params
        Tracer tuning.

    Returns
    -------
    rows, outcome
        ``(n, 5)`` rows ``t_s, x_m, y_m, value, phase`` (the same samples the generators
        yield) and how the task ended.
    """
    if not isinstance(task, Waypoint | TraceTask):
        raise TypeError(f"unknown task type {type(task).__name__}")
    run = _TaskRun(body, task, params, speed_mps=params.transit_speed_mps)
    chunks = []
    while not run.done:
        rows, _ = run.advance(_BATCH_TICKS)
        chunks.append(rows)
    rows = np.concatenate(chunks) if chunks else np.zeros((0, 5))
    return rows, run.outcome()


def warm_up() -> float:
    """Load the compiled tracer (compiling it on a cold cache) before it is needed.

    numba compiles on first call and keeps the result on disk; a process that calls this
    first pays that once, up front, instead of stalling in its first flight (a MAVLink
    vehicle would stop heartbeating meanwhile). Runs a short trace on a small Gaussian
    field, both compiled and through a Python callable field, plus the Python-side ticks.
    Processes that start together (``econdor run`` starts one per vehicle) take turns on
    a lock file in the cache directory: one compiles, the others then load its result.

    Returns
    -------
    float
        Wall seconds it took (well under a second from a warm cache in a warm process;
        about 15 s of one core to compile on a cold cache).
    """
    import time

    t0 = time.perf_counter()
    with m.cache_lock():
        _exercise()
    return time.perf_counter() - t0


def _exercise() -> None:
    from econdor_gcs.core.fields import GaussianSumField
    from econdor_gcs.core.geometry import Region

    region = Region(0.0, 40.0, 0.0, 40.0)
    field = GaussianSumField(region, np.array([[20.0, 20.0]]), np.array([8.0]),
                             np.array([1.0]), scale=10.0)
    for f in (field, lambda x, y: field(x, y)):
        body = SimBody(f, region, 2.0, 2.0, noise_std=0.01, rng=np.random.default_rng(0))
        run_task_batch(body, TraceTask(float(field(28.0, 20.0)), 28.0, 20.0, 5.0, 20.0, 0))
        for _ in trace_contour(body, TraceTask(float(field(12.0, 20.0)), 12.0, 20.0, 5.0,
                                               10.0, 1)):
            pass
        body.hold(Phase.TRANSIT)
