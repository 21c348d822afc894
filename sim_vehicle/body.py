"""A simulated vehicle body: point mass, sim clock and a point sensor.

The sensor reads the field **only at the vehicle's own position**, once per tick, as its
:class:`~sim_vehicle.sensor.SensorModel` says (noise, lag, GNSS position error; perfect by
default). Nothing else in the simulated vehicle may evaluate the field.

Positions (``x_m``, ``y_m``) are where the vehicle *believes* it is (its GNSS), which is
what it flies on and reports; ``true_x_m``, ``true_y_m`` are where it is (see
:mod:`sim_vehicle.sensor`). Without a position error the two are the same.

The body's state lives in one :data:`~sim_vehicle.machine.BODY` record that the compiled
tracer (:mod:`sim_vehicle.machine`) advances in place; the properties here read it. The
body also carries the geofence (:mod:`sim_vehicle.fence`) the machine's guard keeps it in,
and that guard's counters.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from econdor_gcs.core.fields import GaussianSumField, gaussian_sum_at
from econdor_gcs.core.geometry import Region

from .fence import FENCE_MARGIN_M, NO_FENCE, Fence
from .kinematics import VehicleLimits, check_step
from .machine import BODY, body_move
from .sensor import (
    SensorModel,
    carry_state,
    gnss_step,
    restore_state,
    sensed_value,
    state_of,
)

MAX_SUBSTEP_S = 0.02
"""Kinematics are integrated with sub-steps no longer than this."""

_NO_TERMS = np.zeros(0)
_NO_NOISE = np.zeros((0, 3))
_NO_TRACK = np.zeros((0, 5))
# 8-byte slots of the BODY record, read through plain float64 / int64 views (much cheaper
# per read than a field lookup on a record)
_SLOT = {name: offset // 8 for name, (_, offset, *_) in (BODY.fields or {}).items()}
_X, _Y, _VX, _VY = _SLOT["x_m"], _SLOT["y_m"], _SLOT["vx_mps"], _SLOT["vy_mps"]
_ODO, _HDG, _T0, _DT = (_SLOT["odometer_m"], _SLOT["last_heading_rad"], _SLOT["t0_s"],
                        _SLOT["dt_s"])
_TICKS = _SLOT["ticks"]
_FENCE_ATTEMPTS, _FENCE_BREACHES, _FENCE_OUTSIDE, _FENCE_LIMITED, _FENCE_EVENT = (
    _SLOT["fence_attempts"], _SLOT["fence_breaches"], _SLOT["fence_outside"],
    _SLOT["fence_limited"], _SLOT["fence_event_tick"])


class Sample(NamedTuple):
    """One sensor reading: sim time (s), believed position (m), measured value, phase."""

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
        converted with ``float()``. A :class:`~econdor_gcs.core.fields.GaussianSumField`
        (the paper, authors and plume models) is read by compiled code; any other field
        (a raster, a test function) through this call, one tick at a time.
    region
        The area the vehicle's tasks are confined to.
    x_m, y_m
        Initial position (the vehicle starts at rest).
    limits
        Dynamic limits of the point mass.
    sample_rate_hz
        Sensor rate; one :meth:`tick` advances sim time by ``1 / sample_rate_hz``.
    noise_std
        Standard deviation of additive Gaussian sensor noise (value units); the same as
        ``sensor=SensorModel(noise_std=...)`` (give one of the two).
    rng
        Random generator for the noise; a fresh ``np.random.default_rng()`` if None.
    t_s
        Initial sim time.
    fence
        The geofence the flight logic keeps the body inside (:mod:`sim_vehicle.fence`);
        see :meth:`set_fence`.
    sensor
        The sensor's and the GNSS's imperfections (:class:`~sim_vehicle.sensor.SensorModel`).
    position_rng
        Random generator for the GNSS error; by default a child of ``rng`` (so the
        reading noise is the same with or without a position error).
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
        fence: Fence = NO_FENCE,
        sensor: SensorModel | None = None,
        position_rng: np.random.Generator | None = None,
    ) -> None:
        if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0.0):
            raise ValueError(f"sample_rate_hz must be > 0, got {sample_rate_hz!r}")
        if not (math.isfinite(noise_std) and noise_std >= 0.0):
            raise ValueError(f"noise_std must be >= 0, got {noise_std!r}")
        if sensor is None:
            sensor = SensorModel(noise_std=float(noise_std))
        elif noise_std and noise_std != sensor.noise_std:
            raise ValueError("noise_std given twice (and differently): as noise_std and in "
                             "sensor")
        self._field = field
        self.region = region
        self.limits = limits
        self.sample_rate_hz = float(sample_rate_hz)
        self.dt_s = 1.0 / self.sample_rate_hz
        self.sensor_model = sensor
        self.noise_std = sensor.noise_std
        self.sensor = sensor.record(self.dt_s)
        """The sensor's compiled record (:data:`~sim_vehicle.sensor.SENSOR`): model and
        state (the lagged reading, the GNSS error)."""
        self._rng = rng if rng is not None else np.random.default_rng()
        self._pos_rng = position_rng
        if self._pos_rng is None and sensor.position_std_m > 0.0:
            self._pos_rng = self._rng.spawn(1)[0]
        self._noise = _NO_NOISE  # drawn ahead, used in order (one row per tick)
        self._tracks: dict[float, np.ndarray] = {}  # level: where it was traced
        self.state = np.zeros(1, dtype=BODY)
        s = self._s = self.state[0]
        self._f = self.state.view(np.float64)
        self._i = self.state.view(np.int64)
        s["x_m"], s["y_m"] = float(x_m), float(y_m)
        s["t0_s"], s["dt_s"] = float(t_s), self.dt_s
        s["n_sub"] = max(1, math.ceil(self.dt_s / MAX_SUBSTEP_S - 1e-9))
        s["max_speed_mps"] = limits.max_speed_mps
        s["max_accel_mps2"] = limits.max_accel_mps2
        s["max_turn_rate_dps"] = limits.max_turn_rate_dps
        s["xmin"], s["xmax"], s["ymin"], s["ymax"] = (region.xmin, region.xmax, region.ymin,
                                                      region.ymax)
        s["fence_margin_m"] = FENCE_MARGIN_M
        s["fence_last_tick"] = -(1 << 40)  # long ago: the first limiting is a new episode
        self.fence = fence
        self.fence_terms = fence.arrays
        if isinstance(field, GaussianSumField):
            self.field_terms = (1, field.cx_m, field.cy_m, field.inv2s2, field.weights,
                                field.scale, field.offset)
        else:
            self.field_terms = (0, _NO_TERMS, _NO_TERMS, _NO_TERMS, _NO_TERMS, 1.0, 0.0)

    @property
    def t_s(self) -> float:
        """Current sim time in seconds."""
        return self._f.item(_T0) + self._i.item(_TICKS) * self._f.item(_DT)

    @property
    def x_m(self) -> float:
        """Current easting, as the vehicle believes it (its GNSS)."""
        return self._f.item(_X)

    @property
    def y_m(self) -> float:
        """Current northing, as the vehicle believes it (its GNSS)."""
        return self._f.item(_Y)

    @property
    def true_x_m(self) -> float:
        """Current easting (where the sensor is)."""
        return self._f.item(_X) - float(self.sensor[0]["ex_m"])

    @property
    def true_y_m(self) -> float:
        """Current northing (where the sensor is)."""
        return self._f.item(_Y) - float(self.sensor[0]["ey_m"])

    @property
    def vx_mps(self) -> float:
        """Current east velocity."""
        return self._f.item(_VX)

    @property
    def vy_mps(self) -> float:
        """Current north velocity."""
        return self._f.item(_VY)

    @property
    def speed_mps(self) -> float:
        """Current ground speed."""
        return math.hypot(self.vx_mps, self.vy_mps)

    @property
    def heading_rad(self) -> float:
        """Velocity heading (ENU radians); the last heading flown when at rest."""
        vx, vy = self.vx_mps, self.vy_mps
        if vx != 0.0 or vy != 0.0:
            return math.atan2(vy, vx)
        return self._f.item(_HDG)

    @property
    def odometer_m(self) -> float:
        """Distance flown since construction."""
        return self._f.item(_ODO)

    @property
    def ticks(self) -> int:
        """Number of ticks taken so far."""
        return self._i.item(_TICKS)

    def set_fence(self, fence: Fence) -> None:
        """Fly inside ``fence`` from the next tick on (:data:`~sim_vehicle.fence.NO_FENCE`:
        none)."""
        self.fence = fence
        self.fence_terms = fence.arrays

    @property
    def fence_attempts(self) -> int:
        """Episodes in which the guard braked or slowed down before the fence."""
        return self._i.item(_FENCE_ATTEMPTS)

    @property
    def fence_breaches(self) -> int:
        """How often the body got outside the fence."""
        return self._i.item(_FENCE_BREACHES)

    @property
    def fence_outside(self) -> bool:
        """Outside the fence at the last guarded tick."""
        return bool(self._i.item(_FENCE_OUTSIDE))

    @property
    def fence_limited(self) -> bool:
        """The guard limited the last command because of the fence."""
        return bool(self._i.item(_FENCE_LIMITED))

    @property
    def fence_event_t_s(self) -> float:
        """Sim time of the latest breach attempt or breach."""
        return self._f.item(_T0) + self._i.item(_FENCE_EVENT) * self._f.item(_DT)

    def noise_ahead(self, n: int) -> np.ndarray:
        """The random numbers of the next ``n`` ticks, ``(n, 3)``: the reading's noise and
        the GNSS error's two innovations (:mod:`sim_vehicle.sensor`); empty for a sensor
        that needs none. Drawn ahead in order -- the noise from the body's generator, the
        innovations from the position generator -- and consumed by :meth:`noise_used`."""
        model = self.sensor_model
        if not model.stochastic:
            return _NO_NOISE
        k = n - len(self._noise)
        if k > 0:
            more = np.zeros((k, 3))
            if model.noise_std > 0.0:
                more[:, 0] = self._rng.normal(0.0, model.noise_std, size=k)
            if self._pos_rng is not None and model.position_std_m > 0.0:
                more[:, 1:] = self._pos_rng.standard_normal((k, 2))
            self._noise = np.concatenate([self._noise, more])
        return self._noise[:n]

    def noise_used(self, n: int) -> None:
        """Drop the first ``n`` values of the noise drawn ahead."""
        if n:
            self._noise = self._noise[n:]

    def read_field(self) -> float:
        """The true field at the true position (no noise, no lag)."""
        kind, cx, cy, inv, w, scale, offset = self.field_terms
        x, y = self.true_x_m, self.true_y_m
        if kind == 1:
            return offset + scale * gaussian_sum_at(x, y, cx, cy, inv, w)
        return float(self._field(np.float64(x), np.float64(y)))

    def traced_track(self, level: float) -> np.ndarray:
        """Where this vehicle traced ``level`` before: ``(n, 5)`` rows ``x, y, traced_m,
        ux, uy`` (see :func:`sim_vehicle.machine.advance`), empty if it never did."""
        return self._tracks.get(float(level), _NO_TRACK)

    def remember_track(self, level: float, track: np.ndarray) -> None:
        """Keep a finished trace's track of ``level`` (a trace of it later ends where it
        comes onto it)."""
        if len(track):
            level = float(level)
            self._tracks[level] = np.concatenate([self.traced_track(level), track])

    def forget_tracks(self) -> None:
        """A new flight: no trace of it has been flown yet."""
        self._tracks = {}

    def keep_tracks_of(self, other: SimBody) -> None:
        """Take over ``other``'s tracks (a body rebuilt in the same flight)."""
        self._tracks = dict(other._tracks)

    def keep_sensor_of(self, other: SimBody) -> None:
        """Take over ``other``'s sensor state and believed position (the same vehicle,
        rebuilt with other settings: its sensor has not settled anew, its GNSS error goes
        on)."""
        carry_state(self.sensor, other.sensor)
        self.state[0]["x_m"], self.state[0]["y_m"] = other.x_m, other.y_m

    def checkpoint(self) -> dict[str, Any]:
        """Everything that moves (the machine's record: time, position, velocity, heading,
        odometer; the sensor's state), the random numbers drawn ahead, the generators and
        the tracks traced, JSON-safe; :meth:`restore` puts it back exactly."""
        record = {name: self.state[0][name].item() for name in self.state.dtype.names or ()}
        out = {"record": record, "noise_ahead": self._noise.tolist(),
               "rng": self._rng.bit_generator.state, "sensor": state_of(self.sensor),
               "tracks": [[level, track.tolist()] for level, track in self._tracks.items()]}
        if self._pos_rng is not None:
            out["position_rng"] = self._pos_rng.bit_generator.state
        return out

    def restore(self, checkpoint: dict[str, Any]) -> None:
        """Continue from a :meth:`checkpoint` of a body built with the same parameters."""
        for name, value in checkpoint["record"].items():
            self.state[0][name] = value
        ahead = np.asarray(checkpoint["noise_ahead"], dtype=float)
        if ahead.ndim == 1:  # a checkpoint of a noise-only sensor, one value per tick
            ahead = np.column_stack([ahead, np.zeros((len(ahead), 2))])
        self._noise = ahead.reshape(-1, 3) if len(ahead) else _NO_NOISE
        self._rng.bit_generator.state = checkpoint["rng"]
        if "sensor" in checkpoint:
            restore_state(self.sensor, checkpoint["sensor"])
        if self._pos_rng is not None and "position_rng" in checkpoint:
            self._pos_rng.bit_generator.state = checkpoint["position_rng"]
        self._tracks = {float(level): np.asarray(track, dtype=float).reshape(-1, 5)
                        for level, track in checkpoint.get("tracks", [])}

    def sense(self) -> float:
        """The sensor's reading this tick, after the body moved: the GNSS error takes its
        step, then the sensor reads the field at the true position (its lag and noise).

        Returns
        -------
        float
            The measured value.
        """
        noise = self.noise_ahead(1)
        gnss_step(self.sensor[0], self._s, noise, 0)
        value = sensed_value(self.sensor[0], self.read_field(), noise, 0)
        self.noise_used(len(noise))
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
        check_step(self.dt_s, vx_cmd_mps, vy_cmd_mps)
        body_move(self._s, float(vx_cmd_mps), float(vy_cmd_mps))
        return Sample(self.t_s, self.x_m, self.y_m, self.sense(), int(phase))

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
