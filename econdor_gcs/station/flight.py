"""One vehicle's flight as the ground station saw it, and the report made of it.

:class:`Flight` is what one vehicle did for one mission (its samples, the items it
reached, its trace reports, how the flight ended); :func:`build_report` makes the
:class:`~.core.tasks.FlightReport` the DFC takes. :class:`StatusAssembler` joins STATUSTEXT
chunks into texts, for people. No I/O, no clock: :class:`~.telemetry.StationTelemetry`
fills them from what the vehicles send.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from econdor_gcs.core.tasks import (
    FlightReport,
    OutcomeStatus,
    SampleLog,
    Task,
    TaskOutcome,
    TaskStyle,
    TraceReport,
    TraceTask,
)

__all__ = ["Flight", "StatusAssembler", "build_report"]


class StatusAssembler:
    """Joins STATUSTEXT chunks (MAVLink 2 ``id`` / ``chunk_seq``) into whole texts, for
    people (the live display); nothing the station accounts for reads them.

    A text with ``id == 0`` is complete on its own; a chunked one is complete with a chunk
    shorter than 50 bytes (or an empty terminator). Pending chunks of one id are dropped
    when a new chunk sequence for that id starts at 0.
    """

    def __init__(self) -> None:
        self._parts: dict[tuple[int, int], list[str]] = {}

    def add(self, sysid: int, text: str | bytes, text_id: int = 0, chunk_seq: int = 0,
            raw_len: int | None = None) -> str | None:
        if isinstance(text, bytes | bytearray):
            raw = bytes(text)
            text = raw.decode("utf-8", "replace")
        else:
            raw = text.encode("utf-8")
        text = text.rstrip("\x00")
        full = len(raw.rstrip(b"\x00")) >= 50 if raw_len is None else raw_len >= 50
        if text_id == 0:
            return text
        key = (sysid, text_id)
        if chunk_seq == 0:
            self._parts[key] = []
        parts = self._parts.setdefault(key, [])
        parts.append(text)
        if full:
            return None
        del self._parts[key]
        return "".join(parts)


@dataclass
class Flight:
    """What one vehicle did for one mission, as seen from the ground.

    ``task_seqs[k]`` is the ``(first, last)`` mission seq of task ``k`` (default: one item
    per task from ``first_seq``); ``style`` how its contour pieces were given (trace items,
    or waypoint polylines of the estimated contours).
    """

    index: int
    sysid: int
    tasks: list[Task]
    first_seq: int = 2              # mission seq of the first task (0 home, 1 takeoff)
    task_seqs: list[tuple[int, int]] = field(default_factory=list)
    style: TaskStyle = TaskStyle.TRACE
    start_xy: tuple[float, float] = (0.0, 0.0)
    start_ms: int | None = None
    rows: list[tuple[float, float, float, float, int]] = field(default_factory=list)
    row_seqs: list[int] = field(default_factory=list)
    """Mission item of each row (-1 outside items, :data:`LATE` for a sample that arrived
    after later ones: attributed at the end, by time)."""
    pieces: dict[int, TraceReport] = field(default_factory=dict)
    item_flown_m: dict[int, float] = field(default_factory=dict)
    last_ms: int | None = None
    done: bool = False
    interrupted: str | None = None
    """Why the vehicle left this mission before its end on its own (its failsafe: RTL,
    LAND, a hold, a landing), as its telemetry said; its unfinished tasks are flown again."""
    in_mission: bool = False
    """The vehicle has shown (HEARTBEAT or MISSION_CURRENT) that it flies this mission: a
    mode or state it shows later is news about this flight, not an old message."""
    landed: bool = False
    reached: set[int] = field(default_factory=set)
    """Mission items the vehicle reported reached."""

    def __post_init__(self) -> None:
        if not self.task_seqs:
            self.task_seqs = [(self.first_seq + k, self.first_seq + k)
                              for k in range(len(self.tasks))]
        if len(self.task_seqs) != len(self.tasks):
            raise ValueError(f"{len(self.tasks)} tasks but {len(self.task_seqs)} item ranges")

    @property
    def last_seq(self) -> int:
        return self.task_seqs[-1][1] if self.task_seqs else -1

    def task_at(self, seq: int) -> Task | None:
        """The task mission item ``seq`` belongs to (None for home, takeoff, speed)."""
        for task, (first, last) in zip(self.tasks, self.task_seqs, strict=True):
            if first <= seq <= last:
                return task
        return None


def build_report(flight: Flight) -> FlightReport:
    """One :class:`FlightReport` from what was collected during ``flight``."""
    rows = flight.rows
    if rows:
        a = np.asarray(rows, dtype=float)
        log = SampleLog(a[:, 0].copy(), a[:, 1].copy(), a[:, 2].copy(), a[:, 3].copy(),
                        a[:, 4].astype(np.int8),
                        np.full(len(rows), flight.index, dtype=np.int16))
        xy = np.vstack([np.asarray(flight.start_xy)[None, :], a[:, 1:3]])
        flown = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
        end = (float(a[-1, 1]), float(a[-1, 2]))
    else:
        log = SampleLog()
        flown = 0.0
        end = flight.start_xy
    outcomes: list[TaskOutcome] = []
    flown_on = flight.item_flown_m
    for task, (first, last) in zip(flight.tasks, flight.task_seqs, strict=True):
        item_m = sum(flown_on.get(seq, 0.0) for seq in range(first, last + 1))
        reached = flight.done or last in flight.reached
        if isinstance(task, TraceTask) and flight.style == TaskStyle.WAYPOINTS:
            # the estimated contour, flown as waypoints: along it from the first waypoint on
            along_m = sum(flown_on.get(seq, 0.0) for seq in range(first + 1, last + 1))
            status = OutcomeStatus.REACHED if reached else OutcomeStatus.UNREPORTED
            outcomes.append(TaskOutcome(task, status, item_m, along_m if reached else 0.0))
        elif isinstance(task, TraceTask):
            rep = flight.pieces.get(task.piece_id)
            if rep is None:
                outcomes.append(TaskOutcome(task, OutcomeStatus.UNREPORTED, item_m, 0.0))
            else:
                outcomes.append(TaskOutcome(task, rep.status, rep.flown_m, rep.traced_m))
        else:
            status = OutcomeStatus.REACHED if reached else OutcomeStatus.UNREPORTED
            outcomes.append(TaskOutcome(task, status, item_m))
    traced = float(sum(o.traced_m for o in outcomes))
    sim_s = 0.0
    if flight.start_ms is not None and flight.last_ms is not None:
        sim_s = max(0.0, (flight.last_ms - flight.start_ms) / 1000.0)
    return FlightReport(vehicle=flight.index, samples=log, flown_m=flown, traced_m=traced,
                        outcomes=outcomes, end_x_m=end[0], end_y_m=end[1], sim_s=sim_s)
