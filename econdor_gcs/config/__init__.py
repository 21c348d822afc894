"""Mission files: YAML in, a validated :class:`Mission` out.

Every problem is reported as one :class:`~econdor_gcs.errors.MissionError` line that
names the key (``field.sigma1_m: must be > 0, got -3``). Unknown keys are errors, so a
typo never silently falls back to a default. The keys, their types, defaults, bounds and
meanings are one table, :mod:`econdor_gcs.config.schema` (rendered as ``docs/missions.md``).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from econdor_gcs.config.schema import (
    FIELD_SCHEMA,
    MAX_GRID_NODES,
    REQUIRED,
    SCHEMA,
    SENSOR_SCHEMA,
    Section,
)
from econdor_gcs.core.adaptive import (
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
from econdor_gcs.errors import MissionError


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


def _section(name: str, raw: Any, schema: Section) -> dict[str, Any]:
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
            if default is REQUIRED:
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
    (``lag_correction``, :mod:`econdor_gcs.core.lag`; ``estimate``: the station estimates
    the lag from the samples and corrects for that instead; ``none`` leaves the lag in).
    The lag corrected for is also what the onboard tracer traces with: the DFC gives it to
    each trace task (``TraceTask.sensor_lag_s``).
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
    max_starved_iterations: int
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
    probes_at_end: bool
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
        raw = {k: getattr(self.algorithm, k) for k in SCHEMA["algorithm"]}
        raw.update(algorithm)
        algo = AlgorithmConfig(**_section("algorithm", raw, SCHEMA["algorithm"]))
        return _replace(self, algorithm=algo)

    def with_vehicles(self, **vehicles: Any) -> Mission:
        """A copy with some ``vehicles`` keys replaced (validated like the file);
        ``sensor`` (a mapping) replaces only the sensor keys it names, ``noise_std`` is the
        sensor's noise."""
        raw: dict[str, Any] = {k: getattr(self.vehicles, k) for k in SCHEMA["vehicles"]}
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
        raw = {k: getattr(self.adaptive, k) for k in SCHEMA["adaptive"]}
        raw.update(adaptive)
        return _replace(self, adaptive=AdaptiveConfig(**_section("adaptive", raw,
                                                                 SCHEMA["adaptive"])))


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
    unknown = _unknown(raw, [*SCHEMA["vehicles"], "sensor"])
    if unknown:
        raise MissionError(f"vehicles.{unknown[0]}: unknown key (allowed: "
                           f"{', '.join(sorted([*SCHEMA['vehicles'], 'sensor']))})")
    sensor = _section("vehicles.sensor", raw.get("sensor"), SENSOR_SCHEMA)
    sraw = raw.get("sensor") or {}
    veh = _section("vehicles", {k: v for k, v in raw.items() if k != "sensor"},
                   SCHEMA["vehicles"])
    if "noise_std" in raw and "noise_std" in sraw:
        raise MissionError("vehicles.noise_std: given twice, also as vehicles.sensor.noise_std "
                           "(keep one)")
    if "noise_std" in raw:
        sensor["noise_std"] = veh["noise_std"]
    veh["noise_std"] = sensor["noise_std"]
    if veh["speed_mps"] > veh["max_speed_mps"]:
        raise MissionError("vehicles.speed_mps: must be <= vehicles.max_speed_mps")
    return VehicleConfig(**veh, sensor=SensorConfig(**sensor))


_TOP_KEYS = {"name", "seed", "field", *(SCHEMA)}


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
    if not isinstance(model, str) or model not in FIELD_SCHEMA:
        raise MissionError(f"field.model: must be one of {', '.join(FIELD_SCHEMA)}; got {model!r}")
    fparams = _section("field", {k: v for k, v in fraw.items() if k != "model"},
                       FIELD_SCHEMA[model])
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
    sec = {s: _section(s, raw.get(s), SCHEMA[s]) for s in SCHEMA if s != "vehicles"}
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
