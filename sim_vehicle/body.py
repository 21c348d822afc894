"""A simulated vehicle body: point mass, sim clock and a point sensor.

The sensor reads the field **only at the vehicle's own position**, once per tick,
optionally with additive Gaussian noise. Nothing else in the simulated vehicle may
evaluate the field.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from econdor_gcs.core.geometry import Region

from .kinematics import PointMass, VehicleLimits

MAX_SUBSTEP_S = 0.02
"""Kinematics are integrated with sub-steps no longer than this."""


class Sample(NamedTuple):
    """One sensor reading: sim time (s), position (m), measured value, phase."""

    t_s: float
    x_m: float
    y_m: float
    value: float
    phase: int


class SimBody:
    """Point mass + sim clock + sensor that reads field(x, y) only at its own position.

    Parameters
    ----------
    field
        ``field(x, y) -> value``; called with ``np.float64`` scalars, the result is
        converted with ``float()``.
    region
        The area the vehicle's tasks are confined to.
    x_m, y_m
        Initial position (the vehicle starts at rest).
    limits
        Dynamic limits of the point mass.
    sample_rate_hz
        Sensor rate; one :meth:`tick` advances sim time by ``1 / sample_rate_hz``.
    noise_std
        Standard deviation of additive Gaussian sensor noise (value units).
    rng
        Random generator for the noise; a fresh ``np.random.default_rng()`` if None.
    t_s
        Initial sim time.
    """

    def __init__(
        self,
        field: Callable[[Any, Any], Any],
        region: Region,
        x_m: float,
        y_m: float,
        limits: VehicleLimits = VehicleLimits(),  # noqa: B008 - frozen, immutable default
        sample_rate_hz: float = 10.0,
        noise_std: float = 0.0,
        rng: np.random.Generator | None = None,
        t_s: float = 0.0,
    ) -> None:
        if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0.0):
            raise ValueError(f"sample_rate_hz must be > 0, got {sample_rate_hz!r}")
        if not (math.isfinite(noise_std) and noise_std >= 0.0):
            raise ValueError(f"noise_std must be >= 0, got {noise_std!r}")
        self._field = field
        self.region = region
        self.limits = limits
        self.sample_rate_hz = float(sample_rate_hz)
        self.dt_s = 1.0 / self.sample_rate_hz
        self.noise_std = float(noise_std)
        self._rng = rng if rng is not None else np.random.default_rng()
        self._t0_s = float(t_s)
        self._ticks = 0
        self._n_sub = max(1, math.ceil(self.dt_s / MAX_SUBSTEP_S - 1e-9))
        self.point = PointMass(x_m, y_m, limits)

    @property
    def t_s(self) -> float:
        """Current sim time in seconds."""
        return self._t0_s + self._ticks * self.dt_s

    @property
    def x_m(self) -> float:
        """Current easting."""
        return self.point.x_m

    @property
    def y_m(self) -> float:
        """Current northing."""
        return self.point.y_m

    @property
    def vx_mps(self) -> float:
        """Current east velocity."""
        return self.point.vx_mps

    @property
    def vy_mps(self) -> float:
        """Current north velocity."""
        return self.point.vy_mps

    @property
    def speed_mps(self) -> float:
        """Current ground speed."""
        return self.point.speed_mps

    @property
    def heading_rad(self) -> float:
        """Velocity heading (ENU radians)."""
        return self.point.heading_rad

    @property
    def odometer_m(self) -> float:
        """Distance flown since construction."""
        return self.point.odometer_m

    @property
    def ticks(self) -> int:
        """Number of ticks taken so far."""
        return self._ticks

    def state(self) -> dict[str, Any]:
        """Everything that moves: time, position, velocity, heading, odometer and the noise
        generator (JSON-safe; :meth:`restore` puts it back exactly)."""
        p = self.point
        return {"t0_s": self._t0_s, "ticks": self._ticks, "x_m": p.x_m, "y_m": p.y_m,
                "vx_mps": p.vx_mps, "vy_mps": p.vy_mps, "odometer_m": p.odometer_m,
                "heading_rad": p._last_heading_rad, "rng": self._rng.bit_generator.state}

    def restore(self, state: dict[str, Any]) -> None:
        """Continue from a :meth:`state` of a body built with the same parameters."""
        p = self.point
        self._t0_s, self._ticks = float(state["t0_s"]), int(state["ticks"])
        p.x_m, p.y_m = float(state["x_m"]), float(state["y_m"])
        p.vx_mps, p.vy_mps = float(state["vx_mps"]), float(state["vy_mps"])
        p.odometer_m = float(state["odometer_m"])
        p._last_heading_rad = float(state["heading_rad"])
        self._rng.bit_generator.state = state["rng"]

    def sense(self) -> float:
        """Read the sensor at the current position (true value + noise).

        Returns
        -------
        float
            The measured value.
        """
        value = float(self._field(np.float64(self.point.x_m), np.float64(self.point.y_m)))
        if self.noise_std > 0.0:
            value += float(self._rng.normal(0.0, self.noise_std))
        return value

    def tick(self, vx_cmd_mps: float, vy_cmd_mps: float, phase: int) -> Sample:
        """Fly one sensor period with a velocity command, then take a sample.

        Parameters
        ----------
        vx_cmd_mps, vy_cmd_mps
            Commanded velocity, held for the whole tick.
        phase
            Phase tag stored in the sample (see ``econdor_gcs.core.tasks.Phase``).

        Returns
        -------
        Sample
            The reading taken at the new position and time.
        """
        sub_dt_s = self.dt_s / self._n_sub
        for _ in range(self._n_sub):
            self.point.step(sub_dt_s, vx_cmd_mps, vy_cmd_mps)
        self._ticks += 1
        return Sample(self.t_s, self.point.x_m, self.point.y_m, self.sense(), int(phase))

    def hold(self, phase: int) -> Sample:
        """One tick with a zero velocity command (brake / hover).

        Parameters
        ----------
        phase
            Phase tag stored in the sample.

        Returns
        -------
        Sample
            The reading taken at the end of the tick.
        """
        return self.tick(0.0, 0.0, phase)
