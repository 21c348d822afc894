"""The run's own log (``log.jsonl``) fed from the station: the plumbing
:func:`econdor_gcs.app.run.run_mission` wraps a run in."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator

from econdor_gcs.files.runlog import RunLog, Severity
from econdor_gcs.link.codec import MAVLinkMessage, mavlink
from econdor_gcs.link.router import (
    ComponentDiscovered,
    ForeignVehicle,
    Received,
    Router,
    TwinRefused,
    VehicleDiscovered,
    VehicleLost,
    VehicleMoved,
    VehicleRecovered,
)
from econdor_gcs.link.vehicles import EVENTS
from econdor_gcs.station.flight import StatusAssembler


def log_station(router: Router, runlog: RunLog) -> None:
    """Vehicles' STATUSTEXT (chunks joined), discoveries, losses and recoveries into the
    run's log."""

    assembler = StatusAssembler()

    def on_message(sysid: int, msg: MAVLinkMessage) -> None:
        if msg.get_type() != "STATUSTEXT":
            return
        raw = bytes(msg.text) if isinstance(msg.text, bytes | bytearray) else \
            msg.text.encode("utf-8", "replace")
        text = assembler.add(sysid, raw, getattr(msg, "id", 0), getattr(msg, "chunk_seq", 0))
        if text is None:
            return
        sev = (Severity.ERROR if msg.severity <= mavlink.MAV_SEVERITY_ERROR else
               Severity.WARNING if msg.severity == mavlink.MAV_SEVERITY_WARNING else
               Severity.INFO)
        runlog.add(f"vehicle {sysid}", text, sev)

    def on_event(event: object) -> None:
        if isinstance(event, VehicleLost):
            runlog.add(f"vehicle {event.sysid}", f"lost: no heartbeat for {event.silent_s:.0f} s",
                       Severity.ERROR)
        elif isinstance(event, VehicleRecovered):
            runlog.add(f"vehicle {event.sysid}", "heard again", Severity.WARNING)
        elif isinstance(event, VehicleDiscovered):
            runlog.add(f"vehicle {event.sysid}", f"discovered at {event.address[0]}:"
                                                 f"{event.address[1]}")
        elif isinstance(event, ComponentDiscovered):
            runlog.add(f"vehicle {event.sysid}", f"component {event.compid} (MAV_TYPE "
                                                 f"{event.mav_type}) at {event.address[0]}:"
                                                 f"{event.address[1]}")
        elif isinstance(event, TwinRefused):
            runlog.add(f"vehicle {event.sysid}", f"refused a second source of its autopilot at "
                                                 f"{event.address[0]}:{event.address[1]} (a twin: "
                                                 f"the vehicle speaks from {event.known[0]}:"
                                                 f"{event.known[1]}; first message "
                                                 f"{event.message})", Severity.ERROR)
        elif isinstance(event, ForeignVehicle):
            runlog.add(f"vehicle {event.sysid}", f"not in this run's fleet: its messages from "
                                                 f"{event.address[0]}:{event.address[1]} are "
                                                 f"dropped (first {event.message})",
                       Severity.WARNING)
        elif isinstance(event, VehicleMoved):
            runlog.add(f"vehicle {event.sysid}", f"now speaks from {event.new[0]}:{event.new[1]} "
                                                 f"(was {event.old[0]}:{event.old[1]})",
                       Severity.WARNING)

    router.subscribe(Received, lambda r: on_message(r.sysid, r.msg))
    router.subscribe(EVENTS, on_event)


class RunLogHandler(logging.Handler):
    """Station warnings (``logging``, ``econdor_gcs.*``) into the run's log."""

    def __init__(self, runlog: RunLog) -> None:
        super().__init__(logging.WARNING)
        self.runlog = runlog

    def emit(self, record: logging.LogRecord) -> None:
        sev = Severity.ERROR if record.levelno >= logging.ERROR else Severity.WARNING
        try:
            self.runlog.add("station", record.getMessage(), sev)
        except (OSError, ValueError):  # the log file is gone or closed: say so, on stderr
            self.handleError(record)


@contextlib.contextmanager
def logging_to(runlog: RunLog) -> Iterator[None]:
    logger = logging.getLogger("econdor_gcs")
    handler = RunLogHandler(runlog)
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)
