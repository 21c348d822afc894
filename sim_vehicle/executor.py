"""Run tasks and whole plans on a simulated body (in-process fast mode)."""

from __future__ import annotations

from collections.abc import Generator, Sequence

import numpy as np

from econdor_gcs.core.tasks import (
    FlightReport,
    Phase,
    SampleLog,
    Task,
    TaskOutcome,
    TraceTask,
    Waypoint,
)

from .body import Sample, SimBody
from .tracer import EventCallback, TracerParams, fly_to, trace_contour


def run_task(
    body: SimBody,
    task: Task,
    params: TracerParams = TracerParams(),  # noqa: B008 - frozen, immutable default
    on_event: EventCallback | None = None,
) -> Generator[Sample, None, TaskOutcome]:
    """Execute one task, yielding a sample per tick.

    Parameters
    ----------
    body
        The simulated vehicle.
    task
        A :class:`Waypoint` (fly there, status ``"reached"``) or a :class:`TraceTask`.
    params
        Tracer tuning; ``transit_speed_mps`` also sets the waypoint speed.
    on_event
        Event callback forwarded to the tracer.

    Yields
    ------
    Sample
        One sample per tick.

    Returns
    -------
    TaskOutcome
        How the task ended.
    """
    if isinstance(task, Waypoint):
        outcome = yield from fly_to(body, task.x_m, task.y_m, Phase.TRANSIT,
                                    speed_mps=params.transit_speed_mps)
        outcome.task = task
        return outcome
    if isinstance(task, TraceTask):
        return (yield from trace_contour(body, task, params, on_event))
    raise TypeError(f"unknown task type {type(task).__name__}")


def run_plan(
    body: SimBody,
    tasks: Sequence[Task],
    vehicle: int = 0,
    params: TracerParams = TracerParams(),  # noqa: B008 - frozen, immutable default
    return_to: tuple[float, float] | None = None,
) -> FlightReport:
    """Run all tasks to completion and collect every sample.

    Parameters
    ----------
    body
        The simulated vehicle (its state and clock carry on from previous use).
    tasks
        Tasks in execution order.
    vehicle
        Vehicle index stored in the sample log and the report.
    params
        Tracer tuning.
    return_to
        If given, fly back to this point (TRANSIT samples) after the last task; this
        leg is counted in ``flown_m`` and ``sim_s`` but adds no outcome.

    Returns
    -------
    FlightReport
        All samples (every phase), total flown and traced distance, one outcome per
        task, the end position and the sim time elapsed.
    """
    t0_s = body.t_s
    odo0_m = body.odometer_m
    rows: list[Sample] = []
    outcomes: list[TaskOutcome] = []

    def drain(gen: Generator[Sample, None, TaskOutcome]) -> TaskOutcome:
        while True:
            try:
                rows.append(next(gen))
            except StopIteration as stop:
                return stop.value

    for task in tasks:
        outcomes.append(drain(run_task(body, task, params)))
    if return_to is not None:
        drain(fly_to(body, return_to[0], return_to[1], Phase.TRANSIT,
                     speed_mps=params.transit_speed_mps))
    if rows:
        arr = np.array([(s.t_s, s.x_m, s.y_m, s.value, s.phase) for s in rows], dtype=float)
        log = SampleLog(
            t_s=arr[:, 0].copy(),
            x_m=arr[:, 1].copy(),
            y_m=arr[:, 2].copy(),
            value=arr[:, 3].copy(),
            phase=arr[:, 4].astype(np.int8),
            vehicle=np.full(len(rows), vehicle, dtype=np.int16),
        )
    else:
        log = SampleLog()
    return FlightReport(
        vehicle=vehicle,
        samples=log,
        flown_m=body.odometer_m - odo0_m,
        traced_m=float(sum(o.traced_m for o in outcomes)),
        outcomes=outcomes,
        end_x_m=body.x_m,
        end_y_m=body.y_m,
        sim_s=body.t_s - t0_s,
    )
