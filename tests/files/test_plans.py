"""Tasks as files (:mod:`econdor_gcs.files.plans`) and in the resume checkpoint
(:mod:`econdor_gcs.files.checkpoint`): a trace task's sensor lag goes there and back."""

from __future__ import annotations

import json

import pytest

from econdor_gcs.core.tasks import FlightReport, SampleLog, TaskOutcome, TraceTask, Waypoint
from econdor_gcs.dfc.loop import FlightRecord
from econdor_gcs.errors import EcondorError
from econdor_gcs.files.checkpoint import flight_to_json
from econdor_gcs.files.plans import read_tasks, task_from_json, task_to_json, write_tasks

ROUTE = ((10.0, 0.0), (20.0, 0.5))
TOLD = TraceTask(42.5, 10.0, 0.0, 15.0, 0.0, 7, route_m=ROUTE, sensor_lag_s=0.8125)
UNTOLD = TraceTask(42.5, 10.0, 0.0, 15.0, 0.0, 8, route_m=ROUTE)
UNKNOWN = TraceTask(42.5, 10.0, 0.0, 15.0, 0.0, 9, route_m=ROUTE, sensor_lag_s=0.0,
                    lag_unknown=True)


def test_a_trace_tasks_sensor_lag_goes_to_the_file_and_back(tmp_path):
    path = write_tasks(tmp_path / "t.tasks.json", [Waypoint(1.0, 2.0), TOLD, UNTOLD, UNKNOWN])
    back = read_tasks(path)
    assert back == [Waypoint(1.0, 2.0), TOLD, UNTOLD, UNKNOWN]
    assert (back[1].sensor_lag_s, back[2].sensor_lag_s) == (0.8125, None)
    assert [t.lag_unknown for t in back[1:]] == [False, False, True]
    assert back[1].route_m == ROUTE
    # written only when there is one: files without it are as they were
    written = json.loads(path.read_text())["tasks"]
    assert written[1]["sensor_lag_s"] == 0.8125 and "sensor_lag_s" not in written[2]
    assert "lag_unknown" not in written[1] and written[3]["lag_unknown"] is True


@pytest.mark.parametrize(("lag", "unknown"), [(0.0, "yes"), (0.0, 1), (0.5, True)])
def test_a_bad_unknown_lag_is_one_line_naming_the_key(lag, unknown):
    d = {**task_to_json(UNTOLD), "sensor_lag_s": lag, "lag_unknown": unknown}
    with pytest.raises(EcondorError) as err:
        task_from_json(d, "t.tasks.json: tasks[1]")
    msg = str(err.value)
    assert msg.startswith("t.tasks.json: tasks[1].lag_unknown: expected true or false")
    assert "\n" not in msg


def test_the_lag_takes_part_in_comparisons():
    """Resume compares the plans: a task told another lag is another task."""
    other, same = (TraceTask(42.5, 10.0, 0.0, 15.0, 0.0, 7, sensor_lag_s=lag)
                   for lag in (0.5, 0.8125))
    assert other != TOLD and same == TOLD


@pytest.mark.parametrize("value", [-0.5, "1", True, None, float("nan"), float("inf"), [1.0]])
def test_a_bad_sensor_lag_is_one_line_naming_the_key(value):
    d = {**task_to_json(UNTOLD), "sensor_lag_s": value}
    with pytest.raises(EcondorError) as err:
        task_from_json(d, "t.tasks.json: tasks[1]")
    msg = str(err.value)
    assert msg.startswith("t.tasks.json: tasks[1].sensor_lag_s: expected a finite number >= 0")
    assert "\n" not in msg


def test_the_checkpoint_keeps_the_told_lag_and_writes_untold_tasks_as_before():
    record = FlightRecord(2, [[TOLD, Waypoint(3.0, 4.0)], [UNTOLD]],
                          [FlightReport(0, SampleLog(), 10.0, 5.0,
                                        [TaskOutcome(TOLD, "closed", 10.0, 5.0)], 0.0, 0.0, 1.0)],
                          [(0.0, 0.0), (1.0, 1.0)])
    line = json.loads(json.dumps(flight_to_json(record)))
    plans = [[task_from_json(t, "plans") for t in p] for p in line["plans"]]
    assert plans == record.plans and plans[0][0].sensor_lag_s == 0.8125
    assert task_from_json(line["reports"][0]["outcomes"][0]["task"], "o").sensor_lag_s == 0.8125
    # an untold trace task is the object it always was (the keys and order of its fields)
    assert list(line["plans"][1][0]) == ["kind", "level", "x_m", "y_m", "search_radius_m",
                                         "max_length_m", "piece_id", "route_m"]
    assert line["plans"][0][1] == {"kind": "waypoint", "x_m": 3.0, "y_m": 4.0}
