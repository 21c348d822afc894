"""What a page sees of a run: the :class:`Feed` protocol, and :class:`LiveFeed` for a live run.

A feed hands each connected page the messages it has not seen yet (:meth:`Feed.updates`
with that page's :class:`Cursor`), the estimate of any iteration on request
(:meth:`Feed.frame`) and takes the operator's requests (:meth:`Feed.control`).

Threads of a live run and what each does here:

* the DFC thread calls :meth:`LiveFeed.progress` and :meth:`LiveFeed.add_samples`: they
  append references to lists under a lock and return (no copy, no encoding);
* the station's event loop calls :meth:`LiveFeed.on_sample` for every paired sample
  (one tuple appended under a lock) — those are the trails of the flights in progress;
* the web server's thread calls everything else, at most ``rate_hz`` times a second per
  page and only while a page is connected: vehicle snapshots (``status_rows()``), the
  conversion of trail samples to local metres, the encoding of estimates (cached).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np

from econdor_gcs.app.web import messages
from econdor_gcs.app.web.messages import Message
from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.geometry import FloatArray, Grid
from econdor_gcs.core.planners import Batch
from econdor_gcs.core.tasks import Phase, SampleLog, Task
from econdor_gcs.dfc.control import ControlState, RunControl
from econdor_gcs.dfc.loop import DfcEvent, IterationDone, IterationPlanned, RunDone
from econdor_gcs.errors import ControlError
from econdor_gcs.files.rundir import PlannedPiece, RunLog, planned_pieces
from econdor_gcs.link.router import Sample
from econdor_gcs.station.executor import VehicleStatus


@dataclass
class Cursor:
    """How far one page has been served."""

    records: int = 0
    sample_logs: int = 0
    log_lines: int = 0
    trail_base: int = -1
    trail_sent: int = 0
    plan_iteration: int = -1
    frame_iteration: int = -1
    control_version: int = -1
    vehicles_at: float = -math.inf
    done: bool = False


class Feed(Protocol):
    """A run as the page sees it (live or replayed)."""

    def hello(self) -> Message: ...

    def updates(self, cursor: Cursor) -> list[Message]:
        """Messages the page behind ``cursor`` has not had yet (``cursor`` is advanced)."""
        ...

    def frame(self, iteration: int) -> Message | None:
        """The ``frame`` message of ``iteration``, or ``None`` if there is none."""
        ...

    def control(self, action: str) -> Message:
        """Apply an operator's request; the new ``control`` message.

        Raises :class:`~econdor_gcs.errors.ControlError` when it does not apply."""
        ...


StatusSource = Callable[[], Sequence[VehicleStatus]]


class LiveFeed:
    """The :class:`Feed` of a running ``econdor run`` (see the module docstring).

    Parameters
    ----------
    mission_name, planner, grid, origin:
        What the run is; the grid of the estimates, the origin of the trail conversion.
    runlog:
        The run's log (lines are served from it).
    control:
        The operator control the DFC checks between iterations (``None``: no controls).
    rate_hz:
        Vehicle snapshots at most this often (the server polls the feed at the same rate).
    """

    def __init__(self, *, mission_name: str, planner: str, grid: Grid, origin: Origin,
                 runlog: RunLog, control: RunControl | None = None, truth_known: bool = True,
                 max_iterations: int | None = None, run_dir: str = "",
                 rate_hz: float = 4.0) -> None:
        self.mission_name = mission_name
        self.planner = planner
        self.grid = grid
        self.origin = origin
        self.runlog = runlog
        self.run_control = control
        self.truth_known = truth_known
        self.max_iterations = max_iterations
        self.run_dir = run_dir
        self.rate_hz = rate_hz
        self._lock = threading.Lock()
        # written by the DFC thread (references only)
        self._records: list[dict[str, Any]] = []
        self._estimates: dict[int, FloatArray] = {}
        self._plans: dict[int, tuple[Batch, list[list[Task]]]] = {}
        self._planned_iteration = -1
        self._logs: list[SampleLog] = []
        self._summary: dict[str, Any] | None = None
        self._control_version = 0
        self._control_state = ControlState.RUNNING if control else None
        self._control_iteration = 0
        # written by the station's loop: raw samples not yet accounted by the DFC
        self._raw: list[tuple[int, float, float]] = []
        self._raw_base = 0
        # the server's thread only
        self._status: StatusSource | None = None
        self._sysids: list[int] = []
        self._vehicles: list[VehicleStatus] = []
        self._vehicles_at = -math.inf
        self._final_taken = False
        self._frames: dict[int, Message] = {}
        self._pieces: dict[int, list[PlannedPiece]] = {}
        self._sample_msgs: list[Message] = []
        self._trail = _Trail()

    # -- from the run (any thread but the server's) ---------------------------------------------
    def attach(self, status: StatusSource, sysids: Sequence[int]) -> None:
        """The vehicles are known: where their snapshots come from."""
        with self._lock:
            self._status = status
            self._sysids = list(sysids)

    def progress(self, event: DfcEvent) -> None:
        """DFC progress callback (DFC thread): keep references, nothing else."""
        with self._lock:
            if isinstance(event, IterationPlanned):
                self._plans[event.iteration] = (event.batch, event.plans)
                self._planned_iteration = event.iteration
            elif isinstance(event, IterationDone):
                self._records.append(asdict(event.record))
                self._estimates[event.record.iteration] = event.estimate
            elif isinstance(event, RunDone):
                self._summary = dict(event.summary)

    def add_samples(self, log: SampleLog) -> None:
        """DFC ``on_samples`` callback: accounted samples replace the trail so far."""
        with self._lock:
            self._logs.append(log)
            self._raw_base += len(self._raw)
            self._raw.clear()

    def on_sample(self, sample: Sample) -> None:
        """Router sample handler (station loop): one tuple for the in-flight trail."""
        with self._lock:
            self._raw.append((sample.sysid, sample.lat_deg, sample.lon_deg))

    def on_control(self, state: ControlState, iteration: int) -> None:
        """:class:`RunControl` ``on_change`` callback."""
        with self._lock:
            self._control_state = state
            self._control_iteration = iteration
            self._control_version += 1

    def finish(self, summary: dict[str, Any] | None = None) -> None:
        """The run is over (also after a failure: ``summary`` has the ``error``)."""
        with self._lock:
            if summary is not None:
                self._summary = dict(summary)
            elif self._summary is None:
                self._summary = {}

    # -- Feed (the server's thread) ---------------------------------------------------------------
    def hello(self) -> Message:
        r = self.grid.region
        with self._lock:
            sysids = list(self._sysids)
        return messages.hello(
            "live", mission=self.mission_name, planner=self.planner,
            region={"xmin": r.xmin, "xmax": r.xmax, "ymin": r.ymin, "ymax": r.ymax},
            vehicles=sysids, controls=self.run_control is not None,
            truth_known=self.truth_known, max_iterations=self.max_iterations,
            run_dir=self.run_dir)

    def _planned(self, iteration: int) -> list[PlannedPiece]:
        if iteration not in self._pieces:
            with self._lock:
                plan = self._plans.get(iteration)
            self._pieces[iteration] = planned_pieces(*plan) if plan else []
        return self._pieces[iteration]

    def frame(self, iteration: int) -> Message | None:
        if iteration not in self._frames:
            with self._lock:
                est = self._estimates.get(iteration)
            if est is None:
                return None
            self._frames[iteration] = messages.frame(iteration, self.grid.x, self.grid.y, est,
                                                     self._planned(iteration))
        return self._frames[iteration]

    def control(self, action: str) -> Message:
        if self.run_control is None:
            raise ControlError("this page has no controls")
        state = self.run_control.request(action)
        return messages.control(state.value, self.run_control.iteration)

    def _snapshot(self, final: bool) -> list[VehicleStatus]:
        """Vehicle snapshots at most ``rate_hz`` times a second, and one after the run's end."""
        now = time.monotonic()
        if now - self._vehicles_at >= 1.0 / self.rate_hz or (final and not self._final_taken):
            with self._lock:
                status = self._status
            if status is not None:
                self._vehicles = list(status())
                self._vehicles_at = now
            self._final_taken = final
        return self._vehicles

    def updates(self, cursor: Cursor) -> list[Message]:
        out: list[Message] = []
        with self._lock:
            control = (self._control_version, self._control_state, self._control_iteration)
            planned_iteration = self._planned_iteration
            new_logs = self._logs[cursor.sample_logs:]
            records = self._records[cursor.records:]
            latest = max(self._estimates) if self._estimates else -1
            raw_base, raw_end = self._raw_base, self._raw_base + len(self._raw)
            reset = cursor.trail_base != raw_base
            raw = self._raw[0 if reset else max(0, cursor.trail_sent - raw_base):]
            summary = self._summary
        version, state, ctl_iteration = control
        lines = self.runlog.since(cursor.log_lines)
        if lines:
            out.append(messages.log(lines))
            cursor.log_lines += len(lines)
        if planned_iteration > cursor.plan_iteration:
            out.append(messages.plan(planned_iteration, self._planned(planned_iteration)))
            cursor.plan_iteration = planned_iteration
        for log in new_logs:
            k = cursor.sample_logs
            if k >= len(self._sample_msgs):
                self._sample_msgs.append(messages.samples(log))
            out.append(self._sample_msgs[k])
            cursor.sample_logs += 1
        vehicles = self._snapshot(final=summary is not None)
        if reset or raw:
            x, y, vi, ph = self._trail.convert(raw, self.origin, vehicles)
            out.append(messages.trail(reset, x, y, vi, ph))
            cursor.trail_base, cursor.trail_sent = raw_base, raw_end
        if latest > cursor.frame_iteration:  # before its record: the page then has it
            msg = self.frame(latest)
            if msg is not None:
                out.append(msg)
            cursor.frame_iteration = latest
        if records:
            out.append(messages.records(records))
            cursor.records += len(records)
        if state is not None and version != cursor.control_version:  # after what led to it
            out.append(messages.control(state.value, ctl_iteration))
            cursor.control_version = version
        if vehicles and self._vehicles_at > cursor.vehicles_at:
            by_vehicle: dict[int, list[int]] = {}
            for p in self._planned(planned_iteration) if planned_iteration >= 0 else []:
                if p.piece_id >= 0:
                    by_vehicle.setdefault(p.vehicle, []).append(p.piece_id)
            out.append(messages.vehicles(vehicles, by_vehicle))
            cursor.vehicles_at = self._vehicles_at
        if summary is not None and not cursor.done:
            out.append(messages.done(summary))
            cursor.done = True
        return out


@dataclass
class _Trail:
    """Converts raw trail samples to local metres, tagging each with the vehicle's phase as
    of its latest snapshot (the exact phases come with the accounted samples)."""

    index: dict[int, int] = field(default_factory=dict)

    def convert(self, raw: Sequence[tuple[int, float, float]], origin: Origin,
                vehicles: Sequence[VehicleStatus]
                ) -> tuple[FloatArray, FloatArray, np.ndarray, np.ndarray]:
        if not raw:
            z = np.zeros(0)
            return z, z, z.astype(np.uint8), z.astype(np.uint8)
        phase = {v.sysid: int(v.phase) for v in vehicles}
        for v in vehicles:
            self.index[v.sysid] = v.index
        a = np.asarray(raw, dtype=float)
        x, y, _ = origin.to_local_many(a[:, 1], a[:, 2], 0.0)
        sysid = a[:, 0].astype(int)
        vi = np.array([self.index.get(s, 0) for s in sysid.tolist()], dtype=np.uint8)
        ph = np.array([phase.get(s, int(Phase.TRANSIT)) for s in sysid.tolist()], dtype=np.uint8)
        return np.asarray(x), np.asarray(y), vi, ph

