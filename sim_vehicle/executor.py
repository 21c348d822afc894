"""Run tasks and whole plans on a simulated body.

:func:`run_task` yields one sample per tick (the MAVLink vehicle); :func:`run_plan` runs
a whole plan in compiled batches (the in-process executor). Both drive the same compiled
tracer, with the tuning :func:`task_params` gives each task.
"""

from __future__ import annotations

import dataclasses
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
from .tracer import EventCallback, TracerParams, fly_to, run_task_batch, trace_contour


def task_params(task: Task, params: TracerParams) -> TracerParams:
    """The tracer tuning ``task`` is flown with: ``params``, with the sensor lag a trace task
    carries (``TraceTask.sensor_lag_s`` and ``lag_unknown``, the station's) in place of
    theirs.

    >>> told = TraceTask(5.0, 0.0, 0.0, 10.0, 0.0, 1, sensor_lag_s=0.8)
    >>> task_params(told, TracerParams(sensor_lag_s=0.5)).sensor_lag_s
    0.8
    >>> task_params(dataclasses.replace(told, sensor_lag_s=None),
    ...             TracerParams(sensor_lag_s=0.5)).sensor_lag_s
    0.5
    """
    if isinstance(task, TraceTask) and task.sensor_lag_s is not None and (
            task.sensor_lag_s, task.lag_unknown) != (params.sensor_lag_s, params.lag_unknown):
        return dataclasses.replace(params, sensor_lag_s=task.sensor_lag_s,
                                   lag_unknown=task.lag_unknown)
    return params


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
        Tracer tuning (:func:`task_params`); ``transit_speed_mps`` also sets the waypoint
        speed.
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
        return (yield from trace_contour(body, task, task_params(task, params), on_event))
    raise TypeError(f"unknown task type {type(task).__name__}")


def run_plan(
    body: SimBody,
    tasks: Sequence[Task],
    vehicle: int = 0,
    params: TracerParams = TracerParams(),  # noqa: B008 - frozen, immutable default
    return_to: tuple[float, float] | None = None,
    phase: Phase | None = None,
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
        Tracer tuning (each task's: :func:`task_params`).
    return_to
        If given, fly back to this point (TRANSIT samples) after the last task; this
        leg is counted in ``flown_m`` and ``sim_s`` but adds no outcome.
    phase
        The phase of every sample when the station decides it for the whole flight (a
        survey: ``Phase.SURVEY``); None: the phase the tracer flew each one in.

    Returns
    -------
    FlightReport
        All samples (every phase), total flown and traced distance, one outcome per
        task, the end position and the sim time elapsed.
    """
    t0_s = body.t_s
    odo0_m = body.odometer_m
    chunks: list[np.ndarray] = []
    outcomes: list[TaskOutcome] = []
    for task in tasks:
        rows, outcome = run_task_batch(body, task, task_params(task, params))
        chunks.append(rows)
        outcomes.append(outcome)
    if return_to is not None:
        rows, _ = run_task_batch(body, Waypoint(*return_to), params)
        chunks.append(rows)
    arr = np.concatenate(chunks) if chunks else np.zeros((0, 5))
    if phase is not None:
        arr[:, 4] = phase
    log = SampleLog.from_rows(arr, vehicle=vehicle)
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
