"""The mission schema: every key of a mission YAML with its type, default, bound and meaning.

One table serves three readers: the validation (:func:`econdor_gcs.config.parse_mission`
checks each value against its row), the error messages (a row's check says what failed)
and the generated reference ``docs/missions.md`` (:mod:`econdor_gcs.docs`), so the
documentation cannot drift from what the station accepts. The ``adaptive`` rows take their
type, default and meaning from :class:`~econdor_gcs.core.adaptive.AdaptiveParams`, where
the planner's own parameters are written once.
"""

from __future__ import annotations

import dataclasses
import enum
import re
import typing
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from econdor_gcs.core.adaptive import AdaptiveParams
from econdor_gcs.core.planners import PLANNER_NAMES
from econdor_gcs.core.stopping import FAIR_SHARE

REQUIRED: Any = object()
"""The default of a key a mission must give."""


@dataclass(frozen=True)
class Check:
    """A bound on a value: ``test(value)`` is ``None`` when it holds, else the problem;
    ``bound`` says it in words for the reference."""

    bound: str
    test: Callable[[Any], str | None]

    def __call__(self, value: Any) -> str | None:
        return self.test(value)


Type = type | tuple[type, ...]


@dataclass(frozen=True)
class Key:
    """One key of a section: its type, default (:data:`REQUIRED`: none), check and meaning.

    It unpacks as ``(type, default, check)``, the part the validation needs.
    """

    type: Type
    default: Any
    check: Check | None
    doc: str

    def __iter__(self) -> Iterator[Any]:
        return iter((self.type, self.default, self.check))


Section = dict[str, Key]


def number(x: float) -> str:
    """A bound or default as the reference writes it: whole numbers without a point, other
    values in full.

    >>> number(4294967295), number(1e7), number(47.397742), number(1e-4), number(1e12)
    ('4294967295', '10000000', '47.397742', '0.0001', '1e+12')
    """
    if not float(x).is_integer():
        return repr(float(x))
    return str(int(x)) if abs(x) < 1e10 else f"{float(x):g}"


def one_of(*choices: str) -> Check:
    def test(v: Any) -> str | None:
        return None if v in choices else f"must be one of {', '.join(choices)}; got {v!r}"

    return Check(f"one of {', '.join(choices)}", test)


def _numbers_test(v: Any) -> str | None:
    return None if len(v) <= 100 else f"at most 100 values, got {len(v)}"


NUMBERS = Check("at most 100 values", _numbers_test)


def within(lo: float, hi: float) -> Check:
    def test(v: Any) -> str | None:
        return None if lo <= v <= hi else f"must be within [{lo}, {hi}], got {v}"

    return Check(f"{number(lo)} .. {number(hi)}", test)


def between(lo: float, hi: float, *, above: bool = False, why: str = "") -> Check:
    """``lo <= v <= hi`` (``lo < v`` with ``above``); the message says which side failed,
    and ``why`` the bound.

    >>> between(10, 10_000, why="the area the station maps")(0.5)
    'must be >= 10 (the area the station maps), got 0.5'
    >>> between(0, 50, above=True)(0.0), between(0, 50, above=True)(1e9)
    ('must be > 0, got 0.0', 'must be <= 50, got 1000000000.0')
    >>> between(0, 50, above=True).bound
    '> 0, <= 50'
    """
    note = f" ({why})" if why else ""

    def test(v: Any) -> str | None:
        if above and not v > lo:
            return f"must be > {lo:g}{note}, got {v}"
        if v < lo:
            return f"must be >= {lo:g}{note}, got {v}"
        if v > hi:
            return f"must be <= {hi:g}{note}, got {v}"
        return None

    return Check(f"{'>' if above else '>='} {number(lo)}, <= {number(hi)}", test)


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

_POS = between(0, MAX_DISTANCE_M, above=True)
_DIST = between(0, MAX_DISTANCE_M)
_AREA = between(0, MAX_AREA_M, above=True)
_AREA0 = between(0, MAX_AREA_M)


def param_docs(cls: type) -> dict[str, str]:
    """The meaning of each parameter in the numpydoc ``Parameters`` section of ``cls``'s
    docstring, its lines joined.

    >>> param_docs(AdaptiveParams)["batch_m"]
    'Flight planned per vehicle and iteration (m), transit included.'
    """
    doc = (cls.__doc__ or "").split("----------\n", 1)[-1]
    out: dict[str, str] = {}
    name = ""
    for line in doc.splitlines():
        head = re.match(r"^    (\w+) : ", line)
        if head:
            name = head.group(1)
            out[name] = ""
        elif name and line.startswith("        "):
            out[name] = f"{out[name]} {line.strip()}".strip()
    return out


def _from_params(cls: type, checks: dict[str, Check | None]) -> Section:
    """Rows for the keys of ``checks``, with the type, default and meaning the dataclass
    ``cls`` gives them (the planner's own parameters, written once, there)."""
    hints = typing.get_type_hints(cls)
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    docs = param_docs(cls)
    return {k: Key(hints[k], defaults[k], check, docs[k]) for k, check in checks.items()}


_BY_ENUM = None
"""A mode's check: its enum (the row's type) has the values."""

SCHEMA: dict[str, Section] = {
    "area": {
        "width_m": Key(float, 100.0, between(MIN_AREA_M, MAX_AREA_M, why="metres"),
                       "East-west side of the mapped rectangle (m), from the origin east."),
        "height_m": Key(float, 100.0, between(MIN_AREA_M, MAX_AREA_M, why="metres"),
                        "North-south side of the mapped rectangle (m), from the origin "
                        "north."),
    },
    "origin": {
        "lat_deg": Key(float, 47.397742, within(-90, 90),
                       "Latitude of the area's south-west corner, the local ENU frame's "
                       "origin (WGS84 degrees)."),
        "lon_deg": Key(float, 8.545594, within(-180, 180),
                       "Longitude of that corner (WGS84 degrees)."),
        "alt_m": Key(float, 488.0, between(MIN_AMSL_M, MAX_AMSL_M,
                                           why="metres above mean sea level"),
                     "Ground altitude at the origin (m above mean sea level): the "
                     "simulated vehicles' home altitude."),
    },
    "vehicles": {
        "count": Key(int, 3, within(1, 250),
                     "Vehicles flying the mission (simulated ones started, or real ones "
                     "waited for)."),
        "speed_mps": Key(float, 8.0, between(0, MAX_SPEED_MPS, above=True),
                         "Cruise ground speed along the planned paths (m/s)."),
        "max_speed_mps": Key(float, 12.0, between(0, MAX_SPEED_MPS, above=True),
                             "Top speed a simulated vehicle reaches (m/s); at least "
                             "speed_mps."),
        "max_accel_mps2": Key(float, 5.0, between(0, 100, above=True),
                              "Horizontal acceleration limit of a simulated vehicle (m/s²)."),
        "max_turn_rate_dps": Key(float, 180.0, between(0, 3600, above=True),
                                 "Yaw/turn rate limit of a simulated vehicle (deg/s)."),
        "sample_rate_hz": Key(float, 10.0, between(0, MAX_RATE_HZ, above=True),
                              "Rate at which the sensor is sampled and each sample sent "
                              "(Hz)."),
        "altitude_m": Key(float, 30.0, between(1, MAX_ALT_M, why="metres above home"),
                          "Flight altitude (m above home, the relative frame)."),
        "noise_std": Key(float, 0.0, between(0, 1e9),
                         "The sensor's noise standard deviation (field units); the same "
                         "as vehicles.sensor.noise_std (give one of them)."),
        "speedup": Key(float, 50.0, between(0, MAX_SPEEDUP, above=True),
                       "Simulated time over wall time for the simulated vehicles."),
    },
    "initiation": {
        "pattern": Key(str, "diagonals", one_of("diagonals", "lawnmower"),
                       "The first flight, before any estimate: the area's two main "
                       "diagonals (split over the fleet), or a lawnmower survey "
                       "(narrow features the diagonals can miss)."),
        "spacing_m": Key(float, 25.0, _AREA,
                         "Line spacing of the lawnmower initiation (m)."),
        "samples_per_diagonal": Key(int, 0, within(0, 1_000_000),
                                    "Keep only this many samples per diagonal of the "
                                    "initiation, evenly spread (the paper's setting); 0: "
                                    "every sample."),
    },
    "algorithm": {
        "planner": Key(str, "econdor", one_of(*PLANNER_NAMES),
                       "The planner: econdor (the paper's dual stochastic gradient), no-sg "
                       "(its baseline, one more level per iteration), lawnmower (a "
                       "refining survey) or adaptive (uncertainty-driven; threshold "
                       "mapping with target_levels)."),
        "m0": Key(int, 3, within(1, 1000),
                  "M0: the levels traced in the first iteration (paper)."),
        "max_iterations": Key(int, 8, within(1, 1000),
                              "The run stops after this many iterations."),
        "min_iterations": Key(int, 3, within(1, 1000),
                              "The convergence rule (stop_lambda) is not applied before "
                              "this many iterations; at most max_iterations."),
        "grid_spacing_m": Key(float, 1.0, _AREA,
                              "Spacing of the evaluation grid the field is reconstructed "
                              "on (m); at most half the shorter side, at most "
                              f"{MAX_GRID_NODES:,} nodes."),
        "search_radius_m": Key(float, 10.0, _AREA,
                               "Radius the onboard tracer searches for its contour level "
                               "around a task's start (m)."),
        "max_trace_length_m": Key(float, 0.0, _DIST,
                                  "Cap on the length of one trace (m); 0: four times the "
                                  "contour piece's length, at least 100 m."),
        "stop_lambda": Key(float, 0.0, between(0, 1),
                           "Convergence stop: after min_iterations, stop when γn = "
                           "3En/(En + En−1 + En−2) is within 1 ± stop_lambda and the span "
                           "changed by less than 1 %; 0: off."),
        "flight_budget_m": Key(float, 0.0, _DIST,
                               "Total flight distance of the fleet after which the run "
                               "stops (m); 0: no budget."),
        "lloyd_bins": Key(int, 200, within(2, 100000),
                          "Histogram bins of the Lloyd-Max level quantiser."),
        "lloyd_iterations": Key(int, 100, within(1, 100000),
                                "Iterations of the Lloyd-Max level quantiser."),
        "lloyd_variant": Key(str, "textbook", one_of("textbook", "authors"),
                             "E-CONDOR's levels: the textbook eqs. 4-5, or the authors' "
                             "Lloyd_Max_2.m (outer thresholds recomputed, 500 bins first)."),
        "reconstruction": Key(str, "auto", one_of("auto", "exact", "fast", "kriging"),
                              "How the field is reconstructed from the samples: exact "
                              "biharmonic spline, fast (tiled) spline, kriging (a Matérn "
                              "GP), or auto (exact while the samples are few enough, else "
                              "fast)."),
        "min_piece_length_m": Key(float, 2.0, _AREA0,
                                  "Contour pieces of the estimate shorter than this are no "
                                  "trace candidates (m)."),
        "keep_diagonals": Key(bool, True, None,
                              "Keep the initiation's samples in every reconstruction "
                              "(false: drop them once the traces begin)."),
        "max_starved_iterations": Key(int, 0, within(0, 1000),
                                      "An iteration that sampled too little (flew under "
                                      f"{FAIR_SHARE * 100:g} % of the run's largest "
                                      "iteration) does not count "
                                      "against max_iterations, at most this many times; 0: "
                                      "every iteration counts (the paper's iteration n)."),
        "max_idle_iterations": Key(int, 2, within(0, 1000),
                                   "Stop after this many + 1 iterations in a row with "
                                   "nothing to fly."),
        "target_levels": Key(tuple, (), NUMBERS,
                             "Threshold mode (adaptive planner): map only the iso-lines at "
                             "these levels (field units); empty: the whole field."),
    },
    "lawnmower": {
        "spacing_m": Key(float, 0.0, _AREA0,
                         "Line spacing of the first survey, halved each iteration (m); 0: "
                         "a quarter of the area's width."),
        "budget_m": Key(float, 0.0, _DIST,
                        "One survey of the most lines whose flight, turns counted, fits "
                        "this (m); then the planner is done. 0: not set."),
        "lines": Key(int, 0, within(0, 100000),
                     "One survey of this many lines, west edge to east edge, then done; 0: "
                     "not set, else at least 2 (not with budget_m)."),
    },
    "adaptive": _from_params(AdaptiveParams, {
        "batch_m": _POS,
        "batch_growth": between(0, 100),
        "levels": within(1, 1000),
        "piece_m": _AREA,
        "leg_m": _AREA,
        "legs": within(0, 10000),
        "line_spacing_m": _AREA0,
        "line_orientation": _BY_ENUM,
        "start": _BY_ENUM,
        "start_lines": within(0, 1000),
        "start_step_m": _AREA0,
        "model": _BY_ENUM,
        "length_m": _AREA,
        "fit_length": None,
        "floor": between(0, 1e12),
        "gradient_gain_m": _AREA0,
        "power": within(0.5, 4.0),
        "plan_spacing_m": _AREA,
        "search_radius_m": _AREA,
        "resolve_m": _AREA,
        "explore_m": _AREA,
        "band_m": _AREA0,
        "level_tol": within(0.0, 0.5),
        "threshold_batch_m": _POS,
        "crossings_first": None,
        "first_order": _BY_ENUM,
        "open_entry": _BY_ENUM,
        "probes": None,
        "probe_climb": None,
        "probes_at_end": None,
        "probe_m": _AREA,
        "probe_prominence": within(0.0, 1.0),
        "probe_reach": _AREA0,
        "sweeps": None,
        "explore": _BY_ENUM,
        "line_step_m": _AREA,
        "rays": within(0, 3600),
        "line_weight": _BY_ENUM,
        "probe_length_m": _DIST,
    }),
}
"""section -> key -> :class:`Key` (every section but ``field``, and ``vehicles.sensor``)."""

SENSOR_SCHEMA: Section = {
    "noise_std": Key(float, 0.0, between(0, 1e12),
                     "Noise standard deviation of each reading (field units)."),
    "lag_s": Key(float, 0.0, between(0, 600, why="a sensor's response time"),
                 "Time constant of the sensor's first-order response (s); the station "
                 "corrects each sample for it (lag_correction)."),
    "position_std_m": Key(float, 0.0, between(0, 1000),
                          "Standard deviation of the GNSS position error per axis (m), a "
                          "first-order Gauss-Markov process."),
    "position_tau_s": Key(float, 10.0, between(0, 86400, above=True),
                          "Correlation time of that position error (s)."),
    "lag_correction": Key(str, "deconvolve", one_of("deconvolve", "estimate", "none"),
                          "deconvolve: the station undoes the sensor's lag (lag_s) before "
                          "reconstructing; estimate: it estimates the lag from where the "
                          "vehicles crossed their own tracks and undoes that (lag_s then only "
                          "sets the simulated sensor's); none: the lag is left in. The "
                          "onboard tracer is told the lag the station corrects for, with "
                          "the contour items."),
}
"""``vehicles.sensor``: the sensor the vehicles carry (:class:`SensorConfig`); all zero is a
perfect sensor."""

_PEAK = Key(float, 100.0, between(0, 1e12, above=True),
            "The field's maximum (field units).")
_BACKGROUND = Key(float, 10.0, between(-1e12, 1e12), "The flat background level.")


def _gaussians(n1: int, n2: int, what: str) -> Section:
    return {
        "n1": Key(int, n1, within(1, 100000), f"Gaussians of width sigma1_m ({what})."),
        "n2": Key(int, n2, within(0, 100000), f"Gaussians of width sigma2_m ({what})."),
        "sigma1_m": Key(float, 10.0, _AREA, "Width of the first group's Gaussians (m)."),
        "sigma2_m": Key(float, 15.0, _AREA, "Width of the second group's Gaussians (m)."),
        "peak": _PEAK,
    }


FIELD_SCHEMA: dict[str, Section] = {
    "paper": _gaussians(20, 20, "the paper's eqs. 8-9, random centres, positive weights"),
    "authors": _gaussians(150, 150, "the authors' MATLAB generator, signed weights"),
    "plume": {
        "sources": Key(int, 3, within(1, 1000), "Narrow sources on the background."),
        "sigma_min_m": Key(float, 2.0, _AREA, "Smallest source width (m)."),
        "sigma_max_m": Key(float, 5.0, _AREA, "Largest source width (m); at least "
                                              "sigma_min_m."),
        "background": _BACKGROUND,
        "peak": _PEAK,
    },
    "front": {
        "width_min_m": Key(float, 1.0, _AREA, "Narrowest width of the front's step (m)."),
        "width_max_m": Key(float, 3.0, _AREA, "Widest width of the step (m); at least "
                                              "width_min_m."),
        "amplitude_m": Key(float, 10.0, _AREA0, "How far the front meanders (m)."),
        "wavelength_m": Key(float, 60.0, _AREA, "Wavelength of the meander (m)."),
        "islands": Key(int, 2, within(0, 20), "Round islands with the same steep edge."),
        "background": _BACKGROUND,
        "peak": _PEAK,
    },
    "raster": {
        "path": Key(str, REQUIRED, None,
                    "A grid file (.npy, .npz, .mat or .csv) spanning the area node to "
                    "node; relative to the mission file."),
        "variable": Key(str, "", None, "The array's name inside a .npz or .mat file."),
        "method": Key(str, "cubic", one_of("linear", "cubic"),
                      "Interpolation between the grid's nodes."),
    },
}
"""``field``: model -> key -> :class:`Key` (besides ``model`` itself)."""

FIELD_MODELS: dict[str, str] = {
    "paper": "The paper's eqs. 8-9: two groups of isotropic Gaussians with random centres "
             "and positive weights, scaled into (0, peak).",
    "authors": "The authors' MATLAB field generator (150 + 150 Gaussians, signed weights).",
    "plume": "A few narrow sources on a flat background (features the diagonals can miss).",
    "front": "A meandering tanh front across the area with a few round islands, on a "
             "gentle slope.",
    "raster": "A grid loaded from a file and interpolated.",
}

TOP_LEVEL: Section = {
    "name": Key(str, "mission", None,
                "Names the run directories (printable, without / or \\)."),
    "seed": Key(int, 0, within(0, 2**32 - 1),
                "Seed of the synthetic field (studies override it per run)."),
}
"""The mission's own keys besides its sections (checked in
:func:`econdor_gcs.config.parse_mission`)."""


def type_name(typ: Type) -> str:
    """A row's type as the reference names it."""
    if isinstance(typ, type) and issubclass(typ, enum.StrEnum):
        return "one of " + ", ".join(typ)
    names: dict[object, str] = {float: "number", int: "integer", bool: "true/false",
                                str: "string", tuple: "list of numbers"}
    return names.get(typ, str(typ))
