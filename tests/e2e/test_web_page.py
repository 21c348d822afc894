"""The run's web page in a real headless Chromium (Debian's package, driven by playwright).

A short ``econdor run --web`` (3 vehicles, 3 iterations, 100x sim speed) is watched by a
page from start to end; what the page showed is recorded from its DOM and canvas pixels
and asserted by the tests below. ``econdor view`` then replays that run directory, and a
second run is paused and stopped from the page.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import pytest

from tests.helpers.missions import write_small_mission
from tests.helpers.vehicles import wait_for
from tests.helpers.web import (
    Browser,
    EcondorProcess,
    canvas_coloured_fraction,
    canvas_digest,
    confirm_control,
    estimate_iteration,
    estimate_shown,
    pieces_and_vehicles,
    positions_of,
    require_chromium,
    vehicle_positions,
    vehicle_rows,
)

pytestmark = pytest.mark.slow

def write_mission(folder: Path, iterations: int = 3, speedup: float = 100) -> Path:
    return write_small_mission(folder, "web", iterations=iterations, speedup=speedup)


@pytest.fixture(scope="module")
def browser() -> Any:
    require_chromium()
    with Browser() as b:
        yield b


def _watch(page: Any, proc: EcondorProcess, timeout_s: float) -> dict[str, Any]:
    """Poll the page until the run ends: what a person would have seen, in order."""
    seen: dict[str, Any] = {"positions": [], "estimates": {}, "pieces": [], "flight_time": {},
                            "states": []}
    deadline = time.monotonic() + timeout_s
    while proc.proc.poll() is None:
        if time.monotonic() > deadline:
            raise AssertionError(f"the run did not end within {timeout_s} s:\n{proc.output()}")
        title, pieces, rows = pieces_and_vehicles(page)  # one reading: the page as it was
        seen["positions"].append(positions_of(rows))
        for sysid, cells in rows.items():
            seen["flight_time"][sysid] = cells.get("flight-time", "")
        it, digest, painted = estimate_shown(page)
        if it is not None and it not in seen["estimates"]:
            seen["estimates"][it] = (digest, painted)
        if "(flying)" in title:
            seen["pieces"].append((title, pieces, rows))
        seen["states"].append(page.inner_text("#run-state"))
        time.sleep(0.1)
    seen["returncode"] = proc.proc.returncode
    return seen


@pytest.fixture(scope="module")
def live_run(tmp_path_factory: pytest.TempPathFactory, browser: Browser) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("web")
    out = tmp / "run"
    proc = EcondorProcess("run", str(write_mission(tmp)), "--out", str(out), "--quiet",
                          "--web", "127.0.0.1:0")
    try:
        page = browser.page(proc.url)
        seen = _watch(page, proc, timeout_s=240)
        # the run is over: the page keeps its last state
        wait_for(lambda: "finished" in page.inner_text("#run-state"), 10, "finished state")
        seen["final_state"] = page.inner_text("#run-state")
        seen["log"] = page.inner_text("#log")
        seen["charts"] = page.eval_on_selector_all("#charts .uplot", "els => els.length")
        seen["output"] = proc.output()
        page.close()
    finally:
        proc.close()
    seen["out"] = out
    return seen


def test_live_page_shows_the_vehicles_moving(live_run: dict[str, Any]) -> None:
    assert live_run["returncode"] == 0, live_run["output"]
    track: dict[int, list[tuple[float, float]]] = {}
    for snapshot in live_run["positions"]:
        for sysid, xy in snapshot.items():
            if not track.get(sysid) or track[sysid][-1] != xy:
                track.setdefault(sysid, []).append(xy)
    assert sorted(track) == [1, 2, 3]
    for sysid, xy in track.items():
        # several distinct positions over the run, spread over the area (not one jump)
        assert len(xy) >= 6, (sysid, xy)
        span = max(math.dist(a, b) for a in xy[:: max(1, len(xy) // 30)] for b in xy)
        assert span > 30.0, (sysid, span)
    # flight time counts up on the page
    for sysid, text in live_run["flight_time"].items():
        minutes, seconds = text.split(":")
        assert int(minutes) * 60 + int(seconds) > 60, (sysid, text)


def test_live_page_shows_the_estimate_changing_between_iterations(
        live_run: dict[str, Any]) -> None:
    estimates = live_run["estimates"]
    assert len(estimates) >= 3, sorted(estimates)  # iterations 0..3 at 0.25 s polling
    digests = [d for d, _ in estimates.values()]
    assert len(set(digests)) == len(digests)  # each iteration's map differs from the others
    for it, (_, painted) in estimates.items():
        assert painted > 0.5, (it, painted)  # a colour map, not an empty canvas


def test_live_page_lists_the_planned_pieces_with_their_vehicles(live_run: dict[str, Any]) -> None:
    assert live_run["pieces"], "the page never showed an iteration in flight"
    title, rows, vehicles = live_run["pieces"][-1]
    assert rows and all(r[0] in ("1", "2", "3") for r in rows)
    ids = [int(r[1]) for r in rows]
    assert all(i >= 1000 for i in ids)
    # the vehicles table names the same pieces per vehicle
    listed = {sysid: [int(p) for p in cells["pieces"].split(", ") if p]
              for sysid, cells in vehicles.items()}
    for sysid_text, piece, *_ in rows:
        assert int(piece) in listed[int(sysid_text)]


def test_live_page_has_curves_log_and_final_state(live_run: dict[str, Any]) -> None:
    assert live_run["charts"] == 4  # MAE, learning error, kappa and delta, distance
    log = live_run["log"]
    assert "iteration 1 planned" in log and "iteration 3 done" in log
    assert "vehicle 1: piece" in log  # the vehicles' own words (STATUSTEXT)
    assert live_run["final_state"] == "finished (max_iterations)"
    assert "running" in live_run["states"]


def test_live_page_loads_nothing_from_outside(live_run: dict[str, Any],
                                              browser: Browser) -> None:
    assert browser.external == []
    assert browser.errors == []


def test_view_replays_a_finished_run(live_run: dict[str, Any], browser: Browser) -> None:
    out: Path = live_run["out"]
    proc = EcondorProcess("view", str(out), "--web", "127.0.0.1:0")
    try:
        page = browser.page(proc.url)
        wait_for(lambda: estimate_iteration(page) == 3, 30, "the last iteration's estimate")
        last = canvas_digest(page)
        assert canvas_coloured_fraction(page) > 0.5
        end_positions = vehicle_positions(page)
        assert page.inner_text("#run-state") == "finished (max_iterations)"
        # back to the start with the slider (keyboard, as a person would)
        page.focus("#slider")
        page.keyboard.press("Home")
        wait_for(lambda: estimate_iteration(page) == 0, 15, "the initiation's estimate")
        first = canvas_digest(page)
        assert first != last
        start_positions = vehicle_positions(page)
        assert start_positions != end_positions
        assert "#1 " not in page.inner_text("#log")  # only iteration 0's lines
        # one step forward: the pieces that iteration flew, with their vehicles
        page.keyboard.press("ArrowRight")
        wait_for(lambda: estimate_iteration(page) == 1, 15, "iteration 1's estimate")
        assert canvas_digest(page) not in (first, last)
        assert "iteration 1" in (page.text_content("#pieces-title") or "")
        rows = page.eval_on_selector_all("#pieces tbody tr", "r => r.length")
        assert rows >= 1
        assert not page.is_visible("#controls")  # a replay has no controls
        page.close()
    finally:
        proc.close()
    assert browser.errors == []


def test_pause_then_stop_brings_every_vehicle_home(tmp_path: Path, browser: Browser) -> None:
    out = tmp_path / "run"
    proc = EcondorProcess("run", str(write_mission(tmp_path, iterations=4)), "--out", str(out),
                          "--quiet", "--web", "127.0.0.1:0")
    try:
        page = browser.page(proc.url)
        wait_for(lambda: page.is_enabled("#btn-pause"), 60, "the pause button")
        wait_for(lambda: len(vehicle_positions(page)) == 3, 60, "vehicle positions")
        home = {sysid: (0.0, 0.0) for sysid in (1, 2, 3)}  # launch: the mission origin
        confirm_control(page, "#btn-pause")
        wait_for(lambda: page.inner_text("#run-state") == "paused", 90, "paused")
        # the iteration that was flying when we asked
        held = wait_for(lambda: (it := estimate_iteration(page)) is not None and (it,), 10,
                        "the estimate before the pause")[0]
        assert held < 4
        # the flight in progress ends and nothing follows it: hovering where their missions
        # ended, and no new estimate
        wait_for(lambda: {c["status"] for c in vehicle_rows(page).values()} == {"holding"}, 60,
                 "the vehicles holding")
        assert estimate_iteration(page) == held
        away = vehicle_positions(page)
        assert all(math.dist(away[s], home[s]) > 5.0 for s in home)
        confirm_control(page, "#btn-stop")
        assert proc.wait(90) == 0, proc.output()
        wait_for(lambda: page.inner_text("#run-state") == "stopped", 10, "stopped")
        rows = vehicle_rows(page)
        assert {c["status"] for c in rows.values()} == {"landed"}
        for sysid, cells in rows.items():
            x, y = float(cells["x"]), float(cells["y"])
            assert math.dist((x, y), home[sysid]) < 3.0, (sysid, x, y, home[sysid])
            assert float(cells["alt"]) < 0.5
        page.close()
    finally:
        proc.close()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stop_reason"] == "stopped" and summary["iterations"] == held
    log = (out / "log.jsonl").read_text()
    assert f"paused before iteration {held + 1}" in log
    assert f"stopped before iteration {held + 1}" in log


def test_stop_ends_the_flight_in_progress_and_brings_every_vehicle_home(
        tmp_path: Path, browser: Browser) -> None:
    """Stop while the vehicles fly iteration 1 (at 20x, so the flight lasts): they leave
    their missions for home at once; the pieces they had not finished stay unreported,
    the samples flown so far are kept, and the run ends stopped in that iteration."""
    out = tmp_path / "run"
    proc = EcondorProcess("run", str(write_mission(tmp_path, iterations=4, speedup=20)),
                          "--out", str(out), "--quiet", "--web", "127.0.0.1:0")
    try:
        page = browser.page(proc.url)
        wait_for(lambda: page.is_enabled("#btn-stop"), 60, "the stop button")

        def mid_flight() -> bool:
            if estimate_iteration(page) != 0:  # iteration 1 flies on the initiation's estimate
                return False
            rows = vehicle_rows(page).values()
            return sum(c["status"] == "flying" and int(c["item"].split("/")[0]) >= 3
                       for c in rows) >= 2
        wait_for(mid_flight, 120, "vehicles in the middle of iteration 1")
        t_stop = time.monotonic()
        confirm_control(page, "#btn-stop")
        assert proc.wait(120) == 0, proc.output()
        wait_for(lambda: page.inner_text("#run-state") == "stopped", 10, "stopped")
        rows = vehicle_rows(page)
        assert {c["status"] for c in rows.values()} == {"landed"}
        for sysid, cells in rows.items():
            assert math.dist((float(cells["x"]), float(cells["y"])), (0.0, 0.0)) < 3.0, sysid
        page.close()
    finally:
        proc.close()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stop_reason"] == "stopped" and summary["iterations"] == 1, summary
    last = json.loads((out / "iterations.json").read_text())[-1]
    assert last["iteration"] == 1
    assert last["outcomes"].get("unreported", 0) >= 1, last["outcomes"]  # cut short
    assert summary["samples_recorded"] == summary["samples"]  # nothing flown was dropped
    log = (out / "log.jsonl").read_text()
    assert "stopping in iteration 1" in log and "return to launch" in log
    assert time.monotonic() - t_stop < 120
