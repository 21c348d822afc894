"""Vehicles given up, and where their work goes.

:class:`VehicleLosses` is a part of :class:`~.gcs.MavlinkExecutor`. A vehicle is given up
when the router hears no HEARTBEAT from it for its timeout, when a step with it fails after
:data:`LOSS_SILENCE_S` of silence, or when its current mission item takes longer than the
item's time limit (:meth:`VehicleLosses.item_limit_s`; it is then told to return). Its
unfinished tasks go to the vehicles still in service (:meth:`VehicleLosses.reassign`); the
run fails only when no vehicle is left. Like the rest of the executor, this runs on the
station's loop thread.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable, Coroutine, Sequence
from typing import Any

from .core.tasks import FlightReport, OutcomeStatus, Task, TaskStyle, TraceTask
from .errors import LinkError, VehicleTimeout
from .link.router import Router
from .mission import Mission
from .telemetry import VehicleState

__all__ = ["VehicleLosses", "run_all"]

log = logging.getLogger(__name__)

LOSS_SILENCE_S = 5.0
"""A vehicle silent this long (no HEARTBEAT) is lost; its unfinished pieces go to the others."""
DESCENT_RATE_MPS = 1.0
"""Slowest descent we expect of a vehicle landing (PX4 lands at 0.7-1.5 m/s)."""
ITEM_TIME_FACTOR = 3.0
ITEM_TIME_MARGIN_S = 60.0
"""A mission item must finish within ITEM_TIME_FACTOR x its planned flight time (length over
cruise speed) + ITEM_TIME_MARGIN_S of sim time, or the vehicle is lost."""


async def run_all(coros: list[Coroutine[Any, Any, None]]) -> None:
    """Run the steps concurrently; on the first failure cancel the rest and raise it (wrap
    each in :meth:`VehicleLosses.tolerant` for a vehicle's silence not to count)."""
    tasks = [asyncio.ensure_future(c) for c in coros]
    try:
        await asyncio.gather(*tasks)
    except BaseException:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        raise


class VehicleLosses:
    """Gives vehicles up and hands their work to the others (a part of
    :class:`~.gcs.MavlinkExecutor`, on the station's loop thread).

    Parameters
    ----------
    router:
        The station's router: heartbeats, the vehicles' own times, the return command.
    mission:
        Cruise speed, speed-up, area and altitude: the time limits of mission items.
    vehicles:
        The executor's vehicle states, by system id.
    sysids:
        System ids, in vehicle-index order.
    iteration:
        The iteration being flown, recorded with each loss and each reassignment.
    """

    def __init__(self, router: Router, mission: Mission, vehicles: dict[int, VehicleState],
                 sysids: Sequence[int], *, iteration: Callable[[], int]) -> None:
        self.router = router
        self.mission = mission
        self.vehicles = vehicles
        self.sysids = sysids
        self.altitude_m = mission.vehicles.altitude_m
        self.iteration = iteration
        self.records: list[dict[str, Any]] = []
        """Every vehicle given up: sysid, reason, iteration, and ``reassigned``: per batch of
        its tasks, the iteration, the vehicle that flew it, the tasks and piece ids."""

    def mark_lost(self, v: VehicleState, reason: str) -> None:
        """Give ``v`` up: it gets no more work; its unfinished pieces go to the others."""
        if v.lost is not None:
            return
        where = ""
        if v.flight is not None and v.current_seq is not None:
            where = f" at mission item {v.current_seq}/{len(v.items) - 1}"
        v.lost = reason + where
        v.status = "lost"
        log.warning("vehicle %d lost: %s", v.sysid, v.lost)
        self.records.append({"sysid": v.sysid, "reason": v.lost,
                             "iteration": self.iteration(), "reassigned": []})

    def check_lost(self) -> None:
        """Fail only when no vehicle is left; a single loss is handled."""
        if self.vehicles and all(v.lost is not None for v in self.vehicles.values()):
            raise VehicleTimeout("every vehicle lost: " + "; ".join(
                f"vehicle {v.sysid} lost: {v.lost}" for v in self.vehicles.values()))

    async def tolerant(self, v: VehicleState, coro: Coroutine[Any, Any, None]) -> None:
        """Run a step with ``v``; if it fails because ``v`` went silent, ``v`` is lost and
        the run goes on. Any other failure (a refusal from a vehicle that answers) stands."""
        try:
            await coro
        except LinkError as exc:
            link = self.router.vehicles.get(v.sysid)
            silent = time.monotonic() - link.last_heartbeat_mono if link else math.inf
            if v.lost is None and silent <= LOSS_SILENCE_S:
                raise
            self.mark_lost(v, f"{exc} (silent for {silent:.0f} s)")

    def item_limit_s(self, v: VehicleState) -> float:
        """Sim seconds the current mission item may take (module constants)."""
        f, seq = v.flight, v.current_seq
        speed = self.mission.vehicles.speed_mps
        region = self.mission.region
        length = 2 * (region.width_m + region.height_m)  # to anywhere in the area
        if f is not None and not f.tasks:  # home, then down
            return ITEM_TIME_FACTOR * length / speed + ITEM_TIME_MARGIN_S + \
                2 * self.altitude_m / DESCENT_RATE_MPS
        task = f.task_at(seq) if f is not None and seq is not None else None
        if isinstance(task, TraceTask) and f is not None and f.style == TaskStyle.TRACE:
            # the search, then the trace (up to its limit; a closed one fits the area)
            length += 2 * math.pi * task.search_radius_m + (
                task.max_length_m if task.max_length_m > 0 else 4 * length)
        return ITEM_TIME_FACTOR * length / speed + ITEM_TIME_MARGIN_S

    def check_progress(self, flying: list[VehicleState]) -> None:
        """A vehicle whose current item takes longer than its limit is lost. The limit is
        in the vehicle's own sim time (a vehicle slowed by a busy machine is not late); a
        vehicle whose clock stops while it heartbeats is caught by wall time (10x)."""
        now = time.monotonic()
        for v in flying:
            f = v.flight
            if v.lost is not None or f is None or f.done or f.landed:
                continue  # a vehicle that finished (or landed) is not late any more
            limit_s = self.item_limit_s(v)
            sim_ms = (self.router.vehicles[v.sysid].time_boot_ms or 0) - v.item_since_ms
            wall_s = now - v.item_since
            if sim_ms > 1000 * limit_s or wall_s > 10 * limit_s / self.mission.vehicles.speedup:
                self.mark_lost(v, f"mission item {v.current_seq} not finished within "
                                  f"{limit_s:.0f} s of its time")
                self._spawn(self.router.return_to_launch(v.sysid), v)

    def _spawn(self, coro: Coroutine[Any, Any, Any], v: VehicleState) -> None:
        """Send a command to a vehicle given up, without waiting (it may not answer)."""
        task = asyncio.ensure_future(coro)

        def done(t: asyncio.Future[Any]) -> None:
            if not t.cancelled() and t.exception() is not None:
                log.warning("vehicle %d (lost): %r", v.sysid, t.exception())

        task.add_done_callback(done)

    @staticmethod
    def unfinished(report: FlightReport) -> list[Task]:
        """The tasks of a flight without an outcome (a lost vehicle did not finish them)."""
        return [o.task for o in report.outcomes if o.status == OutcomeStatus.UNREPORTED]

    def reassign(self, plans: list[list[Task]], extra: list[tuple[int, list[Task]]],
                 positions_now: Callable[[], list[tuple[float, float]]]
                 ) -> list[list[Task]]:
        """Give the plans of lost vehicles, and the ``extra`` (sysid, tasks) they left
        unfinished, to the vehicles still in service: each batch to the least loaded one,
        nearest its first task first."""
        live = [i for i, s in enumerate(self.sysids) if self.vehicles[s].lost is None]
        if not live:
            self.check_lost()
            return plans
        batches = list(extra)
        for i, s in enumerate(self.sysids):
            if self.vehicles[s].lost is not None and plans[i]:
                batches.append((s, plans[i]))
                plans[i] = []
        positions = positions_now()
        load = {i: len(plans[i]) for i in live}
        for source, tasks in batches:
            # split a lost vehicle's tasks over the vehicles left, in order
            step = max(1, math.ceil(len(tasks) / len(live)))
            for batch in (tasks[k:k + step] for k in range(0, len(tasks), step)):
                first = batch[0]
                i = min(live, key=lambda j: (load[j], math.dist(positions[j],
                                                                (first.x_m, first.y_m))))
                plans[i] = plans[i] + batch
                load[i] += len(batch)
                pieces = [t.piece_id for t in batch if isinstance(t, TraceTask)]
                loss = next(x for x in reversed(self.records) if x["sysid"] == source)
                loss["reassigned"].append({"iteration": self.iteration(), "to": self.sysids[i],
                                           "tasks": len(batch), "pieces": pieces})
                log.warning("vehicle %d (lost): %d tasks (pieces %s) go to vehicle %d",
                            source, len(batch), pieces, self.sysids[i])
        return plans
