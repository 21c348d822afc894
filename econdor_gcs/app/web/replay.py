"""The page of a finished (or partial) run, from its run directory alone (``econdor view``).

Reads ``iterations.json`` (or ``metrics.csv``), ``iterations/iter_NNN.npz``,
``samples.csv``, ``log.jsonl`` and ``summary.json``; a run directory written before
``iterations/`` existed still shows its curves, paths and log, with the final estimate
from ``fields.npz`` as the last iteration's frame.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from econdor_gcs.app.web import messages
from econdor_gcs.app.web.feed import Cursor
from econdor_gcs.app.web.messages import Message
from econdor_gcs.core.tasks import SampleLog
from econdor_gcs.errors import ControlError, WebError
from econdor_gcs.files.rundir import iteration_paths, read_iteration, read_log, read_metrics, read_samples


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise WebError(f"{path}: cannot read ({exc})") from None


class ReplayFeed:
    """The :class:`~.feed.Feed` of a run directory; the page's slider asks for frames."""

    def __init__(self, run_dir: str | Path) -> None:
        self.path = Path(run_dir)
        if not self.path.is_dir():
            raise WebError(f"{self.path}: no such run directory")
        recs_path = self.path / "iterations.json"
        if recs_path.exists():
            self.records: list[dict[str, Any]] = _read_json(recs_path)
        elif (self.path / "metrics.csv").exists():
            self.records = [dict(r) for r in read_metrics(self.path / "metrics.csv")]
        else:
            raise WebError(f"{self.path}: not a run directory (no iterations.json or metrics.csv)")
        summary_path = self.path / "summary.json"
        self.summary: dict[str, Any] = _read_json(summary_path) if summary_path.exists() else {}
        try:
            self.samples = (read_samples(self.path / "samples.csv")
                            if (self.path / "samples.csv").exists() else SampleLog())
        except ValueError as exc:
            raise WebError(f"{self.path / 'samples.csv'}: cannot read ({exc})") from None
        self.lines = read_log(self.path / "log.jsonl")
        self.frame_paths = iteration_paths(self.path)
        self._frames: dict[int, Message] = {}

    def _region(self) -> dict[str, float]:
        region = self.summary.get("region")
        if isinstance(region, dict) and {"xmin", "xmax", "ymin", "ymax"} <= set(region):
            return {k: float(region[k]) for k in ("xmin", "xmax", "ymin", "ymax")}
        if self.frame_paths:
            f = read_iteration(next(iter(self.frame_paths.values())))
            return {"xmin": float(f.grid_x[0]), "xmax": float(f.grid_x[-1]),
                    "ymin": float(f.grid_y[0]), "ymax": float(f.grid_y[-1])}
        if len(self.samples):
            s = self.samples
            return {"xmin": float(np.min(s.x_m)), "xmax": float(np.max(s.x_m)),
                    "ymin": float(np.min(s.y_m)), "ymax": float(np.max(s.y_m))}
        raise WebError(f"{self.path}: cannot tell the mission area (no summary.json region, "
                       f"no iterations/, no samples)")

    def hello(self) -> Message:
        s = self.summary
        truth = s.get("truth_known", any(
            r.get("mae") is not None and not (isinstance(r.get("mae"), float)
                                              and math.isnan(r["mae"]))
            for r in self.records))
        return messages.hello(
            "replay", mission=str(s.get("mission", self.path.name)),
            planner=str(s.get("planner", "")), region=self._region(),
            vehicles=[int(v) for v in s.get("sysids", [])], controls=False,
            truth_known=bool(truth), max_iterations=None, run_dir=str(self.path))

    def frame(self, iteration: int) -> Message | None:
        if iteration in self._frames:
            return self._frames[iteration]
        path = self.frame_paths.get(iteration)
        if path is not None:
            f = read_iteration(path)
            msg = messages.frame(f.iteration, f.grid_x, f.grid_y, f.estimate, f.pieces)
        else:
            last = self.records[-1]["iteration"] if self.records else None
            fields = self.path / "fields.npz"
            if iteration != last or not fields.exists():
                return None
            with np.load(fields) as z:  # a run without iterations/: its final estimate
                msg = messages.frame(iteration, z["grid_x"], z["grid_y"], z["estimate"], [])
        self._frames[iteration] = msg
        return msg

    def control(self, action: str) -> Message:
        raise ControlError("a replay has no controls")

    def updates(self, cursor: Cursor) -> list[Message]:
        """Everything at once on the first call; nothing after (a replay does not change)."""
        if cursor.done:
            return []
        out: list[Message] = []
        if self.records:  # the last frame before the records: the page shows it at once
            msg = self.frame(int(self.records[-1]["iteration"]))
            if msg is not None:
                out.append(msg)
        out.append(messages.records(self.records))
        if len(self.samples):
            out.append(messages.samples(self.samples))
        if self.lines:
            out.append(messages.log(self.lines))
        out.append(messages.done(self.summary))
        cursor.done = True
        return out
