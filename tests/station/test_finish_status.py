"""At the end of a run every vehicle on the ground is ``landed``, whatever its last flight
was called (an operator's stop sends vehicles home mid-flight: one already down when the run
ends must not stay ``interrupted``)."""

from __future__ import annotations

import asyncio
import time
from types import SimpleNamespace
from typing import Any

from econdor_gcs.config import parse_mission
from econdor_gcs.link.router import Received, Sample, VehicleLink
from econdor_gcs.station.executor import MavlinkExecutor
from econdor_gcs.station.status import VehicleStatus


class _GroundRouter:
    """Two vehicles heard just now, both disarmed on the ground."""

    def __init__(self) -> None:
        self.vehicles = {s: VehicleLink(s, ("127.0.0.1", 1), last_heartbeat=time.monotonic(),
                                        rel_alt_m=0.0) for s in (1, 2)}

    def subscribe(self, kinds: Any, handler: Any) -> None:
        assert kinds in (Sample, Received) or isinstance(kinds, tuple)


def test_a_vehicle_on_the_ground_at_the_end_is_landed() -> None:
    mission = parse_mission({"field": {"model": "paper"}})
    ex = MavlinkExecutor(SimpleNamespace(router=_GroundRouter()), mission,  # type: ignore[arg-type]
                         [1, 2])
    ex.vehicles[1].status = VehicleStatus.INTERRUPTED  # sent home by a stop, down already
    ex.vehicles[2].status = VehicleStatus.HOLDING
    reports = asyncio.run(ex._finish())
    assert [v.status for v in ex.vehicles.values()] == [VehicleStatus.LANDED] * 2
    assert all(len(r.samples) == 0 for r in reports)
