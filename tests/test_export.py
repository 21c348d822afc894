"""Mission export: QGC WPL 110, QGroundControl .plan, GeoJSON, and `econdor export`."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest

from econdor_gcs.app.export import export_cli, geojson_for_run, write_geojson
from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.tasks import TraceTask, Waypoint
from econdor_gcs.errors import EcondorError
from econdor_gcs.files.autopilot_files import (
    items_to_plan,
    items_to_wpl,
    read_plan,
    read_wpl,
    write_plan,
    write_wpl,
)
from econdor_gcs.link.transfer import MissionItemSpec, build_mission

ORIGIN = Origin(47.397742, 8.545594, 488.0)
INT_REL, FLOAT_REL = 6, 3


def mission(vehicle_shift: float = 0.0) -> list[MissionItemSpec]:
    tasks: list[Waypoint | TraceTask] = [
        TraceTask(level=42.5, x_m=30.0 + vehicle_shift, y_m=40.0, search_radius_m=10.0,
                  max_length_m=0.0, piece_id=3),
        Waypoint(55.5, 12.25),
        TraceTask(level=-1.125, x_m=80.0, y_m=90.0 + vehicle_shift, search_radius_m=7.5,
                  max_length_m=250.0, piece_id=17),
    ]
    return build_mission(ORIGIN, tasks, altitude_m=20.0)


def make_run(tmp: Path, *, origin: bool = True, missions: bool = True) -> Path:
    run = tmp / "run"
    (run / "missions").mkdir(parents=True)
    # samples.csv holds the 0-based vehicle index; missions and --vehicle use system ids
    summary: dict[str, object] = {"planner": "econdor", "iterations": 2, "vehicles": 2,
                                  "sysids": [1, 2]}
    if origin:
        summary["origin"] = {"lat_deg": ORIGIN.lat_deg, "lon_deg": ORIGIN.lon_deg,
                             "alt_m": ORIGIN.alt_m}
        summary["area"] = {"width_m": 100.0, "height_m": 100.0}
    (run / "summary.json").write_text(json.dumps(summary))
    rows = ["t_s,x_m,y_m,value,phase,vehicle"]
    for index in (0, 1):  # system id index + 1: the path of system v starts at x = v
        for k in range(5):
            rows.append(f"{k * 0.5:.3f},{10.0 * k + index + 1:.3f},{5.0 * k:.3f},"
                        f"{1.5 * k:.6g},0,{index}")
    (run / "samples.csv").write_text("\n".join(rows) + "\n")
    if missions:
        for it in (0, 1):
            for v in (1, 2):
                items = mission(vehicle_shift=float(v + it))
                (run / "missions" / f"iter{it:02d}_v{v}.json").write_text(
                    json.dumps([asdict(x) for x in items]))
    return run


def ns(run: Path, fmt: str, out: Path | str, iteration: int | str | None = None,
       vehicle: int | None = None, style: str = "trace") -> argparse.Namespace:
    """The saved missions of these fake run directories have no tasks beside them: they can
    only be exported as they were sent (``--style trace``)."""
    return argparse.Namespace(source=run, format=fmt, out=out,
                              iteration=None if iteration is None else str(iteration),
                              vehicle=vehicle, style=style)


# ---------------------------------------------------------------------------------- WPL


def test_wpl_layout_exact() -> None:
    items = mission()
    text = items_to_wpl(items)
    lines = text.split("\n")
    assert lines[0] == "QGC WPL 110"
    assert text.endswith("\n") and lines[-1] == ""
    body = lines[1:-1]
    assert len(body) == len(items) == 6
    for it, line in zip(items, body, strict=True):
        cols = line.split("\t")
        assert len(cols) == 12 and " " not in line
        assert cols[0] == str(it.seq) and cols[1] == str(it.current)
        assert cols[2] == "3"  # GLOBAL_RELATIVE_ALT_INT (6) written as GLOBAL_RELATIVE_ALT
        assert cols[3] == str(it.command) and cols[11] == "1"
        assert len(cols[8].split(".")[1]) == 8 and len(cols[9].split(".")[1]) == 8
    trace = body[2].split("\t")
    assert trace[3] == "31000"
    assert [float(v) for v in trace[4:8]] == [42.5, 10.0, 0.0, 3.0]
    assert trace[8] == f"{items[2].x / 1e7:.8f}" and trace[9] == f"{items[2].y / 1e7:.8f}"
    assert float(trace[10]) == 20.0
    assert body[0].split("\t")[:4] == ["0", "1", "3", "16"]


def test_wpl_round_trip_field_by_field(tmp_path: Path) -> None:
    items = mission()
    path = write_wpl(tmp_path / "m.waypoints", items)
    back = read_wpl(path, int_frames=True)
    assert len(back) == len(items)
    for a, b in zip(items, back, strict=True):
        for name in ("seq", "frame", "command", "current", "autocontinue", "param1", "param2",
                     "param3", "param4", "x", "y", "z", "mission_type"):
            assert getattr(a, name) == getattr(b, name), (a.seq, name)
    assert back == items
    # without int_frames the file's float frame is kept
    kept = read_wpl(path)
    assert {it.frame for it in kept} == {FLOAT_REL}
    assert [replace(k, frame=INT_REL) for k in kept] == items
    # text input works too, and odd floats survive exactly
    odd = [replace(items[2], seq=0, param1=0.10000000149011612, param2=math.pi,
                   z=12.345678901)]
    assert read_wpl(items_to_wpl(odd), int_frames=True) == odd
    nan_item = read_wpl(items_to_wpl([replace(items[1], seq=0, param4=math.nan)]))[0]
    assert math.isnan(nan_item.param4)


def test_wpl_bad_files(tmp_path: Path) -> None:
    bad = tmp_path / "bad.waypoints"
    bad.write_text("QGC WPL 100\n0\t1\t3\t16\t0\t0\t0\t0\t47.1\t8.5\t0\t1\n")
    with pytest.raises(EcondorError, match=r"bad\.waypoints line 1: not a QGC WPL 110 file"):
        read_wpl(bad)
    lines = items_to_wpl(mission()).split("\n")
    lines[3] = "\t".join(lines[3].split("\t")[:9])
    bad.write_text("\n".join(lines))
    with pytest.raises(EcondorError, match=r"line 4: expected 12 tab-separated values, got 9"):
        read_wpl(bad)
    lines = items_to_wpl(mission()).split("\n")
    lines[2] = lines[2].replace("22", "xx", 1)
    with pytest.raises(EcondorError, match=r"<text> line 3: not a number"):
        read_wpl("\n".join(lines))
    with pytest.raises(EcondorError, match="cannot read"):
        read_wpl(tmp_path / "missing.waypoints")
    # comments and blank lines are skipped, as MAVProxy does
    text = items_to_wpl(mission()).replace("\n", "\n# note\n\n", 1)
    assert read_wpl(text, int_frames=True) == mission()


@pytest.mark.interop
def test_mavproxy_loads_our_waypoints(tmp_path: Path) -> None:
    mavwp = pytest.importorskip("pymavlink.mavwp")
    items = mission()
    path = write_wpl(tmp_path / "m.waypoints", items)
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(path)) == len(items)
    for it, w in zip(items, (loader.wp(i) for i in range(loader.count())), strict=True):
        assert (w.seq, w.current, w.frame, w.command, w.autocontinue) == (
            it.seq, it.current, FLOAT_REL, it.command, it.autocontinue)
        assert [w.param1, w.param2, w.param3, w.param4] == [it.param1, it.param2, it.param3,
                                                            it.param4]
        assert w.x == pytest.approx(it.x / 1e7, abs=1e-9)
        assert w.y == pytest.approx(it.y / 1e7, abs=1e-9)
        assert w.z == it.z
    # and MAVProxy's own writer's output reads back with ours
    out = tmp_path / "saved.waypoints"
    loader.save(str(out))
    back = read_wpl(out, int_frames=True)
    assert [b.command for b in back] == [it.command for it in items]
    assert all(abs(b.x - it.x) <= 10 and abs(b.y - it.y) <= 10
               for b, it in zip(back, items, strict=True))  # mavwp writes 6 decimals


# ---------------------------------------------------------------------------------- .plan


def test_plan_structure(tmp_path: Path) -> None:
    items = mission()
    doc = items_to_plan(items, home_alt_amsl_m=488.0)
    assert set(doc) == {"fileType", "geoFence", "groundStation", "mission", "rallyPoints",
                        "version"}
    assert doc["fileType"] == "Plan" and doc["version"] == 1
    assert doc["groundStation"] == "QGroundControl"
    assert doc["geoFence"] == {"circles": [], "polygons": [], "version": 2}
    assert doc["rallyPoints"] == {"points": [], "version": 2}
    m = doc["mission"]
    assert m["version"] == 2 and m["firmwareType"] == 12 and m["vehicleType"] == 2
    assert m["plannedHomePosition"] == [items[0].x / 1e7, items[0].y / 1e7, 488.0]
    assert len(m["items"]) == len(items) - 1  # home is not an item
    assert [e["doJumpId"] for e in m["items"]] == list(range(1, len(items)))
    for e, it in zip(m["items"], items[1:], strict=True):
        assert e["type"] == "SimpleItem" and e["autoContinue"] is True
        assert e["command"] == it.command and e["frame"] == FLOAT_REL
        assert len(e["params"]) == 7
    takeoff, trace = m["items"][0], m["items"][1]
    assert takeoff["command"] == 22 and takeoff["AltitudeMode"] == 1
    assert takeoff["Altitude"] == 20 and takeoff["AMSLAltAboveTerrain"] is None
    assert trace["command"] == 31000
    assert trace["params"] == [42.5, 10, 0, 3, items[2].x / 1e7, items[2].y / 1e7, 20]
    path = write_plan(tmp_path / "m.plan", items)
    assert json.loads(path.read_text()) == items_to_plan(items)
    # NaN params are written as null, as QGC does
    nan_doc = items_to_plan([items[0], replace(items[1], param4=math.nan)])
    assert nan_doc["mission"]["items"][0]["params"][3] is None
    assert "NaN" not in json.dumps(nan_doc)


def test_plan_round_trip(tmp_path: Path) -> None:
    items = mission()
    path = write_plan(tmp_path / "m.plan", items, home_alt_amsl_m=488.0)
    assert read_plan(path, int_frames=True) == items
    kept = read_plan(path)
    assert {it.frame for it in kept} == {FLOAT_REL}
    assert read_plan(items_to_plan(items), int_frames=True) == items
    back = read_plan(items_to_plan([items[0], replace(items[1], param4=math.nan)]))
    assert math.isnan(back[1].param4)


def test_plan_bad_files(tmp_path: Path) -> None:
    bad = tmp_path / "bad.plan"
    bad.write_text("{not json")
    with pytest.raises(EcondorError, match=r"bad\.plan line 1: not valid JSON"):
        read_plan(bad)
    with pytest.raises(EcondorError, match="fileType"):
        read_plan({"fileType": "Mission"})
    doc = items_to_plan(mission())
    doc["mission"]["items"][1]["params"] = [0, 0, 0]
    with pytest.raises(EcondorError, match=r"items\[1\]: params must be a list of 7"):
        read_plan(doc)
    doc = items_to_plan(mission())
    doc["mission"]["items"][0] = {"type": "ComplexItem", "complexItemType": "survey"}
    with pytest.raises(EcondorError, match="only SimpleItem"):
        read_plan(doc)


# ---------------------------------------------------------------------------------- GeoJSON


def test_geojson_from_run_dir(tmp_path: Path) -> None:
    run = make_run(tmp_path)
    path = write_geojson(tmp_path / "run.geojson", run)
    doc = json.loads(path.read_text())
    assert doc["type"] == "FeatureCollection"
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    assert kinds.count("samples") == 2 and kinds.count("area") == 1
    assert kinds.count("trace_start") == 2 * 2 * 2 and kinds.count("waypoint") == 2 * 2
    for f in doc["features"]:
        g = f["geometry"]
        pts = {"Point": lambda c: [c], "LineString": lambda c: c,
               "Polygon": lambda c: c[0]}[g["type"]](g["coordinates"])
        for lon, lat in pts:
            assert 8.5 < lon < 8.6 and 47.3 < lat < 47.5  # [lon, lat] order
            assert round(lon, 7) == lon and round(lat, 7) == lat
    line = next(f for f in doc["features"] if f["properties"]["kind"] == "samples")
    assert line["geometry"]["type"] == "LineString" and len(line["geometry"]["coordinates"]) == 5
    lon0, lat0 = line["geometry"]["coordinates"][0]
    exp = ORIGIN.to_global(1.0, 0.0)
    assert lat0 == pytest.approx(exp[0], abs=2e-7) and lon0 == pytest.approx(exp[1], abs=2e-7)
    trace = next(f for f in doc["features"] if f["properties"]["kind"] == "trace_start")
    assert trace["properties"]["level"] == 42.5 and trace["properties"]["piece_id"] == 3
    assert trace["properties"]["command"] == 31000
    area = next(f for f in doc["features"] if f["properties"]["kind"] == "area")
    ring = area["geometry"]["coordinates"][0]
    assert len(ring) == 5 and ring[0] == ring[-1]
    one = geojson_for_run(run, iteration=1, vehicle=2)
    assert {f["properties"].get("vehicle") for f in one["features"]} == {2, None}
    assert {f["properties"].get("iteration") for f in one["features"]} == {1, None}


def test_geojson_vehicle_is_a_system_id_for_samples_and_missions(tmp_path: Path) -> None:
    """samples.csv holds vehicle indices (0-based), missions system ids: ``--vehicle 2`` is
    system 2's path (index 1) with system 2's mission, never index 2 or system 1."""
    run = make_run(tmp_path)
    doc = geojson_for_run(run, vehicle=2)
    paths = [f for f in doc["features"] if f["properties"]["kind"] == "samples"]
    assert [p["properties"]["vehicle"] for p in paths] == [2]
    lon0, lat0 = paths[0]["geometry"]["coordinates"][0]
    exp = ORIGIN.to_global(2.0, 0.0)  # index 1 starts at x = 2
    assert lat0 == pytest.approx(exp[0], abs=2e-7) and lon0 == pytest.approx(exp[1], abs=2e-7)
    points = [f for f in doc["features"] if f["properties"]["kind"] == "trace_start"]
    assert points and {p["properties"]["vehicle"] for p in points} == {2}
    # without every path: system ids 1 and 2, not indices 0 and 1
    every = geojson_for_run(run)
    assert sorted(f["properties"]["vehicle"] for f in every["features"]
                  if f["properties"]["kind"] == "samples") == [1, 2]
    # a run that names other system ids (--connect to vehicles 7 and 9)
    summary = json.loads((run / "summary.json").read_text())
    summary["sysids"] = [7, 9]
    (run / "summary.json").write_text(json.dumps(summary))
    assert [f["properties"]["vehicle"] for f in geojson_for_run(run, vehicle=9)["features"]
            if f["properties"]["kind"] == "samples"] == [9]


def test_geojson_origin_from_home_item(tmp_path: Path) -> None:
    run = make_run(tmp_path, origin=False)
    doc = geojson_for_run(run)
    line = next(f for f in doc["features"] if f["properties"]["kind"] == "samples")
    lon0, lat0 = line["geometry"]["coordinates"][0]
    assert lon0 == pytest.approx(8.5456073, abs=1e-6) and lat0 == pytest.approx(47.397742, abs=1e-6)
    assert not any(f["properties"]["kind"] == "area" for f in doc["features"])
    # area from fields.npz when the summary does not tell it
    np.savez(run / "fields.npz", grid_x=np.linspace(0, 50, 6), grid_y=np.linspace(0, 20, 3))
    assert any(f["properties"]["kind"] == "area" for f in geojson_for_run(run)["features"])
    bare = make_run(tmp_path / "b", origin=False, missions=False)
    with pytest.raises(EcondorError, match="no origin"):
        geojson_for_run(bare)


# ---------------------------------------------------------------------------------- CLI


def test_export_cli_one_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = make_run(tmp_path)
    out = tmp_path / "out" / "one.waypoints"
    assert export_cli(ns(run, "wpl", out, iteration=1, vehicle=2)) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert read_wpl(out, int_frames=True) == mission(vehicle_shift=3.0)
    plan = tmp_path / "one.plan"
    assert export_cli(ns(run, "plan", plan, iteration=0, vehicle=1)) == 0
    doc = json.loads(plan.read_text())
    assert doc["mission"]["plannedHomePosition"][2] == 488.0  # summary origin alt (AMSL)
    assert read_plan(plan, int_frames=True) == mission(vehicle_shift=1.0)
    geo = tmp_path / "run.geojson"
    assert export_cli(ns(run, "geojson", geo)) == 0
    assert json.loads(geo.read_text())["type"] == "FeatureCollection"


def test_export_cli_several_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = make_run(tmp_path)
    outdir = tmp_path / "exp"
    outdir.mkdir()
    assert export_cli(ns(run, "wpl", outdir, iteration="all")) == 0
    printed = capsys.readouterr().out.split()
    names = sorted(p.name for p in outdir.iterdir())
    assert names == ["iter00_v1.waypoints", "iter00_v2.waypoints", "iter01_v1.waypoints",
                     "iter01_v2.waypoints"]
    assert sorted(Path(p).name for p in printed) == names
    assert export_cli(ns(run, "plan", str(tmp_path / "new") + "/", iteration=1)) == 0
    assert sorted(p.name for p in (tmp_path / "new").iterdir()) == ["iter01_v1.plan",
                                                                     "iter01_v2.plan"]


def test_export_cli_errors(tmp_path: Path) -> None:
    run = make_run(tmp_path)
    with pytest.raises(EcondorError, match="4 missions match; pick one with --iteration and "
                                           "--vehicle"):
        export_cli(ns(run, "wpl", tmp_path / "x.waypoints", iteration="all"))
    with pytest.raises(EcondorError, match="no next_batch.json"):
        export_cli(ns(run, "wpl", tmp_path / "x.waypoints"))
    with pytest.raises(EcondorError, match="only --style trace can export it"):
        export_cli(ns(run, "wpl", tmp_path / "x.waypoints", iteration=0, vehicle=1,
                      style="waypoints"))
    with pytest.raises(EcondorError, match="--iteration: expected a number or 'all'"):
        export_cli(ns(run, "wpl", tmp_path / "x.waypoints", iteration="last"))
    with pytest.raises(EcondorError, match=r"no mission saved for iteration 7 \(saved "
                                           r"iterations: 0, 1\)"):
        export_cli(ns(run, "wpl", tmp_path / "x.waypoints", iteration=7))
    with pytest.raises(EcondorError, match="no mission saved for vehicle 9 in iteration 0"):
        export_cli(ns(run, "plan", tmp_path / "x.plan", iteration=0, vehicle=9))
    with pytest.raises(EcondorError, match="no such run directory"):
        export_cli(ns(tmp_path / "nope", "wpl", tmp_path / "x.waypoints"))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(EcondorError, match="not a run directory"):
        export_cli(ns(empty, "wpl", tmp_path / "x.waypoints"))
    inproc = make_run(tmp_path / "inproc", missions=False)
    with pytest.raises(EcondorError, match="no missions saved"):
        export_cli(ns(inproc, "plan", tmp_path / "x.plan", iteration="all"))
    (run / "missions" / "iter00_v1.json").write_text('[{"seq": 0, "bogus": 1}]')
    with pytest.raises(EcondorError, match="unknown keys bogus"):
        export_cli(ns(run, "wpl", tmp_path / "x.waypoints", iteration=0, vehicle=1))


def test_cli_main_prints_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from econdor.cli import main

    run = make_run(tmp_path)
    assert main(["export", str(run), "--format", "wpl", "--out",
                 str(tmp_path / "x.waypoints"), "--iteration", "5"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("econdor: error:") and "iteration 5" in err and "\n" not in err
