"""The in-process executor: the same tracer as the MAVLink vehicle, called directly.

With ``style=TaskStyle.WAYPOINTS`` the vehicles fly as stock autopilots do in ``econdor run``:
each contour piece as the waypoint polyline of its *estimated* contour
(:func:`econdor_gcs.core.waypoints.task_waypoints`), the first waypoint reached in transit
and the legs after it counted as traced (``Phase.TRACE``), exactly as the MAVLink station
accounts for them.
"""

from __future__ import annotations

from collections.abc import Generator
from pathlib import Path
from typing import Any

import numpy as np

from econdor_gcs.config import Mission
from econdor_gcs.core.fields import Field
from econdor_gcs.core.tasks import (
    FlightReport,
    OutcomeStatus,
    Phase,
    SampleLog,
    Task,
    TaskOutcome,
    TaskStyle,
    TraceTask,
    Waypoint,
)
from econdor_gcs.core.waypoints import task_waypoints
from econdor_gcs.dfc.loop import Dfc, Progress, RunResult
from econdor_gcs.errors import RunError
from econdor_gcs.files.checkpoint import read_checkpoint
from econdor_gcs.files.layout import RunDirMode
from econdor_gcs.files.rundir import RunDir, read_run_config
from econdor_gcs.link.items import MISSION_FENCE_MARGIN_M, fence_items
from sim_vehicle.body import Sample, SimBody
from sim_vehicle.executor import run_plan, run_task
from sim_vehicle.fence import Fence
from sim_vehicle.kinematics import VehicleLimits
from sim_vehicle.sensor import SensorModel
from sim_vehicle.tracer import TracerParams


def _brake(body: SimBody, max_ticks: int = 10_000) -> None:
    """Come to rest and hover, as a MAVLink vehicle does between missions (the ticks of
    braking are flown but, like the vehicle's hover ticks, yield no samples)."""
    for _ in range(max_ticks):
        if body.speed_mps < 1e-6:
            return
        body.hold(Phase.TRANSIT)


def sensor_model(mission: Mission) -> SensorModel:
    """The simulated sensor of the mission's vehicles (``vehicles.sensor``)."""
    c = mission.vehicles.sensor
    return SensorModel(noise_std=c.noise_std, lag_s=c.lag_s, position_std_m=c.position_std_m,
                       position_tau_s=c.position_tau_s)


class InProcessExecutor:
    """Simulated vehicles flown one after another in this process (fast studies).

    Vehicles start at the area's origin corner (their home), transit at cruise speed, come
    to rest where their plan ended and keep that position between iterations, and fly home
    at the end, as the MAVLink vehicles do. They fly inside the fence ``econdor run``
    uploads (the area plus ``MISSION_FENCE_MARGIN_M``), read from the very items it sends. They
    carry the mission's sensor (``vehicles.sensor``: noise, lag, GNSS error, each vehicle
    its own seeded draws) and report, as the MAVLink vehicles do, the positions they
    believe they are at.
    """

    def __init__(self, mission: Mission, field: Field, n_vehicles: int | None = None,
                 seed: int = 0, style: TaskStyle = TaskStyle.TRACE,
                 tolerance_m: float = 1.0) -> None:
        v = mission.vehicles
        self.style = style
        self.tolerance_m = tolerance_m
        self.n_vehicles = n_vehicles or v.count
        self.home = (mission.region.xmin, mission.region.ymin)
        limits = VehicleLimits(max_speed_mps=v.max_speed_mps, max_accel_mps2=v.max_accel_mps2,
                               max_turn_rate_dps=v.max_turn_rate_dps)
        rng = np.random.default_rng(seed + 7919)
        # like the MAVLink vehicle: transits at the cruise speed (its SPEED_MPS), not max speed
        # and is told the sensor's lag when the station is (it corrects for it)
        known_lag_s = v.sensor.lag_s if v.sensor.lag_correction == "deconvolve" else 0.0
        self.params = TracerParams(speed_mps=v.speed_mps, transit_speed_mps=v.speed_mps,
                                   sensor_lag_s=known_lag_s)
        self.fence = Fence.from_items(
            fence_items(mission.origin, mission.region, MISSION_FENCE_MARGIN_M), mission.origin)
        self.bodies = [
            SimBody(field, mission.region, *self.home, limits=limits,
                    sample_rate_hz=v.sample_rate_hz, sensor=sensor_model(mission),
                    rng=np.random.default_rng(rng.integers(2**32)), fence=self.fence)
            for _ in range(self.n_vehicles)
        ]

    def positions(self) -> list[tuple[float, float]]:
        return [(b.x_m, b.y_m) for b in self.bodies]

    def fly(self, plans: list[list[Task]], iteration: int, *, survey: bool = False
            ) -> list[FlightReport]:
        """Fly each vehicle's plan; the samples of a ``survey`` flight are
        ``Phase.SURVEY``, the others have the phase the vehicle flew them in."""
        phase = Phase.SURVEY if survey else None
        reports = []
        for i, (body, tasks) in enumerate(zip(self.bodies, plans, strict=True)):
            if self.style == TaskStyle.WAYPOINTS:
                reports.append(self._fly_waypoints(body, tasks, i, phase))
            else:
                reports.append(run_plan(body, tasks, vehicle=i, params=self.params,
                                        phase=phase))
            _brake(body)
        return reports

    def _fly_waypoints(self, body: SimBody, tasks: list[Task], vehicle: int,
                       phase: Phase | None = None) -> FlightReport:
        """Each task as waypoints (a trace task: its estimated contour, simplified); the
        phase of a leg's samples is the one its mission item implies, or ``phase``."""
        t0_s, odo0_m = body.t_s, body.odometer_m
        rows: list[tuple[float, float, float, float, int]] = []
        outcomes: list[TaskOutcome] = []

        def leg(wp: Waypoint, item_phase: Phase) -> tuple[float, OutcomeStatus]:
            odo = body.odometer_m
            p = int(phase if phase is not None else item_phase)
            gen: Generator[Sample, None, TaskOutcome] = run_task(body, wp, self.params)
            while True:
                try:
                    s = next(gen)
                except StopIteration as stop:
                    return body.odometer_m - odo, stop.value.status
                rows.append((s.t_s, s.x_m, s.y_m, s.value, p))

        for task in tasks:
            wps = task_waypoints(task, self.tolerance_m)
            along = isinstance(task, TraceTask)
            legs = [leg(wp, Phase.TRACE if along and k > 0 else Phase.TRANSIT)
                    for k, wp in enumerate(wps)]
            flown = [m for m, _ in legs]
            # a leg whose time budget ran out makes the whole task unreachable
            status = next((st for _, st in legs if st != OutcomeStatus.REACHED),
                          OutcomeStatus.REACHED)
            outcomes.append(TaskOutcome(task, status, sum(flown),
                                        sum(flown[1:]) if along else 0.0))
        return FlightReport(vehicle=vehicle, samples=SampleLog.from_rows(rows, vehicle),
                            flown_m=body.odometer_m - odo0_m,
                            traced_m=float(sum(o.traced_m for o in outcomes)),
                            outcomes=outcomes, end_x_m=body.x_m, end_y_m=body.y_m,
                            sim_s=body.t_s - t0_s)

    def state(self) -> dict[str, Any]:
        """The vehicles' state between flights (what a resumed run restores)."""
        return {"bodies": [b.checkpoint() for b in self.bodies]}

    def restore(self, state: dict[str, Any]) -> None:
        bodies = state["bodies"]
        if len(bodies) != len(self.bodies):
            raise RunError(f"cannot resume: {len(bodies)} vehicles recorded, "
                           f"{len(self.bodies)} now")
        for body, b in zip(self.bodies, bodies, strict=True):
            body.restore(b)

    def finish(self) -> list[FlightReport]:
        return self.fly([[Waypoint(*self.home)] for _ in self.bodies], -1)


def run_inprocess(mission: Mission, out: str | Path, *, planner: str | None = None,
                  seed: int | None = None, n_vehicles: int | None = None,
                  mode: RunDirMode = RunDirMode.NEW, progress: Progress | None = None,
                  extra: dict[str, Any] | None = None, style: TaskStyle = TaskStyle.TRACE,
                  tolerance_m: float = 1.0) -> RunResult:
    """One in-process DFC run into the run directory ``out``.

    With ``mode=RunDirMode.RESUME`` the run recorded in ``out`` (its ``run.json`` gives the
    planner, seed and fleet size) continues after its last finished flight: the finished
    flights are replayed from ``flights.jsonl`` and ``samples.csv``, the vehicles restored to
    where they were, and the run ends with exactly the result an uninterrupted run of the
    same seed has.
    """
    out = Path(out)
    if mode == RunDirMode.RESUME:
        config = read_run_config(out)
        if config.get("transport") != "in-process":
            raise RunError(f"{out}: a {config.get('transport')} run; resume it with econdor run")
        for key, given in (("planner", planner), ("seed", seed), ("vehicles", n_vehicles)):
            if given is not None and given != config[key]:
                raise RunError(f"{out}: recorded with {key} {config[key]}, not {given}")
        planner, seed, n_vehicles = config["planner"], config["seed"], config["vehicles"]
    planner = planner or mission.algorithm.planner
    seed = mission.seed if seed is None else seed
    n = n_vehicles or mission.vehicles.count
    replay = read_checkpoint(out) if mode == RunDirMode.RESUME else []
    rd = RunDir(out, mode)
    try:
        if mode != RunDirMode.RESUME:
            rd.write_run_config({"transport": "in-process", "mission": mission.name,
                                 "planner": planner, "seed": seed, "vehicles": n}, None)
        field = mission.build_field(seed)
        executor = InProcessExecutor(mission, field, n_vehicles=n, seed=seed, style=style,
                                     tolerance_m=tolerance_m)
        dfc = Dfc(mission, executor, planner=planner, truth=field, seed=seed,
                  progress=progress, on_flight=rd.record_flight, replay=replay)
        result = dfc.run()
        resumed = {"resumed": {"flights_replayed": dfc.replayed,
                               "samples_interrupted": rd.interrupted_samples}} if replay else {}
        rd.write_result(result, {"mission": mission.name, "transport": "in-process",
                                 **resumed, **(extra or {})})
    finally:
        rd.close()
    return result
