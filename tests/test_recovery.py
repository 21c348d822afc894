"""The station's sample recovery (README, "No sample lost") against a scripted vehicle: how
many rounds of resends a live vehicle gets before a sample is given up."""

from __future__ import annotations

import asyncio
import bisect
import time
from types import SimpleNamespace
from typing import Any

import pytest

from econdor_gcs.core.tasks import SAMPLE_COUNT_COMMAND, SAMPLE_RESEND_COMMAND
from econdor_gcs.station import recovery
from econdor_gcs.station.recovery import RECOVERY_STALLED_ROUNDS, SampleRecovery
from econdor_gcs.station.telemetry import VehicleState

TAKEN_MS = list(range(1000, 10_001, 100))  # 10 Hz
MISSING_MS = 5000


class ScriptedVehicle:
    """A router with one vehicle that took ``TAKEN_MS``: its counts always arrive; its answer
    to the first ``lost_answers`` resend requests for ``MISSING_MS`` is lost on the way."""

    def __init__(self, state: VehicleState, lost_answers: int) -> None:
        self.state = state
        self.lost_answers = lost_answers
        self.requests = 0
        self.vehicles = {state.sysid: SimpleNamespace(time_boot_ms=TAKEN_MS[-1],
                                                      sample_compid=1)}

    async def command_int(self, sysid: int, command: int, x: int, y: int, *,
                          timeout_s: float, retries: int, compid: int = 1) -> Any:
        assert command == SAMPLE_COUNT_COMMAND and compid == 1  # the payload's component
        return SimpleNamespace(result_param2=sum(x <= t <= y for t in TAKEN_MS))

    def send_command_int(self, sysid: int, command: int, x: int, y: int, *,
                         compid: int = 1) -> None:
        assert command == SAMPLE_RESEND_COMMAND and compid == 1
        if not x <= MISSING_MS <= y:
            return
        self.requests += 1
        if self.requests > self.lost_answers:
            receive(self.state, MISSING_MS)


def receive(v: VehicleState, t: int) -> None:
    if t not in v._seen:
        v._seen.add(t)
        bisect.insort(v.seen_ms, t)


class NoLosses:
    def check_lost(self) -> None:
        pass

    async def tolerant(self, v: VehicleState, step: Any) -> None:
        await step()


async def until(cond: Any, *, tick_s: float = 0.25, on_tick: Any = None,
                deadline: float | None = None) -> bool:
    while not cond():
        if deadline is not None and time.monotonic() > deadline:
            return False
        await asyncio.sleep(0.001)
    return True


def recover(lost_answers: int, monkeypatch: pytest.MonkeyPatch) -> tuple[VehicleState, int]:
    monkeypatch.setattr(recovery, "RECOVERY_SETTLE_S", 0.005)
    v = VehicleState(0, 1)
    for t in TAKEN_MS:
        if t != MISSING_MS:
            receive(v, t)
    v.newest_ms = TAKEN_MS[-1]
    router = ScriptedVehicle(v, lost_answers)
    mission = SimpleNamespace(vehicles=SimpleNamespace(sample_rate_hz=10.0))
    rec = SampleRecovery(router, mission, {1: v}, {}, NoLosses(), until,  # type: ignore[arg-type]
                         aborted=lambda: False)
    asyncio.run(rec.recover([v]))
    return v, router.requests


def test_a_sample_whose_answer_is_lost_round_after_round_still_comes(monkeypatch) -> None:
    """At 10 % loss each way a round fails to bring a last missing sample 27 % of the time;
    six such rounds in a row (a 4e-4 chance, met over many runs) must not make the station give
    up a sample the vehicle still has."""
    v, requests = recover(6, monkeypatch)
    assert MISSING_MS in v.seen_ms and v.missing == 0
    assert v.vehicle_samples == len(TAKEN_MS) and requests == 7


def test_a_sample_that_never_comes_is_given_up_and_counted(monkeypatch, caplog) -> None:
    """A vehicle that never answers for one sample: after RECOVERY_STALLED_ROUNDS rounds
    without progress the station stops asking, logs it and counts it missing."""
    v, requests = recover(10**9, monkeypatch)
    assert MISSING_MS not in v.seen_ms and v.missing == 1
    assert v.vehicle_samples == len(TAKEN_MS)
    assert requests == RECOVERY_STALLED_ROUNDS  # each round asked once, none brought it
    assert "1 of its 91 samples" in caplog.text
