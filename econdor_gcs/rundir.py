"""The run directory (DESIGN.md §5): everything a run produced, written as it goes.

Layout::

    run.json          how the run was started (planner, seed, vehicles, ...): what --resume reads
    mission.yaml      the mission file the run was started with (resume and vehicles read it)
    summary.json      planner, iterations, final_mae, ..., vehicles (see RunResult.summary)
    metrics.csv       one row per iteration (IterationRecord.CSV_COLUMNS)
    iterations.json   the full per-iteration records (levels, dropped levels, outcomes)
    samples.csv       every sample a vehicle took: t_s, x_m, y_m, value, phase, vehicle,
                      iteration (appended and flushed before the DFC uses them)
    flights.jsonl     one line per finished flight (plans, outcomes, distances, positions):
                      the checkpoint a resumed run replays; samples.csv rows of an iteration
                      without its line here belong to an interrupted flight
    fields.npz        grid_x, grid_y, estimate, truth (if known)
    telemetry.tlog    MAVLink runs only
    missions/         missions sent (MAVLink runs), exports
    figures/          PNG figures (econdor report RUN_DIR redraws them)

A run directory is never clobbered: a non-empty one is refused unless the run is started
with ``--force`` (:attr:`RunDirMode.FORCE`: an earlier *run* directory is replaced) or
``--resume`` (:attr:`RunDirMode.RESUME`: it is continued).
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
from dataclasses import asdict
from enum import StrEnum
from pathlib import Path
from typing import IO, Any

import numpy as np

from .core.tasks import FlightReport, SampleLog, Task, TaskOutcome, TraceTask, Waypoint
from .dfc import FlightRecord, IterationRecord, RunResult
from .errors import RunError

SAMPLE_COLUMNS = ("t_s", "x_m", "y_m", "value", "phase", "vehicle", "iteration")
RUN_FILES = ("run.json", "summary.json", "samples.csv", "metrics.csv", "flights.jsonl",
             "telemetry.tlog")
"""Files that only a run directory has (``--force`` replaces only such a directory)."""


class RunDirMode(StrEnum):
    """What to do with an existing, non-empty run directory."""

    NEW = "new"
    """Refuse it (the default: nothing of an earlier run is ever overwritten silently)."""
    FORCE = "force"
    """Replace it, if it is a run directory."""
    RESUME = "resume"
    """Continue it: samples and flights are appended."""


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


def _sync(f: IO[Any]) -> None:
    f.flush()
    os.fsync(f.fileno())


def prepare_run_dir(path: Path, mode: RunDirMode) -> None:
    """Check ``path`` against ``mode`` (see :class:`RunDirMode`); for ``FORCE`` empty it.

    Raises :class:`RunError` with one line naming the directory and the way out.
    """
    if path.exists() and not path.is_dir():
        raise RunError(f"{path}: exists and is not a directory")
    busy = path.is_dir() and any(path.iterdir())
    if mode == RunDirMode.RESUME:
        if not (path / "run.json").is_file():
            raise RunError(f"{path}: nothing to resume (no run.json: not a run directory, or a "
                           "run from before resume existed)")
        return
    if not busy:
        return
    if mode == RunDirMode.NEW:
        raise RunError(f"{path}: not empty (an earlier run?); use --force to replace it or "
                       "--resume to continue it")
    if not any((path / name).exists() for name in RUN_FILES):
        raise RunError(f"{path}: not empty and not a run directory; refusing to replace it "
                       "even with --force")
    shutil.rmtree(path)


class RunDir:
    """Creates and fills a run directory. Samples are appended as they arrive.

    Parameters
    ----------
    path:
        The directory.
    mode:
        :class:`RunDirMode`; ``NEW`` refuses a non-empty directory.
    """

    def __init__(self, path: str | Path, mode: RunDirMode = RunDirMode.NEW) -> None:
        self.path = Path(path)
        self.mode = RunDirMode(mode)
        prepare_run_dir(self.path, self.mode)
        self.path.mkdir(parents=True, exist_ok=True)
        (self.path / "figures").mkdir(exist_ok=True)
        (self.path / "missions").mkdir(exist_ok=True)
        self.samples_path = self.path / "samples.csv"
        self.flights_path = self.path / "flights.jsonl"
        self.n_samples = 0
        self.interrupted_samples = 0
        resume = self.mode == RunDirMode.RESUME and self.samples_path.exists()
        if resume:
            self.n_samples, self.interrupted_samples = self._set_aside_interrupted()
        self._samples_file = self.samples_path.open("a" if resume else "w", newline="",
                                                    encoding="utf-8")
        self._writer = csv.writer(self._samples_file)
        if not resume:
            self._writer.writerow(SAMPLE_COLUMNS)
        self._samples_file.flush()
        self._flights_file = self.flights_path.open("a" if resume else "w", encoding="utf-8")

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
    def append_samples(self, log: SampleLog, iteration: int) -> None:
        """Append ``log`` (taken in ``iteration``) and flush it to the OS."""
        for row in zip(log.t_s, log.x_m, log.y_m, log.value, log.phase, log.vehicle,
                       strict=True):
            self._writer.writerow((repr(float(row[0])), repr(float(row[1])), repr(float(row[2])),
                                   repr(float(row[3])), int(row[4]), int(row[5]), iteration))
        self.n_samples += len(log)
        self._samples_file.flush()

    def record_flight(self, record: FlightRecord) -> None:
        """Samples first, then the flight's line: a line in ``flights.jsonl`` means its
        samples are on disk (both synced)."""
        for r in record.reports:
            self.append_samples(r.samples, record.iteration)
        _sync(self._samples_file)
        self._flights_file.write(json.dumps(flight_to_json(record), allow_nan=False) + "\n")
        _sync(self._flights_file)

    def write_run_config(self, config: dict[str, Any], mission_text: str | None) -> None:
        """``run.json`` (and ``mission.yaml``): what ``--resume`` needs to start again."""
        if mission_text is not None:
            (self.path / "mission.yaml").write_text(mission_text, encoding="utf-8")
        write_json(self.path / "run.json", config)

    def write_metrics(self, records: list[IterationRecord]) -> None:
        with (self.path / "metrics.csv").open("w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=IterationRecord.CSV_COLUMNS)
            w.writeheader()
            for r in records:
                w.writerow(r.csv_row())
        write_json(self.path / "iterations.json", [asdict(r) for r in records])

    def write_result(self, result: RunResult, extra: dict[str, Any] | None = None) -> None:
        self.write_metrics(result.records)
        summary = result.summary()
        summary["samples_recorded"] = self.n_samples
        if extra:
            summary.update(extra)
        write_json(self.path / "summary.json", summary)
        arrays: dict[str, Any] = {"grid_x": result.grid.x, "grid_y": result.grid.y,
                                  "estimate": result.estimate}
        if result.truth is not None:
            arrays["truth"] = result.truth
        np.savez_compressed(self.path / "fields.npz", **arrays)

    def write_partial(self, records: list[IterationRecord], summary: dict[str, Any]) -> None:
        """What to leave behind when a run fails part-way."""
        self.write_metrics(records)
        write_json(self.path / "summary.json", summary)

    def close(self) -> None:
        for f in (self._samples_file, self._flights_file):
            if not f.closed:
                f.close()


# --------------------------------------------------------------------------------------------
# flights.jsonl: the checkpoint


def _task_to_json(task: Task) -> dict[str, Any]:
    kind = "trace" if isinstance(task, TraceTask) else "waypoint"
    return {"kind": kind, **asdict(task)}


def _task_from_json(d: dict[str, Any]) -> Task:
    d = dict(d)
    kind = d.pop("kind")
    return TraceTask(**d) if kind == "trace" else Waypoint(**d)


def flight_to_json(record: FlightRecord) -> dict[str, Any]:
    """One ``flights.jsonl`` line (samples are in ``samples.csv``, counted here).

    Floats are written with ``repr`` precision, so a resumed run reads back exactly what
    the interrupted one computed with.
    """
    return {
        "iteration": record.iteration,
        "plans": [[_task_to_json(t) for t in plan] for plan in record.plans],
        "positions_before_m": [list(p) for p in record.positions_before_m],
        "executor_state": record.executor_state,
        "reports": [{
            "vehicle": r.vehicle, "samples": len(r.samples), "flown_m": r.flown_m,
            "traced_m": r.traced_m, "end_x_m": r.end_x_m, "end_y_m": r.end_y_m,
            "sim_s": r.sim_s,
            "outcomes": [{"task": _task_to_json(o.task), "status": o.status,
                          "flown_m": o.flown_m, "traced_m": o.traced_m} for o in r.outcomes],
        } for r in record.reports],
    }


def read_flight_lines(path: Path) -> list[dict[str, Any]]:
    """The complete lines of ``flights.jsonl`` (a torn last line from a crash is ignored)."""
    if not path.exists():
        return []
    out = []
    with path.open(encoding="utf-8") as f:
        for line in f:
            if not line.endswith("\n"):
                break  # written but never finished: that flight did not finish either
            out.append(json.loads(line))
    return out


def read_checkpoint(run_dir: str | Path) -> list[FlightRecord]:
    """The finished flights of a run directory, with their samples, for a resumed run."""
    run_dir = Path(run_dir)
    lines = read_flight_lines(run_dir / "flights.jsonl")
    samples = _read_sample_rows(run_dir / "samples.csv")
    records = []
    for d in lines:
        it = d["iteration"]
        mine = samples[samples[:, 6] == it] if len(samples) else samples
        reports = []
        for r in d["reports"]:
            rows = mine[mine[:, 5] == r["vehicle"]] if len(mine) else mine
            if len(rows) != r["samples"]:
                raise RunError(f"{run_dir}: iteration {it}, vehicle {r['vehicle']}: "
                               f"{len(rows)} samples on disk, {r['samples']} recorded")
            log = SampleLog(rows[:, 0].copy(), rows[:, 1].copy(), rows[:, 2].copy(),
                            rows[:, 3].copy(), rows[:, 4].astype(np.int8),
                            rows[:, 5].astype(np.int16)) if len(rows) else SampleLog()
            outcomes = [TaskOutcome(_task_from_json(o["task"]), o["status"], o["flown_m"],
                                    o["traced_m"]) for o in r["outcomes"]]
            reports.append(FlightReport(r["vehicle"], log, r["flown_m"], r["traced_m"],
                                        outcomes, r["end_x_m"], r["end_y_m"], r["sim_s"]))
        records.append(FlightRecord(
            iteration=it,
            plans=[[_task_from_json(t) for t in plan] for plan in d["plans"]],
            reports=reports,
            positions_before_m=[(float(p[0]), float(p[1])) for p in d["positions_before_m"]],
            executor_state=d.get("executor_state")))
    return records


def _read_sample_rows(path: Path) -> np.ndarray:
    if not path.exists():
        return np.zeros((0, len(SAMPLE_COLUMNS)))
    a = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return a if a.size else np.zeros((0, len(SAMPLE_COLUMNS)))


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
    """Load ``samples.csv`` back into a SampleLog."""
    a = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if a.size == 0:
        return SampleLog()
    return SampleLog(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4].astype(np.int8),
                     a[:, 5].astype(np.int16))


def read_metrics(path: str | Path) -> list[dict[str, float]]:
    with Path(path).open(encoding="utf-8") as f:
        return [{k: float(v) if v not in ("", "nan") else math.nan for k, v in row.items()}
                for row in csv.DictReader(f)]
