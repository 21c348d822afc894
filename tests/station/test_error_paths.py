"""Errors on the error path are logged and reported, never swallowed."""

from __future__ import annotations

import asyncio
import json
import logging
import socket
import threading
from pathlib import Path
from types import SimpleNamespace

import pytest

from econdor_gcs.app.run_failures import write_partial as _write_partial
from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.tasks import Waypoint
from econdor_gcs.errors import RunError
from econdor_gcs.files.rundir import RunDir
from econdor_gcs.link.items import build_mission
from econdor_gcs.station.loop import Station
from econdor_gcs.station.sorties import VehicleMissions
from sim_vehicle.transport import UdpTransport, parse_endpoint

ORIGIN = Origin(47.397742, 8.545594, 488.0)


class _BrokenExecutor:
    iteration = 2
    losses: list[dict] = []

    def pending_samples(self):
        raise ValueError("half a sample")

    def sample_accounting(self) -> dict:
        return {}


def test_partial_summary_reports_samples_it_could_not_write(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    rd = RunDir(tmp_path / "run")
    with caplog.at_level(logging.ERROR):
        _write_partial(rd, None, _BrokenExecutor(), {"planner": "econdor"}, {}, lambda: None,
                       "vehicle 2 lost")
    rd.close()
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["error"] == "vehicle 2 lost"
    assert summary["error_path"] == [
        "the samples still pending were not written: ValueError('half a sample')"]
    assert "the samples still pending were not written" in caplog.text


def test_a_summary_that_cannot_be_written_is_logged(tmp_path: Path,
                                                    caplog: pytest.LogCaptureFixture) -> None:
    rd = RunDir(tmp_path / "run")
    (tmp_path / "run" / "metrics.csv").mkdir()  # writing metrics.csv fails
    with caplog.at_level(logging.ERROR):
        _write_partial(rd, None, None, {}, {}, lambda: None, "boom")
    rd.close()
    assert "the partial summary.json was not written" in caplog.text
    assert "IsADirectoryError" in caplog.text


def test_a_mission_that_cannot_be_saved_fails_the_run(tmp_path: Path) -> None:
    items = build_mission(ORIGIN, [Waypoint(10.0, 20.0)], 30.0)
    missions = tmp_path / "missions"
    missions.mkdir()
    (missions / "iter01_v2.waypoints").mkdir()  # the WPL copy cannot be written
    fake = SimpleNamespace(missions_dir=missions)
    with pytest.raises(RunError, match=r"cannot save the mission of vehicle 2 in .*missions"):
        VehicleMissions.save_mission(fake, 1, 2, items, [Waypoint(10.0, 20.0)])  # type: ignore[arg-type]


def test_station_close_reports_a_router_that_fails_to_close(
        caplog: pytest.LogCaptureFixture) -> None:
    station = Station("udpin:127.0.0.1:0")
    station.start()

    closed = station.router.close

    async def refuse() -> None:
        await closed()  # the socket is closed, then the failure
        raise OSError("device gone")

    station.router.close = refuse  # type: ignore[method-assign]
    with caplog.at_level(logging.ERROR):
        station.close()
    assert station.close_error == "closing the GCS endpoint failed: OSError('device gone')"
    assert station.close_error in caplog.text


def test_station_close_ends_what_an_interrupted_wait_left_on_its_loop(
        caplog: pytest.LogCaptureFixture) -> None:
    """Ctrl-C during ``Station.call`` leaves its coroutine on the loop: closing the station
    ends it before the loop closes (a loop closed under it prints "Task was destroyed but
    it is pending!" after the run's one line)."""
    station = Station("udpin:127.0.0.1:0")
    station.start()
    started = threading.Event()

    async def wait_forever() -> None:
        started.set()
        await asyncio.Event().wait()

    left = asyncio.run_coroutine_threadsafe(wait_forever(), station.loop)
    assert started.wait(10)
    with caplog.at_level(logging.ERROR):
        station.close()
    assert left.cancelled()
    assert "destroyed" not in caplog.text


class _IcmpSocket:
    """recvfrom: an ICMP error first, then a datagram, then nothing."""

    def __init__(self) -> None:
        self.script: list[object] = [ConnectionRefusedError(111, "refused"),
                                     (b"x", ("127.0.0.1", 9))]

    def recvfrom(self, n: int):
        if not self.script:
            raise BlockingIOError
        item = self.script.pop(0)
        if isinstance(item, Exception):
            raise item
        return item


def test_vehicle_transport_counts_receive_errors() -> None:
    t = UdpTransport(parse_endpoint("udpin:127.0.0.1:0"))
    real = t.sock
    t.sock = _IcmpSocket()  # type: ignore[assignment]
    try:
        assert t.recv_all(10) == [(("127.0.0.1", 9), b"x")]
        assert t.rx_errors == 1
    finally:
        t.sock = real
        t.close()
    assert isinstance(real, socket.socket)
