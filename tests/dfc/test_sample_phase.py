"""A sample's phase is decided once, by the executor that made it: the DFC tells the
executor which flight is the survey and never re-tags a sample."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from econdor_gcs.config import load_mission
from econdor_gcs.core.tasks import FlightReport, Phase, SampleLog, TaskStyle, Waypoint
from econdor_gcs.dfc.loop import Dfc
from econdor_lab.inprocess import InProcessExecutor

ROOT = Path(__file__).resolve().parents[2]


def _mission(**algorithm):
    return load_mission(ROOT / "missions" / "demo.yaml").with_overrides(
        grid_spacing_m=4, max_iterations=2, min_iterations=2, **algorithm)


class TransitOnly:
    """An executor whose vehicle reports every sample in TRANSIT, even when told that the
    flight is a survey (a wrong executor: what it reports is what the run must show)."""

    n_vehicles = 1

    def __init__(self) -> None:
        self.rng = np.random.default_rng(0)
        self.told: list[tuple[int, bool]] = []

    def positions(self):
        return [(0.0, 0.0)]

    def fly(self, plans, iteration, *, survey=False):
        self.told.append((iteration, survey))
        x, y = self.rng.uniform(0.0, 100.0, (2, 200))
        value = 50.0 + 20.0 * np.sin(x / 30.0) * np.cos(y / 40.0)
        log = SampleLog(np.arange(200) / 10.0, x, y, value,
                        np.full(200, Phase.TRANSIT, np.int8), np.zeros(200, np.int16))
        return [FlightReport(0, log, 200.0, 0.0, [], float(x[-1]), float(y[-1]), 20.0)]

    def finish(self):
        return []


def test_the_dfc_tells_the_executor_the_survey_and_keeps_the_phases_it_reports():
    ex = TransitOnly()
    result = Dfc(_mission(), ex, planner="no-sg").run()
    assert ex.told[0] == (0, True)  # the mission's pattern is the survey
    assert all(not survey for _, survey in ex.told[1:]) and len(ex.told) > 1
    # nothing re-tags the executor's samples: the DFC overwrote them with SURVEY once
    assert set(result.samples.phase.tolist()) == {int(Phase.TRANSIT)}


def test_in_process_survey_samples_are_survey_from_the_start():
    mission = _mission()
    field = mission.build_field(1)
    plans = [[Waypoint(50.0, 50.0)], [Waypoint(20.0, 80.0)], [Waypoint(90.0, 10.0)]]
    for style in TaskStyle:
        survey = InProcessExecutor(mission, field, seed=1, style=style).fly(plans, 0,
                                                                             survey=True)
        other = InProcessExecutor(mission, field, seed=1, style=style).fly(plans, 0)
        for s, o in zip(survey, other, strict=True):
            assert len(s.samples) > 10
            assert set(s.samples.phase.tolist()) == {int(Phase.SURVEY)}
            assert set(o.samples.phase.tolist()) == {int(Phase.TRANSIT)}
            # the same flight otherwise, sample for sample
            np.testing.assert_array_equal(s.samples.x_m, o.samples.x_m)
            np.testing.assert_array_equal(s.samples.value, o.samples.value)


def test_a_run_keeps_its_survey_samples_out_of_later_reconstructions_as_before():
    """keep_diagonals = false drops the survey's samples once traces begin; the DFC finds
    them by the phase the executor gave them."""
    mission = _mission(keep_diagonals=False)
    field = mission.build_field(1)
    dfc = Dfc(mission, InProcessExecutor(mission, field, seed=1), planner="econdor",
              truth=field)
    result = dfc.run()
    first = result.records[0].samples
    assert first > 0
    assert (result.samples.phase[:first] == Phase.SURVEY).all()
    assert not (result.samples.phase[first:] == Phase.SURVEY).any()
