"""The in-process executor: the same tracer as the MAVLink vehicle, called directly."""

from __future__ import annotations

import numpy as np

from econdor_gcs.core.fields import Field
from econdor_gcs.core.tasks import FlightReport, Phase, Task, Waypoint
from econdor_gcs.mission import Mission
from sim_vehicle.body import SimBody
from sim_vehicle.executor import run_plan
from sim_vehicle.kinematics import VehicleLimits
from sim_vehicle.tracer import TracerParams


def _brake(body: SimBody, max_ticks: int = 10_000) -> None:
    """Come to rest and hover, as a MAVLink vehicle does between missions (the ticks of
    braking are flown but, like the vehicle's hover ticks, yield no samples)."""
    for _ in range(max_ticks):
        if body.speed_mps < 1e-6:
            return
        body.hold(Phase.TRANSIT)


class InProcessExecutor:
    """Simulated vehicles flown one after another in this process (fast studies).

    Vehicles start at the area's origin corner (their home), transit at cruise speed, come
    to rest where their plan ended and keep that position between iterations, and fly home
    at the end, as the MAVLink vehicles do.
    """

    def __init__(self, mission: Mission, field: Field, n_vehicles: int | None = None,
                 seed: int = 0) -> None:
        v = mission.vehicles
        self.n_vehicles = n_vehicles or v.count
        self.home = (mission.region.xmin, mission.region.ymin)
        limits = VehicleLimits(max_speed_mps=v.max_speed_mps, max_accel_mps2=v.max_accel_mps2,
                               max_turn_rate_dps=v.max_turn_rate_dps)
        rng = np.random.default_rng(seed + 7919)
        # like the MAVLink vehicle: transits at the cruise speed (its SPEED_MPS), not max speed
        self.params = TracerParams(speed_mps=v.speed_mps, transit_speed_mps=v.speed_mps)
        self.bodies = [
            SimBody(field, mission.region, *self.home, limits=limits,
                    sample_rate_hz=v.sample_rate_hz, noise_std=v.noise_std,
                    rng=np.random.default_rng(rng.integers(2**32)))
            for _ in range(self.n_vehicles)
        ]

    def positions(self) -> list[tuple[float, float]]:
        return [(b.x_m, b.y_m) for b in self.bodies]

    def fly(self, plans: list[list[Task]], iteration: int) -> list[FlightReport]:
        reports = []
        for i, (body, tasks) in enumerate(zip(self.bodies, plans, strict=True)):
            reports.append(run_plan(body, tasks, vehicle=i, params=self.params))
            _brake(body)
        return reports

    def finish(self) -> list[FlightReport]:
        return self.fly([[Waypoint(*self.home)] for _ in self.bodies], -1)
