"""The station's command vocabulary: what it asks of a vehicle, each as one protocol run.

:class:`CommandVocabulary` needs only a way to drive a protocol machine against a vehicle
(``run_protocol``), to send a message (``send``) and the vehicle table (``vehicles``); the
:class:`~.router.Router` shell provides them, so the words live here and the shell stays I/O.
Every command goes to the vehicle's autopilot (its route, see :mod:`.vehicles`) unless a
component is named (``compid``), e.g. a companion computer that keeps the samples.
"""

from __future__ import annotations

import asyncio
from typing import Any, Protocol

from econdor_gcs.link.items import MissionItemSpec
from econdor_gcs.link.transfer import (
    DEFAULT_RETRIES,
    DEFAULT_TIMEOUT_S,
    CommandSender,
    MissionClear,
    MissionDownloader,
    MissionUploader,
)

from ..errors import LinkError, MissionRejected
from .codec import MAVLinkMessage, mavlink
from .vehicles import AUTOPILOT_COMPONENT, VehicleLink

__all__ = ["CommandVocabulary", "Machine"]

FORCE_ARM_DISARM = 21196
"""COMPONENT_ARM_DISARM param2 that disarms in the air / skips the checks."""
NO_SPACE_WAIT_S = 10.0
"""How long an upload refused whole with MAV_MISSION_NO_SPACE is tried again: ArduCopter
answers so until its mission storage is ready, about 3 s of its own time after boot."""
NO_SPACE_RETRY_S = 0.25
ARDUPILOT_IN_PLACE = frozenset({mavlink.MAV_MISSION_TYPE_MISSION, mavlink.MAV_MISSION_TYPE_RALLY})
"""Mission types ArduPilot writes as the items come: an upload left part-way leaves the new
items over the old (seen on SITL for the mission and the rally points; its fence is replaced
only when an upload completes)."""


class Machine(Protocol):
    done: bool
    result: object
    error: Exception | None
    target_system: int
    target_component: int

    def receive(self, msg: MAVLinkMessage, now: float) -> None: ...
    def poll(self, now: float) -> list[MAVLinkMessage]: ...
    def next_deadline(self) -> float | None: ...


class CommandVocabulary:
    """Mission transfers and commands by name (a part of the :class:`~.router.Router`)."""

    vehicles: dict[int, VehicleLink]
    _mission_locks: dict[int, asyncio.Lock]

    async def run_protocol(self, sysid: int, machine: Machine,
                           timeout_s: float | None = None) -> Any:  # pragma: no cover
        raise NotImplementedError

    def send(self, sysid: int, msg: MAVLinkMessage) -> None:  # pragma: no cover
        raise NotImplementedError

    # -- addressing -------------------------------------------------------------------------
    def _vehicle(self, sysid: int) -> VehicleLink:
        link = self.vehicles.get(sysid)
        if link is None:
            raise LinkError(f"vehicle {sysid} has never been heard from")
        return link

    def _compid(self, sysid: int) -> int:
        """The autopilot: commands and missions go to (system, component 1)."""
        return AUTOPILOT_COMPONENT

    def _lock(self, sysid: int) -> asyncio.Lock:
        return self._mission_locks.setdefault(sysid, asyncio.Lock())

    # -- missions ---------------------------------------------------------------------------
    async def upload_mission(self, sysid: int, items: list[MissionItemSpec], *,
                             mission_type: int = 0, timeout_s: float = DEFAULT_TIMEOUT_S,
                             retries: int = DEFAULT_RETRIES, legacy_items: bool = False,
                             no_space_wait_s: float = NO_SPACE_WAIT_S) -> int:
        """Upload a mission; return the number of items.  One mission transfer per vehicle at a
        time (later calls wait). A whole mission refused with MAV_MISSION_NO_SPACE is sent
        again for up to ``no_space_wait_s`` (an autopilot that has just booted).

        An upload the station leaves after the vehicle began to take it (no answer, an error,
        the caller cancelled) is cancelled with MISSION_ACK(OPERATION_CANCELLED), as the
        mission protocol says: PX4 refuses every new count (MAV_MISSION_ERROR) while it
        takes an upload until that cancel, or 5 s without a word, ends it; a count refused
        so is followed by the cancel too (the first may have been lost). One that ends
        part-way on an ArduPilot, which writes each item into its mission as it comes and
        does not act on that cancel, is kept in
        :attr:`~.vehicles.VehicleLink.partial_missions`: its mission is now part new, part
        old (:meth:`clear_mission` empties it)."""
        loop = asyncio.get_running_loop()
        give_up = loop.time() + no_space_wait_s
        async with self._lock(sysid):
            while True:
                machine = MissionUploader(sysid, self._compid(sysid), items, mission_type,
                                          timeout_s=timeout_s, retries=retries,
                                          legacy_items=legacy_items)
                try:
                    n = int(await self.run_protocol(sysid, machine))
                except MissionRejected as exc:
                    self._left_part_way(sysid, machine, cancel=False)
                    if exc.seq is None and exc.result == mavlink.MAV_MISSION_ERROR:
                        # PX4 refuses a count so while it takes an upload (ours, left part
                        # way, whose cancel was lost): cancel it, so the next one is taken
                        self._cancel(sysid, mission_type)
                    if exc.result != mavlink.MAV_MISSION_NO_SPACE or exc.seq is not None \
                            or loop.time() + NO_SPACE_RETRY_S > give_up:
                        raise
                except BaseException:
                    self._left_part_way(sysid, machine, cancel=True)
                    raise
                else:
                    self._vehicle(sysid).partial_missions.discard(mission_type)
                    return n
                await asyncio.sleep(NO_SPACE_RETRY_S)

    def _left_part_way(self, sysid: int, machine: MissionUploader, *, cancel: bool) -> None:
        """The upload ``machine`` ended without success: if the vehicle had begun to take it,
        cancel it (unless the vehicle ended it itself, ``cancel`` False) and note an
        ArduPilot's partial mission."""
        if not machine.requested:
            return
        link = self.vehicles.get(sysid)
        if cancel:
            self._cancel(sysid, machine.mission_type)
        if link is not None and link.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA \
                and machine.mission_type in ARDUPILOT_IN_PLACE:
            link.partial_missions.add(machine.mission_type)

    async def download_mission(self, sysid: int, *, mission_type: int = 0,
                               timeout_s: float = DEFAULT_TIMEOUT_S,
                               retries: int = DEFAULT_RETRIES) -> list[MissionItemSpec]:
        async with self._lock(sysid):
            machine = MissionDownloader(sysid, self._compid(sysid), mission_type,
                                        timeout_s=timeout_s, retries=retries)
            return list(await self.run_protocol(sysid, machine))

    async def clear_mission(self, sysid: int, *, mission_type: int = 0,
                            timeout_s: float = DEFAULT_TIMEOUT_S,
                            retries: int = DEFAULT_RETRIES) -> None:
        async with self._lock(sysid):
            machine = MissionClear(sysid, self._compid(sysid), mission_type,
                                   timeout_s=timeout_s, retries=retries)
            await self.run_protocol(sysid, machine)
        partial = self._vehicle(sysid).partial_missions
        for t in (list(partial) if mission_type == mavlink.MAV_MISSION_TYPE_ALL
                  else [mission_type]):
            partial.discard(t)

    def _cancel(self, sysid: int, mission_type: int) -> None:
        """MISSION_ACK(OPERATION_CANCELLED): the mission protocol's word that the station
        gives up the upload of ``mission_type`` it began (PX4 ends it; ArduPilot ignores it
        and times out)."""
        self.send(sysid, mavlink.MAVLink_mission_ack_message(
            sysid, self._compid(sysid), mavlink.MAV_MISSION_OPERATION_CANCELLED, mission_type))

    async def clear_partial_missions(self, sysid: int, *,
                                     timeout_s: float = DEFAULT_TIMEOUT_S,
                                     retries: int = DEFAULT_RETRIES) -> list[int]:
        """Clear each mission type whose last upload to ``sysid`` ended part-way on an
        autopilot that keeps what it took (:attr:`~.vehicles.VehicleLink.partial_missions`;
        MISSION_CLEAR_ALL also ends ArduPilot's transfer if it still runs); return the types
        cleared, in order. Waits for an upload still ending (the mission lock)."""
        cleared: list[int] = []
        async with self._lock(sysid):
            partial = self._vehicle(sysid).partial_missions
            for mtype in sorted(partial):
                await self.run_protocol(sysid, MissionClear(
                    sysid, self._compid(sysid), mtype, timeout_s=timeout_s, retries=retries))
                partial.discard(mtype)
                cleared.append(mtype)
        return cleared

    # -- commands ---------------------------------------------------------------------------
    async def command(self, sysid: int, cmd: int, *params: float,
                      timeout_s: float = DEFAULT_TIMEOUT_S, retries: int = DEFAULT_RETRIES,
                      compid: int | None = None) -> MAVLinkMessage:
        """COMMAND_LONG with up to 7 params; return the accepting COMMAND_ACK."""
        machine = CommandSender(sysid, self._compid(sysid) if compid is None else compid, cmd,
                                params, timeout_s=timeout_s, retries=retries)
        return await self.run_protocol(sysid, machine)

    async def command_int(self, sysid: int, cmd: int, x: int, y: int, z: float = 0.0,
                          *params: float, timeout_s: float = DEFAULT_TIMEOUT_S,
                          retries: int = DEFAULT_RETRIES,
                          compid: int | None = None) -> MAVLinkMessage:
        """COMMAND_INT with exact int32 ``x``/``y``; return the accepting COMMAND_ACK."""
        machine = CommandSender(sysid, self._compid(sysid) if compid is None else compid, cmd,
                                params, timeout_s=timeout_s, retries=retries,
                                position=(x, y, z))
        return await self.run_protocol(sysid, machine)

    def send_command_int(self, sysid: int, cmd: int, x: int, y: int, z: float = 0.0, *,
                         compid: int | None = None) -> None:
        """COMMAND_INT without waiting for its answer (requests whose effect is seen)."""
        self.send(sysid, mavlink.MAVLink_command_int_message(
            sysid, self._compid(sysid) if compid is None else compid,
            mavlink.MAV_FRAME_GLOBAL_INT, cmd, 0, 0, 0.0, 0.0, 0.0, 0.0, x, y, z))

    async def arm(self, sysid: int, *, force: bool = False) -> MAVLinkMessage:
        return await self.command(sysid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1,
                                  FORCE_ARM_DISARM if force else 0)

    async def disarm(self, sysid: int, *, force: bool = False) -> MAVLinkMessage:
        return await self.command(sysid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                  FORCE_ARM_DISARM if force else 0)

    async def set_mode(self, sysid: int, main_mode: int, sub_mode: int = 0,
                       base_mode: int = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                       ) -> MAVLinkMessage:
        """MAV_CMD_DO_SET_MODE: param1 ``base_mode``, param2 the custom main mode, param3 the
        custom sub mode.

        PX4 reads its main mode (4 = AUTO) from param2 and the AUTO sub mode (2 TAKEOFF,
        3 LOITER, 4 MISSION, 5 RTL, 6 LAND) from param3 -- not the packed
        ``main << 16 | sub << 24`` of its HEARTBEAT; ArduPilot reads its mode number from
        param2 (``sub_mode`` 0).
        """
        return await self.command(sysid, mavlink.MAV_CMD_DO_SET_MODE, base_mode, main_mode,
                                  sub_mode)

    async def takeoff(self, sysid: int, alt_rel_m: float) -> MAVLinkMessage:
        """MAV_CMD_NAV_TAKEOFF to ``alt_rel_m`` above home, here.

        PX4 (and our simulated vehicle) read param7 as an altitude AMSL: home's AMSL altitude
        comes from the vehicle's last GLOBAL_POSITION_INT (``alt - relative_alt``). ArduPilot
        reads param7 above home, so it gets ``alt_rel_m`` as is.
        """
        link = self._vehicle(sysid)
        param7 = alt_rel_m
        if link.autopilot != mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
            if link.alt_m is None or link.rel_alt_m is None:
                raise LinkError(f"vehicle {sysid}: no position yet, so no home altitude to "
                                "take off from")
            param7 = link.alt_m - link.rel_alt_m + alt_rel_m
        nan = float("nan")
        return await self.command(sysid, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan,
                                  param7)

    async def start_mission(self, sysid: int, first: int = 0, last: int = 0) -> MAVLinkMessage:
        """MAV_CMD_MISSION_START (``first = last = 0``: the whole mission)."""
        return await self.command(sysid, mavlink.MAV_CMD_MISSION_START, first, last)

    async def return_to_launch(self, sysid: int) -> MAVLinkMessage:
        return await self.command(sysid, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)

    async def set_message_interval(self, sysid: int, message_id: int,
                                   interval_s: float) -> MAVLinkMessage:
        """MAV_CMD_SET_MESSAGE_INTERVAL (``interval_s <= 0``: -1, stop the stream)."""
        interval_us = -1 if interval_s <= 0 else interval_s * 1e6
        return await self.command(sysid, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, message_id,
                                  interval_us)

    def request_data_streams(self, sysid: int, rate_hz: int = 1) -> None:
        """Ask for all telemetry streams the legacy way (REQUEST_DATA_STREAM; ArduPilot sends only
        heartbeats until asked).  Fire and forget; PX4 and our simulated vehicle ignore it.

        ``rate_hz`` is in the vehicle's time: ArduPilot has some thirty messages in these
        streams, and SITL at a 20x speed-up sent them at 80 Hz each at 4 Hz, enough to
        fill its link and make it thin out every stream (the positions too: gaps of
        1.2 s). What the station needs faster (the positions) it asks for by message."""
        self.send(sysid, mavlink.MAVLink_request_data_stream_message(
            sysid, self._compid(sysid), mavlink.MAV_DATA_STREAM_ALL, rate_hz, 1))
