"""The noise bench's flights (``bench/noise.py``): its conditions (a sensor per field, noise
level and variant), one planner run, one survey scan with the condition's sensor, and the
pool that flies them; every row stamped with what it was flown with (:mod:`saved_rows`)."""

from __future__ import annotations

import hashlib
import json
import math
import sys
import time
from collections.abc import Iterator
from concurrent.futures import as_completed
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from runs import mid_level, mission_for, mission_raw, row_of, run_survey, split_variant  # noqa: E402
from saved_rows import code_fingerprint, code_of, commit, current_code  # noqa: E402
from surveys import SurveyScan  # noqa: E402

from econdor_lab.workers import WorkerPool  # noqa: E402

SPAN = {"plume": 90.0, "paper": 93.0, "authors": 50.0, "front": 100.0}
"""Each field's value range, about: a noise level is given in the plume's units (span 90)
and another field gets the same fraction of its own span (paper, eqs. 8-9: 1 -> 1.033)."""
SENSORS: dict[str, dict[str, Any]] = {
    "lag 0.5 s": {"lag_s": 0.5},
    "lag 0.5 s, unknown": {"lag_s": 0.5, "lag_correction": "none"},
    "lag 1 s": {"lag_s": 1.0},
    "lag 1 s, unknown": {"lag_s": 1.0, "lag_correction": "none"},
    "lag 1 s, estimated": {"lag_s": 1.0, "lag_correction": "estimate"},
    "GNSS 1 m": {"position_std_m": 1.0, "position_tau_s": 10.0},
    "plume-noisy": {"lag_s": 0.5, "position_std_m": 1.0, "position_tau_s": 10.0},
}
"""The sensor variants (``--sensors``), on top of the noise of ``--sensor-noise``; lag is
known to the station (and corrected) unless said: ``unknown`` left in, ``estimated`` from
the samples' crossovers and corrected."""
BUDGET_M = 4_000.0
THRESHOLD_BUDGET_M = 10_000.0
ISO_TARGET_M = 0.5


def condition_sensor(field: str, noise: float, variant: str) -> dict[str, Any]:
    """The ``vehicles.sensor`` of a condition: the noise scaled to ``field``'s span, and
    the variant's lag and position error."""
    sensor: dict[str, Any] = {"noise_std": round(noise * SPAN[field] / SPAN["plume"], 4)}
    sensor.update(SENSORS[variant] if variant else {})
    return sensor


def condition_name(noise: float, variant: str) -> str:
    return f"noise {noise:g}" + (f", {variant}" if variant else "")


# -- runs ------------------------------------------------------------------------------------


def run_one(args: tuple[str, int, str, float, str]) -> dict[str, Any]:
    """One planner run of a condition: a row per estimate (:func:`runs.row_of`, with the
    MAE and the noise estimated)."""
    from econdor_gcs.dfc.loop import Dfc
    from econdor_lab.inprocess import InProcessExecutor

    field, seed, label, noise, variant = args
    threshold = label.endswith(":threshold")
    planner, settings = split_variant(label.removesuffix(":threshold"))
    budget = THRESHOLD_BUDGET_M if threshold else BUDGET_M
    target = (mid_level(mission_for(field, budget, planner, "auto"), seed),) if threshold else ()
    mission = mission_for(field, budget, planner, "auto", target, adaptive=settings)
    mission = mission.with_vehicles(sensor=condition_sensor(field, noise, variant))
    truth = mission.build_field(seed)
    t0 = time.perf_counter()
    res = Dfc(mission, InProcessExecutor(mission, truth, seed=seed), planner=planner,
              truth=truth, seed=seed).run()
    rows = []
    for rec in res.records:
        row = row_of(rec)
        row.update(mae=rec.mae, noise_std=rec.noise_std)
        rows.append(row)
    return {"kind": "run", "field": field, "seed": seed, "planner": label, "noise": noise,
            "variant": variant, "rows": rows, "stop": res.stop_reason,
            "target": target[0] if target else math.nan, "wall_s": time.perf_counter() - t0,
            **provenance(field, noise, variant)}


def provenance(field: str, noise: float, variant: str, survey: bool = False
               ) -> dict[str, Any]:
    """What a saved row was flown with: the sensor, the fingerprint of the code it ran (a
    survey: only what a survey runs), the commit."""
    return {"sensor": condition_sensor(field, noise, variant),
            "code": code_of("survey" if survey else "run"), "commit": commit()}


def current(row: dict[str, Any]) -> bool:
    """Whether a saved row was flown by this code with its condition's sensor."""
    return current_code(row) and row.get("sensor") == condition_sensor(
        row["field"], row["noise"], row["variant"])


class NoisySurveyScan(SurveyScan):
    """:class:`surveys.SurveyScan` with the condition's sensor, cached under a key that
    holds it."""

    def __init__(self, field: str, seed: int, sensor: dict[str, Any], cache_dir: Path | None
                 ) -> None:
        super().__init__(field, seed, "auto", None)
        self.sensor = sensor
        self.dir = cache_dir / noisy_survey_key(field, sensor) if cache_dir else None

    def fly(self, lines: int) -> dict[str, Any]:
        return fly_survey(self.field, self.seed, lines, self.sensor)


def noisy_survey_key(field: str, sensor: dict[str, Any]) -> str:
    mission = mission_raw(field, 0.0, "lawnmower", "auto", survey_lines=2)
    mission["lawnmower"] = {}
    text = json.dumps({"mission": mission, "sensor": sensor, "code": code_fingerprint()},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def fly_survey(field: str, seed: int, lines: int, sensor: dict[str, Any]) -> dict[str, Any]:
    """One survey of ``lines`` north-south lines with ``sensor``: its one estimate."""
    return run_survey(field, seed, lines, "auto", sensor)


def scan_one(args: tuple[str, int, float, str, str | None]) -> dict[str, Any]:
    """Every survey of one field, seed and condition within the 4 km budget."""
    field, seed, noise, variant, cache = args
    scan = NoisySurveyScan(field, seed, condition_sensor(field, noise, variant),
                           Path(cache) if cache else None)
    t0 = time.perf_counter()
    rows = scan.all_within(BUDGET_M)
    # threshold mode's reference may need more than 4 km of survey: every count up to the
    # one that gets there
    to_iso = scan.shortest_reaching(lambda r: r["iso"][1] <= ISO_TARGET_M, THRESHOLD_BUDGET_M)
    return {"kind": "survey", "field": field, "seed": seed, "noise": noise, "variant": variant,
            "scanned": sorted(scan.runs.values(), key=lambda r: r["lines"]),
            "to_iso": ({"flight_m": to_iso["flight_m"], "lines": to_iso["lines"]} if to_iso
                       else {"flight_m": math.inf, "lines": 0}),
            "flown": scan.flown, "wall_s": time.perf_counter() - t0, "within": len(rows),
            **provenance(field, noise, variant, survey=True)}


def selected(r: dict[str, Any], seeds: list[int], fields: list[str],
             conditions: list[tuple[float, str]], labels: list[str]) -> bool:
    """Whether a saved row is of the :func:`selection`."""
    return (r["seed"] in seeds and r["field"] in fields
            and (r["noise"], r["variant"]) in conditions
            and (r["kind"] == "survey" or r["planner"] in labels))


def job_again(r: dict[str, Any], cache: str | None) -> tuple[str, tuple[Any, ...]]:
    """The job that flies saved row ``r`` again."""
    if r["kind"] == "survey":
        return "survey", (r["field"], r["seed"], r["noise"], r["variant"], cache)
    return "run", (r["field"], r["seed"], r["planner"], r["noise"], r["variant"])


def fly(jobs: list[tuple[str, tuple[Any, ...]]], workers: int
        ) -> Iterator[tuple[int, dict[str, Any]]]:
    """Fly ``jobs`` (survey scans and planner runs) on ``workers`` processes: each job's
    index and row as it comes in."""
    with WorkerPool(workers) as pool:
        futs = {pool.submit(scan_one if kind == "survey" else run_one, job): i
                for i, (kind, job) in enumerate(jobs)}
        for fut in as_completed(futs):
            yield futs[fut], fut.result()


def fly_in_order(jobs: list[tuple[str, tuple[Any, ...]]], workers: int
                 ) -> list[dict[str, Any]]:
    """:func:`fly`'s rows in the order of ``jobs``."""
    rows: dict[int, dict[str, Any]] = dict(fly(jobs, workers))
    return [rows[i] for i in range(len(jobs))]
