"""What the DFC asks a vehicle to do, and what comes back.

These types are shared by the in-process executor and the MAVLink layers: a
:class:`TraceTask` becomes one ``MAV_CMD_WAYPOINT_USER_1`` mission item, a
:class:`Waypoint` a ``MAV_CMD_NAV_WAYPOINT``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

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
    """

    level: float
    x_m: float
    y_m: float
    search_radius_m: float
    max_length_m: float
    piece_id: int


Task = Waypoint | TraceTask


class Phase(IntEnum):
    """What a vehicle was doing when it took a sample."""

    TRANSIT = 0
    SEARCH = 1
    TRACE = 2
    SURVEY = 3


@dataclass
class SampleLog:
    """Columns of samples: time (s, sim), position (m), value, phase, vehicle index."""

    t_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    x_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    y_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    value: FloatArray = field(default_factory=lambda: np.zeros(0))
    phase: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    vehicle: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int16))

    def __len__(self) -> int:
        return len(self.x_m)

    @classmethod
    def concat(cls, logs: list[SampleLog]) -> SampleLog:
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


@dataclass
class TaskOutcome:
    """How one task ended, as reported by the vehicle's tracer / navigator."""

    task: Task
    status: str  # "reached" | "closed" | "boundary" | "length_limit" | "not_found" | "lost" | ...
    flown_m: float
    traced_m: float = 0.0


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
