"""The web page of one ``econdor run``: feed, operator control and server, wired to the run."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from econdor_gcs.app.web.feed import LiveFeed, StatusSource
from econdor_gcs.app.web.server import WebServer, parse_web_address
from econdor_gcs.config import Mission
from econdor_gcs.core.tasks import SampleLog
from econdor_gcs.dfc.control import ControlState, RunControl
from econdor_gcs.dfc.loop import DfcEvent
from econdor_gcs.files.rundir import RunLog
from econdor_gcs.link.router import Router, Sample


class LiveWeb:
    """``econdor run --web``: serve the run's page; pause after the iteration, resume, stop.

    Stop ends the flight in progress at once (``on_stop`` of :meth:`attach`, the executor's
    ``abort_flight``): every vehicle returns to launch and the DFC ends after taking in
    what was flown.

    Parameters
    ----------
    address:
        ``[HOST:]PORT`` (port 0: any free port; the returned address says which).
    """

    def __init__(self, address: str, *, mission: Mission, planner: str, run_dir: str,
                 runlog: RunLog, rate_hz: float = 4.0, token: str | None = None) -> None:
        host, port = parse_web_address(address)
        self.runlog = runlog
        self.control = RunControl(on_change=self._on_control)
        self._on_stop: Callable[[], None] | None = None
        self.feed = LiveFeed(mission_name=mission.name, planner=planner, grid=mission.grid,
                             origin=mission.origin, runlog=runlog, control=self.control,
                             max_iterations=mission.algorithm.max_iterations,
                             run_dir=run_dir, rate_hz=rate_hz)
        self.server = WebServer(self.feed, host, port, token=token, controls=True,
                                rate_hz=rate_hz)

    def start(self) -> str:
        """Bind and serve; the page's address, with the token its controls need."""
        return self.server.start()

    @property
    def exposed(self) -> bool:
        """Served beyond this machine: the controls are on the network (token-guarded)."""
        return self.server.exposed

    def _on_control(self, state: ControlState, iteration: int) -> None:
        if state is ControlState.STOPPING and self._on_stop is not None:
            self._on_stop()
        self.feed.on_control(state, iteration)
        where = {ControlState.PAUSING: f"pausing after iteration {iteration}",
                 ControlState.PAUSED: f"paused before iteration {iteration}",
                 ControlState.RUNNING: "resumed",
                 ControlState.STOPPING: f"stopping in iteration {iteration}: the flight "
                                        "in progress ends, every vehicle returns to launch",
                 ControlState.STOPPED: f"stopped before iteration {iteration}: vehicles "
                                       "return to launch",
                 ControlState.FINISHED: "run over"}[state]
        if state is not ControlState.FINISHED:
            self.runlog.add("operator", where)

    def attach(self, status: StatusSource, sysids: Sequence[int], router: Router,
               on_stop: Callable[[], None] | None = None) -> None:
        """The fleet is up: vehicle snapshots from ``status``, trails from ``router``;
        ``on_stop`` ends the flight in progress when the operator stops the run."""
        self._on_stop = on_stop
        self.feed.attach(status, sysids)
        router.subscribe(Sample, self.feed.on_sample)

    def progress(self, event: DfcEvent) -> None:
        self.feed.progress(event)

    def add_samples(self, log: SampleLog) -> None:
        self.feed.add_samples(log)

    def checkpoint(self, iteration: int) -> bool:
        return self.control.checkpoint(iteration)

    def close(self, summary: dict[str, Any] | None = None) -> None:
        """The run is over: tell the pages (their last update), then stop serving."""
        self.control.finish()
        self.feed.finish(summary)
        self.server.stop()


__all__ = ["LiveWeb"]
