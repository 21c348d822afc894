"""Waypoint missions for stock autopilots: routes, mission layout, export sources and styles,
import checks (the line or key at fault), and the plan files a run leaves behind."""

from __future__ import annotations

import argparse
import json
import math
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import shapely

from econdor_gcs.app.export import export_cli
from econdor_gcs.config import load_mission
from econdor_gcs.core.planners import ContourPlanner, PlanContext
from econdor_gcs.core.tasks import Phase, TaskStyle, TraceTask, Waypoint
from econdor_gcs.core.waypoints import piece_route, simplify_route, task_waypoints
from econdor_gcs.errors import EcondorError
from econdor_gcs.files.autopilot_files import read_mission_file, read_plan, read_wpl
from econdor_gcs.files.plans import read_next_batch, read_tasks, write_next_batch, write_tasks
from econdor_gcs.link.codec import mavlink
from econdor_gcs.link.items import plan_mission

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "missions" / "demo.yaml"
MISSION = load_mission(DEMO)
CMD = mavlink


def bump_batch():
    """A real planner batch: Lloyd-Max levels of a smooth bump, its contour pieces."""
    grid = MISSION.grid
    xx, yy = grid.mesh
    est = 50 + 40 * np.exp(-((xx - 40) ** 2 + (yy - 60) ** 2) / 600.0) + 0.1 * xx
    planner = ContourPlanner(m0=3, search_radius_m=10.0)
    ctx = PlanContext(iteration=1, region=MISSION.region, n_vehicles=1, grid=grid,
                      estimate=est, positions_m=[(0.0, 0.0)])
    return planner.next_batch(ctx)


# -- routes ----------------------------------------------------------------------------------


def test_simplified_route_stays_within_tolerance_of_the_contour():
    t = np.linspace(0, 2 * np.pi, 400)
    ring = np.column_stack([50 + 20 * np.cos(t), 50 + 12 * np.sin(t)])
    route = piece_route(ring, True, (90.0, 50.0))
    assert np.allclose(route[0], route[-1]) and np.allclose(route[0], (70.0, 50.0), atol=0.5)
    for tol in (0.2, 1.0, 3.0):
        simple = simplify_route(route, tol)
        line = shapely.LineString(simple)
        worst = max(line.distance(shapely.Point(p)) for p in route)
        assert worst <= tol + 1e-9
        assert np.allclose(simple[0], route[0]) and np.allclose(simple[-1], route[-1])
    assert len(simplify_route(route, 3.0)) < len(simplify_route(route, 0.2)) < len(route)
    with pytest.raises(ValueError, match="tolerance_m must be >= 0"):
        simplify_route(route, -1.0)
    with pytest.raises(ValueError, match=r"\(k, 2\) points"):
        simplify_route(np.zeros((3, 3)), 1.0)


def test_planned_trace_tasks_carry_their_estimated_contour():
    batch = bump_batch()
    assert batch.jobs
    for job in batch.jobs:
        task = job.tasks[0]
        assert isinstance(task, TraceTask) and len(task.route_m) >= 2
        # the route is the piece itself, from where the vehicle comes
        pts = job.piece.points_m
        route = np.asarray(task.route_m)
        assert {tuple(p) for p in np.round(route, 9)} <= {tuple(p) for p in np.round(pts, 9)}
    wps = task_waypoints(batch.jobs[0].tasks[0], 1.0)
    assert 2 <= len(wps) < len(batch.jobs[0].tasks[0].route_m)
    assert task_waypoints(Waypoint(1.0, 2.0), 1.0) == [Waypoint(1.0, 2.0)]
    with pytest.raises(ValueError, match="piece 5: no route"):
        task_waypoints(TraceTask(1.0, 0, 0, 10, 0, 5), 1.0)


def test_waypoint_mission_layout_phases_and_item_ranges():
    route = ((10.0, 0.0), (20.0, 0.1), (30.0, 0.0), (30.0, 10.0))
    tasks = [Waypoint(5.0, 5.0), TraceTask(42.0, 10.0, 0.0, 10.0, 0.0, 7, route_m=route)]
    plan = plan_mission(MISSION.origin, tasks, 25.0, style=TaskStyle.WAYPOINTS,
                        tolerance_m=0.5, speed_mps=6.0, end="rtl")
    cmds = [it.command for it in plan.items]
    assert cmds == [CMD.MAV_CMD_NAV_WAYPOINT, CMD.MAV_CMD_NAV_TAKEOFF,
                    CMD.MAV_CMD_DO_CHANGE_SPEED] + [CMD.MAV_CMD_NAV_WAYPOINT] * 4 + \
        [CMD.MAV_CMD_NAV_RETURN_TO_LAUNCH]
    speed = plan.items[2]
    assert (speed.frame, speed.param1, speed.param2) == (CMD.MAV_FRAME_MISSION, 1.0, 6.0)
    assert plan.task_seqs == [(3, 3), (4, 6)]
    assert [plan.item_phases[s] for s in range(3, 7)] == [Phase.TRANSIT, Phase.TRANSIT,
                                                         Phase.TRACE, Phase.TRACE]
    assert [it.seq for it in plan.items] == list(range(len(plan.items)))
    assert sum(it.current for it in plan.items) == 1
    trace = plan_mission(MISSION.origin, tasks, 25.0, end="none")
    assert trace.task_seqs == [(2, 2), (3, 3)] and trace.items[3].command == 31000
    assert trace.item_phases[3] == Phase.SEARCH


# -- export sources and styles ----------------------------------------------------------------


def export_args(source: Path, out: Path, **kw) -> argparse.Namespace:
    base = {"format": "wpl", "style": "waypoints", "alt_m": None, "speed_mps": None,
            "tolerance_m": 1.0, "vehicles": 1, "spacing_m": None, "fence_margin_m": 10.0,
            "iteration": None, "vehicle": None}
    base.update(kw)
    return argparse.Namespace(source=source, out=out, **base)


def fake_run(tmp: Path) -> Path:
    run = tmp / "run"
    (run / "missions").mkdir(parents=True)
    shutil.copy(DEMO, run / "mission.yaml")
    (run / "summary.json").write_text(json.dumps({"planner": "econdor", "vehicles": 1}))
    write_next_batch(run / "next_batch.json", bump_batch(), 4)
    return run


def test_export_next_batch_as_waypoints_and_as_trace_items(tmp_path, capsys):
    run = fake_run(tmp_path)
    assert export_cli(export_args(run, tmp_path / "w.waypoints", alt_m=35.0,
                                  speed_mps=5.5)) == 0
    items = read_wpl(tmp_path / "w.waypoints", int_frames=True)
    cmds = [it.command for it in items]
    assert cmds[:3] == [16, 22, 178] and cmds[-1] == 20
    assert set(cmds[3:-1]) == {16} and len(cmds) > 8  # contours as waypoint polylines
    assert items[1].z == 35.0 and items[2].param2 == 5.5
    assert all(it.z == 35.0 for it in items[3:-1])
    n_pieces = len(read_next_batch(run / "next_batch.json")[1])
    assert export_cli(export_args(run, tmp_path / "t.waypoints", style="trace")) == 0
    trace = read_wpl(tmp_path / "t.waypoints")
    assert [it.command for it in trace].count(31000) == n_pieces
    assert {int(it.param4) for it in trace if it.command == 31000} == \
        set(range(4000, 4000 + n_pieces))
    # a tighter tolerance keeps more of the contour
    export_cli(export_args(run, tmp_path / "fine.waypoints", tolerance_m=0.1))
    assert len(read_wpl(tmp_path / "fine.waypoints")) > len(items)
    assert 31013 not in [it.command for it in trace]  # the run corrected no lag
    # a run whose station corrected a 0.8 s lag (known or estimated) tells the tracer so,
    # once, before the first contour item; the waypoint style has no tracer to tell
    summary = json.loads((run / "summary.json").read_text())
    (run / "summary.json").write_text(json.dumps({**summary, "lag_s": 0.8}))
    assert export_cli(export_args(run, tmp_path / "lag.waypoints", style="trace")) == 0
    told = read_wpl(tmp_path / "lag.waypoints")
    cmds = [it.command for it in told]
    assert cmds.count(31013) == 1 and cmds.index(31013) + 1 == cmds.index(31000)
    assert told[cmds.index(31013)].param1 == pytest.approx(0.8)
    assert [c for c in cmds if c != 31013] == [it.command for it in trace]
    assert export_cli(export_args(run, tmp_path / "lag_w.waypoints")) == 0
    assert 31013 not in [it.command for it in read_wpl(tmp_path / "lag_w.waypoints")]
    (run / "summary.json").write_text(json.dumps(summary))
    # a run that estimates the lag and has no estimate yet tells a lag of unknown size
    mission_yaml = (run / "mission.yaml").read_text()
    (run / "mission.yaml").write_text(mission_yaml.replace(
        "vehicles:\n", "vehicles:\n  sensor: {lag_s: 0.8, lag_correction: estimate}\n", 1))
    assert export_cli(export_args(run, tmp_path / "est.waypoints", style="trace")) == 0
    told = [it for it in read_wpl(tmp_path / "est.waypoints") if it.command == 31013]
    assert [(it.param1, it.param2) for it in told] == [(0.0, 1.0)]
    # ... and once it has estimated 0, a known lag of 0 (as the station tells it)
    (run / "summary.json").write_text(json.dumps({**summary, "lag_s": 0.0}))
    assert export_cli(export_args(run, tmp_path / "est0.waypoints", style="trace")) == 0
    told = [it for it in read_wpl(tmp_path / "est0.waypoints") if it.command == 31013]
    assert [(it.param1, it.param2) for it in told] == [(0.0, 0.0)]
    (run / "summary.json").write_text(json.dumps(summary))
    (run / "mission.yaml").write_text(mission_yaml)
    # two aircraft: two files
    export_cli(export_args(run, str(tmp_path / "two") + "/", vehicles=2))
    assert sorted(p.name for p in (tmp_path / "two").iterdir()) == [
        "next04_v1.waypoints", "next04_v2.waypoints"]
    capsys.readouterr()


def test_export_plan_has_geofence_around_the_area_and_rally_at_home(tmp_path):
    run = fake_run(tmp_path)
    out = tmp_path / "m.plan"
    assert export_cli(export_args(run, out, format="plan", fence_margin_m=15.0)) == 0
    doc = json.loads(out.read_text())
    poly = doc["geoFence"]["polygons"][0]
    assert poly["inclusion"] is True and len(poly["polygon"]) == 4
    corners = [MISSION.origin.to_local(lat, lon)[:2] for lat, lon in poly["polygon"]]
    r = MISSION.region
    xs, ys = [c[0] for c in corners], [c[1] for c in corners]
    assert min(xs) == pytest.approx(r.xmin - 15, abs=0.05)
    assert max(ys) == pytest.approx(r.ymax + 15, abs=0.05)
    (lat, lon, alt), = doc["rallyPoints"]["points"]
    assert (lat, lon) == pytest.approx((MISSION.origin.lat_deg, MISSION.origin.lon_deg),
                                       abs=1e-7)
    assert alt == MISSION.vehicles.altitude_m
    assert doc["mission"]["plannedHomePosition"][2] == MISSION.origin.alt_m
    mf = read_mission_file(out)
    assert len(mf.fence) == 4 and all(f.param1 == 4 for f in mf.fence)
    assert mf.fence[0].command == CMD.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
    assert len(mf.rally) == 1 and mf.rally[0].command == CMD.MAV_CMD_NAV_RALLY_POINT
    # the mission itself round-trips with the WPL export of the same batch
    export_cli(export_args(run, tmp_path / "m.waypoints"))
    assert read_plan(out, int_frames=True)[1:] == \
        read_wpl(tmp_path / "m.waypoints", int_frames=True)[1:]


def test_export_from_a_mission_yaml_diagonals_and_survey(tmp_path):
    out = tmp_path / "d.waypoints"
    assert export_cli(export_args(DEMO, out)) == 0
    items = read_wpl(out, int_frames=True)
    wps = [MISSION.origin.to_local(it.lat_deg, it.lon_deg)[:2] for it in items[3:-1]]
    r = MISSION.region
    corners = {(r.xmin, r.ymin), (r.xmax, r.ymax), (r.xmax, r.ymin), (r.xmin, r.ymax)}
    assert len(wps) == 4 and all(
        min(math.dist(w, c) for c in corners) < 0.02 for w in wps)
    assert export_cli(export_args(DEMO, tmp_path / "s.waypoints", spacing_m=25.0)) == 0
    survey = read_wpl(tmp_path / "s.waypoints", int_frames=True)
    assert len(survey) == 3 + 2 * 5 + 1  # five lines at 0, 25, .., 100 m
    with pytest.raises(EcondorError, match="--iteration and --vehicle apply to a run"):
        export_cli(export_args(DEMO, out, iteration="1"))


def test_export_iteration_rebuilds_from_saved_tasks(tmp_path):
    run = fake_run(tmp_path)
    route = ((10.0, 10.0), (20.0, 10.0), (30.0, 14.0))
    tasks = [Waypoint(5.0, 5.0), TraceTask(61.5, 10.0, 10.0, 10.0, 0.0, 1003, route_m=route)]
    write_tasks(run / "missions" / "iter01_v2.tasks.json", tasks)
    assert read_tasks(run / "missions" / "iter01_v2.tasks.json") == tasks
    (run / "missions" / "iter01_v2.json").write_text("[]")
    out = tmp_path / "i.waypoints"
    assert export_cli(export_args(run, out, iteration="1", vehicle=2)) == 0
    items = read_wpl(out, int_frames=True)
    assert [it.command for it in items] == [16, 22, 178, 16, 16, 16, 16, 20]


def test_plan_files_errors_name_the_key(tmp_path):
    bad = tmp_path / "t.json"
    bad.write_text('{"version": 1, "tasks": [{"kind": "trace", "level": 1, "x_m": 0}]}')
    with pytest.raises(EcondorError, match=r"tasks\[0\].y_m: expected a finite number"):
        read_tasks(bad)
    bad.write_text('{"version": 1, "tasks": [{"kind": "circle"}]}')
    with pytest.raises(EcondorError, match=r"tasks\[0\].kind: expected 'waypoint' or 'trace'"):
        read_tasks(bad)
    bad.write_text('{"version": 7}')
    with pytest.raises(EcondorError, match="not an econdor plan file"):
        read_next_batch(bad)


# -- import: errors name the line or key ------------------------------------------------------


WPL_OK = ("QGC WPL 110\n"
          "0\t1\t3\t16\t0\t0\t0\t0\t47.39774200\t8.54559400\t0.0\t1\n"
          "1\t0\t3\t22\t0\t0\t0\t0\t47.39774200\t8.54559400\t20.0\t1\n"
          "2\t0\t3\t16\t0\t0\t0\t0\t47.39800000\t8.54600000\t20.0\t1\n")


@pytest.mark.parametrize("line, message", [
    ("2\t0\t3\t16\t0\t0\t0\t0\t47.398\t8.546\t20.0", r"line 4: expected 12 tab-separated values"),
    ("2\t0\t3\t16\t0\t0\t0\t0\tnan\t8.546\t20.0\t1", r"line 4: latitude/longitude must be finite"),
    ("2\t0\t3\t16\t0\t0\t0\t0\t97.398\t8.546\t20.0\t1", r"line 4: latitude/longitude out of range"),
    ("2\t0\t3\t16\t0\t0\t0\t0\t47.398\t8.546\tnan\t1", r"line 4: altitude must be finite"),
    ("2\t0\t99\t16\t0\t0\t0\t0\t47.398\t8.546\t20.0\t1", r"line 4: unknown frame 99"),
    ("2\t0\t3\t12345\t0\t0\t0\t0\t47.398\t8.546\t20.0\t1", r"line 4: unknown command 12345"),
    ("5\t0\t3\t16\t0\t0\t0\t0\t47.398\t8.546\t20.0\t1", r"line 4: item index 5, expected 2"),
    ("2\t0\t3\t16\t0\t0\t0\t0\t47.398\t8.546\t20.0\t7", r"line 4: CURRENT and AUTOCONTINUE"),
])
def test_import_names_the_wpl_line_at_fault(tmp_path, line, message):
    bad = tmp_path / "bad.waypoints"
    bad.write_text("\n".join(WPL_OK.splitlines()[:3] + [line]) + "\n")
    with pytest.raises(EcondorError, match=rf"bad\.waypoints {message}"):
        read_mission_file(bad)
    bad.write_text("QGC WPL 100\n")
    with pytest.raises(EcondorError, match=r"bad\.waypoints line 1: not a QGC WPL 110 file"):
        read_mission_file(bad)


def plan_doc():
    return {"fileType": "Plan", "version": 1,
            "geoFence": {"circles": [], "polygons": [{"inclusion": True, "version": 1,
                                                      "polygon": [[47.39, 8.54], [47.40, 8.54],
                                                                  [47.40, 8.55]]}],
                         "version": 2},
            "rallyPoints": {"points": [[47.3977, 8.5456, 30]], "version": 2},
            "mission": {"version": 2, "plannedHomePosition": [47.3977, 8.5456, 488.0],
                        "items": [{"type": "SimpleItem", "command": 22, "frame": 3,
                                   "autoContinue": True, "doJumpId": 1,
                                   "params": [0, 0, 0, None, 47.3977, 8.5456, 20]}]}}


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.update(version=2), r"\.plan\.version: expected 1, got 2"),
    (lambda d: d["mission"].update(version=1), r"mission\.version: expected 2"),
    (lambda d: d["mission"]["items"][0].pop("frame"), r"mission\.items\[0\]: missing key 'frame'"),
    (lambda d: d["mission"]["items"][0].update(frame=77),
     r"mission\.items\[0\]: unknown frame 77"),
    (lambda d: d["mission"]["items"][0]["params"].__setitem__(4, 123.0),
     r"mission\.items\[0\]: latitude/longitude out of range"),
    (lambda d: d["mission"]["items"][0]["params"].__setitem__(6, "high"),
     r"mission\.items\[0\]\.params\[6\]: expected a number"),
    (lambda d: d["mission"].update(plannedHomePosition=[47.0, 8.0]),
     r"mission\.plannedHomePosition: expected \[lat, lon, alt\]"),
    (lambda d: d["geoFence"]["polygons"][0]["polygon"].pop(),
     r"geoFence\.polygons\[0\]\.polygon: a polygon needs at least 3 vertices"),
    (lambda d: d["geoFence"]["polygons"][0]["polygon"][1].__setitem__(0, 400.0),
     r"geoFence\.polygons\[0\]\.polygon\[1\]: latitude/longitude out of range"),
    (lambda d: d["rallyPoints"].update(points=[[47.0, 8.0]]),
     r"rallyPoints\.points\[0\]: expected \[lat, lon, alt\]"),
])
def test_import_names_the_plan_key_at_fault(tmp_path, edit, message):
    doc = plan_doc()
    good = tmp_path / "good.plan"
    good.write_text(json.dumps(doc))
    mf = read_mission_file(good)
    assert (len(mf.items), len(mf.fence), len(mf.rally)) == (2, 3, 1)
    assert math.isnan(mf.items[1].param4) and mf.home_alt_amsl_m == 488.0
    edit(doc)
    bad = tmp_path / "bad.plan"
    bad.write_text(json.dumps(doc))
    with pytest.raises(EcondorError, match=rf"bad\.plan: {message}" if message[0] != "\\"
                       else rf"bad{message}"):
        read_mission_file(bad)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX pipes")
def test_import_cli_whose_reader_went_away_stops_quietly(tmp_path):
    """``econdor import m.waypoints | head -1``: the reader closes the pipe; the command
    ends as a Unix tool ended by SIGPIPE does (128 + 13), with no traceback."""
    path = tmp_path / "m.waypoints"
    path.write_text(WPL_OK)
    proc = subprocess.Popen([sys.executable, "-m", "econdor", "import", str(path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # gone before the command writes a line
    err = proc.stderr.read()
    proc.stderr.close()
    assert proc.wait(timeout=60) == 128 + signal.SIGPIPE, err
    assert err == ""


def test_import_cli_says_what_the_file_holds(tmp_path, capsys):
    from econdor.cli import main

    path = tmp_path / "m.waypoints"
    path.write_text(WPL_OK)
    assert main(["import", str(path)]) == 0
    out = capsys.readouterr().out
    assert "a valid mission file" in out and "3 items (2 NAV_WAYPOINT, 1 NAV_TAKEOFF)" in out
    assert main(["import", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [it["command"] for it in doc["items"]] == [16, 22, 16] and doc["fence"] == []
    path.write_text(WPL_OK.replace("47.39800000", "-97.1"))
    assert main(["import", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "m.waypoints line 4: latitude/longitude out of range" in err
