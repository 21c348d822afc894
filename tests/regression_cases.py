"""The pinned runs of tests/test_regression.py (shared with tests/data/record_regression.py)."""

from __future__ import annotations

from pathlib import Path

import yaml

from econdor_gcs.config import Mission, load_mission, parse_mission
from econdor_gcs.dfc.loop import Dfc, RunResult
from econdor_lab.inprocess import InProcessExecutor

ROOT = Path(__file__).resolve().parents[1]

#: Samples of iterations 0 .. PINNED_ITERATIONS - 1 are stored whole.
PINNED_ITERATIONS = 2

#: name -> (field section or None for the paper mission's own, seed)
CASES: dict[str, tuple[dict[str, object] | None, int]] = {
    "paper-0": (None, 0),
    "paper-1": (None, 1),
    "paper-2": (None, 2),
    # the plume field of bench/efficiency.py
    "plume-3": ({"model": "plume", "sources": 3, "sigma_min_m": 3.0, "sigma_max_m": 6.0,
                 "background": 10.0}, 3),
}


def case_mission(name: str) -> Mission:
    """The paper mission, with the case's field section if it has one."""
    field, _ = CASES[name]
    if field is None:
        return load_mission(ROOT / "missions" / "paper.yaml")
    raw = yaml.safe_load((ROOT / "missions" / "paper.yaml").read_text(encoding="utf-8"))
    raw["field"] = field
    return parse_mission(raw, base_dir=ROOT / "missions")


def run_case(name: str) -> RunResult:
    """The whole in-process DFC run of one pinned case (econdor planner, one vehicle)."""
    mission = case_mission(name)
    _, seed = CASES[name]
    field = mission.build_field(seed)
    executor = InProcessExecutor(mission, field, seed=seed)
    return Dfc(mission, executor, planner="econdor", truth=field, seed=seed).run()
