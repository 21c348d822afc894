"""``flights.jsonl``: the checkpoint a resumed run replays (one line per finished flight,
its samples in ``samples.csv``)."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from econdor_gcs.core.tasks import FlightReport, SampleLog, TaskOutcome
from econdor_gcs.dfc.loop import FlightRecord
from econdor_gcs.errors import RunError
from econdor_gcs.files.plans import task_from_json, task_to_json

__all__ = ["flight_to_json", "read_checkpoint", "read_flight_lines"]

SAMPLE_COLUMNS = ("t_s", "x_m", "y_m", "value", "phase", "vehicle", "iteration")


def flight_to_json(record: FlightRecord) -> dict[str, Any]:
    """One ``flights.jsonl`` line (samples are in ``samples.csv``, counted here).

    Floats are written with ``repr`` precision, so a resumed run reads back exactly what
    the interrupted one computed with.
    """
    return {
        "iteration": record.iteration,
        "plans": [[task_to_json(t) for t in plan] for plan in record.plans],
        "positions_before_m": [list(p) for p in record.positions_before_m],
        "executor_state": record.executor_state,
        "reports": [{
            "vehicle": r.vehicle, "samples": len(r.samples), "flown_m": r.flown_m,
            "traced_m": r.traced_m, "end_x_m": r.end_x_m, "end_y_m": r.end_y_m,
            "sim_s": r.sim_s,
            "outcomes": [{"task": task_to_json(o.task), "status": o.status,
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
        where = f"{run_dir / 'flights.jsonl'}: iteration {it}"
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
            at = f"{where}, vehicle {r['vehicle']}, outcomes"
            outcomes = [TaskOutcome(task_from_json(o["task"], f"{at}[{k}].task"), o["status"],
                                    o["flown_m"], o["traced_m"])
                        for k, o in enumerate(r["outcomes"])]
            reports.append(FlightReport(r["vehicle"], log, r["flown_m"], r["traced_m"],
                                        outcomes, r["end_x_m"], r["end_y_m"], r["sim_s"]))
        records.append(FlightRecord(
            iteration=it,
            plans=[[task_from_json(t, f"{where}, plans[{v}][{k}]") for k, t in enumerate(plan)]
                   for v, plan in enumerate(d["plans"])],
            reports=reports,
            positions_before_m=[(float(p[0]), float(p[1])) for p in d["positions_before_m"]],
            executor_state=d.get("executor_state")))
    return records


def _read_sample_rows(path: Path) -> np.ndarray:
    if not path.exists():
        return np.zeros((0, len(SAMPLE_COLUMNS)))
    with path.open(encoding="utf-8") as f:
        f.readline()  # the header
        rows = f.read()
    if not rows.strip():
        return np.zeros((0, len(SAMPLE_COLUMNS)))
    return np.loadtxt(io.StringIO(rows), delimiter=",", ndmin=2)
