"""What a DFC run produces and tells as it goes, and how an estimate is scored against
the truth.

:class:`IterationRecord` (a row of ``metrics.csv``), :class:`FlightRecord` (a flight as the
run directory keeps it and a resumed run replays it), :class:`RunResult`, the progress
events a run sends (:data:`DfcEvent`) and the checkpoint it asks (:data:`Checkpoint`); and
the truth-only scores (:func:`isoline_levels`, :func:`isoline_errors`). The loop that makes
them is :mod:`.loop`; the run directory, the displays and the studies read them. Truth is
used here for scoring only, never for planning.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from econdor_gcs.core import metrics
from econdor_gcs.core.geometry import FloatArray, Grid
from econdor_gcs.core.planners import Batch
from econdor_gcs.core.tasks import FlightReport, SampleLog, Task

__all__ = [
    "FINISH",
    "Checkpoint",
    "DfcEvent",
    "FlightRecord",
    "IterationDone",
    "IterationPlanned",
    "IterationRecord",
    "Progress",
    "RunDone",
    "RunResult",
    "RunStarted",
    "isoline_errors",
    "isoline_levels",
]


@dataclass
class IterationRecord:
    """One row of ``metrics.csv`` (DESIGN.md §5)."""

    iteration: int
    levels_planned: int
    levels_traced: int
    kappa: int
    delta: float
    learning_error: float
    mae: float
    mae_db: float
    span_ratio: float
    contour_distance_m: float
    flight_distance_m: float
    samples: int
    mae_rel: float = math.nan
    sim_s: float = 0.0
    reconstruction_s: float = 0.0
    levels: list[float] = field(default_factory=list)
    dropped: list[float] = field(default_factory=list)
    pieces: int = 0
    outcomes: dict[str, int] = field(default_factory=dict)
    isoline_error_m: dict[str, float] = field(default_factory=dict)
    forced: int = 0
    noise_std: float = math.nan
    """The samples' noise as this iteration's reconstruction estimated it (field units; 0:
    taken as exact and interpolated; the previous iteration's when nothing new was flown)."""
    lag_s: float = math.nan
    """The sensor lag (s) the station corrected this iteration's samples for: the mission's
    when known (0 when none is corrected), its estimate from the samples when
    ``lag_correction`` is ``estimate`` (NaN until the crossovers tell)."""
    noise_floor: float = 0.0
    """The learning error the samples' noise alone would make in this iteration (0 for
    exact samples; :func:`~econdor_gcs.core.stopping.noise_floor`)."""
    span_noise: float = 0.0
    """What the noise may move the estimate's span by in this iteration."""

    CSV_COLUMNS = (
        "iteration", "levels_planned", "levels_traced", "kappa", "delta", "learning_error",
        "mae", "mae_db", "span_ratio", "contour_distance_m", "flight_distance_m", "samples",
    )

    def csv_row(self) -> dict[str, Any]:
        d = asdict(self)
        return {k: d[k] for k in self.CSV_COLUMNS}


FINISH = -1
"""The iteration number of the flight home (:meth:`Executor.finish`) in flight records."""


@dataclass
class FlightRecord:
    """One flight of the executor as the run directory keeps it (``flights.jsonl`` plus the
    samples in ``samples.csv``); a resumed run replays these instead of flying again.

    ``positions_before_m`` are the vehicle positions the flight was planned from;
    ``executor_state`` is what an executor with ``state()`` / ``restore(state)`` (the
    in-process one) needs to continue exactly where it was after the flight.
    """

    iteration: int
    plans: list[list[Task]]
    reports: list[FlightReport]
    positions_before_m: list[tuple[float, float]]
    executor_state: dict[str, Any] | None = None


@dataclass
class RunResult:
    planner: str
    seed: int
    records: list[IterationRecord]
    samples: SampleLog
    grid: Grid
    estimate: FloatArray
    truth: FloatArray | None
    converged: bool
    stop_reason: str
    vehicles: int
    sim_s: float
    wall_s: float
    reconstruction_s: float
    flight_distance_m: float
    contour_distance_m: float
    isoline_error_m: dict[str, float] = field(default_factory=dict)
    mission: dict[str, Any] = field(default_factory=dict)
    return_m: float = 0.0
    """Flight home after the last iteration: flown, but behind no estimate, so neither in
    ``flight_distance_m`` nor in any record's (``total_flown_m`` has it)."""
    starved_iterations: int = 0
    """Iterations that sampled too little and so did not count against ``max_iterations``
    (``algorithm.max_starved_iterations``)."""

    @property
    def total_flown_m(self) -> float:
        """Everything flown: ``flight_distance_m`` and the flight home."""
        return self.flight_distance_m + self.return_m

    def summary(self) -> dict[str, Any]:
        last = self.records[-1] if self.records else None
        return {
            "planner": self.planner,
            "seed": self.seed,
            "iterations": max(0, len(self.records) - 1),  # after the initiation (row 0)
            "starved_iterations": self.starved_iterations,
            "final_mae": last.mae if last else math.nan,
            "final_mae_db": last.mae_db if last else math.nan,
            "final_mae_rel": last.mae_rel if last else math.nan,
            "span_ratio": last.span_ratio if last else math.nan,
            "flight_distance_m": self.flight_distance_m,
            "return_m": self.return_m,
            "total_flown_m": self.total_flown_m,
            "contour_distance_m": self.contour_distance_m,
            "samples": len(self.samples),
            "converged": self.converged,
            "stop_reason": self.stop_reason,
            "wall_s": self.wall_s,
            "sim_s": self.sim_s,
            "reconstruction_s": self.reconstruction_s,
            "noise_std": last.noise_std if last else math.nan,
            "lag_s": last.lag_s if last else math.nan,
            "vehicles": self.vehicles,
            "isoline_error_m": self.isoline_error_m,
            **self.mission,
        }


# -- progress events --------------------------------------------------------------------------


@dataclass(frozen=True)
class RunStarted:
    planner: str
    seed: int
    vehicles: int


@dataclass(frozen=True)
class IterationPlanned:
    """A batch is about to be flown: its levels, and each vehicle's task list."""

    iteration: int
    batch: Batch
    plans: list[list[Task]]


@dataclass(frozen=True)
class IterationDone:
    """An iteration was flown and re-estimated (row ``record`` of metrics.csv)."""

    record: IterationRecord
    estimate: FloatArray


@dataclass(frozen=True)
class RunDone:
    summary: dict[str, Any]


DfcEvent = RunStarted | IterationPlanned | IterationDone | RunDone
Progress = Callable[[DfcEvent], None]
Checkpoint = Callable[[int], bool]
"""Asked between iterations with the number of the next one: ``True`` flies it, ``False``
stops the run (the vehicles are then brought home). It may block, e.g. while an operator
has paused the run (:class:`econdor_gcs.dfc.control.RunControl`)."""


def isoline_levels(truth: FloatArray, fractions: tuple[float, ...] = (0.25, 0.5, 0.75)
                   ) -> list[float]:
    """The levels at ``fractions`` of the true field's span."""
    lo, hi = float(np.min(truth)), float(np.max(truth))
    return [lo + f * (hi - lo) for f in fractions]


def isoline_errors(truth: FloatArray, estimate: FloatArray, grid: Grid,
                   targets: Sequence[float] = ()) -> dict[str, float]:
    """Iso-line error (m) at 25, 50 and 75 % of the true span; with target levels also
    the error at each (``target@L``) and their mean (``target``), and the true iso-line
    pieces missed (``target@L_missed``; all levels: ``target_missed`` of
    ``target_pieces``)."""
    out = {f"p{frac}": metrics.isoline_error(truth, estimate, grid, lv)
           for frac, lv in zip((25, 50, 75), isoline_levels(truth), strict=True)}
    if targets:
        errs = [metrics.isoline_error(truth, estimate, grid, lv) for lv in targets]
        missed = [metrics.isoline_components_missed(truth, estimate, grid, lv)
                  for lv in targets]
        finite = [e for e in errs if not math.isnan(e)]
        out["target"] = sum(finite) / len(finite) if finite else math.nan
        for lv, e, (m, _n) in zip(targets, errs, missed, strict=True):
            out[f"target@{lv:g}"] = e
            out[f"target@{lv:g}_missed"] = float(m)
        out["target_missed"] = float(sum(m for m, _ in missed))
        out["target_pieces"] = float(sum(n for _, n in missed))
    return out
