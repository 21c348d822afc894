"""The vehicles made ready for a run: :class:`VehicleStartup`, a part of
:class:`~.executor.MavlinkExecutor`.

Before the first flight the station waits for a position from every vehicle (asking for
the data streams again each second: ArduPilot sends only heartbeats until asked), takes
every sample a vehicle reports from then on as this run's, sets the stream rates (the
positions at the sensor's rate in vehicle time, the display streams at a few Hz of wall
time) and uploads the geofence (a vehicle that refuses it flies without one, and is
recorded). It shares the executor's router, vehicle states, missions and losses, and
waits with the executor's ``until``, on the station's loop thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import math
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

from econdor_gcs.errors import LinkError, VehicleTimeout
from econdor_gcs.link.codec import mavlink
from econdor_gcs.link.items import MISSION_FENCE_MARGIN_M, fence_items
from econdor_gcs.station.losses import VehicleLosses, run_all

if TYPE_CHECKING:
    from econdor_gcs.config import Mission
    from econdor_gcs.link.router import Router
    from econdor_gcs.station.recovery import Until
    from econdor_gcs.station.sorties import VehicleMissions
    from econdor_gcs.station.telemetry import VehicleState

__all__ = ["POSITIONS_PER_SAMPLE", "STREAM_WALL_HZ", "VehicleStartup"]

POSITIONS_PER_SAMPLE = 4
"""Positions asked for per sensor period: a sample between two positions is placed by linear
interpolation, and an autopilot's positions are its filter's output, which is not a straight
line between fixes a sensor period apart (docs/experiments/2026-12-04-sitl.md)."""

#: Wall-clock rates asked of the periodic (display) streams; samples are not affected.
STREAM_WALL_HZ = {
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 1.0,
}


class VehicleStartup:
    """Makes the vehicles ``sysids`` ready (module docstring); :meth:`run` once per run."""

    def __init__(self, router: Router, mission: Mission, sysids: Sequence[int],
                 vehicles: dict[int, VehicleState], vehicle_missions: VehicleMissions,
                 losses: VehicleLosses, until: Until, timeout_s: float) -> None:
        self.router = router
        self.mission = mission
        self.origin = mission.origin
        self.sysids = list(sysids)
        self.vehicles = vehicles
        self.vehicle_missions = vehicle_missions
        self.losses = losses
        self.until = until
        self.timeout_s = timeout_s

    async def run(self) -> None:
        """Ask for the streams (ArduPilot sends only heartbeats until asked; the request is
        repeated each second in case it was lost) and wait for a position from everyone."""
        requested = {"at": -math.inf}

        def ask() -> None:
            now = time.monotonic()
            if now - requested["at"] < 1.0:
                return
            requested["at"] = now
            for sysid in self.sysids:
                if self.router.vehicles[sysid].lat_deg is None:
                    self.router.request_data_streams(sysid)

        deadline = time.monotonic() + self.timeout_s
        ask()
        if not await self.until(lambda: all(self.router.vehicles[s].lat_deg is not None
                                            for s in self.sysids), on_tick=ask,
                                deadline=deadline):
            missing = [s for s in self.sysids if self.router.vehicles[s].lat_deg is None]
            raise VehicleTimeout(f"vehicle {missing[0]} sent no position within "
                                 f"{self.timeout_s:g} s")
        for v in self.vehicles.values():
            # this run accounts for the samples from now on (a vehicle that flew for an
            # earlier run, or for this one before a resume, keeps those to itself)
            v.synced_ms = max(v.newest_ms, self.router.vehicles[v.sysid].time_boot_ms or 0)
        await asyncio.gather(*(self.slow_streams(s) for s in self.sysids))
        fence = fence_items(self.origin, self.mission.region, MISSION_FENCE_MARGIN_M)
        await run_all([self.losses.tolerant(v, functools.partial(
            self.vehicle_missions.upload_fence, v, fence)) for v in self.vehicles.values()])

    async def slow_streams(self, sysid: int) -> None:
        """Ask for the positions at the sensor's rate and the display-only streams at a few
        Hz of *wall* time.

        A sample is placed by interpolating the vehicle's positions at its time
        (:mod:`.link.pairing`), so GLOBAL_POSITION_INT comes at the mission's sample rate,
        in vehicle time. At high speed-ups the display streams would otherwise arrive at up
        to 50 Hz per message and vehicle, and ten vehicles then flood the endpoint while the
        DFC reconstructs. Intervals are in vehicle (sim) time, hence the speed-up factor. A
        vehicle that does not support the command keeps its default rates.
        """
        speedup = self.mission.vehicles.speedup
        with contextlib.suppress(LinkError):
            await self.router.set_message_interval(
                sysid, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                1.0 / (POSITIONS_PER_SAMPLE * self.mission.vehicles.sample_rate_hz))
        for message_id, wall_hz in STREAM_WALL_HZ.items():
            with contextlib.suppress(LinkError):
                await self.router.set_message_interval(sysid, message_id, speedup / wall_hz)
