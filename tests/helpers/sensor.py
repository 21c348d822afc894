"""Flights of the simulated body with a sensor model (shared by the sensor and lag tests)."""

from __future__ import annotations

import numpy as np

from econdor_gcs.core.geometry import Region
from econdor_gcs.core.tasks import SampleLog, Waypoint
from sim_vehicle.body import SimBody
from sim_vehicle.executor import run_plan
from sim_vehicle.kinematics import VehicleLimits
from sim_vehicle.sensor import SensorModel

BIG = Region(0.0, 2000.0, 0.0, 2000.0)
LIMITS = VehicleLimits(max_speed_mps=8.0)


def ramp_x(x, y):
    """The field is the easting: a reading is where the sensor (truly) was."""
    return np.asarray(x, dtype=float) + 0.0 * np.asarray(y, dtype=float)


def fly(sensor: SensorModel, field=ramp_x, legs=((1900.0, 1000.0),), seed: int = 0,
        start=(100.0, 1000.0)) -> tuple[SimBody, SampleLog]:
    body = SimBody(field, BIG, *start, limits=LIMITS, sensor=sensor,
                   rng=np.random.default_rng(seed))
    report = run_plan(body, [Waypoint(*p) for p in legs])
    return body, report.samples
