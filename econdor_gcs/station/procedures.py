"""Commands over a lossy link: a command is done when the vehicle's own telemetry says so.

A ``COMMAND_ACK`` can be lost as easily as the command: at 20 % loss each way a command
and its answer both arrive 64 % of the time, and six tries in a row fail 0.2 % of the time,
about once a run over dozens of commands. The vehicle's telemetry says the same thing again
every second (HEARTBEAT: armed, mode; MISSION_CURRENT: the mission's state), so the station
asks it before it sends a command (nothing to do when the vehicle already is where the
command would take it), and again after a command went unanswered, before it sends it once
more. Only the machine-readable messages count (never STATUSTEXT).

:func:`ensure` is that loop; :class:`Commands` the procedures of a flight built on it
(start a mission the autopilot's way, return to launch, disarm). It runs on the station's
loop thread, a part of :class:`~.gcs.MavlinkExecutor`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Awaitable, Callable

from econdor_gcs.errors import CommandRejected, LinkError, VehicleTimeout
from econdor_gcs.link.autopilots import (
    AutopilotKind,
    FlightMode,
    arm_when_ready,
    flight_mode,
    mission_start_params,
    set_mode,
)
from econdor_gcs.link.router import AIRBORNE_ALT_M, Router
from econdor_gcs.station.recovery import Until
from econdor_gcs.station.telemetry import VehicleState

__all__ = ["COMMAND_TRIES", "EVIDENCE_WAIT_S", "Commands", "ensure"]

log = logging.getLogger(__name__)

EVIDENCE_WAIT_S = 2.5
"""After a command went unanswered: how long to wait for telemetry that shows it done
(the HEARTBEAT and MISSION_CURRENT come every second; at 20 % loss two in a row are both
lost 4 % of the time) before the command is sent again."""
COMMAND_TRIES = 4
"""Commands (each with the link layer's own retries) sent before the station gives up on
one that neither an acknowledgement nor the vehicle's telemetry shows done: 4 x 6 tries,
all lost at 20 % each way: 0.36**24 = 2e-11."""


async def ensure(send: Callable[[], Awaitable[object]], done: Callable[[], bool], what: str,
                 until: Until, *, tries: int = COMMAND_TRIES) -> None:
    """Send until ``done()`` holds or the vehicle acknowledges.

    ``done`` is the vehicle's telemetry saying the command's effect is there: checked first
    (nothing is sent when it holds), and awaited :data:`EVIDENCE_WAIT_S` after an
    unanswered send. A refusal (:class:`CommandRejected`) stands unless ``done`` holds; an
    unanswered command sent ``tries`` times raises the last :class:`VehicleTimeout`.
    """
    last: LinkError | None = None
    for attempt in range(tries):
        if done():
            return
        try:
            await send()
            return
        except CommandRejected:
            if done():
                return
            raise
        except VehicleTimeout as exc:
            last = exc
            if await until(done, deadline=time.monotonic() + EVIDENCE_WAIT_S):
                log.info("%s: no acknowledgement, but the vehicle's telemetry shows it done",
                         what)
                return
            if attempt + 1 < tries:
                log.warning("%s: no answer and no sign of it in the telemetry; again", what)
    assert last is not None
    raise last


class Commands:
    """A flight's commands, each done when acknowledged or seen done (a part of
    :class:`~.gcs.MavlinkExecutor`).

    Parameters
    ----------
    router:
        The station's router: the commands, and the vehicles' HEARTBEATs.
    until:
        The executor's wait (woken by whatever the vehicles send).
    timeout_s:
        How long arming may wait for the pre-arm checks.
    """

    def __init__(self, router: Router, until: Until, timeout_s: float) -> None:
        self.router = router
        self.until = until
        self.timeout_s = timeout_s

    def _kind(self, v: VehicleState) -> AutopilotKind:
        return AutopilotKind.of(self.router.vehicles[v.sysid].autopilot)

    def mode(self, v: VehicleState) -> FlightMode | None:
        """The vehicle's mode, from its last HEARTBEAT."""
        link = self.router.vehicles[v.sysid]
        return flight_mode(AutopilotKind.of(link.autopilot), link.custom_mode)

    def armed(self, v: VehicleState) -> bool:
        return self.router.vehicles[v.sysid].armed

    def down(self, v: VehicleState) -> bool:
        """Landed and disarmed (its HEARTBEAT and its last position)."""
        link = self.router.vehicles[v.sysid]
        return not link.armed and (link.rel_alt_m or 0.0) < AIRBORNE_ALT_M

    async def start_mission(self, v: VehicleState, first_seq: int = 1) -> None:
        """Arm (when ready) and start the uploaded mission at ``first_seq`` the autopilot's
        way (:func:`~.link.autopilots.start_mission`), each step done when acknowledged or
        when the telemetry shows it: GUIDED in the HEARTBEAT (ArduPilot), armed in the
        HEARTBEAT, and news of the uploaded mission after the first MISSION_START was sent:
        a MISSION_CURRENT of it ACTIVE, PAUSED or COMPLETE (a short mission can be over
        within a second), or a MISSION_ITEM_REACHED (ArduPilot stays in AUTO after a
        mission: its mode alone cannot tell an old mission from the new one). A second
        MISSION_START would fly the mission again from its start."""
        sysid = v.sysid
        if self._kind(v) == AutopilotKind.ARDUPILOT and not self.armed(v):
            await ensure(lambda: set_mode(self.router, sysid, FlightMode.GUIDED),
                         lambda: self.mode(v) == FlightMode.GUIDED,
                         f"vehicle {sysid}: GUIDED", self.until)
        deadline = time.monotonic() + self.timeout_s

        async def arm() -> None:  # the pre-arm wait is one, over every try
            await arm_when_ready(self.router, sysid, max(0.0, deadline - time.monotonic()))

        await ensure(arm, lambda: self.armed(v), f"vehicle {sysid}: arming", self.until)
        sent = time.monotonic()
        first, last = mission_start_params(self._kind(v), first_seq)
        await ensure(lambda: self.router.start_mission(sysid, first, last),
                     lambda: v.mission_news_at > sent and self.armed(v),
                     f"vehicle {sysid}: MAV_CMD_MISSION_START", self.until)

    async def return_to_launch(self, v: VehicleState) -> None:
        """RTL, done when the HEARTBEAT shows RTL or LAND, or the vehicle is down already
        (a refusal then is no failure: a landed vehicle refuses an RTL)."""
        await ensure(lambda: self.router.return_to_launch(v.sysid),
                     lambda: self.mode(v) in (FlightMode.RTL, FlightMode.LAND) or self.down(v),
                     f"vehicle {v.sysid}: RTL", self.until)

    async def disarm(self, v: VehicleState) -> None:
        await ensure(lambda: self.router.disarm(v.sysid), lambda: not self.armed(v),
                     f"vehicle {v.sysid}: disarming", self.until)
