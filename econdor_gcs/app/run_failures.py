"""When ``econdor run`` fails part-way: a usable run directory, and one line that says why.

:func:`write_partial` leaves the samples received so far, the metrics and a
``summary.json`` with ``"error"`` (on a full disk, after freeing the space the run held
back); :func:`checked_disk` ends the run at the next flight once a file written as
messages arrive (the tlog, the log) could not be written; :func:`refusals` names the
vehicles whose packets signing refused (a wrong key, no signature).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from econdor_gcs.errors import RunError
from econdor_gcs.files.rundir import RunDir, RunLog, disk_error
from econdor_gcs.link.router import Router
from econdor_gcs.link.tlog import TlogWriter

if TYPE_CHECKING:
    from econdor_gcs.dfc.loop import FlightRecord
    from econdor_gcs.station.executor import MavlinkExecutor

__all__ = ["REFUSALS", "checked_disk", "refusals", "write_partial"]

log = logging.getLogger(__name__)


def checked_disk(rd: RunDir, tlog: TlogWriter, runlog: RunLog
                  ) -> Callable[[FlightRecord], None]:
    """``rd.record_flight``, after checking that every file of the run is still being
    written: a full disk seen first by the tlog or the log (both written as messages arrive,
    where a failure cannot be raised) ends the run here, at the next flight."""
    def record(flight: FlightRecord) -> None:
        error = (disk_error(tlog.path, tlog.error) if tlog.error is not None else
                 RunError(runlog.error) if runlog.error is not None else None)
        if error is not None:
            rd.unwritten.append(flight)  # its samples: the error path writes them
            raise error
        rd.record_flight(flight)

    return record


def write_partial(rd: Any, dfc: Any, executor: MavlinkExecutor | None,
                   base: dict[str, Any], timings: dict[str, float], fill: Any,
                   error: str, disk: Sequence[str] = ()) -> None:
    """Leave a usable run directory after ``error``: the samples still pending, the metrics
    so far, a ``summary.json`` with ``"error"``.

    The space the run held back is freed first (a full disk is a likely ``error``).
    Failures on this path do not hide the original error: each is logged (one line on
    stderr) and listed in the summary's ``"error_path"``, with the files that had stopped
    being written (``disk``).
    """
    problems: list[str] = list(disk)
    try:
        rd.salvage()  # a full disk: the space held back is free now
        for flight in rd.unwritten:  # flights the disk refused: without a flights.jsonl
            for r in flight.reports:  # line, a resume sets them aside
                rd.append_samples(r.samples, flight.iteration)
    except Exception as exc:  # noqa: BLE001 - the run failed already; report, go on
        problems.append(f"the samples of the last flight were not written: {exc}")
        log.exception("econdor: %s", problems[-1])
    if executor is not None:
        try:
            pending = executor.pending_samples()
            if len(pending):
                # an unfinished flight: resume sets these aside (no flights.jsonl line)
                rd.append_samples(pending, executor.iteration)
        except Exception as exc:  # noqa: BLE001 - the run failed already; report, go on
            problems.append(f"the samples still pending were not written: {exc!r}"
                            if not isinstance(exc, RunError) else
                            f"the samples still pending were not written: {exc}")
            log.exception("econdor: %s", problems[-1])
    fill()
    records = list(dfc.records) if dfc is not None else []
    last = records[-1] if records else None
    summary = {
        **base,
        "error": error,
        "iterations": max(0, len(records) - 1),
        "final_mae": last.mae if last else None,
        "final_mae_db": last.mae_db if last else None,
        "span_ratio": last.span_ratio if last else None,
        "flight_distance_m": dfc.flight_m - dfc.return_m if dfc is not None else 0.0,
        "contour_distance_m": dfc.contour_m if dfc is not None else 0.0,
        "samples": sum(len(s) for s in dfc.logs) if dfc is not None else 0,
        "samples_recorded": rd.n_samples,
        "samples_received": getattr(rd, "n_received", None),
        "converged": False,
        "wall_s": timings.get("total_wall_s"),
        "sim_s": timings.get("sim_s", 0.0),
        "timings": timings,
    }
    if executor is not None:
        summary["lost_vehicles"] = executor.losses
        summary["sample_recovery"] = executor.sample_accounting()
    if problems:
        summary["error_path"] = problems
    try:
        rd.write_partial(records, summary)
    except Exception as exc:  # noqa: BLE001 - as above
        log.exception("econdor: the partial summary.json was not written: %r", exc)


REFUSALS = {
    "bad_signature": "its packets are signed with another key",
    "unsigned": "its packets are not signed (this station signs: --signing-key)",
    "replayed": "its packets replay old signing timestamps",
}


def refusals(router: Router) -> str:
    """Why vehicles may not have appeared: the systems whose packets signing refused,
    named with the reason (``; vehicle 2: its packets are signed with another key (31
    refused)``), or nothing."""
    parts = []
    for sysid, counts in sorted(router.parser.refused_by_source().items()):
        if sysid in router.vehicles and counts.keys() == {"replayed"}:
            continue  # a vehicle heard: a few reordered packets are no news
        reason, n = max(counts.items(), key=lambda kv: kv[1])
        parts.append(f"vehicle {sysid}: {REFUSALS[reason]} ({n} refused)")
    return "".join(f"; {p}" for p in parts)
