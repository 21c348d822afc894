"""One vehicle's flight as the ground station saw it, and the report made of it.

:class:`Flight` is what one vehicle did for one mission (its samples, the items it
reached, its trace reports, how the flight ended); :func:`settle` puts its samples in
order and decides their phases, :func:`build_report` makes the
:class:`~.core.tasks.FlightReport` the DFC takes. :class:`StatusAssembler` joins STATUSTEXT
chunks into texts, for people. No I/O, no clock: :class:`~.telemetry.StationTelemetry`
fills them from what the vehicles send.

A received sample has no phase until its flight is settled: the vehicle's ``PHASE`` report
that covers it may come after it (a resent range repeats its changes), so its phase is
decided once, at the end, with everything the vehicle said (:func:`decide_phases`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from econdor_gcs.core.tasks import (
    FlightReport,
    OutcomeStatus,
    Phase,
    SampleLog,
    Task,
    TaskOutcome,
    TaskStyle,
    TraceReport,
    TraceTask,
)
from econdor_gcs.link.reports import PhaseTrack

__all__ = ["LATE", "Flight", "StatusAssembler", "build_report", "decide_phases", "settle",
           "settled_samples"]

LATE = -2
"""Mission seq of a sample that arrived after later ones (attributed by time at the end)."""
RECEIVED_COLUMNS = ("time_boot_ms", "x_m", "y_m", "value", "seq")
"""Columns of a batch of received samples (:attr:`Flight.received`): the vehicle's time,
local ENU metres, the value, and the mission item current when it arrived (-1 outside
items, :data:`LATE`)."""


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
    item_phases: dict[int, Phase] = field(default_factory=dict)
    """The phase each item of its mission implies (for a vehicle that reports none)."""
    survey: bool = False
    """The station flies this flight as a survey: its samples are ``Phase.SURVEY``."""
    received: list[np.ndarray] = field(default_factory=list)
    """Batches of samples as received, phase undecided (:data:`RECEIVED_COLUMNS`)."""
    samples: SampleLog = field(default_factory=SampleLog)
    """Its samples in time order with their phases, once :func:`settle` d."""
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


def decide_phases(t_ms: np.ndarray, seqs: np.ndarray, track: PhaseTrack,
                  item_phases: Mapping[int, Phase], survey: bool = False) -> np.ndarray:
    """The phase of each sample, decided once: ``SURVEY`` in a flight the station flies as a
    survey (the vehicle only knows it flies to waypoints); else the phase the vehicle
    reported for the sample's time; else, for a vehicle that reports none (a stock
    autopilot), the one its mission item implies (``TRANSIT`` outside the items).

    >>> t = PhaseTrack(); t.add(1000, Phase.TRACE)
    >>> ms, seqs = np.array([900, 1000]), np.array([2, 3])
    >>> decide_phases(ms, seqs, t, {}).tolist(), decide_phases(ms, seqs, t, {}, True).tolist()
    ([0, 2], [3, 3])
    >>> decide_phases(ms, seqs, PhaseTrack(), {3: Phase.TRACE}).tolist()
    [0, 2]
    """
    if survey:
        return np.full(len(t_ms), Phase.SURVEY, dtype=np.int8)
    if track.known:
        return np.array([track.at(int(t)) for t in t_ms], dtype=np.int8)
    return np.array([item_phases.get(int(s), Phase.TRANSIT) for s in seqs], dtype=np.int8)


def settled_samples(batches: Sequence[np.ndarray], index: int, track: PhaseTrack,
                    item_phases: Mapping[int, Phase], survey: bool = False
                    ) -> tuple[SampleLog, np.ndarray]:
    """Received ``batches`` (:data:`RECEIVED_COLUMNS`) as one vehicle's samples in time order
    (resent ones arrive late), each late one in the mission item of the sample before it,
    every phase decided (:func:`decide_phases`); and the mission item of each."""
    a = np.concatenate(batches) if batches else np.zeros((0, len(RECEIVED_COLUMNS)))
    a = a[np.argsort(a[:, 0], kind="stable")]
    seqs = a[:, 4].astype(np.int64)
    # a late sample takes the item of the sample before it (-1 before any)
    known = np.flatnonzero(seqs != LATE)
    before = np.searchsorted(known, np.arange(len(seqs)), side="right") - 1
    seqs = np.where(before >= 0, seqs[known[np.maximum(before, 0)]] if len(known) else -1, -1)
    phase = decide_phases(a[:, 0], seqs, track, item_phases, survey)
    log = SampleLog(a[:, 0] / 1000.0, a[:, 1].copy(), a[:, 2].copy(), a[:, 3].copy(), phase,
                    np.full(len(a), index, dtype=np.int16))
    return log, seqs


def settle(flight: Flight, track: PhaseTrack) -> None:
    """Make the flight's :attr:`~Flight.samples` of what it received
    (:func:`settled_samples`) and the distance flown per mission item, along the ordered
    path from where the flight began."""
    flight.samples, seqs = settled_samples(flight.received, flight.index, track,
                                           flight.item_phases, flight.survey)
    flight.received = []
    s = flight.samples
    xy = np.vstack([np.asarray(flight.start_xy)[None, :], np.column_stack([s.x_m, s.y_m])])
    steps = np.hypot(*np.diff(xy, axis=0).T)
    flight.item_flown_m = {}
    for seq, step in zip(seqs.tolist(), steps.tolist(), strict=True):
        if seq >= 0:
            flight.item_flown_m[seq] = flight.item_flown_m.get(seq, 0.0) + step


def build_report(flight: Flight) -> FlightReport:
    """One :class:`FlightReport` from what was collected during ``flight`` (settled)."""
    log = flight.samples
    if len(log):
        xy = np.vstack([np.asarray(flight.start_xy)[None, :],
                        np.column_stack([log.x_m, log.y_m])])
        flown = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
        end = (float(log.x_m[-1]), float(log.y_m[-1]))
    else:
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
