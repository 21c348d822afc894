"""The DFC loop asks its planner and never checks which planner it has."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from econdor_gcs.config import load_mission
from econdor_gcs.core.planners import PLANNER_NAMES, Batch, PlanContext, survey_jobs
from econdor_gcs.core.tasks import FlightReport
from econdor_gcs.dfc import loop as dfc
from econdor_gcs.errors import MissionError
from econdor_lab.inprocess import InProcessExecutor

ROOT = Path(__file__).resolve().parents[2]


class TwoLines:
    """A planner the loop has never heard of: one north-south line per iteration."""

    name = "two-lines"

    def __init__(self) -> None:
        self.contexts: list[PlanContext] = []
        self.observed: list[tuple[float, int]] = []

    def initiation(self, context: PlanContext) -> Batch | None:
        return None  # fly the mission's diagonals

    def next_batch(self, context: PlanContext) -> Batch:
        self.contexts.append(context)
        x = 25.0 * len(self.contexts)
        jobs = survey_jobs(context.region, np.array([x]))
        return Batch(jobs, levels_planned=0, survey_m=sum(j.length_m for j in jobs))

    def observe(self, learning_error: float, reports: Sequence[FlightReport]) -> None:
        self.observed.append((learning_error, len(reports)))


def test_a_new_planner_plugs_in_without_editing_the_loop(monkeypatch):
    mission = load_mission(ROOT / "missions" / "demo.yaml").with_overrides(
        max_iterations=2, min_iterations=2).with_vehicles(count=1)
    planner = TwoLines()
    monkeypatch.setitem(dfc.PLANNERS, "two-lines", lambda m: planner)
    field = mission.build_field(1)
    events: list[dfc.DfcEvent] = []
    result = dfc.Dfc(mission, InProcessExecutor(mission, field), planner="two-lines",
                     truth=field, progress=events.append).run()
    assert [r.iteration for r in result.records] == [0, 1, 2]
    # the planner saw the estimate, every sample so far and where the vehicle was
    first = planner.contexts[0]
    assert first.iteration == 1 and first.estimate is not None
    assert len(first.samples) == result.records[0].samples
    assert len(first.positions_m) == 1
    assert len(planner.observed) == 2 and all(n == 1 for _, n in planner.observed)
    # its survey lines count as productive ('contour') distance, 100 m each
    assert result.contour_distance_m == pytest.approx(200.0)
    kinds = [type(e).__name__ for e in events]
    assert kinds[0] == "RunStarted" and kinds[-1] == "RunDone"
    # iteration 0 (the diagonals) is announced like the others
    assert kinds.count("IterationPlanned") == 3 and kinds.count("IterationDone") == 3


def test_every_named_planner_has_a_factory_and_unknown_names_are_refused():
    assert tuple(dfc.PLANNERS) == PLANNER_NAMES
    mission = load_mission(ROOT / "missions" / "demo.yaml")
    with pytest.raises(MissionError, match="unknown planner 'nope'"):
        dfc.build_planner("nope", mission)
