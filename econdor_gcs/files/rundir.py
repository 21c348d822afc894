"""The run directory (DESIGN.md §5): everything a run produced, written as it goes.

Layout::

    run.json          how the run was started (planner, seed, vehicles, ...): what --resume reads
    mission.yaml      the mission file the run was started with (resume and vehicles read it)
    summary.json      planner, iterations, final_mae, ..., vehicles (see RunResult.summary)
    metrics.csv       one row per iteration (IterationRecord.CSV_COLUMNS); rewritten after
                      every iteration, so a partial run has the rows it finished
    iterations.json   the full per-iteration records (levels, dropped levels, outcomes;
                      ``samples`` = rows of samples.csv up to the end of that iteration)
    iterations/       iter_NNN.npz per iteration (MAVLink runs; see ITERATION_ARRAYS)
    samples.csv       every sample a vehicle took: t_s, x_m, y_m, value, phase, vehicle,
                      iteration (appended and flushed before the DFC uses them)
    flights.jsonl     one line per finished flight (plans, outcomes, distances, positions):
                      the checkpoint a resumed run replays; samples.csv rows of an iteration
                      without its line here belong to an interrupted flight
    fields.npz        grid_x, grid_y, estimate, truth (if known)
    log.jsonl         the run's log lines (DFC progress, vehicles' STATUSTEXT, station
                      warnings, operator actions), one JSON object per line (LogLine)
    telemetry.tlog    MAVLink runs only
    missions/         missions sent (MAVLink runs), exports
    figures/          PNG figures (econdor report RUN_DIR redraws them)

``iterations/`` and ``log.jsonl`` are what ``econdor view RUN_DIR`` replays, iteration by
iteration, without anything else; they are small (the estimate as float32, compressed:
about 40 kB per iteration on a 101 x 101 grid).

A run directory is never clobbered: a non-empty one is refused unless the run is started
with ``--force`` (:attr:`RunDirMode.FORCE`: what an earlier run wrote there is deleted, and
a file no run writes makes it refuse, naming the file) or ``--resume``
(:attr:`RunDirMode.RESUME`: it is continued). What a run writes and how a failed write is
reported live in :mod:`.rundir_files`, the log lines in :mod:`.runlog`, the checkpoint
(``flights.jsonl``) in :mod:`.checkpoint`; all are re-exported here. The file by file
description for users is ``docs/run-directory.md``.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from econdor_gcs.core.geometry import FloatArray, Grid
from econdor_gcs.core.planners import Batch
from econdor_gcs.core.tasks import SampleLog, Task, TraceTask, Waypoint
from econdor_gcs.dfc.loop import (
    DfcEvent,
    FlightRecord,
    IterationDone,
    IterationPlanned,
    IterationRecord,
    RunResult,
)
from econdor_gcs.errors import RunError
from econdor_gcs.files.checkpoint import flight_to_json as flight_to_json
from econdor_gcs.files.checkpoint import read_checkpoint as read_checkpoint
from econdor_gcs.files.checkpoint import read_flight_lines as read_flight_lines
from econdor_gcs.files.layout import RESERVE_NAME as RESERVE_NAME
from econdor_gcs.files.layout import RUN_FILES as RUN_FILES
from econdor_gcs.files.layout import RUN_WRITTEN as RUN_WRITTEN
from econdor_gcs.files.layout import RunDirMode as RunDirMode
from econdor_gcs.files.layout import disk_error as disk_error
from econdor_gcs.files.layout import foreign_files as foreign_files
from econdor_gcs.files.layout import prepare_run_dir as prepare_run_dir
from econdor_gcs.files.layout import writing as writing
from econdor_gcs.files.runlog import LogLine as LogLine
from econdor_gcs.files.runlog import RunLog as RunLog
from econdor_gcs.files.runlog import Severity as Severity
from econdor_gcs.files.runlog import read_log as read_log

SAMPLE_COLUMNS = ("t_s", "x_m", "y_m", "value", "phase", "vehicle", "iteration")
RESERVE_BYTES = 2 << 20
"""Disk space a run holds back for its last words when the disk fills up
(:meth:`RunDir.release_reserve`): ``summary.json``, metrics and the samples in memory take
a few hundred kB."""
RECEIVED_COLUMNS = ("t_s", "x_m", "y_m", "value", "phase", "vehicle", "iteration")
"""``samples_received.csv``: every sample as it arrived (see :meth:`RunDir.journal`)."""


UNRECORDED = -2
"""The iteration of samples appended outside a recorded flight (an observer's copy)."""



def _clean(obj: Any) -> Any:
    """JSON-safe: NaN/inf -> None, numpy scalars -> Python."""
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_json(path: Path, data: Any) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(_clean(data), indent=2, allow_nan=False) + "\n", encoding="utf-8")
    tmp.replace(path)


# -- what each iteration planned -----------------------------------------------------------


@dataclass(frozen=True)
class PlannedPiece:
    """What one vehicle was sent to fly in an iteration.

    A contour piece (``piece_id >= 0``): the estimated iso-line at ``level`` the tracer
    was sent to, as a polyline. A survey or pattern leg (``piece_id == -1``, ``level`` NaN):
    the vehicle's consecutive waypoints.
    """

    vehicle: int
    """Vehicle index (0-based, the order of ``summary.json`` ``sysids``)."""
    piece_id: int
    level: float
    points_m: FloatArray
    """Shape (k, 2): x, y in local metres."""


def planned_pieces(batch: Batch, plans: list[list[Task]]) -> list[PlannedPiece]:
    """Each vehicle's contour pieces and waypoint legs from an iteration's batch and plans.

    >>> from econdor_gcs.core.planners import Batch
    >>> from econdor_gcs.core.tasks import Waypoint
    >>> [p.points_m.tolist() for p in planned_pieces(
    ...     Batch([], 0), [[Waypoint(0, 0), Waypoint(0, 10)], []])]
    [[[0.0, 0.0], [0.0, 10.0]]]
    """
    outline = {j.tasks[0].piece_id: j.piece.points_m for j in batch.jobs
               if j.piece is not None and j.tasks and isinstance(j.tasks[0], TraceTask)}
    out: list[PlannedPiece] = []
    for vehicle, tasks in enumerate(plans):
        legs: list[tuple[float, float]] = []
        for task in [*tasks, None]:
            if isinstance(task, Waypoint):
                legs.append((task.x_m, task.y_m))
                continue
            if legs:
                out.append(PlannedPiece(vehicle, -1, math.nan, np.asarray(legs, dtype=float)))
                legs = []
            if isinstance(task, TraceTask):
                pts = outline.get(task.piece_id, np.array([[task.x_m, task.y_m]]))
                out.append(PlannedPiece(vehicle, task.piece_id, task.level,
                                        np.asarray(pts, dtype=float)))
    return out


ITERATION_ARRAYS = {
    "iteration": "int, the iteration (0 = the initiation)",
    "grid_x": "float64 (nx,), grid node eastings (m)",
    "grid_y": "float64 (ny,), grid node northings (m)",
    "estimate": "float32 (ny, nx), the estimate after the iteration",
    "piece_vehicle": "int16 (k,), vehicle index of each planned piece",
    "piece_id": "int32 (k,), piece id (-1: waypoint legs)",
    "piece_level": "float32 (k,), contour level (NaN: waypoint legs)",
    "piece_offsets": "int32 (k + 1,), piece i is piece_xy[offsets[i]:offsets[i + 1]]",
    "piece_xy": "float32 (n, 2), the pieces' points (m)",
}
"""The arrays of ``iterations/iter_NNN.npz`` (compressed)."""


@dataclass(frozen=True)
class IterationFrame:
    """One iteration as stored in ``iterations/iter_NNN.npz``."""

    iteration: int
    grid_x: FloatArray
    grid_y: FloatArray
    estimate: FloatArray
    pieces: list[PlannedPiece]


def write_iteration(path: Path, frame: IterationFrame) -> None:
    """Write one frame (atomically: a reader never sees half a file)."""
    offsets = np.cumsum([0] + [len(p.points_m) for p in frame.pieces]).astype(np.int32)
    xy = (np.concatenate([p.points_m for p in frame.pieces]) if frame.pieces
          else np.zeros((0, 2)))
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as f:
        np.savez_compressed(
            f, iteration=np.int64(frame.iteration),
            grid_x=np.asarray(frame.grid_x, dtype=float),
            grid_y=np.asarray(frame.grid_y, dtype=float),
            estimate=np.asarray(frame.estimate, dtype=np.float32),
            piece_vehicle=np.array([p.vehicle for p in frame.pieces], dtype=np.int16),
            piece_id=np.array([p.piece_id for p in frame.pieces], dtype=np.int32),
            piece_level=np.array([p.level for p in frame.pieces], dtype=np.float32),
            piece_offsets=offsets, piece_xy=xy.astype(np.float32))
    tmp.replace(path)


def read_iteration(path: str | Path) -> IterationFrame:
    """Load one ``iterations/iter_NNN.npz``."""
    with np.load(path) as z:
        off = z["piece_offsets"]
        xy = z["piece_xy"].astype(float)
        pieces = [PlannedPiece(int(v), int(i), float(lv), xy[off[k]:off[k + 1]])
                  for k, (v, i, lv) in enumerate(zip(z["piece_vehicle"], z["piece_id"],
                                                     z["piece_level"], strict=True))]
        return IterationFrame(int(z["iteration"]), z["grid_x"], z["grid_y"],
                              z["estimate"].astype(float), pieces)


def iteration_paths(run_dir: str | Path) -> dict[int, Path]:
    """``iterations/iter_NNN.npz`` of a run directory by iteration number."""
    folder = Path(run_dir) / "iterations"
    out: dict[int, Path] = {}
    for p in sorted(folder.glob("iter_*.npz")):
        try:
            out[int(p.stem.removeprefix("iter_"))] = p
        except ValueError:
            continue  # not one of ours
    return out


# -- the directory -----------------------------------------------------------------------------


def _sync(f: IO[Any]) -> None:
    f.flush()
    os.fsync(f.fileno())


class RunDir:
    """Creates and fills a run directory. Samples are appended as they arrive.

    Parameters
    ----------
    path:
        The directory.
    mode:
        :class:`RunDirMode`; ``NEW`` refuses a non-empty directory.
    grid:
        With a grid, :meth:`progress` (a DFC progress callback) also keeps
        ``metrics.csv`` / ``iterations.json`` current after every iteration and writes
        ``iterations/iter_NNN.npz``.
    received:
        Keep ``samples_received.csv``, the journal of samples as they arrive
        (:meth:`journal`; a run over MAVLink).
    """

    def __init__(self, path: str | Path, mode: RunDirMode = RunDirMode.NEW,
                 grid: Grid | None = None, received: bool = False) -> None:
        self.path = Path(path)
        self.mode = RunDirMode(mode)
        self.grid = grid
        self._records: list[IterationRecord] = []
        self._pieces: dict[int, list[PlannedPiece]] = {}
        self.write_s = 0.0
        """Wall time spent in :meth:`progress` (on the DFC thread)."""
        prepare_run_dir(self.path, self.mode)
        self.samples_path = self.path / "samples.csv"
        self.flights_path = self.path / "flights.jsonl"
        self.received_path = self.path / "samples_received.csv"
        self.n_samples = 0
        self.n_received = 0
        self.interrupted_samples = 0
        with writing(self.path):
            self.path.mkdir(parents=True, exist_ok=True)
            self._reserve_space()
            (self.path / "figures").mkdir(exist_ok=True)
            (self.path / "missions").mkdir(exist_ok=True)
            resume = self.mode == RunDirMode.RESUME and self.samples_path.exists()
            if resume:
                self.n_samples, self.interrupted_samples = self._set_aside_interrupted()
            self._samples_file = self.samples_path.open("a" if resume else "w", newline="",
                                                        encoding="utf-8")
            self._writer = csv.writer(self._samples_file)
            if not resume:
                self._writer.writerow(SAMPLE_COLUMNS)
            self._samples_file.flush()
            self._good = (os.fstat(self._samples_file.fileno()).st_size, self.n_samples)
            self._flights_file = self.flights_path.open("a" if resume else "w",
                                                        encoding="utf-8")
            self._received_file: IO[str] | None = None
            if received:
                journal_exists = self.received_path.exists()
                self._received_file = self.received_path.open("a", newline="",
                                                              encoding="utf-8")
                self._received = csv.writer(self._received_file)
                if not journal_exists:
                    self._received.writerow(RECEIVED_COLUMNS)
                    self._received_file.flush()
        self.journal_error: str | None = None
        """Why ``samples_received.csv`` stopped being written (the run fails on it)."""
        self.unwritten: list[FlightRecord] = []
        """Flights whose recording failed (a full disk): the error path writes their
        samples once it has freed the space held back."""

    # -- the space held back ----------------------------------------------------------------
    def _reserve_space(self) -> None:
        """Hold :data:`RESERVE_BYTES` back in :data:`RESERVE_NAME`: when the disk fills up,
        the failing run frees it (:meth:`release_reserve`) and still writes its
        ``summary.json``, metrics and the samples it has in memory."""
        with (self.path / RESERVE_NAME).open("wb") as f:
            f.write(bytes(RESERVE_BYTES))  # written, so its blocks are taken

    def release_reserve(self) -> None:
        """Give the held-back space to the error path (and to nobody else: once)."""
        with contextlib.suppress(FileNotFoundError):
            (self.path / RESERVE_NAME).unlink()

    # -- resume ---------------------------------------------------------------------------------
    def _set_aside_interrupted(self) -> tuple[int, int]:
        """Move the samples of flights that never finished to ``samples_interrupted.csv``
        (kept, not used); return (samples kept, samples set aside)."""
        done = {rec["iteration"] for rec in read_flight_lines(self.flights_path)}
        with self.samples_path.open(newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
        if not rows or tuple(rows[0]) != SAMPLE_COLUMNS:
            raise RunError(f"{self.samples_path}: not a samples file of this version "
                           f"(columns {', '.join(SAMPLE_COLUMNS)})")
        keep = [r for r in rows[1:] if r and int(r[6]) in done]
        aside = [r for r in rows[1:] if r and int(r[6]) not in done]
        if aside:
            target = self.path / "samples_interrupted.csv"
            new = not target.exists()
            with target.open("a", newline="", encoding="utf-8") as f:
                w = csv.writer(f)
                if new:
                    w.writerow(SAMPLE_COLUMNS)
                w.writerows(aside)
                _sync(f)
        tmp = self.samples_path.with_suffix(".csv.tmp")
        with tmp.open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(SAMPLE_COLUMNS)
            w.writerows(keep)
            _sync(f)
        tmp.replace(self.samples_path)
        return len(keep), len(aside)

    # -- writing --------------------------------------------------------------------------------
    def append_samples(self, log: SampleLog, iteration: int = UNRECORDED) -> None:
        """Append ``log`` (taken in ``iteration``) and flush it to the OS."""
        with writing(self.samples_path):
            for row in zip(log.t_s, log.x_m, log.y_m, log.value, log.phase, log.vehicle,
                           strict=True):
                self._writer.writerow((repr(float(row[0])), repr(float(row[1])),
                                       repr(float(row[2])), repr(float(row[3])), int(row[4]),
                                       int(row[5]), iteration))
            self._samples_file.flush()
            self.n_samples += len(log)
            self._good = (os.fstat(self._samples_file.fileno()).st_size, self.n_samples)

    def salvage(self) -> None:
        """After a failed write (a full disk): ``samples.csv`` back to its last complete
        flush (no torn row, and the rows that would not go out are not left in a buffer to
        go out twice), then the space held back freed for the error path's writes."""
        with contextlib.suppress(OSError):  # its buffer would not go out: dropped here
            self._samples_file.close()
        size, n = self._good
        with contextlib.suppress(OSError):
            os.truncate(self.samples_path, size)
            self.n_samples = n
        self.release_reserve()
        with writing(self.samples_path):
            self._samples_file = self.samples_path.open("a", newline="", encoding="utf-8")
            self._writer = csv.writer(self._samples_file)

    def journal(self, rows: Sequence[tuple[float, float, float, float, int]], vehicle: int,
                iteration: int) -> None:
        """Append samples as they arrive to ``samples_received.csv`` and flush it: a batch
        of one vehicle's rows ``(t_s, x_m, y_m, value, phase)`` (the phase as known on
        arrival), taken in ``iteration``. Nothing received is lost even if the station
        dies before the flight ends; ``samples.csv`` gets the same samples again, in time
        order with their final phase, when the flight is over.

        Called on the station's loop thread: a failure is kept in :attr:`journal_error`
        (the run fails on it at the next flight) rather than raised into the link."""
        if self.journal_error is not None or self._received_file is None \
                or self._received_file.closed:
            return
        try:
            for t, x, y, value, phase in rows:
                self._received.writerow((repr(t), repr(x), repr(y), repr(value), phase,
                                         vehicle, iteration))
            self._received_file.flush()
            self.n_received += len(rows)
        except OSError as exc:
            self.journal_error = str(disk_error(self.received_path, exc))

    def record_flight(self, record: FlightRecord) -> None:
        """Samples first, then the flight's line: a line in ``flights.jsonl`` means its
        samples are on disk (both synced)."""
        try:
            if self.journal_error is not None:
                raise RunError(self.journal_error)
            for r in record.reports:
                self.append_samples(r.samples, record.iteration)
        except RunError:
            self.unwritten.append(record)
            raise
        with writing(self.flights_path):
            _sync(self._samples_file)
            self._flights_file.write(json.dumps(flight_to_json(record), allow_nan=False)
                                     + "\n")
            _sync(self._flights_file)

    def write_run_config(self, config: dict[str, Any], mission_text: str | None) -> None:
        """``run.json`` (and ``mission.yaml``): what ``--resume`` needs to start again."""
        with writing(self.path / "run.json"):
            if mission_text is not None:
                (self.path / "mission.yaml").write_text(mission_text, encoding="utf-8")
            write_json(self.path / "run.json", config)

    def progress(self, event: DfcEvent) -> None:
        """DFC progress callback: per-iteration files as soon as an iteration is done."""
        t0 = time.perf_counter()
        if isinstance(event, IterationPlanned):
            self._pieces[event.iteration] = planned_pieces(event.batch, event.plans)
        elif isinstance(event, IterationDone):
            it = event.record.iteration
            self._records.append(event.record)
            self.write_metrics(self._records)
            if self.grid is not None:
                folder = self.path / "iterations"
                path = folder / f"iter_{it:03d}.npz"
                with writing(path):
                    folder.mkdir(exist_ok=True)
                    write_iteration(path, IterationFrame(
                        it, self.grid.x, self.grid.y, event.estimate,
                        self._pieces.pop(it, [])))
        self.write_s += time.perf_counter() - t0

    def write_metrics(self, records: list[IterationRecord]) -> None:
        with writing(self.path / "metrics.csv"), \
                (self.path / "metrics.csv").open("w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=IterationRecord.CSV_COLUMNS)
            w.writeheader()
            for r in records:
                w.writerow(r.csv_row())
        with writing(self.path / "iterations.json"):
            write_json(self.path / "iterations.json", [asdict(r) for r in records])

    def write_result(self, result: RunResult, extra: dict[str, Any] | None = None) -> None:
        self.write_metrics(result.records)
        summary = result.summary()
        summary["samples_recorded"] = self.n_samples
        if extra:
            summary.update(extra)
        with writing(self.path / "summary.json"):
            write_json(self.path / "summary.json", summary)
        arrays: dict[str, Any] = {"grid_x": result.grid.x, "grid_y": result.grid.y,
                                  "estimate": result.estimate}
        if result.truth is not None:
            arrays["truth"] = result.truth
        with writing(self.path / "fields.npz"):
            np.savez_compressed(self.path / "fields.npz", **arrays)

    def write_partial(self, records: list[IterationRecord], summary: dict[str, Any]) -> None:
        """What to leave behind when a run fails part-way (``summary.json`` first: the
        metrics can be rebuilt from ``iterations/``, the reason cannot)."""
        with writing(self.path / "summary.json"):
            write_json(self.path / "summary.json", summary)
        self.write_metrics(records)

    def close(self) -> None:
        for f in (self._samples_file, self._flights_file, self._received_file):
            if f is not None and not f.closed:
                with contextlib.suppress(OSError):  # a full disk: reported where it happened
                    f.close()
        self.release_reserve()


def read_run_config(run_dir: str | Path) -> dict[str, Any]:
    """``run.json`` of a run directory (one clear error if it is missing or damaged)."""
    path = Path(run_dir) / "run.json"
    try:
        config = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RunError(f"{run_dir}: nothing to resume (no run.json)") from None
    except (OSError, ValueError) as exc:
        raise RunError(f"{path}: cannot read it ({exc})") from None
    if not isinstance(config, dict):
        raise RunError(f"{path}: not a run configuration")
    return config


def read_samples(path: str | Path) -> SampleLog:
    """Load ``samples.csv`` back into a SampleLog (empty when it has only its header).

    A last line without its newline is a row still being written (a run in progress, or
    one killed mid-write): it is left out.
    """
    with Path(path).open(encoding="utf-8") as f:
        f.readline()  # the header
        rows = f.read()
    if rows and not rows.endswith("\n"):
        rows = rows[: rows.rfind("\n") + 1]
    if not rows.strip():
        return SampleLog()
    a = np.loadtxt(io.StringIO(rows), delimiter=",", ndmin=2)
    return SampleLog(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4].astype(np.int8),
                     a[:, 5].astype(np.int16))


def read_metrics(path: str | Path) -> list[dict[str, float]]:
    with Path(path).open(encoding="utf-8") as f:
        return [{k: float(v) if v not in ("", "nan") else math.nan for k, v in row.items()}
                for row in csv.DictReader(f)]
