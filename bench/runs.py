"""The benches' runs: their missions, one planner run, one survey, and the rows they keep.

Every planner is flown on the same fields (``FIELDS``, a 100 x 100 m area), by the same
simulated vehicle (the in-process executor), reconstructed the same way, and booked the
same way: a row is one estimate and the flight behind it (the DFC's ``flight_distance_m``:
everything flown up to that estimate — initiation, transits, searches, traces, lines —
and never the flight home after the last iteration, which no estimate uses).
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the packages before bench/ (bench/sim_vehicle.py is a script)

from econdor_gcs.config import Mission, parse_mission  # noqa: E402
from econdor_gcs.dfc.loop import Dfc, isoline_levels  # noqa: E402
from econdor_lab.inprocess import InProcessExecutor  # noqa: E402

FIELDS: dict[str, dict[str, Any]] = {
    "authors": {"model": "authors"},
    "paper": {"model": "paper"},
    "plume": {"model": "plume", "sources": 3, "sigma_min_m": 3.0, "sigma_max_m": 6.0,
              "background": 10.0},
    "front": {"model": "front"},
}
"""``authors``: the paper's setting (the authors' generator, ``missions/paper.yaml``);
``paper``: the paper's eqs. 8-9; ``plume``: 3 narrow sources on a flat background;
``front``: a meandering sharp front and round islands."""
AREA_M = 100.0


def parse_settings(text: str) -> dict[str, Any]:
    """``"model=proxy,floor=20"`` -> ``{"model": "proxy", "floor": 20.0}``.

    >>> parse_settings("model=proxy,legs=0,probes=false")
    {'model': 'proxy', 'legs': 0, 'probes': False}
    """
    out: dict[str, Any] = {}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        if value in ("true", "false"):
            out[key] = value == "true"
            continue
        try:
            out[key] = int(value)
        except ValueError:
            try:
                out[key] = float(value)
            except ValueError:
                out[key] = value
    return out


def split_variant(planner: str) -> tuple[str, dict[str, Any]]:
    """``"adaptive[batch_m=200]"`` -> ``("adaptive", {"batch_m": 200})``.

    >>> split_variant("adaptive[batch_m=200,legs=0]")
    ('adaptive', {'batch_m': 200, 'legs': 0})
    >>> split_variant("no-sg")
    ('no-sg', {})
    """
    name, bracket, rest = planner.partition("[")
    if not bracket:
        return planner, {}
    if not rest.endswith("]"):
        raise ValueError(f"planner {planner!r}: settings must end with ']'")
    return name, parse_settings(rest[:-1])


def split_planners(text: str) -> list[str]:
    """Split ``--planners`` at the commas outside brackets.

    >>> split_planners("adaptive,adaptive[batch_m=200,legs=0],no-sg")
    ['adaptive', 'adaptive[batch_m=200,legs=0]', 'no-sg']
    """
    out, depth, item = [], 0, ""
    for ch in text:
        depth += {"[": 1, "]": -1}.get(ch, 0)
        if ch == "," and depth == 0:
            out.append(item)
            item = ""
        else:
            item += ch
    out.append(item)
    return out


def mission_raw(field: str, budget_m: float, planner: str, reconstruction: str,
                target_levels: tuple[float, ...] = (), survey_lines: int = 0,
                adaptive: dict[str, Any] | None = None) -> dict[str, Any]:
    """The benchmark mission as YAML would hold it: 100 x 100 m, one vehicle, a binding
    budget (the iteration cap out of reach); with ``survey_lines``, one survey of that
    many lines (``lawnmower.lines``), the planner then done."""
    algo: dict[str, Any] = {
        "planner": planner, "max_iterations": 1000, "min_iterations": 1000,
        "flight_budget_m": budget_m, "reconstruction": reconstruction,
        "target_levels": list(target_levels), "max_idle_iterations": 2}
    raw: dict[str, Any] = {"name": f"efficiency-{field}", "field": FIELDS[field],
                           "area": {"width_m": AREA_M, "height_m": AREA_M},
                           "vehicles": {"count": 1}, "algorithm": algo,
                           "adaptive": adaptive or {}}
    if survey_lines:
        raw["lawnmower"] = {"lines": survey_lines}
        algo.update(planner="lawnmower", flight_budget_m=0.0)
    return raw


def mission_for(field: str, budget_m: float, planner: str, reconstruction: str,
                target_levels: tuple[float, ...] = (), survey_lines: int = 0,
                adaptive: dict[str, Any] | None = None) -> Mission:
    """:func:`mission_raw`, validated."""
    return parse_mission(mission_raw(field, budget_m, planner, reconstruction, target_levels,
                                     survey_lines, adaptive), base_dir=ROOT / "missions")


def max_survey_lines(budget_m: float) -> int:
    """The most survey lines whose planned flight (lines and cross legs) fits the budget:
    the scan tries every count up to here (the turns make the last one or two longer
    than planned; the budget then excludes them)."""
    return int((budget_m - AREA_M) // AREA_M)


def mid_level(mission: Mission, seed: int) -> float:
    """The middle of the true field's range on the grid (the 50 % iso-line)."""
    xx, yy = mission.grid.mesh
    return isoline_levels(np.asarray(mission.build_field(seed)(xx, yy)), (0.5,))[0]


def sources_missed(field: Any, x_m: np.ndarray, y_m: np.ndarray) -> int:
    """Plume sources with no sample within one sigma of their centre."""
    centres = getattr(field, "centres_m", None)
    if centres is None or len(x_m) == 0:
        return 0
    d, _ = cKDTree(np.column_stack([x_m, y_m])).query(centres)
    return int(np.sum(d > field.sigmas_m))


def row_of(rec: Any) -> dict[str, Any]:
    """One estimate: the flight behind it (no flight home), its MAE and iso-line errors."""
    iso = rec.isoline_error_m
    at = [iso.get(k, math.nan) for k in ("p25", "p50", "p75")]
    finite = [x for x in at if not math.isnan(x)]
    return {"flight_m": rec.flight_distance_m, "mae_db": rec.mae_db, "samples": rec.samples,
            "iso": at, "iso_mean": sum(finite) / len(finite) if finite else math.nan,
            "iso_target": iso.get("target", math.nan),
            "target_missed": iso.get("target_missed", math.nan)}


def run_planner(args: tuple[str, int, str, float, str, bool, dict[str, Any]]
                ) -> dict[str, Any]:
    """One budget-true run: a row per estimate, and the plume sources missed by then; in
    threshold mode also the metres flown by kind of job (``bench/anatomy.py``)."""
    from anatomy import instrument

    field, seed, label, budget_m, recon, threshold, adaptive = args
    planner, variant = split_variant(label)
    adaptive = {**adaptive, **variant}
    targets = (mid_level(mission_for(field, budget_m, planner, recon), seed),) if threshold else ()
    mission = mission_for(field, budget_m, planner, recon, targets, adaptive=adaptive)
    truth = mission.build_field(seed)
    t0 = time.perf_counter()
    dfc = Dfc(mission, InProcessExecutor(mission, truth, seed=seed), planner=planner,
              truth=truth, seed=seed)
    metres = instrument(dfc) if threshold and planner == "adaptive" else {}
    res = dfc.run()
    rows = [row_of(rec) for rec in res.records]
    s = res.samples
    for rec, row in zip(res.records, rows, strict=True):
        n = row["samples"]
        row["missed"] = sources_missed(truth, s.x_m[:n], s.y_m[:n])
        if metres:
            row["metres"] = metres.get(rec.iteration, {})
    return {"field": field, "seed": seed, "planner": label + (":threshold" if threshold else ""),
            "rows": rows, "stop": res.stop_reason, "wall_s": time.perf_counter() - t0,
            "target": targets[0] if targets else math.nan, "return_m": res.return_m}


def run_survey(field: str, seed: int, lines: int, recon: str,
               sensor: dict[str, Any] | None = None) -> dict[str, Any]:
    """One survey of ``lines`` north-south lines (``lawnmower.lines``), with ``sensor``
    (``vehicles.sensor``; default the mission's): its one estimate, at its end, its MAE and
    the noise the reconstruction found, and the plume sources it missed."""
    mission = mission_for(field, 0.0, "lawnmower", recon, survey_lines=lines)
    if sensor is not None:
        mission = mission.with_vehicles(sensor=sensor)
    truth = mission.build_field(seed)
    t0 = time.perf_counter()
    res = Dfc(mission, InProcessExecutor(mission, truth, seed=seed), planner="lawnmower",
              truth=truth, seed=seed).run()
    if res.stop_reason != "planner_done" or len(res.records) != 1:
        raise RuntimeError(f"survey {field} seed {seed}, {lines} lines: ended "
                           f"{res.stop_reason!r} after {len(res.records)} rows")
    row = row_of(res.records[0])
    n = row["samples"]
    row["missed"] = sources_missed(truth, res.samples.x_m[:n], res.samples.y_m[:n])
    row.update(lines=lines, mae=res.records[0].mae, noise_std=res.records[0].noise_std,
               wall_s=time.perf_counter() - t0)
    return row
