"""The missions the station gives each vehicle: planned, saved, uploaded.

:class:`VehicleMissions` is a part of :class:`~.executor.MavlinkExecutor`: per vehicle and
flight, the tasks become a mission "item 0 home, takeoff, DO_CHANGE_SPEED, the tasks"
(:func:`~.link.mission.plan_mission`), saved in the run directory and uploaded; a vehicle
that refuses a contour (trace) item, or the sensor lag item that goes before one, gets the
estimated contours as waypoint polylines from then on, and an upload whose answers were lost
starts again (:data:`UPLOAD_ATTEMPTS`). The mission area is uploaded to every vehicle as its
geofence. Like the rest of the executor, this runs on the station's loop thread.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
from collections.abc import Sequence
from pathlib import Path

from econdor_gcs.config import Mission
from econdor_gcs.core.tasks import Task, TaskStyle, TraceTask
from econdor_gcs.errors import MissionRejected, ProtocolError, RunError, VehicleTimeout
from econdor_gcs.files.autopilot_files import write_wpl
from econdor_gcs.link.codec import mavlink
from econdor_gcs.link.items import (
    MAV_CMD_WAYPOINT_USER_1,
    SENSOR_LAG_COMMAND,
    MissionItemSpec,
    command_name,
    plan_mission,
)
from econdor_gcs.link.router import Router
from econdor_gcs.station.flight import Flight
from econdor_gcs.station.losses import SILENT_S, VehicleLosses
from econdor_gcs.station.status import VehicleStatus
from econdor_gcs.station.telemetry import StationTelemetry, VehicleState

__all__ = ["VehicleMissions", "mission_items_json"]

log = logging.getLogger(__name__)

UPLOAD_ATTEMPTS = 3
"""Uploads of one mission to a vehicle that says no transfer is running (MAV_MISSION_RESULT
INVALID_SEQUENCE, ArduPilot: ERROR) or that gave up on it (ERROR, ArduPilot:
OPERATION_CANCELLED after 8 s of its time without an item): its answer to an earlier item
was lost, or the station was too slow for a vehicle running faster than real time; and
uploads that ran out of answers while the vehicle heartbeats."""
RESTART_RESULTS = frozenset({mavlink.MAV_MISSION_INVALID_SEQUENCE, mavlink.MAV_MISSION_ERROR,
                             mavlink.MAV_MISSION_OPERATION_CANCELLED})
"""MISSION_ACK results after which the upload starts again from MISSION_COUNT."""


def mission_items_json(items: Sequence[MissionItemSpec]) -> str:
    return json.dumps([dataclasses.asdict(it) for it in items], indent=1) + "\n"


class VehicleMissions:
    """Plans, saves and uploads each vehicle's missions, and its geofence (a part of
    :class:`~.executor.MavlinkExecutor`, on the station's loop thread).

    Parameters
    ----------
    router:
        The station's router: the mission transfers.
    telemetry:
        The vehicles' state; a flight begins there when its mission is planned.
    losses:
        Asked whether any vehicle is left when an upload times out.
    mission:
        Origin, altitude and cruise speed of the missions.
    missions_dir, timeout_s, tolerance_m:
        As for :class:`~.executor.MavlinkExecutor`.
    home:
        Item 0 of the missions (local metres).
    """

    def __init__(self, router: Router, telemetry: StationTelemetry, losses: VehicleLosses,
                 mission: Mission, *, missions_dir: Path | None, timeout_s: float,
                 tolerance_m: float, home: tuple[float, float]) -> None:
        self.router = router
        self.telemetry = telemetry
        self.losses = losses
        self.mission = mission
        self.origin = mission.origin
        self.altitude_m = mission.vehicles.altitude_m
        self.missions_dir = missions_dir
        self.timeout_s = timeout_s
        self.tolerance_m = tolerance_m
        self.home = home
        self.fences_refused: list[int] = []
        """Vehicles that refused the geofence upload (they fly without one)."""

    def save_mission(self, iteration: int, sysid: int, items: list[MissionItemSpec],
                     tasks: Sequence[Task], round_no: int = 0) -> None:
        """``iter{NN}_v{sysid}.json`` (items), ``.waypoints`` (QGC WPL) and ``.tasks.json``
        (the tasks, with the estimated contours, for ``econdor export --iteration``)."""
        if self.missions_dir is None:
            return
        from econdor_gcs.files.plans import write_tasks

        self.missions_dir.mkdir(parents=True, exist_ok=True)
        # a second round (pieces of a lost vehicle) in the same iteration gets its own file
        suffix = f"_r{round_no}" if round_no else ""
        stem = self.missions_dir / f"iter{iteration:02d}_v{sysid}{suffix}"
        try:
            stem.with_suffix(".json").write_text(mission_items_json(items), encoding="utf-8")
            write_wpl(stem.with_suffix(".waypoints"), items)
            write_tasks(stem.with_suffix(".tasks.json"), tasks)
        except OSError as exc:
            raise RunError(f"cannot save the mission of vehicle {sysid} in {stem.parent}: "
                           f"{exc.strerror or exc}") from exc

    async def plan_and_upload(self, v: VehicleState, tasks: list[Task], iteration: int,
                              round_no: int, survey: bool = False) -> None:
        """Upload ``tasks`` to ``v`` as trace items, or as waypoint polylines once ``v`` has
        refused a trace item or its sensor lag item (the flight begins first: a failed upload
        leaves its tasks unfinished, for the others; ``survey``: it is flown as a survey).

        A vehicle's refusal is its MISSION_ACK to the refused item; when that ACK is lost we
        send the item again and a vehicle with no transfer running answers INVALID_SEQUENCE
        (ERROR: it gave up waiting). Either starts the upload again, up to
        :data:`UPLOAD_ATTEMPTS` times."""
        style = v.style or TaskStyle.TRACE
        f: Flight | None = None
        attempts = 0
        while True:
            attempts += 1
            plan = plan_mission(self.origin, tasks, self.altitude_m, style=style,
                                tolerance_m=self.tolerance_m, home=self.home,
                                speed_mps=self.mission.vehicles.speed_mps, end="none")
            self.save_mission(iteration, v.sysid, plan.items, tasks, round_no)
            if f is None:
                f = self.telemetry.begin(v, tasks, plan, survey=survey)
            else:
                f.task_seqs, f.style = list(plan.task_seqs), plan.style
                f.item_phases = dict(plan.item_phases)
            try:
                await self.upload(v, plan.items)
            except MissionRejected as exc:
                refused_trace = (exc.result == mavlink.MAV_MISSION_UNSUPPORTED
                                 and exc.command in (MAV_CMD_WAYPOINT_USER_1,
                                                     SENSOR_LAG_COMMAND))
                if exc.result in RESTART_RESULTS and attempts < UPLOAD_ATTEMPTS:
                    log.warning("vehicle %d: %s; uploading the mission again", v.sysid, exc)
                    continue
                if not (refused_trace and style == TaskStyle.TRACE):
                    raise
                log.info("vehicle %d refused %s: its pieces go as waypoints", v.sysid,
                         command_name(exc.command) if exc.command is not None else "an item")
                style = v.style = TaskStyle.WAYPOINTS
                attempts = 0
                continue
            if any(isinstance(t, TraceTask) for t in tasks):
                v.style = style
            return

    async def _transfer(self, v: VehicleState, items: list[MissionItemSpec],
                        mission_type: int, what: str) -> None:
        """Upload ``items``; one that runs out of answers while the vehicle heartbeats (the
        protocol's messages were lost, not the vehicle) starts again, up to
        :data:`UPLOAD_ATTEMPTS` times. One that fails while the vehicle is silent is left
        to :meth:`~.losses.VehicleLosses.tolerant` (it waits for the link)."""
        for attempt in range(1, UPLOAD_ATTEMPTS + 1):
            try:
                await asyncio.wait_for(self.router.upload_mission(
                    v.sysid, items, mission_type=mission_type), self.timeout_s)
                return
            except (TimeoutError, VehicleTimeout) as exc:
                self.losses.check_lost()  # a vehicle that went silent says so
                text = (f"vehicle {v.sysid}: {what} did not finish within {self.timeout_s:g} s"
                        if isinstance(exc, TimeoutError) else str(exc))
                if attempt == UPLOAD_ATTEMPTS or self.losses.silent_s(v) > SILENT_S:
                    if mission_type in self.router.vehicles[v.sysid].partial_missions:
                        text += (" (it holds part of this mission over the one before, as "
                                 "ArduPilot stores items as they come: clear it, or upload "
                                 "another, before flying it in AUTO)")
                    raise VehicleTimeout(text) from None
                log.warning("%s; the vehicle heartbeats: uploading it again", text)

    async def upload(self, v: VehicleState, items: list[MissionItemSpec]) -> None:
        v.status = VehicleStatus.UPLOADING
        await self._transfer(v, items, mavlink.MAV_MISSION_TYPE_MISSION, "mission upload")
        v.items = items
        v.current_seq = None
        v.status = VehicleStatus.UPLOADED

    async def upload_fence(self, v: VehicleState, fence: list[MissionItemSpec]) -> None:
        """The area plus :data:`~econdor_gcs.link.items.MISSION_FENCE_MARGIN_M` as the
        vehicle's inclusion fence (mission type FENCE): an autopilot that enforces fences keeps
        the vehicle inside."""
        try:
            await self._transfer(v, fence, mavlink.MAV_MISSION_TYPE_FENCE, "fence upload")
        except ProtocolError as exc:  # a vehicle without fences flies without one
            log.warning("vehicle %d refused the fence: %s", v.sysid, exc)
            self.fences_refused.append(v.sysid)
