"""The run directory (DESIGN.md §5): everything a run produced, written as it goes.

Layout::

    summary.json      planner, iterations, final_mae, ..., vehicles (see RunResult.summary)
    metrics.csv       one row per iteration (IterationRecord.CSV_COLUMNS)
    iterations.json   the full per-iteration records (levels, dropped levels, outcomes)
    samples.csv       every sample: t_s, x_m, y_m, value, phase, vehicle (appended live)
    fields.npz        grid_x, grid_y, estimate, truth (if known)
    telemetry.tlog    MAVLink runs only
    missions/         missions sent (MAVLink runs), exports
    figures/          PNG figures (econdor report RUN_DIR redraws them)
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from .core.tasks import SampleLog
from .dfc import IterationRecord, RunResult

SAMPLE_COLUMNS = ("t_s", "x_m", "y_m", "value", "phase", "vehicle")


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


class RunDir:
    """Creates and fills a run directory. Samples are appended as they arrive."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.mkdir(parents=True, exist_ok=True)
        (self.path / "figures").mkdir(exist_ok=True)
        (self.path / "missions").mkdir(exist_ok=True)
        self.samples_path = self.path / "samples.csv"
        self._samples_file = self.samples_path.open("w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._samples_file)
        self._writer.writerow(SAMPLE_COLUMNS)
        self._samples_file.flush()
        self.n_samples = 0

    def append_samples(self, log: SampleLog) -> None:
        for row in zip(log.t_s, log.x_m, log.y_m, log.value, log.phase, log.vehicle,
                       strict=True):
            self._writer.writerow((f"{row[0]:.3f}", f"{row[1]:.3f}", f"{row[2]:.3f}",
                                   f"{row[3]:.6g}", int(row[4]), int(row[5])))
        self.n_samples += len(log)
        self._samples_file.flush()

    def write_metrics(self, records: list[IterationRecord]) -> None:
        with (self.path / "metrics.csv").open("w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=IterationRecord.CSV_COLUMNS)
            w.writeheader()
            for r in records:
                w.writerow(r.csv_row())
        from dataclasses import asdict

        write_json(self.path / "iterations.json", [asdict(r) for r in records])

    def write_result(self, result: RunResult, extra: dict[str, Any] | None = None) -> None:
        self.write_metrics(result.records)
        summary = result.summary()
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
        if not self._samples_file.closed:
            self._samples_file.close()


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
