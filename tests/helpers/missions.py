"""The small mission the end-to-end tests fly: a 100 m square of the paper's field (4 x 4
Gaussians), a 2 m grid and traces capped at 300 m, so that a whole MAVLink run at 100x sim
speed takes seconds, not minutes, and still traces every level of every iteration."""

from __future__ import annotations

from pathlib import Path

TEMPLATE = """\
name: %(name)s
seed: %(seed)d
area: {width_m: 100, height_m: 100}
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488.0}
field: {model: paper, n1: 4, n2: 4}
vehicles: {count: %(vehicles)d, speed_mps: 8, max_speed_mps: 12, sample_rate_hz: 10, altitude_m: 30,
           %(extra)s}
initiation: {pattern: diagonals}
algorithm: {planner: econdor, max_iterations: %(iterations)d, min_iterations: %(min_iterations)d,
            search_radius_m: 10, grid_spacing_m: 2, max_trace_length_m: %(max_trace_length_m)g}
"""


def small_mission(name: str, *, seed: int = 3, vehicles: int = 3, iterations: int = 2,
                  min_iterations: int = 1, speedup: float | None = 100,
                  max_trace_length_m: float = 300, sensor: str | None = None) -> str:
    """The mission's YAML. ``speedup=None`` leaves it out (in-process runs have no sim speed);
    ``sensor`` is the flow mapping of ``vehicles.sensor``, e.g. ``"{noise_std: 0.2}"``."""
    extra = [f"speedup: {speedup:g}"] if speedup is not None else []
    if sensor is not None:
        extra.append(f"sensor: {sensor}")
    return TEMPLATE % {"name": name, "seed": seed, "vehicles": vehicles, "iterations": iterations,
                       "min_iterations": min_iterations, "max_trace_length_m": max_trace_length_m,
                       "extra": ", ".join(extra)}


def write_small_mission(folder: Path, name: str, **kw: object) -> Path:
    """:func:`small_mission` written to ``folder/<name>.yaml``."""
    path = folder / f"{name}.yaml"
    path.write_text(small_mission(name, **kw), encoding="utf-8")  # type: ignore[arg-type]
    return path
