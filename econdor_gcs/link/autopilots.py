"""What the station knows about each autopilot family, and the flight procedures built on it.

The station tells PX4 and ArduPilot apart by ``HEARTBEAT.autopilot`` and speaks to each in its
own way (read in PX4's ``commander`` and ArduPilot's ``GCS_MAVLink`` / ``ArduCopter`` sources):

================  =====================================  ======================================
                  PX4                                    ArduCopter
================  =====================================  ======================================
modes             ``DO_SET_MODE(CUSTOM, main, sub)``:    ``DO_SET_MODE(CUSTOM, number)``:
                  AUTO (4) . MISSION 4, LOITER 3,        AUTO 3, GUIDED 4, LOITER 5, RTL 6,
                  RTL 5, LAND 6                          LAND 9
takeoff param7    altitude AMSL                          altitude above home
arming            any hold/auto mode                     GUIDED (or LOITER / STABILIZE), not
                                                         AUTO; fails until the pre-arm checks
                                                         pass
starting          arm, ``MISSION_START(first)``          GUIDED, arm, ``MISSION_START(0, 0)``
                                                         (DENIED for any other first/last)
mission upload    ``MISSION_REQUEST_INT``                ``MISSION_REQUEST``; item 0 becomes
                                                         home
telemetry         streams from boot                      only after REQUEST_DATA_STREAM /
                                                         SET_MESSAGE_INTERVAL
================  =====================================  ======================================

:func:`arm_when_ready` waits while SYS_STATUS says the pre-arm checks fail and retries an
arming refused with FAILED / TEMPORARILY_REJECTED until its deadline: both autopilots refuse
to arm for a while after boot.
"""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass
from enum import StrEnum

from ..errors import CommandRejected, EcondorError, LinkError, VehicleTimeout
from .codec import MAVLinkMessage, mavlink
from .router import Router

__all__ = ["ARDUPILOT_POSITION_COMMANDS", "AutopilotKind", "FlightMode", "arm_when_ready",
           "flight_mode", "mission_start_params", "mode_params", "set_mode", "start_mission",
           "takeoff", "AUTOPILOT_NAMES", "VehicleKind"]

ARDUPILOT_POSITION_COMMANDS = frozenset({
    mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_UNLIM,
    mavlink.MAV_CMD_NAV_LOITER_TURNS, mavlink.MAV_CMD_NAV_LOITER_TIME, mavlink.MAV_CMD_NAV_LAND,
    mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_NAV_CONTINUE_AND_CHANGE_ALT,
    mavlink.MAV_CMD_NAV_LOITER_TO_ALT, mavlink.MAV_CMD_NAV_SPLINE_WAYPOINT,
    mavlink.MAV_CMD_NAV_GUIDED_ENABLE, mavlink.MAV_CMD_DO_SET_HOME, mavlink.MAV_CMD_DO_LAND_START,
    mavlink.MAV_CMD_DO_GO_AROUND, mavlink.MAV_CMD_DO_SET_ROI, mavlink.MAV_CMD_NAV_VTOL_TAKEOFF,
    mavlink.MAV_CMD_NAV_VTOL_LAND, mavlink.MAV_CMD_NAV_PAYLOAD_PLACE,
})
"""The mission commands ArduPilot stores with a position (``AP_Mission::stored_in_location``).
Any other comes back with frame 0 (MAV_FRAME_GLOBAL) and x, y, z = 0, whatever was sent:
DO_CHANGE_SPEED, RTL, ..."""
PX4_MAIN_AUTO = 4
PX4_SUB = {"mission": 4, "hold": 3, "rtl": 5, "land": 6, "takeoff": 2}
COPTER_NUMBER = {"mission": 3, "guided": 4, "hold": 5, "rtl": 6, "land": 9}
RETRYABLE_ARM = frozenset({mavlink.MAV_RESULT_FAILED, mavlink.MAV_RESULT_TEMPORARILY_REJECTED})


class AutopilotKind(StrEnum):
    """An autopilot family, from ``HEARTBEAT.autopilot``."""

    PX4 = "px4"
    ARDUPILOT = "ardupilot"
    GENERIC = "generic"

    @classmethod
    def of(cls, autopilot: int) -> AutopilotKind:
        """
        >>> AutopilotKind.of(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA).value
        'ardupilot'
        """
        if autopilot == mavlink.MAV_AUTOPILOT_PX4:
            return cls.PX4
        if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
            return cls.ARDUPILOT
        return cls.GENERIC


class FlightMode(StrEnum):
    """The modes the station asks for (each autopilot has its own number for them)."""

    MISSION = "mission"
    HOLD = "hold"
    GUIDED = "guided"
    RTL = "rtl"
    LAND = "land"


def mode_params(kind: AutopilotKind, mode: FlightMode) -> tuple[float, float, float]:
    """``DO_SET_MODE`` params 1-3 for ``mode`` on ``kind``.

    PX4 has no GUIDED: its AUTO.LOITER (hold) is what the station means by it.

    >>> mode_params(AutopilotKind.PX4, FlightMode.MISSION)
    (1.0, 4.0, 4.0)
    >>> mode_params(AutopilotKind.ARDUPILOT, FlightMode.GUIDED)
    (1.0, 4.0, 0.0)
    """
    base = float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
    if kind == AutopilotKind.PX4:
        sub = PX4_SUB["hold" if mode == FlightMode.GUIDED else mode.value]
        return base, float(PX4_MAIN_AUTO), float(sub)
    if kind == AutopilotKind.ARDUPILOT:
        return base, float(COPTER_NUMBER[mode.value]), 0.0
    raise LinkError(f"cannot set mode {mode.value!r} on a {kind.value} autopilot: its mode "
                    "numbers are not known")


def flight_mode(kind: AutopilotKind, custom_mode: int) -> FlightMode | None:
    """The mode a HEARTBEAT's ``custom_mode`` names, the inverse of :func:`mode_params`
    (None: a mode the station never asks for, e.g. PX4's AUTO.TAKEOFF, or an unknown
    autopilot).

    >>> flight_mode(AutopilotKind.PX4, (4 << 16) | (5 << 24)).value
    'rtl'
    >>> flight_mode(AutopilotKind.ARDUPILOT, 3).value
    'mission'
    """
    if kind == AutopilotKind.PX4:
        if (custom_mode >> 16) & 0xFF != PX4_MAIN_AUTO:
            return None
        sub = (custom_mode >> 24) & 0xFF
        return next((FlightMode(name) for name, n in PX4_SUB.items()
                     if n == sub and name in FlightMode.__members__.values()), None)
    if kind == AutopilotKind.ARDUPILOT:
        return next((FlightMode(name) for name, n in COPTER_NUMBER.items()
                     if n == custom_mode), None)
    return None


def _kind(router: Router, sysid: int) -> AutopilotKind:
    link = router.vehicles.get(sysid)
    if link is None:
        raise LinkError(f"vehicle {sysid} has never been heard from")
    return AutopilotKind.of(link.autopilot)


async def set_mode(router: Router, sysid: int, mode: FlightMode) -> MAVLinkMessage:
    """``MAV_CMD_DO_SET_MODE`` with the vehicle's own numbers for ``mode``."""
    return await router.command(sysid, mavlink.MAV_CMD_DO_SET_MODE,
                                *mode_params(_kind(router, sysid), mode))


async def takeoff(router: Router, sysid: int, alt_rel_m: float,
                  home_alt_amsl_m: float) -> MAVLinkMessage:
    """``MAV_CMD_NAV_TAKEOFF`` to ``alt_rel_m`` above home (PX4 wants param7 AMSL)."""
    kind = _kind(router, sysid)
    p7 = alt_rel_m + home_alt_amsl_m if kind == AutopilotKind.PX4 else alt_rel_m
    nan = math.nan
    return await router.command(sysid, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, p7)


async def arm_when_ready(router: Router, sysid: int, timeout_s: float = 30.0,
                         retry_s: float = 0.5) -> None:
    """Arm ``sysid``; wait while its pre-arm checks fail, retry a refused arming.

    Raises :class:`~econdor_gcs.errors.VehicleTimeout` naming the last refusal when the
    vehicle is not ready within ``timeout_s``, and
    :class:`~econdor_gcs.errors.CommandRejected` at once for a refusal that waiting cannot
    cure (DENIED, UNSUPPORTED).
    """
    deadline = time.monotonic() + timeout_s
    last = "its pre-arm checks fail (SYS_STATUS)"
    while True:
        link = router.vehicles.get(sysid)
        if link is not None and link.armed:
            return
        if link is None or link.prearm_ok is not False:
            try:
                await router.arm(sysid)
                return
            except CommandRejected as exc:
                if exc.result not in RETRYABLE_ARM:
                    raise
                last = str(exc)
        if time.monotonic() + retry_s > deadline:
            raise VehicleTimeout(f"vehicle {sysid} not ready to arm within {timeout_s:g} s: "
                                 f"{last}")
        await asyncio.sleep(retry_s)


def mission_start_params(kind: AutopilotKind, first_seq: int) -> tuple[int, int]:
    """``MAV_CMD_MISSION_START`` params 1-2 (first, last item) for a mission flown from
    ``first_seq``: ArduCopter denies any but ``(0, 0)`` ("first-item/last item not supported",
    its ``GCS_MAVLink_Copter.cpp``) and flies a mission from item 1 anyway (item 0 is home).

    >>> mission_start_params(AutopilotKind.ARDUPILOT, 1), mission_start_params(AutopilotKind.PX4, 1)
    ((0, 0), (1, 0))
    """
    return (0, 0) if kind == AutopilotKind.ARDUPILOT else (first_seq, 0)


async def start_mission(router: Router, sysid: int, first_seq: int = 1,
                        timeout_s: float = 30.0) -> None:
    """Arm (when ready) and start the uploaded mission at ``first_seq``, the autopilot's way.

    ArduCopter is first put in GUIDED (it does not arm in AUTO); both then get
    ``MAV_CMD_MISSION_START`` (:func:`mission_start_params`), which switches to the mission
    mode.
    """
    link = router.vehicles.get(sysid)
    kind = _kind(router, sysid)
    if kind == AutopilotKind.ARDUPILOT and not (link and link.armed):
        await set_mode(router, sysid, FlightMode.GUIDED)
    await arm_when_ready(router, sysid, timeout_s)
    await router.start_mission(sysid, *mission_start_params(kind, first_seq))


AUTOPILOT_NAMES = ("px4", "ardupilot")


@dataclass(frozen=True)
class VehicleKind:
    """A simulated vehicle's personality and whether a companion computer runs the tracer.

    >>> VehicleKind.parse("ardupilot+companion")
    VehicleKind(autopilot='ardupilot', companion=True)
    >>> str(VehicleKind("px4", False))
    'px4'
    """

    autopilot: str = "px4"
    companion: bool = True

    @classmethod
    def parse(cls, text: str) -> VehicleKind:
        name, plus, extra = text.strip().partition("+")
        if name not in AUTOPILOT_NAMES or (plus and extra != "companion"):
            raise EcondorError(f"--autopilot: {text!r} is not one of px4, ardupilot, "
                               "px4+companion, ardupilot+companion")
        return cls(name, bool(plus))

    def args(self) -> list[str]:
        """The ``sim-vehicle`` options for this kind."""
        return ["--autopilot", self.autopilot, *(["--companion"] if self.companion else [])]

    def __str__(self) -> str:
        return self.autopilot + ("+companion" if self.companion else "")
