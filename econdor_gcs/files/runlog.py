"""The run's log lines (``log.jsonl``): what the DFC, the vehicles, the station and the
operator said, kept in memory for the live page and written as they come."""

from __future__ import annotations

import contextlib
import json
import math
import threading
import time
from dataclasses import asdict, dataclass
from enum import StrEnum
from pathlib import Path
from typing import IO

from econdor_gcs.dfc.loop import DfcEvent, IterationDone, IterationPlanned, RunDone, RunStarted
from econdor_gcs.files.layout import disk_error, writing

__all__ = ["LogLine", "RunLog", "Severity", "read_log"]



class Severity(StrEnum):
    INFO = "info"
    WARNING = "warning"
    ERROR = "error"


@dataclass(frozen=True)
class LogLine:
    """One line of ``log.jsonl``."""

    wall_s: float
    """Seconds since the run started (wall clock)."""
    iteration: int
    """The iteration running (or planned) when the line was written."""
    source: str
    """``dfc``, ``station``, ``operator`` or ``vehicle N`` (N: system id)."""
    severity: Severity
    text: str


def _describe(event: DfcEvent) -> str:
    """One log line for a DFC progress event."""
    if isinstance(event, RunStarted):
        return (f"run started: planner {event.planner}, seed {event.seed}, "
                f"{event.vehicles} vehicles")
    if isinstance(event, IterationPlanned):
        b = event.batch
        flying = sum(1 for p in event.plans if p)
        levels = f"{len(b.levels)} levels (κ {b.kappa}, δ {b.delta:.3g}), " if len(b.levels) else ""
        return (f"iteration {event.iteration} planned: {levels}{len(b.jobs)} jobs for "
                f"{flying} vehicles")
    if isinstance(event, IterationDone):
        r = event.record
        mae = f"MAE {r.mae_db:.1f} dB, " if math.isfinite(r.mae_db) else ""
        le = f"learning error {r.learning_error:.3g}, " if math.isfinite(r.learning_error) else ""
        return (f"iteration {r.iteration} done: {mae}{le}flown {r.flight_distance_m:.0f} m, "
                f"{r.samples} samples")
    assert isinstance(event, RunDone)
    s = event.summary
    return (f"run finished ({s.get('stop_reason')}): {s.get('iterations')} iterations, "
            f"flown {s.get('flight_distance_m', 0.0):.0f} m")


class RunLog:
    """The run's log lines: kept in memory for the live page and appended to ``log.jsonl``.

    Thread-safe: lines come from the DFC thread (progress), the station's loop (vehicle
    STATUSTEXT), the web server (operator actions) and ``logging``.
    """

    def __init__(self, path: str | Path | None = None) -> None:
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self._lines: list[LogLine] = []
        self.path = None if path is None else Path(path)
        self._file: IO[str] | None = None
        self.error: str | None = None
        """Why ``log.jsonl`` stopped being written (a full disk...); the lines are still kept
        in memory, for the live page."""
        if self.path is not None:
            with writing(self.path):
                self._file = self.path.open("w", encoding="utf-8")
        self.iteration = 0

    def add(self, source: str, text: str, severity: Severity = Severity.INFO) -> LogLine:
        with self._lock:
            line = LogLine(round(time.monotonic() - self._t0, 3), self.iteration, source,
                           severity, text)
            self._lines.append(line)
            if self._file is not None and not self._file.closed:
                try:
                    self._file.write(json.dumps(asdict(line), ensure_ascii=False) + "\n")
                    self._file.flush()
                except OSError as exc:
                    # lines come from every thread (a vehicle's text on the station's loop):
                    # a full disk must not break them; the run reports it (``error``)
                    self.error = str(disk_error(self.path, exc))
                    with contextlib.suppress(OSError):
                        self._file.close()
        return line

    def progress(self, event: DfcEvent) -> None:
        """A DFC progress callback: one line per event."""
        if isinstance(event, IterationPlanned):
            self.iteration = event.iteration
        self.add("dfc", _describe(event))

    def since(self, n: int) -> list[LogLine]:
        """Lines from the ``n``-th on (a reader's cursor is the count it has seen)."""
        with self._lock:
            return self._lines[n:]

    def __len__(self) -> int:
        with self._lock:
            return len(self._lines)

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()


def read_log(path: str | Path) -> list[LogLine]:
    """Load ``log.jsonl`` (a torn last line of a killed run is skipped)."""
    out: list[LogLine] = []
    p = Path(path)
    if not p.exists():
        return out
    for text in p.read_text(encoding="utf-8").splitlines():
        try:
            d = json.loads(text)
            out.append(LogLine(float(d["wall_s"]), int(d["iteration"]), str(d["source"]),
                               Severity(d["severity"]), str(d["text"])))
        except (json.JSONDecodeError, KeyError, ValueError, TypeError):
            continue
    return out
