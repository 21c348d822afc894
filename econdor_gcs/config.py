"""Mission files: YAML in, a validated :class:`Mission` out.

Every problem is reported as one :class:`~econdor_gcs.errors.MissionError` line that
names the key (``field.sigma1_m: must be > 0, got -3``). Unknown keys are errors, so a
typo never silently falls back to a default.

Schema (all sections optional except ``field``; defaults shown in ``_SCHEMA``, those of
``adaptive`` taken from :class:`~econdor_gcs.core.adaptive.AdaptiveParams`)::

    name: demo
    seed: 0                          # field seed (studies override it per run)
    area: {width_m: 100, height_m: 100}
    origin: {lat_deg: 47.3977, lon_deg: 8.5456, alt_m: 488}
    field: {model: paper | authors | plume | front | raster, ...model keys...}
    vehicles: {count, speed_mps, max_accel_mps2, max_turn_rate_dps, sample_rate_hz,
               altitude_m, noise_std, speedup,
               sensor: {noise_std, lag_s, position_std_m, position_tau_s, lag_correction}}
    initiation: {pattern: diagonals | lawnmower, spacing_m, samples_per_diagonal}
    algorithm: {planner, m0, max_iterations, grid_spacing_m, search_radius_m,
                max_trace_length_m, stop_lambda, min_iterations, flight_budget_m,
                lloyd_bins, lloyd_iterations, lloyd_variant, reconstruction,
                min_piece_length_m, keep_diagonals, max_idle_iterations, target_levels}
    lawnmower: {spacing_m, budget_m, lines}
    adaptive: {batch_m, batch_growth, levels, piece_m, leg_m, legs, line_spacing_m,
               line_orientation, start, start_lines, start_step_m, model, length_m,
               fit_length, floor, gradient_gain_m, power, plan_spacing_m, search_radius_m,
               resolve_m, explore_m, band_m, level_tol, threshold_batch_m, crossings_first,
               first_order, open_entry, probes, probe_climb, probe_m, probe_prominence,
               probe_reach, sweeps, explore, line_step_m, rays, line_weight,
               probe_length_m}
"""

from __future__ import annotations

import dataclasses
import enum
import math
import typing
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from econdor_gcs.core.adaptive import (
    AdaptiveParams,
    Explore,
    FirstOrder,
    LineOrientation,
    LineWeight,
    Model,
    OpenEntry,
    Start,
)
from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.planners import PLANNER_NAMES
from econdor_gcs.errors import MissionError

_REQUIRED = object()

Check = Callable[[Any], str | None]


def _one_of(*choices: str) -> Check:
    def check(v: Any) -> str | None:
        return None if v in choices else f"must be one of {', '.join(choices)}; got {v!r}"

    return check


def _numbers(v: Any) -> str | None:
    return None if len(v) <= 100 else f"at most 100 values, got {len(v)}"


def _range(lo: float, hi: float) -> Check:
    def check(v: Any) -> str | None:
        return None if lo <= v <= hi else f"must be within [{lo}, {hi}], got {v}"

    return check


def _between(lo: float, hi: float, *, above: bool = False, why: str = "") -> Check:
    """``lo <= v <= hi`` (``lo < v`` with ``above``); the message says which side failed,
    and ``why`` the bound.

    >>> _between(10, 10_000, why="the area the station maps")(0.5)
    'must be >= 10 (the area the station maps), got 0.5'
    >>> _between(0, 50, above=True)(0.0), _between(0, 50, above=True)(1e9)
    ('must be > 0, got 0.0', 'must be <= 50, got 1000000000.0')
    """
    note = f" ({why})" if why else ""

    def check(v: Any) -> str | None:
        if above and not v > lo:
            return f"must be > {lo:g}{note}, got {v}"
        if v < lo:
            return f"must be >= {lo:g}{note}, got {v}"
        if v > hi:
            return f"must be <= {hi:g}{note}, got {v}"
        return None

    return check


MIN_AREA_M = 10.0
MAX_AREA_M = 10_000.0
"""The side of a mission area: below 10 m nothing is left to map between the fence margins
and the tracer's search radius; above 10 km a local ENU frame and the evaluation grid stop
making sense (and a typo such as ``100000000`` would send vehicles 2,000 km away)."""
MAX_ALT_M = 1_000.0
"""Flight altitude above home: far above any drone's legal ceiling (120 m in most places),
below anything a multicopter reaches."""
MAX_SPEED_MPS = 100.0
"""Cruise and top speed: no multicopter flies faster."""
MAX_RATE_HZ = 1_000.0
"""Sample rate: the simulated sensor's own limit (its SAMPLE_HZ parameter)."""
MAX_SPEEDUP = 1_000.0
"""Sim time over wall time: the simulated vehicles keep ~100x on one core."""
MAX_DISTANCE_M = 1e7
"""Any flight distance or budget (10,000 km: farther than any battery)."""
MAX_GRID_NODES = 4_000_000
"""The evaluation grid (P x Q nodes, float64 arrays of several copies): 2001 x 2001."""
MIN_AMSL_M, MAX_AMSL_M = -500.0, 9_000.0
"""Home altitude above mean sea level: from the Dead Sea shore to above Everest."""

_POS = _between(0, MAX_DISTANCE_M, above=True)
_DIST = _between(0, MAX_DISTANCE_M)
_AREA = _between(0, MAX_AREA_M, above=True)
_AREA0 = _between(0, MAX_AREA_M)


def _from_params(cls: type, checks: dict[str, Check | None]
                 ) -> dict[str, tuple[type | tuple[type, ...], Any, Check | None]]:
    """Schema rows for the keys of ``checks``, with the type and default the dataclass
    ``cls`` gives them (the planner's own parameters, written once, there)."""
    hints = typing.get_type_hints(cls)
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    return {k: (hints[k], defaults[k], check) for k, check in checks.items()}


# section -> key -> (type, default, check)
_SCHEMA: dict[str, dict[str, tuple[type | tuple[type, ...], Any, Check | None]]] = {
    "area": {
        "width_m": (float, 100.0, _between(MIN_AREA_M, MAX_AREA_M, why="metres")),
        "height_m": (float, 100.0, _between(MIN_AREA_M, MAX_AREA_M, why="metres")),
    },
    "origin": {
        "lat_deg": (float, 47.397742, _range(-90, 90)),
        "lon_deg": (float, 8.545594, _range(-180, 180)),
        "alt_m": (float, 488.0, _between(MIN_AMSL_M, MAX_AMSL_M,
                                         why="metres above mean sea level")),
    },
    "vehicles": {
        "count": (int, 3, _range(1, 250)),
        "speed_mps": (float, 8.0, _between(0, MAX_SPEED_MPS, above=True)),
        "max_speed_mps": (float, 12.0, _between(0, MAX_SPEED_MPS, above=True)),
        "max_accel_mps2": (float, 5.0, _between(0, 100, above=True)),
        "max_turn_rate_dps": (float, 180.0, _between(0, 3600, above=True)),
        "sample_rate_hz": (float, 10.0, _between(0, MAX_RATE_HZ, above=True)),
        "altitude_m": (float, 30.0, _between(1, MAX_ALT_M, why="metres above home")),
        "noise_std": (float, 0.0, _between(0, 1e9)),
        "speedup": (float, 50.0, _between(0, MAX_SPEEDUP, above=True)),
    },
    "initiation": {
        "pattern": (str, "diagonals", _one_of("diagonals", "lawnmower")),
        "spacing_m": (float, 25.0, _AREA),
        "samples_per_diagonal": (int, 0, _range(0, 1_000_000)),
    },
    "algorithm": {
        "planner": (str, "econdor", _one_of(*PLANNER_NAMES)),
        "m0": (int, 3, _range(1, 1000)),
        "max_iterations": (int, 8, _range(1, 1000)),
        "min_iterations": (int, 3, _range(1, 1000)),
        "grid_spacing_m": (float, 1.0, _AREA),
        "search_radius_m": (float, 10.0, _AREA),
        "max_trace_length_m": (float, 0.0, _DIST),
        "stop_lambda": (float, 0.0, _between(0, 1)),
        "flight_budget_m": (float, 0.0, _DIST),
        "lloyd_bins": (int, 200, _range(2, 100000)),
        "lloyd_iterations": (int, 100, _range(1, 100000)),
        "lloyd_variant": (str, "textbook", _one_of("textbook", "authors")),
        "reconstruction": (str, "auto", _one_of("auto", "exact", "fast", "kriging")),
        "min_piece_length_m": (float, 2.0, _AREA0),
        "keep_diagonals": (bool, True, None),
        "max_idle_iterations": (int, 2, _range(0, 1000)),
        "target_levels": (tuple, (), _numbers),
    },
    "lawnmower": {
        "spacing_m": (float, 0.0, _AREA0),
        "budget_m": (float, 0.0, _DIST),
        "lines": (int, 0, _range(0, 100000)),
    },
    "adaptive": _from_params(AdaptiveParams, {
        "batch_m": _POS,
        "batch_growth": _between(0, 100),
        "levels": _range(1, 1000),
        "piece_m": _AREA,
        "leg_m": _AREA,
        "legs": _range(0, 10000),
        "line_spacing_m": _AREA0,
        "line_orientation": None,  # its enum has the values
        "start": None,  # its enum has the values
        "start_lines": _range(0, 1000),
        "start_step_m": _AREA0,
        "model": None,  # its enum has the values
        "length_m": _AREA,
        "fit_length": None,
        "floor": _between(0, 1e12),
        "gradient_gain_m": _AREA0,
        "power": _range(0.5, 4.0),
        "plan_spacing_m": _AREA,
        "search_radius_m": _AREA,
        "resolve_m": _AREA,
        "explore_m": _AREA,
        "band_m": _AREA0,
        "level_tol": _range(0.0, 0.5),
        "threshold_batch_m": _POS,
        "crossings_first": None,
        "first_order": None,  # its enum has the values
        "open_entry": None,  # its enum has the values
        "probes": None,
        "probe_climb": None,
        "probe_m": _AREA,
        "probe_prominence": _range(0.0, 1.0),
        "probe_reach": _AREA0,
        "sweeps": None,
        "explore": None,  # its enum has the values
        "line_step_m": _AREA,
        "rays": _range(0, 3600),
        "line_weight": None,  # its enum has the values
        "probe_length_m": _DIST,
    }),
}

_SENSOR_SCHEMA: dict[str, tuple[type | tuple[type, ...], Any, Check | None]] = {
    "noise_std": (float, 0.0, _between(0, 1e12)),
    "lag_s": (float, 0.0, _between(0, 600, why="a sensor's response time")),
    "position_std_m": (float, 0.0, _between(0, 1000)),
    "position_tau_s": (float, 10.0, _between(0, 86400, above=True)),
    "lag_correction": (str, "deconvolve", _one_of("deconvolve", "none")),
}
"""``vehicles.sensor``: the sensor the vehicles carry (:class:`SensorConfig`)."""

_FIELD_SCHEMA: dict[str, dict[str, tuple[type | tuple[type, ...], Any, Check | None]]] = {
    "paper": {
        "n1": (int, 20, _range(1, 100000)),
        "n2": (int, 20, _range(0, 100000)),
        "sigma1_m": (float, 10.0, _AREA),
        "sigma2_m": (float, 15.0, _AREA),
        "peak": (float, 100.0, _between(0, 1e12, above=True)),
    },
    "authors": {
        "n1": (int, 150, _range(1, 100000)),
        "n2": (int, 150, _range(0, 100000)),
        "sigma1_m": (float, 10.0, _AREA),
        "sigma2_m": (float, 15.0, _AREA),
        "peak": (float, 100.0, _between(0, 1e12, above=True)),
    },
    "plume": {
        "sources": (int, 3, _range(1, 1000)),
        "sigma_min_m": (float, 2.0, _AREA),
        "sigma_max_m": (float, 5.0, _AREA),
        "background": (float, 10.0, _between(-1e12, 1e12)),
        "peak": (float, 100.0, _between(0, 1e12, above=True)),
    },
    "front": {
        "width_min_m": (float, 1.0, _AREA),
        "width_max_m": (float, 3.0, _AREA),
        "amplitude_m": (float, 10.0, _AREA0),
        "wavelength_m": (float, 60.0, _AREA),
        "islands": (int, 2, _range(0, 20)),
        "background": (float, 10.0, _between(-1e12, 1e12)),
        "peak": (float, 100.0, _between(0, 1e12, above=True)),
    },
    "raster": {
        "path": (str, _REQUIRED, None),
        "variable": (str, "", None),
        "method": (str, "cubic", _one_of("linear", "cubic")),
    },
}


def _coerce(where: str, value: Any, typ: type | tuple[type, ...]) -> Any:
    if typ is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise MissionError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise MissionError(f"{where}: must be finite, got {value!r}")
        return float(value)
    if typ is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise MissionError(f"{where}: expected an integer, got {value!r}")
        return value
    if typ is bool:
        if not isinstance(value, bool):
            raise MissionError(f"{where}: expected true or false, got {value!r}")
        return value
    if typ is str:
        if not isinstance(value, str):
            raise MissionError(f"{where}: expected a string, got {value!r}")
        return value
    if isinstance(typ, type) and issubclass(typ, enum.StrEnum):  # a mode: one of its values
        if not isinstance(value, str) or value not in set(typ):
            raise MissionError(f"{where}: must be one of {', '.join(typ)}; got {value!r}")
        return typ(value)
    if typ is tuple:  # a list of numbers
        if not isinstance(value, list | tuple):
            raise MissionError(f"{where}: expected a list of numbers, got {value!r}")
        return tuple(_coerce(f"{where}[{i}]", x, float) for i, x in enumerate(value))
    raise AssertionError(typ)  # pragma: no cover


def _key(key: Any) -> str:
    """A key as an error message shows it: plain if it is plain text, else its repr (so a
    message stays one line whatever the YAML held).

    >>> _key("width_m"), _key("a\\nb"), _key(3)
    ('width_m', "'a\\\\nb'", '3')
    """
    if isinstance(key, str) and key and key.isprintable() and key.strip() == key:
        return key
    return repr(key)


def _unknown(raw: Mapping[Any, Any], allowed: Iterable[str]) -> list[str]:
    allowed = set(allowed)
    return sorted(_key(k) for k in raw if not (isinstance(k, str) and k in allowed))


def _section(
    name: str, raw: Any, schema: Mapping[str, tuple[type | tuple[type, ...], Any, Check | None]]
) -> dict[str, Any]:
    if raw is None:
        raw = {}
    if not isinstance(raw, Mapping):
        raise MissionError(f"{name}: expected a mapping, got {type(raw).__name__}")
    unknown = _unknown(raw, schema)
    if unknown:
        raise MissionError(
            f"{name}.{unknown[0]}: unknown key (allowed: {', '.join(sorted(schema))})"
        )
    out: dict[str, Any] = {}
    for key, (typ, default, check) in schema.items():
        where = f"{name}.{key}"
        if key not in raw:
            if default is _REQUIRED:
                raise MissionError(f"{where}: missing required key")
            out[key] = default
            continue
        value = _coerce(where, raw[key], typ)
        if check is not None and (problem := check(value)) is not None:
            raise MissionError(f"{where}: {problem}")
        out[key] = value
    return out


@dataclass(frozen=True)
class SensorConfig:
    """The vehicles' sensor (``vehicles.sensor``; ``vehicles.noise_std`` is its
    ``noise_std`` written the older way).

    ``noise_std`` (field units), ``lag_s`` (the first-order response's time constant),
    ``position_std_m`` and ``position_tau_s`` (the GNSS error, a first-order Gauss-Markov
    process per axis) are what the simulated vehicles sense with
    (:mod:`sim_vehicle.sensor`); all zero: a perfect sensor. ``lag_s`` is also what the
    station knows of the real sensor: it corrects each sample for it
    (``lag_correction``, :mod:`econdor_gcs.core.lag`; ``none`` leaves the lag in).
    """

    noise_std: float = 0.0
    lag_s: float = 0.0
    position_std_m: float = 0.0
    position_tau_s: float = 10.0
    lag_correction: str = "deconvolve"


@dataclass(frozen=True)
class VehicleConfig:
    count: int
    speed_mps: float
    max_speed_mps: float
    max_accel_mps2: float
    max_turn_rate_dps: float
    sample_rate_hz: float
    altitude_m: float
    noise_std: float
    """The sensor's noise (the same as ``sensor.noise_std``)."""
    speedup: float
    sensor: SensorConfig = SensorConfig()

    def __post_init__(self) -> None:
        # one noise, wherever it was given (a copy made with dataclasses.replace too)
        if self.sensor.noise_std != self.noise_std:
            if self.sensor.noise_std and self.noise_std:
                raise MissionError(f"vehicles.noise_std: {self.noise_std:g} differs from "
                                   f"vehicles.sensor.noise_std {self.sensor.noise_std:g}")
            noise = self.noise_std or self.sensor.noise_std
            object.__setattr__(self, "noise_std", noise)
            object.__setattr__(self, "sensor", dataclasses.replace(self.sensor,
                                                                   noise_std=noise))


@dataclass(frozen=True)
class InitiationConfig:
    pattern: str
    spacing_m: float
    samples_per_diagonal: int


@dataclass(frozen=True)
class AlgorithmConfig:
    planner: str
    m0: int
    max_iterations: int
    min_iterations: int
    grid_spacing_m: float
    search_radius_m: float
    max_trace_length_m: float
    stop_lambda: float
    flight_budget_m: float
    lloyd_bins: int
    lloyd_iterations: int
    lloyd_variant: str
    reconstruction: str
    min_piece_length_m: float
    keep_diagonals: bool
    max_idle_iterations: int
    target_levels: tuple[float, ...]


@dataclass(frozen=True)
class LawnmowerConfig:
    spacing_m: float
    budget_m: float
    lines: int = 0


@dataclass(frozen=True)
class AdaptiveConfig:
    """The adaptive planner's settings (``econdor_gcs.core.adaptive.AdaptiveParams``)."""

    batch_m: float
    batch_growth: float
    levels: int
    piece_m: float
    leg_m: float
    legs: int
    line_spacing_m: float
    line_orientation: LineOrientation
    start: Start
    start_lines: int
    start_step_m: float
    model: Model
    length_m: float
    fit_length: bool
    floor: float
    gradient_gain_m: float
    power: float
    plan_spacing_m: float
    search_radius_m: float
    resolve_m: float
    explore_m: float
    band_m: float
    level_tol: float
    threshold_batch_m: float
    crossings_first: bool
    first_order: FirstOrder
    open_entry: OpenEntry
    probes: bool
    probe_climb: bool
    probe_m: float
    probe_prominence: float
    probe_reach: float
    sweeps: bool
    explore: Explore
    line_step_m: float
    rays: int
    line_weight: LineWeight
    probe_length_m: float


@dataclass(frozen=True)
class Mission:
    """A validated mission. Build fields with :meth:`build_field`."""

    name: str
    seed: int
    region: Region
    origin: Origin
    field_model: str
    field_params: dict[str, Any]
    vehicles: VehicleConfig
    initiation: InitiationConfig
    algorithm: AlgorithmConfig
    lawnmower: LawnmowerConfig
    adaptive: AdaptiveConfig
    base_dir: Path = field(default_factory=Path.cwd)

    @property
    def grid(self) -> Grid:
        """The P x Q evaluation grid (MAE, learning error, reconstruction)."""
        return Grid.with_spacing(self.region, self.algorithm.grid_spacing_m)

    def build_field(self, seed: int | None = None):  # -> Field
        """The synthetic (or raster) true field for ``seed`` (default: the mission's)."""
        from econdor_gcs.core.fields import make_field

        params = dict(self.field_params)
        if self.field_model == "raster":
            p = Path(params["path"])
            params["path"] = str(p if p.is_absolute() else self.base_dir / p)
        return make_field(self.field_model, params, self.region,
                          self.seed if seed is None else seed)

    def with_overrides(self, **algorithm: Any) -> Mission:
        """A copy with some ``algorithm`` keys replaced (validated like the file)."""
        raw = {k: getattr(self.algorithm, k) for k in _SCHEMA["algorithm"]}
        raw.update(algorithm)
        algo = AlgorithmConfig(**_section("algorithm", raw, _SCHEMA["algorithm"]))
        return _replace(self, algorithm=algo)

    def with_vehicles(self, **vehicles: Any) -> Mission:
        """A copy with some ``vehicles`` keys replaced (validated like the file);
        ``sensor`` (a mapping) replaces only the sensor keys it names, ``noise_std`` is the
        sensor's noise."""
        raw: dict[str, Any] = {k: getattr(self.vehicles, k) for k in _SCHEMA["vehicles"]}
        sensor = {k: v for k, v in dataclasses.asdict(self.vehicles.sensor).items()
                  if k != "noise_std"}
        new_sensor = vehicles.pop("sensor", None)
        if isinstance(new_sensor, Mapping):
            sensor.update(new_sensor)
        elif new_sensor is not None:
            raise MissionError(f"vehicles.sensor: expected a mapping, got "
                               f"{type(new_sensor).__name__}")
        if "noise_std" in sensor:  # the override gives it there: not twice
            raw.pop("noise_std")
        raw.update(vehicles)
        raw["sensor"] = sensor
        return _replace(self, vehicles=_vehicles(raw))

    def with_adaptive(self, **adaptive: Any) -> Mission:
        """A copy with some ``adaptive`` keys replaced (validated like the file)."""
        raw = {k: getattr(self.adaptive, k) for k in _SCHEMA["adaptive"]}
        raw.update(adaptive)
        return _replace(self, adaptive=AdaptiveConfig(**_section("adaptive", raw,
                                                                 _SCHEMA["adaptive"])))


def _replace(m: Mission, **kw: Any) -> Mission:
    from dataclasses import replace

    return replace(m, **kw)


def _vehicles(raw: Any) -> VehicleConfig:
    """The ``vehicles`` section, its ``sensor`` mapping included; the noise may be given
    as ``vehicles.noise_std`` or ``vehicles.sensor.noise_std``, not both."""
    if raw is None:
        raw = {}
    if not isinstance(raw, Mapping):
        raise MissionError(f"vehicles: expected a mapping, got {type(raw).__name__}")
    unknown = _unknown(raw, [*_SCHEMA["vehicles"], "sensor"])
    if unknown:
        raise MissionError(f"vehicles.{unknown[0]}: unknown key (allowed: "
                           f"{', '.join(sorted([*_SCHEMA['vehicles'], 'sensor']))})")
    sensor = _section("vehicles.sensor", raw.get("sensor"), _SENSOR_SCHEMA)
    sraw = raw.get("sensor") or {}
    veh = _section("vehicles", {k: v for k, v in raw.items() if k != "sensor"},
                   _SCHEMA["vehicles"])
    if "noise_std" in raw and "noise_std" in sraw:
        raise MissionError("vehicles.noise_std: given twice, also as vehicles.sensor.noise_std "
                           "(keep one)")
    if "noise_std" in raw:
        sensor["noise_std"] = veh["noise_std"]
    veh["noise_std"] = sensor["noise_std"]
    if veh["speed_mps"] > veh["max_speed_mps"]:
        raise MissionError("vehicles.speed_mps: must be <= vehicles.max_speed_mps")
    return VehicleConfig(**veh, sensor=SensorConfig(**sensor))


_TOP_KEYS = {"name", "seed", "field", *(_SCHEMA)}


def parse_mission(raw: Any, base_dir: Path | None = None, source: str = "mission") -> Mission:
    """Validate an already-parsed YAML document."""
    if not isinstance(raw, Mapping):
        raise MissionError(f"{source}: expected a mapping at the top level")
    unknown = _unknown(raw, _TOP_KEYS)
    if unknown:
        raise MissionError(f"{unknown[0]}: unknown key (allowed: {', '.join(sorted(_TOP_KEYS))})")
    if "field" not in raw:
        raise MissionError("field: missing required key")
    fraw = raw["field"]
    if not isinstance(fraw, Mapping):
        raise MissionError("field: expected a mapping")
    model = fraw.get("model")
    if model is None:
        raise MissionError("field.model: missing required key")
    if not isinstance(model, str) or model not in _FIELD_SCHEMA:
        raise MissionError(f"field.model: must be one of {', '.join(_FIELD_SCHEMA)}; got {model!r}")
    fparams = _section("field", {k: v for k, v in fraw.items() if k != "model"},
                       _FIELD_SCHEMA[model])
    if model == "plume" and fparams["sigma_max_m"] < fparams["sigma_min_m"]:
        raise MissionError("field.sigma_max_m: must be >= field.sigma_min_m")
    if model == "front" and fparams["width_max_m"] < fparams["width_min_m"]:
        raise MissionError("field.width_max_m: must be >= field.width_min_m")
    name = raw.get("name", "mission")
    if not isinstance(name, str):
        raise MissionError(f"name: expected a string, got {name!r}")
    if not name or not name.isprintable() or any(c in name for c in "/\\"):
        raise MissionError(f"name: must be printable text without / or \\ (it names run "
                           f"directories), got {name!r}")
    seed = _coerce("seed", raw.get("seed", 0), int)
    if not 0 <= seed < 2**32:
        raise MissionError(f"seed: must be within 0..{2**32 - 1} (a random generator's seed), "
                           f"got {seed}")
    sec = {s: _section(s, raw.get(s), _SCHEMA[s]) for s in _SCHEMA if s != "vehicles"}
    algo = sec["algorithm"]
    if algo["min_iterations"] > algo["max_iterations"]:
        raise MissionError("algorithm.min_iterations: must be <= algorithm.max_iterations")
    lm = sec["lawnmower"]
    if lm["lines"] == 1:
        raise MissionError("lawnmower.lines: must be 0 (not set) or >= 2, got 1")
    if lm["lines"] and lm["budget_m"]:
        raise MissionError("lawnmower.lines: give lines or budget_m, not both")
    vehicles = _vehicles(raw.get("vehicles"))
    area = sec["area"]
    spacing = algo["grid_spacing_m"]
    side = min(area["width_m"], area["height_m"])
    if spacing > side / 2:
        raise MissionError(f"algorithm.grid_spacing_m: must be <= half the area's shorter side "
                           f"({side / 2:g} m: the grid needs at least 3 x 3 nodes), got "
                           f"{spacing:g}")
    nodes = (round(area["width_m"] / spacing) + 1) * (round(area["height_m"] / spacing) + 1)
    if nodes > MAX_GRID_NODES:
        raise MissionError(f"algorithm.grid_spacing_m: {spacing:g} m makes a grid of {nodes:,} "
                           f"nodes over this area, more than {MAX_GRID_NODES:,}; use a coarser "
                           "spacing")
    return Mission(
        name=name,
        seed=seed,
        region=Region(0.0, area["width_m"], 0.0, area["height_m"]),
        origin=Origin(**sec["origin"]),
        field_model=model,
        field_params=fparams,
        vehicles=vehicles,
        initiation=InitiationConfig(**sec["initiation"]),
        algorithm=AlgorithmConfig(**algo),
        lawnmower=LawnmowerConfig(**sec["lawnmower"]),
        adaptive=AdaptiveConfig(**sec["adaptive"]),
        base_dir=base_dir or Path.cwd(),
    )


def load_mission(path: str | Path) -> Mission:
    """Read and validate a mission YAML file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise MissionError(f"{p}: no such mission file") from exc
    except OSError as exc:
        raise MissionError(f"{p}: cannot read ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise MissionError(f"{p}: not UTF-8 text (byte {exc.start})") from exc
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise MissionError(f"{p}: malformed YAML{where}: {problem}") from exc
    return parse_mission(raw, base_dir=p.resolve().parent, source=str(p))
