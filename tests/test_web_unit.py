"""The web page's parts without a browser: operator control, the DFC checkpoint, the run
directory's per-iteration frames and log, the feeds, the server's access rules, the CLI."""

from __future__ import annotations

import asyncio
import doctest
import http.client
import json
import math
import socket
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from econdor import cli
from econdor_gcs.app.web import messages
from econdor_gcs.app.web import server as server_module
from econdor_gcs.app.web.feed import Cursor, LiveFeed
from econdor_gcs.app.web.replay import ReplayFeed
from econdor_gcs.app.web.server import WebServer, parse_web_address
from econdor_gcs.config import load_mission
from econdor_gcs.core.contours import ContourPiece
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.core.planners import Batch, Job
from econdor_gcs.core.tasks import Phase, SampleLog, TraceTask, Waypoint
from econdor_gcs.dfc import control as control_module
from econdor_gcs.dfc.control import ControlAction, ControlState, RunControl
from econdor_gcs.dfc.loop import Dfc, IterationDone, IterationPlanned, IterationRecord, RunDone
from econdor_gcs.errors import ControlError, WebError
from econdor_gcs.files import rundir as rundir_module
from econdor_gcs.files.rundir import (
    IterationFrame,
    PlannedPiece,
    RunDir,
    RunLog,
    Severity,
    planned_pieces,
    read_iteration,
    read_log,
    write_iteration,
)
from econdor_gcs.link.router import Sample
from econdor_gcs.station.executor import VehicleStatus
from econdor_lab.inprocess import InProcessExecutor

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "missions" / "demo.yaml"


def test_doctests_of_the_web_modules() -> None:
    for module in (control_module, rundir_module, server_module, messages):
        result = doctest.testmod(module)
        assert result.attempted > 0 and result.failed == 0, module.__name__


# -- operator control ---------------------------------------------------------------------------


def _in_thread(fn: Any) -> tuple[threading.Thread, list[Any]]:
    out: list[Any] = []
    t = threading.Thread(target=lambda: out.append(fn()), daemon=True)
    t.start()
    return t, out


def test_pause_holds_the_checkpoint_until_resume() -> None:
    changes: list[tuple[ControlState, int]] = []
    c = RunControl(on_change=lambda s, it: changes.append((s, it)), poll_s=0.02)
    assert c.request("pause") is ControlState.PAUSING
    t, out = _in_thread(lambda: c.checkpoint(2))
    time.sleep(0.3)
    assert t.is_alive() and c.state is ControlState.PAUSED  # held between iterations
    assert c.request(ControlAction.RESUME) is ControlState.RUNNING
    t.join(2.0)
    assert out == [True]
    assert changes == [(ControlState.PAUSING, 0), (ControlState.PAUSED, 2),
                       (ControlState.RUNNING, 2)]


def test_stop_while_paused_ends_the_loop() -> None:
    c = RunControl(poll_s=0.02)
    c.request("pause")
    t, out = _in_thread(lambda: c.checkpoint(1))
    time.sleep(0.2)
    c.request("stop")
    t.join(2.0)
    assert out == [False] and c.state is ControlState.STOPPED


def test_control_refuses_what_does_not_apply() -> None:
    c = RunControl()
    with pytest.raises(ControlError, match="cannot resume: the run is running"):
        c.request("resume")
    with pytest.raises(ControlError, match="unknown control action 'land'"):
        c.request("land")
    assert c.checkpoint(1) is True
    c.finish()
    assert c.state is ControlState.FINISHED
    with pytest.raises(ControlError, match="cannot stop: the run is finished"):
        c.request("stop")


def test_the_dfc_stops_at_its_checkpoint_and_brings_the_vehicles_home() -> None:
    mission = load_mission(DEMO).with_overrides(max_iterations=4, min_iterations=4) \
        .with_vehicles(count=2)
    field = mission.build_field(1)
    executor = InProcessExecutor(mission, field)
    asked: list[int] = []

    def checkpoint(iteration: int) -> bool:
        asked.append(iteration)
        return iteration < 2

    result = Dfc(mission, executor, planner="lawnmower", truth=field,
                 checkpoint=checkpoint).run()
    assert asked == [1, 2]
    assert result.stop_reason == "stopped" and not result.converged
    assert [r.iteration for r in result.records] == [0, 1]
    for x, y in executor.positions():  # finish() flew everyone home
        assert math.dist((x, y), executor.home) < 1.0


# -- the run directory: per-iteration frames and the log ---------------------------------------


def _piece(level: float, pts: list[tuple[float, float]]) -> Job:
    p = ContourPiece(level, np.asarray(pts, dtype=float), closed=False)
    job = Job([], (0.0, 0.0), (0.0, 0.0), p.length_m, piece=p)
    job.retarget(*p.midpoint(), 10.0, 0.0, 0)
    return job


def test_planned_pieces_name_each_vehicles_pieces_and_legs() -> None:
    from econdor_gcs.core.assignment import assign_jobs

    jobs = [_piece(10.0, [(0, 0), (10, 0), (20, 0)]), _piece(20.0, [(50, 50), (60, 60)]),
            _piece(30.0, [(90, 0), (90, 30)])]
    batch = Batch(jobs, levels_planned=3)
    plans = assign_jobs(jobs, [(0.0, 0.0), (80.0, 0.0)], first_piece_id=1000)
    plans[0] = [Waypoint(0, 0), Waypoint(0, 100), *plans[0]]  # a survey leg first
    pieces = planned_pieces(batch, plans)
    legs = [p for p in pieces if p.piece_id == -1]
    assert len(legs) == 1 and legs[0].vehicle == 0 and math.isnan(legs[0].level)
    assert legs[0].points_m.tolist() == [[0.0, 0.0], [0.0, 100.0]]
    traced = {p.piece_id: p for p in pieces if p.piece_id >= 0}
    assert sorted(traced) == [1000, 1001, 1002]
    for vehicle, tasks in enumerate(plans):
        for task in tasks:
            if isinstance(task, TraceTask):
                got = traced[task.piece_id]
                assert got.vehicle == vehicle and got.level == task.level
                job = next(j for j in jobs if j.tasks[0].piece_id == task.piece_id)
                assert job.piece is not None
                np.testing.assert_array_equal(got.points_m, job.piece.points_m)


def test_iteration_frames_round_trip_and_stay_small(tmp_path: Path) -> None:
    grid = Grid(Region(0, 100, 0, 100), 101, 101)
    xx, yy = grid.mesh
    est = 50 + 30 * np.sin(xx / 17.0) * np.cos(yy / 23.0)
    pieces = [PlannedPiece(1, 2003, 42.5, np.array([[1.0, 2.0], [3.0, 4.5]])),
              PlannedPiece(0, -1, math.nan, np.array([[0.0, 0.0], [100.0, 100.0]]))]
    path = tmp_path / "iter_002.npz"
    write_iteration(path, IterationFrame(2, grid.x, grid.y, est, pieces))
    got = read_iteration(path)
    assert got.iteration == 2
    np.testing.assert_allclose(got.estimate, est, rtol=1e-6)  # float32
    np.testing.assert_array_equal(got.grid_x, grid.x)
    assert [(p.vehicle, p.piece_id) for p in got.pieces] == [(1, 2003), (0, -1)]
    assert got.pieces[0].level == pytest.approx(42.5) and math.isnan(got.pieces[1].level)
    np.testing.assert_allclose(got.pieces[0].points_m, [[1.0, 2.0], [3.0, 4.5]])
    assert path.stat().st_size < 45_000  # 101 x 101 float64 would be 81.6 kB raw


def _record(it: int, samples: int) -> IterationRecord:
    return IterationRecord(it, 3, 3, 1, 0.5, 0.1 * (it + 1), 2.0 / (it + 1), -3.0 * it, 0.9,
                           100.0 * it, 150.0 * it, samples)


def test_rundir_writes_each_iteration_as_it_ends(tmp_path: Path) -> None:
    grid = Grid(Region(0, 10, 0, 10), 11, 11)
    rd = RunDir(tmp_path / "run", grid=grid)
    job = _piece(5.0, [(1, 1), (9, 9)])
    plans = [[job.tasks[0]]]
    rd.progress(IterationDone(_record(0, 10), np.zeros(grid.shape)))
    rd.progress(IterationPlanned(1, Batch([job], levels_planned=1), plans))
    assert not (tmp_path / "run" / "iterations" / "iter_001.npz").exists()
    rd.progress(IterationDone(_record(1, 25), np.ones(grid.shape)))
    rd.close()
    frames = sorted(p.name for p in (tmp_path / "run" / "iterations").iterdir())
    assert frames == ["iter_000.npz", "iter_001.npz"]
    one = read_iteration(tmp_path / "run" / "iterations" / "iter_001.npz")
    assert [(p.vehicle, p.level) for p in one.pieces] == [(0, 5.0)]
    assert (tmp_path / "run" / "metrics.csv").read_text().count("\n") == 3  # header + 2
    recs = json.loads((tmp_path / "run" / "iterations.json").read_text())
    assert [r["samples"] for r in recs] == [10, 25]


def test_runlog_lines_survive_a_torn_tail(tmp_path: Path) -> None:
    log = RunLog(tmp_path / "log.jsonl")
    log.add("vehicle 2", "piece 7: contour found")
    log.progress(IterationPlanned(3, Batch([], levels_planned=0), [[]]))
    log.add("station", "vehicle 2 lost", Severity.ERROR)
    log.close()
    with (tmp_path / "log.jsonl").open("a") as f:
        f.write('{"wall_s": 1.0, "iter')  # a run killed mid-line
    lines = read_log(tmp_path / "log.jsonl")
    assert [(ln.iteration, ln.source, ln.severity) for ln in lines] == [
        (0, "vehicle 2", Severity.INFO), (3, "dfc", Severity.INFO),
        (3, "station", Severity.ERROR)]
    assert lines[1].text == "iteration 3 planned: 0 jobs for 0 vehicles"


# -- the feeds ---------------------------------------------------------------------------------


def _status(sysid: int, x: float, phase: Phase = Phase.TRACE) -> VehicleStatus:
    return VehicleStatus(sysid=sysid, index=sysid - 1, x_m=x, y_m=2.0, alt_rel_m=30.0,
                         heading_deg=90.0, flight_time_s=12.0, armed=True, lost=False, item=2,
                         items=3, phase=phase, flown_m=100.0, samples=10, status="flying")


def _live_feed(rate_hz: float = 1000.0) -> tuple[LiveFeed, RunControl, list[VehicleStatus]]:
    mission = load_mission(DEMO).with_overrides(grid_spacing_m=5.0)
    control = RunControl()
    feed = LiveFeed(mission_name="demo", planner="econdor", grid=mission.grid,
                    origin=mission.origin, runlog=RunLog(), control=control, rate_hz=rate_hz)
    control._on_change = feed.on_control  # what web.session.LiveWeb wires
    rows = [_status(1, 10.0), _status(2, 20.0)]
    feed.attach(lambda: list(rows), [1, 2])
    return feed, control, rows


def _types(msgs: list[dict[str, Any]]) -> list[str]:
    return [m["type"] for m in msgs]


def test_live_feed_sends_each_thing_once_in_order() -> None:
    feed, control, rows = _live_feed()
    mission = load_mission(DEMO).with_overrides(grid_spacing_m=5.0)
    cur = Cursor()
    first = feed.updates(cur)
    assert _types(first) == ["trail", "control", "vehicles"]
    assert first[-1]["vehicles"][0]["x_m"] == 10.0 and first[-1]["vehicles"][0]["phase"] == "trace"
    est = np.fromfunction(lambda r, c: r + c, mission.grid.shape)
    feed.progress(IterationDone(_record(0, 2), est))
    job = _piece(5.0, [(1, 1), (9, 9)])
    feed.progress(IterationPlanned(1, Batch([job], levels_planned=1), [[job.tasks[0]], []]))
    lat, lon, _ = mission.origin.to_global(5.0, 6.0)
    feed.on_sample(Sample(2, 1000, lat, lon, 30.0, 1.0))
    rows[0] = _status(1, 11.0)
    time.sleep(0.01)
    msgs = feed.updates(cur)
    assert _types(msgs) == ["plan", "trail", "frame", "records", "vehicles"]
    plan, trail, frame = msgs[0], msgs[1], msgs[2]
    assert plan["iteration"] == 1 and plan["pieces"][0]["piece_id"] == job.tasks[0].piece_id
    assert not trail["reset"] and trail["n"] == 1
    xy = np.frombuffer(__import__("base64").b64decode(trail["x"]), "<f4")
    assert xy[0] == pytest.approx(5.0, abs=1e-3)
    assert frame["iteration"] == 0 and frame["contours"] and frame["max"] == pytest.approx(est.max())
    assert msgs[-1]["vehicles"][0]["pieces"] == [job.tasks[0].piece_id]
    # the DFC accounts the flight: its samples replace the trail
    feed.add_samples(SampleLog(np.zeros(3), np.ones(3), np.ones(3), np.ones(3),
                               np.full(3, Phase.TRACE, dtype=np.int8),
                               np.zeros(3, dtype=np.int16)))
    msgs = feed.updates(cur)
    assert _types(msgs)[:2] == ["samples", "trail"] and msgs[1]["reset"] and msgs[1]["n"] == 0
    # operator control and the end of the run
    assert feed.control("pause")["state"] == "pausing"
    feed.progress(RunDone({"stop_reason": "stopped", "iterations": 1}))
    msgs = feed.updates(cur)
    assert "control" in _types(msgs) and msgs[-1] == {
        "type": "done", "summary": {"stop_reason": "stopped", "iterations": 1}}
    assert feed.updates(cur) == [] or _types(feed.updates(cur)) == ["vehicles"]
    json.dumps(msgs, allow_nan=False)


def test_a_late_page_gets_the_whole_run_so_far() -> None:
    feed, _, _ = _live_feed()
    grid = load_mission(DEMO).with_overrides(grid_spacing_m=5.0).grid
    for it in range(3):
        feed.progress(IterationDone(_record(it, 5 * (it + 1)), np.full(grid.shape, float(it))))
    msgs = feed.updates(Cursor())
    recs = next(m for m in msgs if m["type"] == "records")["records"]
    assert [r["iteration"] for r in recs] == [0, 1, 2]
    assert next(m for m in msgs if m["type"] == "frame")["iteration"] == 2
    assert feed.frame(1) is not None and feed.frame(7) is None


def test_replay_of_a_run_directory_without_frames(tmp_path: Path) -> None:
    """A run directory from before iterations/ existed: curves, paths, the final estimate."""
    mission = load_mission(DEMO).with_overrides(max_iterations=1, min_iterations=1) \
        .with_vehicles(count=1)
    field = mission.build_field(1)
    rd = RunDir(tmp_path / "old")
    result = Dfc(mission, InProcessExecutor(mission, field), planner="lawnmower", truth=field,
                 on_samples=rd.append_samples).run()
    rd.write_result(result)
    rd.close()
    feed = ReplayFeed(tmp_path / "old")
    hello = feed.hello()
    assert hello["mode"] == "replay" and hello["controls"] is False and hello["truth_known"]
    assert hello["region"] == {"xmin": 0.0, "xmax": 100.0, "ymin": 0.0, "ymax": 100.0}
    msgs = feed.updates(Cursor())
    assert _types(msgs) == ["frame", "records", "samples", "done"]
    assert msgs[0]["iteration"] == 1 and msgs[2]["n"] == len(result.samples)
    assert feed.frame(0) is None  # only the final estimate was kept
    with pytest.raises(ControlError, match="a replay has no controls"):
        feed.control("stop")
    with pytest.raises(WebError, match="not a run directory"):
        ReplayFeed(tmp_path)


# -- the server: addresses and access ------------------------------------------------------------


def test_parse_web_address_rejects_nonsense() -> None:
    assert parse_web_address("localhost:9000") == ("localhost", 9000)
    with pytest.raises(WebError, match=r"expected \[HOST:\]PORT"):
        parse_web_address("127.0.0.1:http")
    with pytest.raises(WebError, match="port must be 0..65535"):
        parse_web_address("70000")
    with pytest.raises(WebError, match="IPv6 address in brackets"):
        parse_web_address("::1:8765")


def test_another_host_than_loopback_needs_a_token() -> None:
    feed = ReplayFeed.__new__(ReplayFeed)  # never served: only the server's policy is asked
    s = WebServer(feed, "0.0.0.0", 8765)
    assert s.token and len(s.token) >= 20 and s.url.endswith(f"/?token={s.token}")
    assert s.exposed
    assert WebServer(feed, "127.0.0.1", 8765).token is None  # a replay: nothing to guard
    live = WebServer(feed, "127.0.0.1", 8765, controls=True)  # the controls: always a token
    assert live.token and live.url.endswith(f"/?token={live.token}") and not live.exposed


@pytest.fixture()
def replay_server(tmp_path: Path) -> Any:
    grid = Grid(Region(0, 10, 0, 10), 11, 11)
    rd = RunDir(tmp_path / "run", grid=grid)
    rd.progress(IterationDone(_record(0, 0), np.zeros(grid.shape)))
    rd.close()
    servers: list[WebServer] = []

    def start(token: str | None = None) -> WebServer:
        s = WebServer(ReplayFeed(tmp_path / "run"), "127.0.0.1", 0, token=token)
        s.start()
        servers.append(s)
        return s

    yield start
    for s in servers:
        s.stop(flush_s=0.2)


def _get(port: int, path: str, host: str | None = None) -> tuple[int, dict[str, str], bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    conn.request("GET", path, headers={"Host": host} if host else {})
    r = conn.getresponse()
    body = r.read()
    conn.close()
    return r.status, dict(r.getheaders()), body


def _ws(port: int, path: str = "/ws", origin: str | None = None,
        send: list[dict[str, Any]] | None = None, n: int = 1) -> list[dict[str, Any]]:
    import aiohttp

    async def main() -> list[dict[str, Any]]:
        headers = {"Origin": origin} if origin else {}
        async with aiohttp.ClientSession() as session, session.ws_connect(
                f"http://127.0.0.1:{port}{path}", headers=headers) as ws:
            for m in send or []:
                await ws.send_json(m)
            return [await ws.receive_json(timeout=5) for _ in range(n)]

    return asyncio.run(main())


def test_the_page_and_its_assets_are_served_offline(replay_server: Any) -> None:
    s = replay_server()
    status, headers, body = _get(s.bound_port, "/")
    assert status == 200 and b"app.js" in body
    assert "default-src 'self'" in headers["Content-Security-Policy"]
    for asset in ("static/app.js", "static/style.css", "static/vendor/uplot/uPlot.iife.min.js",
                  "static/vendor/uplot/LICENSE"):
        assert f'"{asset}"'.encode() in body or asset.endswith("LICENSE")
        status, _, data = _get(s.bound_port, "/" + asset)
        assert status == 200 and data
    assert b"http" not in body.replace(b"http-equiv", b"")  # nothing from elsewhere


def test_loopback_page_refuses_foreign_host_names_and_origins(replay_server: Any) -> None:
    import aiohttp

    s = replay_server()
    status, _, body = _get(s.bound_port, "/", host=f"attacker.example:{s.bound_port}")
    assert status == 403 and b"not a loopback address" in body
    with pytest.raises(aiohttp.WSServerHandshakeError):
        _ws(s.bound_port, origin="http://attacker.example")
    hello, *rest = _ws(s.bound_port, origin=f"http://127.0.0.1:{s.bound_port}", n=2)
    assert hello["type"] == "hello" and hello["mode"] == "replay"
    assert rest[0]["type"] == "frame"


def test_a_token_guards_the_page_and_its_socket(replay_server: Any) -> None:
    import aiohttp

    s = replay_server(token="s3cret-token")
    assert _get(s.bound_port, "/")[0] == 403
    assert _get(s.bound_port, "/?token=wrong")[0] == 403
    assert _get(s.bound_port, "/?token=s3cret-token")[0] == 200
    with pytest.raises(aiohttp.WSServerHandshakeError):
        _ws(s.bound_port)
    assert _ws(s.bound_port, "/ws?token=s3cret-token")[0]["type"] == "hello"


@pytest.mark.parametrize("origin", [None, "null"])
def test_no_control_without_the_token_whatever_the_origin(origin: str | None) -> None:
    """A page of another site cannot stop the run: on loopback a socket without the token
    (no Origin, as a script sends; or ``Origin: null``, a sandboxed frame or a file://
    page) gets no controls and its requests are refused; only the token obeys."""
    import aiohttp

    feed, control, _ = _live_feed()
    s = WebServer(feed, "127.0.0.1", 0, controls=True)
    s.start()
    try:
        stop = [{"type": "control", "action": "stop"}]
        if origin == "null":
            with pytest.raises(aiohttp.WSServerHandshakeError):
                _ws(s.bound_port, origin=origin, send=stop)
        else:
            hello, *rest = _ws(s.bound_port, send=stop, n=5)
            assert hello["type"] == "hello" and hello["controls"] is False
            assert any(m["type"] == "error" and "need the token" in m["text"] for m in rest)
        assert control.state is ControlState.RUNNING
        hello, *rest = _ws(s.bound_port, f"/ws?token={s.token}", send=stop, n=5)
        assert hello["controls"] is True
        assert any(m["type"] == "control" and m["state"] == "stopping" for m in rest), rest
        assert control.state is ControlState.STOPPING
    finally:
        s.stop(flush_s=0.2)


def test_requests_a_replay_cannot_grant_come_back_as_errors(replay_server: Any) -> None:
    s = replay_server()
    msgs = _ws(s.bound_port, send=[{"type": "control", "action": "stop"},
                                   {"type": "seek", "iteration": 5}], n=6)
    errors = [m["text"] for m in msgs if m["type"] == "error"]
    assert errors == ["a replay has no controls", "no estimate stored for iteration 5"]


# -- the command line ----------------------------------------------------------------------------


def test_view_of_a_missing_run_directory_is_one_line(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["view", str(tmp_path / "nope")]) == 1
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "no such run directory" in err


def test_run_with_a_busy_web_port_is_one_line(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = cli.main(["run", str(DEMO), "--out", str(tmp_path / "run"), "--quiet",
                         "--web", f"127.0.0.1:{port}"])
    err = capsys.readouterr().err
    assert code == 1 and err.strip().count("\n") == 0
    assert f"--web 127.0.0.1:{port}: cannot listen" in err
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert "cannot listen" in summary["error"]  # the run directory says why, too


def test_run_with_a_malformed_web_address_is_one_line(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["run", str(DEMO), "--out", str(tmp_path / "run"), "--quiet",
                     "--web", "localhost:eighty"])
    assert code == 1
    assert "expected [HOST:]PORT" in capsys.readouterr().err


def test_the_last_update_has_the_vehicles_as_they_ended() -> None:
    """However recent the last snapshot, the run's end brings a fresh one (e.g. landed)."""
    feed, _, rows = _live_feed(rate_hz=0.001)  # one snapshot per 1000 s
    cur = Cursor()
    assert feed.updates(cur)[-1]["vehicles"][0]["status"] == "flying"
    rows[0] = VehicleStatus(**{**_status(1, 0.0).__dict__, "status": "landed"})
    assert "vehicles" not in _types(feed.updates(cur))  # rate-limited
    feed.finish({"stop_reason": "stopped"})
    msgs = feed.updates(cur)
    assert _types(msgs) == ["vehicles", "done"]
    assert msgs[0]["vehicles"][0]["status"] == "landed"


def test_control_reports_arrive_in_the_order_of_the_changes() -> None:
    """A stop while paused: the DFC's checkpoint turns STOPPING into STOPPED at once, on its
    own thread; the page must still hear STOPPING before STOPPED, even when the callback
    for STOPPING is slow (it ends the flight in progress first)."""
    heard: list[ControlState] = []

    def on_change(state: ControlState, iteration: int) -> None:
        if state is ControlState.STOPPING:
            time.sleep(0.3)  # the checkpoint polls every 0.01 s meanwhile
        heard.append(state)

    control = RunControl(on_change=on_change, poll_s=0.01)
    control.request(ControlAction.PAUSE)
    result: list[bool] = []
    dfc = threading.Thread(target=lambda: result.append(control.checkpoint(2)))
    dfc.start()
    deadline = time.monotonic() + 5
    while control.state is not ControlState.PAUSED:
        assert time.monotonic() < deadline
        time.sleep(0.005)
    control.request(ControlAction.STOP)
    dfc.join(5)
    assert result == [False]
    assert heard == [ControlState.PAUSING, ControlState.PAUSED, ControlState.STOPPING,
                     ControlState.STOPPED]
