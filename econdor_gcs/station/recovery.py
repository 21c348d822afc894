"""Sample recovery (README, "No sample lost"): after each flight the station asks every
vehicle how many samples it took in the flight's time range, asks again for every gap in what
arrived, and waits for the resends, until all are in or rounds stop bringing any.

The questions go to the component that sends the samples (the payload: a companion
computer, or the autopilot itself). One that does not answer them (a stock autopilot with a
Lua sensor script says MAV_RESULT_UNSUPPORTED) is asked no more: the station keeps what
arrives, logs it once and says so in ``summary.json`` (``sample_recovery``), and the run
goes on.

:class:`SampleRecovery` is a part of :class:`~.gcs.MavlinkExecutor`: it shares the
executor's router, mission, vehicle states and timings, gives up vehicles through its
:class:`~.losses.VehicleLosses` and waits with the executor's ``until`` (which wakes on
whatever the vehicles send), on the station's loop thread like the rest of the executor.
"""

from __future__ import annotations

import bisect
import functools
import logging
import time
from collections.abc import Awaitable, Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

from econdor_gcs.core.tasks import (
    SAMPLE_COUNT_COMMAND,
    SAMPLE_RESEND_COMMAND,
    SAMPLE_RESEND_MAX,
    TRACE_RESEND_COMMAND,
    TaskStyle,
    TraceTask,
)
from econdor_gcs.errors import CommandRejected, VehicleTimeout
from econdor_gcs.link.transfer import enum_name
from econdor_gcs.station.losses import run_all

if TYPE_CHECKING:
    from econdor_gcs.config import Mission
    from econdor_gcs.link.router import Router
    from econdor_gcs.station.losses import VehicleLosses
    from econdor_gcs.station.telemetry import VehicleState

__all__ = ["SampleRecovery"]

log = logging.getLogger(__name__)

RECOVERY_ROUNDS = 200
"""At most this many rounds of resend requests for one vehicle's missing samples ..."""
RECOVERY_STALLED_ROUNDS = 12
"""... and the station gives up earlier when this many rounds in a row brought nothing. On a
link losing 10 % each way a round brings a last missing sample back with p = 0.9 (the
request) x 0.81 (both halves of the answer) = 0.73; with 4 rounds a live vehicle's sample was
given up in 0.27**4 = 0.5 % of such endings, about one run in ten of the lossy demo (~20
recoveries). With 12 it is 2e-7; a sample that truly cannot come costs ~12 x 0.3 s."""
RECOVERY_GAPS_PER_ROUND = 100
"""Resend requests per round: a vehicle answers them in one burst, and a burst larger than
its socket's send buffer (~1000 packets) is dropped on the vehicle itself."""
RECOVERY_SETTLE_S = 0.25
"""Wall time without a new sample after which a round of resends counts as arrived."""


def _all_in(keys: Sequence[int], mapping: dict[int, Any]) -> bool:
    return all(k in mapping for k in keys)


class Until(Protocol):
    """The executor's wait: until ``cond()`` holds (woken by whatever the vehicles send),
    False at ``deadline``."""

    def __call__(self, cond: Callable[[], bool], *, tick_s: float = 0.25,
                 on_tick: Callable[[], object] | None = None,
                 deadline: float | None = None) -> Awaitable[bool]: ...


class SampleRecovery:
    """The sample recovery of a :class:`~.gcs.MavlinkExecutor`.

    Parameters
    ----------
    router, mission, vehicles, timings
        The executor's: the link, the mission (sample rate), each vehicle's state (what
        arrived), and its timings (``recovery_s`` is added up here).
    losses
        Gives up a vehicle that falls silent while it is asked (the run goes on with the
        others) and fails when none is left.
    until
        The executor's wait.
    aborted
        Whether the operator stopped the flight (then only the items a vehicle got past
        have a TRACE report to ask for).
    """

    def __init__(self, router: Router, mission: Mission, vehicles: dict[int, VehicleState],
                 timings: dict[str, float], losses: VehicleLosses, until: Until,
                 aborted: Callable[[], bool]) -> None:
        self.router = router
        self.mission = mission
        self.vehicles = vehicles
        self.timings = timings
        self.losses = losses
        self._until = until
        self._aborted = aborted

    async def recover(self, vs: list[VehicleState]) -> None:
        """Bring in every sample the vehicles ``vs`` took since their last recovery (and
        the TRACE reports of their flight), as far as rounds of resends can."""
        t0 = time.monotonic()
        await run_all([self.losses.tolerant(v, functools.partial(self._recover_one, v))
                       for v in vs if v.lost is None])
        self.timings["recovery_s"] = self.timings.get("recovery_s", 0.0) + \
            time.monotonic() - t0

    def _payload(self, v: VehicleState) -> int:
        """The component that sends ``v``'s samples (the one asked about them)."""
        link = self.router.vehicles.get(v.sysid)
        return link.sample_compid if link is not None and link.sample_compid else 1

    async def _count(self, v: VehicleState, first_ms: int, last_ms: int) -> int | None:
        """The vehicle's own count of samples in the range; None when its payload does not
        answer the question (then it is never asked again)."""
        compid = self._payload(v)
        try:
            ack = await self.router.command_int(v.sysid, SAMPLE_COUNT_COMMAND, first_ms,
                                                last_ms, timeout_s=0.3, retries=20,
                                                compid=compid)
        except CommandRejected as exc:
            why = f"component {compid} answered the sample count with " \
                  f"{enum_name('MAV_RESULT', exc.result)}"
        except VehicleTimeout:
            self.losses.check_lost()  # a vehicle that went silent is given up, not this
            why = f"component {compid} did not answer the sample count"
        else:
            return int(ack.result_param2)
        v.no_recovery = why
        log.warning("vehicle %d: %s: lost samples cannot be asked for again; the station "
                    "keeps what arrives", v.sysid, why)
        return None

    def _gaps(self, v: VehicleState, first_ms: int, last_ms: int) -> list[tuple[int, int]]:
        """Time ranges of [first_ms, last_ms] with no sample here that may hold samples the
        vehicle took: between two received samples more than 1.5 sensor periods apart,
        and before the first / after the last. (A range where the vehicle took none, e.g.
        while it climbed, costs one request and brings nothing.)"""
        lo = bisect.bisect_left(v.seen_ms, first_ms)
        hi = bisect.bisect_right(v.seen_ms, last_ms)
        times = [first_ms - 1, *v.seen_ms[lo:hi], last_ms + 1]
        period_ms = 1000.0 / self.mission.vehicles.sample_rate_hz
        # a long gap goes in pieces the vehicle will resend (half its limit at our rate)
        piece_ms = max(1, int(SAMPLE_RESEND_MAX * period_ms / 2))
        gaps = []
        for a, b in zip(times, times[1:], strict=False):
            if b - a > 1.5 * period_ms or (a == first_ms - 1 and b > first_ms) \
                    or (b == last_ms + 1 and a < last_ms):
                gaps += [(s, min(s + piece_ms - 1, b - 1)) for s in range(a + 1, b, piece_ms)]
        return gaps

    def _pieces(self, first_ms: int, last_ms: int) -> list[tuple[int, int]]:
        """[first_ms, last_ms] in ranges of at most a quarter of a resend's limit at the
        mission's sample rate."""
        step = max(1, int(SAMPLE_RESEND_MAX * 1000.0 / self.mission.vehicles.sample_rate_hz
                          / 4))
        return [(s, min(s + step - 1, last_ms)) for s in range(first_ms, last_ms + 1, step)]

    async def _recover_one(self, v: VehicleState) -> None:
        """Make sure every sample ``v`` took since the last recovery is here: ask for its
        count, request every gap again, wait for the resends, repeat."""
        link = self.router.vehicles[v.sysid]
        first = v.synced_ms + 1
        last = max(link.time_boot_ms or 0, v.newest_ms)
        if last < first or v.no_recovery is not None:
            return
        n = have = 0
        v.recovering = True
        try:
            counted = await self._recover_range(v, first, last)
            if counted is None:
                return
            n, have = counted
            # a report may be stamped after the last time we know of (the vehicle's last
            # position report can lag behind its last item): ask up to the end of time
            await self._recover_reports(v, first, 2**31 - 1)
        finally:
            v.recovering = False
        v.vehicle_samples = (v.vehicle_samples or 0) + n
        if v.missing is not None:
            v.missing += max(0, n - have)
        if n > have:
            log.error("vehicle %d: %d of its %d samples in %d..%d ms never arrived", v.sysid,
                      n - have, n, first, last)
        v.synced_ms = last

    async def _recover_range(self, v: VehicleState, first: int, last: int
                             ) -> tuple[int, int] | None:
        n = have = 0
        stalled, best = 0, -1
        for round_no in range(RECOVERY_ROUNDS):
            self.losses.check_lost()
            counted = await self._count(v, first, last)
            if counted is None:
                return None
            n = counted
            have = v.count_seen(first, last)
            if have >= n:
                break
            stalled = stalled + 1 if have <= best else 0
            best = max(best, have)
            if stalled >= RECOVERY_STALLED_ROUNDS:
                break
            # a sample missing where the spacing does not show it (a vehicle sampling faster
            # than the mission says): the whole range again, in pieces it will resend
            gaps = self._gaps(v, first, last) or self._pieces(first, last)
            # fire and forget (what arrives is what counts), a round's worth at a time,
            # rotating, so gaps where the vehicle took nothing (a climb) cannot crowd out
            # the others
            k = round_no * RECOVERY_GAPS_PER_ROUND % len(gaps)
            compid = self._payload(v)
            for a, b in (gaps[k:] + gaps[:k])[:RECOVERY_GAPS_PER_ROUND]:
                self.router.send_command_int(v.sysid, SAMPLE_RESEND_COMMAND, a, b,
                                             compid=compid)
            await self._quiet(v)
        return n, have

    async def _recover_reports(self, v: VehicleState, first: int, last: int) -> None:
        """Ask again for the TRACE reports of trace items that have none (lost on the way)."""
        f = v.flight
        if f is None or f.style != TaskStyle.TRACE:
            return  # contours flown as waypoints have no TRACE reports
        # after an operator's stop (or the vehicle's own failsafe) only the items the
        # vehicle got past have a report
        cut = self._aborted() or f.interrupted is not None
        current = v.current_seq if v.current_seq is not None else 0
        due = [t for t, (_, last) in zip(f.tasks, f.task_seqs, strict=True)
               if not cut or last < current or last in f.reached]
        for _ in range(RECOVERY_ROUNDS):
            missing = [t.piece_id for t in due
                       if isinstance(t, TraceTask) and t.piece_id not in f.pieces]
            if not missing:
                return
            await self.router.command_int(v.sysid, TRACE_RESEND_COMMAND, first, last,
                                          timeout_s=0.3, retries=20, compid=self._payload(v))
            await self._until(functools.partial(_all_in, missing, f.pieces),
                              deadline=time.monotonic() + 1.0)
        log.error("vehicle %d: no TRACE report for pieces %s", v.sysid,
                  [t.piece_id for t in due
                   if isinstance(t, TraceTask) and t.piece_id not in f.pieces])

    async def _quiet(self, v: VehicleState) -> None:
        """Wait until ``v``'s samples stop arriving (the resends are in, or lost)."""
        start = time.monotonic()
        seen = [len(v.seen_ms), start]  # samples so far, and when that last changed

        def quiet() -> bool:
            now = time.monotonic()
            if len(v.seen_ms) != seen[0]:
                seen[:] = [len(v.seen_ms), now]
            return now - seen[1] >= RECOVERY_SETTLE_S

        await self._until(quiet, tick_s=0.05, deadline=start + 5.0)

    def sample_accounting(self) -> dict[str, dict[str, int | str | None]]:
        """Per vehicle: samples it took (its own count at its last recovery), received,
        recovered by resends, duplicates dropped, missing (None for a vehicle given up, or
        one whose samples cannot be recovered: what it took is unknown), for summary.json."""
        return {str(v.sysid): {"vehicle_count": v.vehicle_samples, "received": v.samples,
                               "recovered": v.recovered, "duplicates": v.duplicates,
                               "missing": v.missing if v.no_recovery is None else None,
                               "lost": v.lost is not None, "no_recovery": v.no_recovery}
                for v in self.vehicles.values()}
