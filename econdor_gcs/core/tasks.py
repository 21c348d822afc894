"""What the DFC asks a vehicle to do, and what comes back.

These types are shared by the in-process executor and the MAVLink layers: a
:class:`TraceTask` becomes one ``MAV_CMD_WAYPOINT_USER_1`` mission item (after a
:data:`SENSOR_LAG_COMMAND` item when it carries a sensor lag the one before it did not), a
:class:`Waypoint` a ``MAV_CMD_NAV_WAYPOINT``.

What comes back over MAVLink besides the samples is machine-readable (README, "MAVLink
conventions"): the phase of the samples as ``NAMED_VALUE_INT`` named :data:`PHASE_NAME`, and
the end of each trace item as a :class:`TraceReport` in a ``DEBUG_FLOAT_ARRAY`` named
:data:`TRACE_REPORT_NAME`. This module defines their content; the vehicle and the station
build and read the messages.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntEnum, StrEnum

import numpy as np

from .geometry import FloatArray


@dataclass(frozen=True)
class Waypoint:
    """Fly to ``(x_m, y_m)`` (local ENU metres), sampling on the way."""

    x_m: float
    y_m: float


@dataclass(frozen=True)
class TraceTask:
    """Search for ``level`` near the start point, then trace that iso-line.

    ``max_length_m = 0`` means "until the loop closes (or the boundary is hit on both sides)".
    ``route_m`` is the *estimated* contour piece as a vehicle without the onboard tracer
    would fly it from where it comes (:func:`econdor_gcs.core.waypoints.piece_route`; empty
    when unknown); it takes no part in comparisons. ``sensor_lag_s`` is the sensor lag (s)
    the station corrects the samples for, which the onboard tracer uses for this trace
    (``TracerParams.sensor_lag_s``); None: the tracer's own setting. ``lag_unknown``: the
    sensor lags by an amount the station does not know yet (it estimates the lag and has
    no usable estimate); the tracer traces as with a lag, compensating none
    (``TracerParams.lag_unknown``; ``sensor_lag_s`` is then 0).
    """

    level: float
    x_m: float
    y_m: float
    search_radius_m: float
    max_length_m: float
    piece_id: int
    route_m: tuple[tuple[float, float], ...] = field(default=(), compare=False, repr=False)
    sensor_lag_s: float | None = None
    lag_unknown: bool = False


Task = Waypoint | TraceTask


class TaskStyle(StrEnum):
    """How a vehicle is given a contour piece: a contour item for its onboard tracer
    (``TRACE``), or the estimated piece as a waypoint polyline (``WAYPOINTS``, any autopilot)."""

    TRACE = "trace"
    WAYPOINTS = "waypoints"


class Phase(IntEnum):
    """What a vehicle was doing when it took a sample."""

    TRANSIT = 0
    SEARCH = 1
    TRACE = 2
    SURVEY = 3


SAMPLE_COLUMNS = ("t_s", "x_m", "y_m", "value", "phase", "vehicle")
"""The columns of a :class:`SampleLog`, in the order of its rows."""


@dataclass
class SampleLog:
    """Columns of samples: time (s, sim), position (m), value, phase, vehicle index.

    The one type a sample has from the vehicle to the reconstruction. Its ``phase`` is
    decided once, by whoever makes the log from what the vehicle did (the vehicle's
    reported phase at the sample's time, else the mission item it was flown in, else
    ``SURVEY`` for a flight the station declares a survey); nothing downstream re-tags it.

    A log is indexed like its columns, and the result is a log: ``log[mask]``,
    ``log.take(idx)``, ``log[a:b]`` (a slice shares the columns' memory, as numpy's do).

    >>> log = SampleLog.from_rows([(0.0, 1.0, 2.0, 5.0, 2), (0.1, 1.5, 2.0, 6.0, 0)],
    ...                           vehicle=3)
    >>> len(log), log.vehicle.tolist(), log[log.phase == Phase.TRACE].value.tolist()
    (2, [3, 3], [5.0])
    >>> log.take([1, 1]).t_s.tolist()
    [0.1, 0.1]
    """

    t_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    x_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    y_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    value: FloatArray = field(default_factory=lambda: np.zeros(0))
    phase: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    vehicle: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int16))

    def __post_init__(self) -> None:
        lengths = {c: len(getattr(self, c)) for c in SAMPLE_COLUMNS}
        if len(set(lengths.values())) > 1:
            raise ValueError(f"SampleLog columns differ in length: {lengths}")

    def __len__(self) -> int:
        return len(self.x_m)

    def __getitem__(self, key: slice | np.ndarray | Sequence[int]) -> SampleLog:
        """The samples ``key`` selects: a boolean mask, indices or a slice (a log again;
        one sample ``k`` is ``log[k:k + 1]``)."""
        if isinstance(key, int | np.integer):
            raise TypeError("a SampleLog is indexed by a mask, indices or a slice "
                            "(one sample k: log[k:k + 1])")
        if not isinstance(key, slice):
            key = np.asarray(key)
            if key.dtype != bool:
                key = key.astype(np.intp)
        return SampleLog(*(getattr(self, c)[key] for c in SAMPLE_COLUMNS))

    def take(self, idx: np.ndarray | Sequence[int]) -> SampleLog:
        """The samples at the indices ``idx``, in that order."""
        return self[np.asarray(idx, dtype=np.intp)]

    def copy(self) -> SampleLog:
        """A log with its own columns."""
        return SampleLog(*(getattr(self, c).copy() for c in SAMPLE_COLUMNS))

    @classmethod
    def from_rows(cls, rows: np.ndarray | Sequence[Sequence[float]],
                  vehicle: int | None = None) -> SampleLog:
        """A log of ``rows`` ``(t_s, x_m, y_m, value, phase[, vehicle])``; ``vehicle``
        (the vehicle index of every row) stands for the sixth column."""
        a = np.asarray(rows, dtype=float).reshape(-1, 5 if vehicle is not None else 6) \
            if len(rows) else np.zeros((0, 6))
        vehicles = np.full(len(a), vehicle, dtype=np.int16) if vehicle is not None \
            else a[:, 5].astype(np.int16)
        return cls(a[:, 0].copy(), a[:, 1].copy(), a[:, 2].copy(), a[:, 3].copy(),
                   a[:, 4].astype(np.int8), vehicles)

    @classmethod
    def concat(cls, logs: Sequence[SampleLog]) -> SampleLog:
        if not logs:
            return cls()
        return cls(
            t_s=np.concatenate([s.t_s for s in logs]),
            x_m=np.concatenate([s.x_m for s in logs]),
            y_m=np.concatenate([s.y_m for s in logs]),
            value=np.concatenate([s.value for s in logs]),
            phase=np.concatenate([s.phase for s in logs]).astype(np.int8),
            vehicle=np.concatenate([s.vehicle for s in logs]).astype(np.int16),
        )


class OutcomeStatus(StrEnum):
    """How a task ended.

    ``REACHED`` ends a waypoint (``UNREACHABLE`` when its generous time budget ran out
    first); a trace ends ``CLOSED`` (the loop closed), ``BOUNDARY`` (the
    area boundary was reached on both sides), ``LENGTH_LIMIT``, ``NOT_FOUND`` (the search
    failed) or ``LOST``. ``UNREPORTED`` is the station's word for an outcome that never
    arrived; it has no wire code.

    >>> OutcomeStatus("closed").code, OutcomeStatus.from_code(2)
    (1, <OutcomeStatus.BOUNDARY: 'boundary'>)
    """

    REACHED = "reached"
    UNREACHABLE = "unreachable"
    CLOSED = "closed"
    BOUNDARY = "boundary"
    LENGTH_LIMIT = "length_limit"
    NOT_FOUND = "not_found"
    LOST = "lost"
    UNREPORTED = "unreported"

    @property
    def code(self) -> int:
        """The status in a :class:`TraceReport` (ValueError for ``UNREPORTED``)."""
        try:
            return _STATUS_CODES[self]
        except KeyError:
            raise ValueError(f"{self.value!r} has no wire code") from None

    @classmethod
    def from_code(cls, code: int) -> OutcomeStatus:
        for status, c in _STATUS_CODES.items():
            if c == code:
                return status
        raise ValueError(f"unknown outcome status code {code}")


_STATUS_CODES = {
    OutcomeStatus.REACHED: 0, OutcomeStatus.CLOSED: 1, OutcomeStatus.BOUNDARY: 2,
    OutcomeStatus.LENGTH_LIMIT: 3, OutcomeStatus.NOT_FOUND: 4, OutcomeStatus.LOST: 5,
    OutcomeStatus.UNREACHABLE: 6,
}


@dataclass(init=False)
class TaskOutcome:
    """How one task ended, as reported by the vehicle's tracer / navigator.

    ``status`` may be given as its string value; it is stored as an :class:`OutcomeStatus`
    (an unknown status is a ValueError).
    """

    task: Task
    status: OutcomeStatus
    flown_m: float
    traced_m: float = 0.0

    def __init__(self, task: Task, status: str, flown_m: float, traced_m: float = 0.0) -> None:
        self.task = task
        self.status = OutcomeStatus(status)
        self.flown_m = flown_m
        self.traced_m = traced_m


PHASE_NAME = "PHASE"
"""``NAMED_VALUE_INT.name`` of a phase change: ``value`` is the :class:`Phase` of the samples
from ``time_boot_ms`` on (the time of the first sample in the new phase)."""

TRACE_REPORT_NAME = "TRACE"
"""``DEBUG_FLOAT_ARRAY.name`` of a :class:`TraceReport` (``array_id`` = mission item seq)."""

# Sample recovery (README, "No sample lost"): two commands, sent as COMMAND_INT so the
# times are exact integers (x = first, y = last time_boot_ms of a range, both included).
SAMPLE_COUNT_COMMAND = 31010
"""``MAV_CMD_USER_1``: how many samples did you take in [x, y] ms? COMMAND_ACK ACCEPTED with
``result_param2`` = the count.

>>> from pymavlink.dialects.v20 import common
>>> (SAMPLE_COUNT_COMMAND, SAMPLE_RESEND_COMMAND, TRACE_RESEND_COMMAND,
...  SENSOR_LAG_COMMAND) == (common.MAV_CMD_USER_1, common.MAV_CMD_USER_2,
...                          common.MAV_CMD_USER_3, common.MAV_CMD_USER_4)
True
"""
SAMPLE_RESEND_COMMAND = 31011
"""``MAV_CMD_USER_2``: send the samples of [x, y] ms again (the same GLOBAL_POSITION_INT +
NAMED_VALUE_FLOAT pairs, with the PHASE changes of the range). COMMAND_ACK ACCEPTED with
``result_param2`` = how many will follow, or DENIED if that is more than
:data:`SAMPLE_RESEND_MAX` (ask for a smaller range)."""
SAMPLE_RESEND_MAX = 400
"""Most samples one resend request may ask for."""
TRACE_RESEND_COMMAND = 31012
"""``MAV_CMD_USER_3``: send the TRACE reports of [x, y] ms again (by the report's sim time);
COMMAND_ACK ACCEPTED with ``result_param2`` = how many follow."""
SENSOR_LAG_COMMAND = 31013
"""``MAV_CMD_USER_4``, a mission item (a DO command, no position): the onboard tracer takes
``param1`` as the sensor lag (s, >= 0) from this item on, in this mission and later ones,
until an item tells it another (:attr:`TraceTask.sensor_lag_s`). Only a vehicle whose
tracer runs on board (a companion computer) accepts it, as it accepts the contour item."""


@dataclass(frozen=True)
class TraceReport:
    """A vehicle's final word on one trace item.

    On the wire: ``DEBUG_FLOAT_ARRAY`` named :data:`TRACE_REPORT_NAME`, ``array_id`` = the
    item's mission seq, ``data[0:5]`` = piece id, :attr:`OutcomeStatus.code`, traced metres,
    flown metres (transit and search included), level. Floats are float32 on the wire: ids
    are exact below 2**24, distances to about 7 digits.

    >>> r = TraceReport(3, 1002, OutcomeStatus.BOUNDARY, 120.5, 150.25, 42.0)
    >>> TraceReport.from_array(3, r.to_array()) == r
    True
    """

    seq: int
    piece_id: int
    status: OutcomeStatus
    traced_m: float
    flown_m: float
    level: float = math.nan

    def to_array(self) -> list[float]:
        return [float(self.piece_id), float(self.status.code), float(self.traced_m),
                float(self.flown_m), float(self.level)]

    @classmethod
    def from_array(cls, seq: int, data: Sequence[float]) -> TraceReport:
        """Decode ``data``; ValueError names what is wrong with it."""
        if len(data) < 5:
            raise ValueError(f"trace report of item {seq}: {len(data)} values, expected 5")
        piece, code, traced, flown, level = (float(v) for v in data[:5])
        if not (math.isfinite(piece) and piece == int(piece) and math.isfinite(code)
                and code == int(code)):
            raise ValueError(f"trace report of item {seq}: piece id {piece!r} and status "
                             f"code {code!r} must be integers")
        if not (math.isfinite(traced) and math.isfinite(flown) and traced >= 0 and flown >= 0):
            raise ValueError(f"trace report of item {seq}: distances must be finite and "
                             f">= 0, got {traced!r}, {flown!r}")
        return cls(int(seq), int(piece), OutcomeStatus.from_code(int(code)), traced, flown,
                   level)


@dataclass
class FlightReport:
    """Everything one vehicle did for one plan."""

    vehicle: int
    samples: SampleLog
    flown_m: float
    traced_m: float
    outcomes: list[TaskOutcome]
    end_x_m: float
    end_y_m: float
    sim_s: float
