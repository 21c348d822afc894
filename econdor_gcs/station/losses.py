"""Vehicles given up, and where their work goes.

:class:`VehicleLosses` is a part of :class:`~.executor.MavlinkExecutor`. A vehicle is given up
only when its HEARTBEAT is gone for the link timeout (``--link-timeout``, default
:data:`LINK_TIMEOUT_S`: the router's :class:`~.link.router.VehicleLost`), or when its
current mission item takes longer than the item's time limit
(:meth:`VehicleLosses.item_limit_s`; it is then told to return). A step with a vehicle that
fails while the vehicle is silent (its link is out: a radio drop-out) waits for the link to
come back and runs again (:meth:`VehicleLosses.tolerant`); a lost acknowledgement that the
vehicle's own telemetry contradicts never counts (:mod:`.commands`). Its unfinished tasks go
to the vehicles still in service (:meth:`VehicleLosses.reassign`); the run fails only when
no vehicle is left. Like the rest of the executor, this runs on the station's loop thread.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable, Coroutine, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from econdor_gcs.config import Mission
from econdor_gcs.core.tasks import FlightReport, OutcomeStatus, Task, TaskStyle, TraceTask
from econdor_gcs.errors import LinkError, VehicleTimeout
from econdor_gcs.link.router import Router
from econdor_gcs.station.status import VehicleStatus
from econdor_gcs.station.telemetry import VehicleState

if TYPE_CHECKING:
    from econdor_gcs.station.recovery import Until

__all__ = ["LINK_TIMEOUT_S", "VehicleLosses", "run_all"]

log = logging.getLogger(__name__)

LINK_TIMEOUT_S = 120.0
"""A vehicle silent this long (no HEARTBEAT) is given up; its unfinished pieces go to the
others. Long enough for the drop-outs of a telemetry radio (15 s is ordinary, a minute
happens), during which the vehicle's own failsafe (RTL after 5 s) keeps it safe and its
samples on board; the station picks up where it left when the link is back."""
LOSS_SILENCE_S = 5.0
"""The shortest link timeout that makes sense: a vehicle heartbeats at 1 Hz."""
SILENT_S = 3.0
"""No HEARTBEAT for this long: the link is out (three in a row lost; at 20 % loss each
way, 1 % of the time for 3 s), so a failing step waits for it instead of failing the run,
and the item time limits stop counting."""
LINK_BACK_S = 2.0
"""The link counts as back after HEARTBEATs for this long (two in a row)."""
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


@dataclass
class LinkWatch:
    """What :class:`VehicleLosses` keeps of one vehicle's link between its checks (the
    heartbeats themselves are the link table's: :class:`~.link.vehicles.VehicleLink`)."""

    silent: bool = False
    """Its link was out when the item time limits were last checked."""
    link_out: bool = False
    """Its link was found out (no HEARTBEAT for :data:`SILENT_S`) and is not back yet."""
    back_since: float | None = None
    """Monotonic time its HEARTBEATs came back after a silence."""


class VehicleLosses:
    """Gives vehicles up and hands their work to the others (a part of
    :class:`~.executor.MavlinkExecutor`, on the station's loop thread).

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
                 sysids: Sequence[int], *, iteration: Callable[[], int],
                 until: Until | None = None, link_timeout_s: float = LINK_TIMEOUT_S) -> None:
        self.router = router
        self.until = until
        self.link_timeout_s = link_timeout_s
        self.mission = mission
        self.vehicles = vehicles
        self.sysids = sysids
        self.altitude_m = mission.vehicles.altitude_m
        self.watch = {sysid: LinkWatch() for sysid in sysids}
        """Each vehicle's link as this part last saw it, by system id."""
        self.iteration = iteration
        self.records: list[dict[str, Any]] = []
        """Every vehicle given up: sysid, reason, iteration, and ``reassigned``: per batch of
        its tasks, the iteration, the vehicle that flew it, the tasks and piece ids."""
        self.interruptions: list[dict[str, Any]] = []
        """Every flight a vehicle left before its end on its own (its failsafe): sysid,
        reason, iteration, and ``reassigned`` as for :attr:`records`."""
        self._open: dict[int, dict[str, Any]] = {}
        """The record (loss or interruption) whose tasks are handed out now, by sysid."""

    def mark_lost(self, v: VehicleState, reason: str) -> None:
        """Give ``v`` up: it gets no more work; its unfinished pieces go to the others."""
        if v.lost is not None:
            return
        where = ""
        if v.flight is not None and v.current_seq is not None:
            where = f" at mission item {v.current_seq}/{len(v.items) - 1}"
        v.lost = reason + where
        v.status = VehicleStatus.LOST
        v.missing = None  # what it took since it was last asked is unknown
        log.warning("vehicle %d lost: %s", v.sysid, v.lost)
        self.records.append({"sysid": v.sysid, "reason": v.lost,
                             "iteration": self.iteration(), "reassigned": []})
        self._open[v.sysid] = self.records[-1]

    def record_interruption(self, v: VehicleState, reason: str, left: list[Task]) -> None:
        """``v`` left its mission on its own (``reason``) with ``left`` unfinished (they are
        flown again, by whoever :meth:`reassign` gives them to)."""
        self.interruptions.append({"sysid": v.sysid, "reason": reason,
                                   "iteration": self.iteration(), "unfinished": len(left),
                                   "reassigned": []})
        self._open[v.sysid] = self.interruptions[-1]

    def check_lost(self) -> None:
        """Fail only when no vehicle is left; a single loss is handled."""
        if self.vehicles and all(v.lost is not None for v in self.vehicles.values()):
            raise VehicleTimeout("every vehicle lost: " + "; ".join(
                f"vehicle {v.sysid} lost: {v.lost}" for v in self.vehicles.values()))

    def silent_s(self, v: VehicleState, now: float | None = None) -> float:
        """Seconds since ``v``'s last HEARTBEAT."""
        link = self.router.vehicles.get(v.sysid)
        now = time.monotonic() if now is None else now
        return now - link.last_heartbeat if link is not None else math.inf

    def link_back(self, v: VehicleState) -> bool:
        """``v``'s link is up: heard within :data:`SILENT_S`, and, after a silence, for
        :data:`LINK_BACK_S` since (or ``v`` is given up: nothing to wait for)."""
        link = self.router.vehicles.get(v.sysid)
        if v.lost is not None or link is None:
            return True
        now = time.monotonic()
        w = self.watch[v.sysid]
        if now - link.last_heartbeat > SILENT_S:
            w.link_out, w.back_since = True, None
            return False
        if not w.link_out:
            return True
        if w.back_since is None:
            w.back_since = now
        if now - w.back_since >= LINK_BACK_S:
            w.link_out, w.back_since = False, None
            return True
        return False

    async def wait_link(self, v: VehicleState) -> bool:
        """Wait until ``v``'s link is back (True) or ``v`` is given up at the link timeout
        (False)."""
        if self.until is None:
            return False
        log.warning("vehicle %d: waiting for its link (last heartbeat %.0f s ago; it is given "
                    "up after %.0f s)", v.sysid, self.silent_s(v), self.link_timeout_s)
        left_s = max(0.0, self.link_timeout_s - self.silent_s(v))
        await self.until(lambda: self.link_back(v) or v.lost is not None,
                         deadline=time.monotonic() + left_s + LINK_BACK_S)
        if v.lost is None and not self.link_back(v):
            self.mark_lost(v, f"no heartbeat for {self.silent_s(v):.0f} s")
        return v.lost is None

    async def tolerant(self, v: VehicleState,
                       step: Callable[[], Coroutine[Any, Any, None]]) -> None:
        """Run ``step()`` with ``v``. If it fails while ``v`` is silent (its link is out),
        wait for the link and run it again; ``v`` is given up only when its HEARTBEAT stays
        away for the link timeout, and the run goes on without it. Any other failure (a
        refusal, a vehicle that heartbeats but never answers) stands."""
        while True:
            if v.lost is not None:
                return
            try:
                await step()
                return
            except LinkError as exc:
                if v.lost is not None:
                    return
                if self.silent_s(v) <= SILENT_S:
                    raise
                if not await self.wait_link(v):
                    return
                log.warning("vehicle %d: its link is back (%s was cut short); again", v.sysid,
                            exc)

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
        vehicle whose clock stops while it heartbeats is caught by wall time (10x). While a
        vehicle is silent its clock is not watched; when it is heard again its item starts
        anew (its own failsafe may have flown it elsewhere meanwhile)."""
        now = time.monotonic()
        for v in flying:
            f = v.flight
            if v.lost is not None or f is None or f.done or f.landed or \
                    f.interrupted is not None:
                continue  # a vehicle that finished (or landed, or left) is not late any more
            w = self.watch[v.sysid]
            if self.silent_s(v, now) > SILENT_S:
                w.silent = True
                continue
            if w.silent:
                w.silent = False
                v.item_since = now
                v.item_since_ms = self.router.vehicles[v.sysid].time_boot_ms or 0
                continue
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
                record = self._open[source]
                record["reassigned"].append({"iteration": self.iteration(),
                                             "to": self.sysids[i], "tasks": len(batch),
                                             "pieces": pieces})
                why = "lost" if self.vehicles[source].lost is not None else "interrupted"
                log.warning("vehicle %d (%s): %d tasks (pieces %s) go to vehicle %d",
                            source, why, len(batch), pieces, self.sysids[i])
        return plans
