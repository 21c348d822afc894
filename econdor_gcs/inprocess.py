"""The in-process executor: the same tracer as the MAVLink vehicle, called directly."""

from __future__ import annotations

import numpy as np

from sim_vehicle.body import SimBody
from sim_vehicle.executor import run_plan
from sim_vehicle.kinematics import VehicleLimits
from sim_vehicle.tracer import TracerParams

from .core.fields import Field
from .core.tasks import FlightReport, Task, Waypoint
from .mission import Mission


class InProcessExecutor:
    """Simulated vehicles flown one after another in this process (fast studies).

    Vehicles start at the area's origin corner (their home), keep their position between
    iterations and fly home at the end, as the MAVLink vehicles do.
    """

    def __init__(self, mission: Mission, field: Field, n_vehicles: int | None = None,
                 seed: int = 0) -> None:
        v = mission.vehicles
        self.n_vehicles = n_vehicles or v.count
        self.home = (mission.region.xmin, mission.region.ymin)
        limits = VehicleLimits(max_speed_mps=v.max_speed_mps, max_accel_mps2=v.max_accel_mps2,
                               max_turn_rate_dps=v.max_turn_rate_dps)
        rng = np.random.default_rng(seed + 7919)
        self.params = TracerParams(speed_mps=v.speed_mps)
        self.bodies = [
            SimBody(field, mission.region, *self.home, limits=limits,
                    sample_rate_hz=v.sample_rate_hz, noise_std=v.noise_std,
                    rng=np.random.default_rng(rng.integers(2**32)))
            for _ in range(self.n_vehicles)
        ]

    def positions(self) -> list[tuple[float, float]]:
        return [(b.x_m, b.y_m) for b in self.bodies]

    def fly(self, plans: list[list[Task]], iteration: int) -> list[FlightReport]:
        return [run_plan(body, tasks, vehicle=i, params=self.params)
                for i, (body, tasks) in enumerate(zip(self.bodies, plans, strict=True))]

    def finish(self) -> list[FlightReport]:
        return self.fly([[Waypoint(*self.home)] for _ in self.bodies], -1)
