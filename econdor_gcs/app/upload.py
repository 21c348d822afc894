"""``econdor upload``: a mission file to any MAVLink autopilot, read back and verified.

The file (QGC WPL or QGroundControl ``.plan``, :mod:`econdor_gcs.files.autopilot_files`) goes up with
the station's mission state machine (:class:`~econdor_gcs.link.transfer.MissionUploader`:
timeouts, retries, either request flavour), with the ``.plan``'s geofence and rally points as
mission types FENCE and RALLY. Each is then downloaded and compared item by item
(:func:`compare_items`), allowing what autopilots are known to do to a mission they store:

* ArduPilot replaces item 0 with its home position (frame MAV_FRAME_GLOBAL, altitude AMSL),
  reports the float frames (3 for 6, 0 for 5, 10 for 11), keeps altitudes in centimetres and
  sets autocontinue, and keeps no position for commands that have none (DO_CHANGE_SPEED,
  RTL, ...: :data:`~.link.autopilots.ARDUPILOT_POSITION_COMMANDS`), which come back with
  frame 0 and x, y, z = 0; every autopilot may report ``current`` its own way;
* values travel as float32 (params, altitude) and degE7 integers (latitude/longitude).

Anything else that comes back different is an error naming the item and the field.
``--start`` then starts the mission the autopilot's way (:func:`~.link.autopilots.start_mission`:
mode, pre-arm wait, arm, MISSION_START).
"""

from __future__ import annotations

import argparse
import math
import struct
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from econdor_gcs.errors import EcondorError, MissionRejected
from econdor_gcs.files.autopilot_files import MissionFile, is_global_frame, is_home_item, read_mission_file
from econdor_gcs.files.plausibility import check_plausible
from econdor_gcs.link.autopilots import ARDUPILOT_POSITION_COMMANDS, AutopilotKind, start_mission
from econdor_gcs.link.codec import mavlink
from econdor_gcs.link.items import INT_TO_FLOAT_FRAME, SENSOR_LAG_COMMAND, MissionItemSpec
from econdor_gcs.link.router import Router

if TYPE_CHECKING:
    from econdor_gcs.station.loop import Station

__all__ = ["Mismatch", "compare_items", "upload_cli", "upload_verified"]

ARDUPILOT_ALT_STEP_M = 0.01
"""ArduPilot stores mission altitudes in centimetres."""
_TYPE_NAMES = {mavlink.MAV_MISSION_TYPE_MISSION: "mission", mavlink.MAV_MISSION_TYPE_FENCE: "fence",
               mavlink.MAV_MISSION_TYPE_RALLY: "rally"}


@dataclass(frozen=True)
class Mismatch:
    """Item ``seq`` came back with ``field`` = ``got`` instead of ``sent``."""

    seq: int
    field: str
    sent: object
    got: object

    def __str__(self) -> str:
        return f"item {self.seq} {self.field}: sent {self.sent!r}, got back {self.got!r}"


def _float_frame(frame: int) -> int:
    return INT_TO_FLOAT_FRAME.get(frame, frame)


def _f32(v: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", v))[0])


def _same_float(a: float, b: float, tol: float = 0.0) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(_f32(a) - _f32(b)) <= tol


def compare_items(sent: Sequence[MissionItemSpec], got: Sequence[MissionItemSpec],
                  autopilot: AutopilotKind = AutopilotKind.GENERIC) -> list[Mismatch]:
    """What came back different from what was sent, beyond the autopilot's known habits.

    >>> from econdor_gcs.link.items import waypoint_item
    >>> a = [waypoint_item(0, 47.0, 8.0, 10.0), waypoint_item(1, 47.1, 8.1, 12.345)]
    >>> b = [waypoint_item(0, 46.0, 7.0, 500.0), waypoint_item(1, 47.1, 8.1, 12.35)]
    >>> compare_items(a, b, AutopilotKind.ARDUPILOT)
    []
    >>> [str(m) for m in compare_items(a, b, AutopilotKind.PX4)][:1]
    ['item 0 x: sent 470000000, got back 460000000']

    ArduPilot keeps no frame or position for a command without one:

    >>> from econdor_gcs.link.items import change_speed_item, rtl_item
    >>> import dataclasses
    >>> sent = [change_speed_item(0, 8.0), rtl_item(1)]
    >>> back = [dataclasses.replace(it, frame=0) for it in sent]
    >>> compare_items(sent, back, AutopilotKind.ARDUPILOT), len(compare_items(sent, back))
    ([], 2)
    """
    if len(sent) != len(got):
        return [Mismatch(-1, "count", len(sent), len(got))]
    ardupilot = autopilot == AutopilotKind.ARDUPILOT
    z_tol = ARDUPILOT_ALT_STEP_M / 2 + 1e-4 if ardupilot else 0.0
    out: list[Mismatch] = []
    for a, b in zip(sent, got, strict=True):
        mission = a.mission_type == mavlink.MAV_MISSION_TYPE_MISSION
        if ardupilot and mission and a.seq == 0:
            continue  # ArduPilot keeps its home position as item 0
        # ArduPilot stores no position (nor frame) for a command that has none
        no_position = ardupilot and mission and a.command not in ARDUPILOT_POSITION_COMMANDS
        frame_ok = _float_frame(a.frame) == _float_frame(b.frame) or \
            (no_position and b.frame == mavlink.MAV_FRAME_GLOBAL)
        checks: list[tuple[str, object, object, bool]] = [
            ("seq", a.seq, b.seq, a.seq == b.seq),
            ("command", a.command, b.command, a.command == b.command),
            ("frame", a.frame, b.frame, frame_ok),
            ("autocontinue", a.autocontinue, b.autocontinue,
             a.autocontinue == b.autocontinue or ardupilot),
        ]
        for name in ("param1", "param2", "param3", "param4"):
            va, vb = getattr(a, name), getattr(b, name)
            checks.append((name, va, vb, _same_float(va, vb)))
        if no_position and (b.x, b.y, b.z) == (0, 0, 0.0):
            pass
        elif is_global_frame(a.frame):
            checks += [("x", a.x, b.x, a.x == b.x), ("y", a.y, b.y, a.y == b.y),
                       ("z", a.z, b.z, _same_float(a.z, b.z, z_tol))]
        else:
            checks += [("x", a.x, b.x, _same_float(a.x, b.x)),
                       ("y", a.y, b.y, _same_float(a.y, b.y)),
                       ("z", a.z, b.z, _same_float(a.z, b.z, z_tol))]
        out += [Mismatch(a.seq, name, va, vb) for name, va, vb, ok in checks if not ok]
    return out


@dataclass
class UploadResult:
    sysid: int
    autopilot: AutopilotKind
    counts: dict[str, int]
    home_replaced: bool


async def upload_verified(router: Router, sysid: int, mfile: MissionFile,
                          timeout_s: float = 30.0) -> UploadResult:
    """Upload the mission (and fence, rally), download each back, verify item by item.

    Raises :class:`~econdor_gcs.errors.MissionRejected` when the vehicle refuses an item, and
    :class:`~econdor_gcs.errors.EcondorError` listing the differences when what it stored is
    not what was sent.
    """
    link = router.vehicles[sysid]
    kind = AutopilotKind.of(link.autopilot)
    if kind == AutopilotKind.ARDUPILOT and mfile.items and not is_home_item(mfile.items):
        first = mfile.items[0]
        raise EcondorError(f"vehicle {sysid} is an ArduPilot: it replaces item 0 with its home, "
                           f"and item 0 of this mission is command {first.command}, not a home "
                           "waypoint (put a home item first, as econdor export does)")
    counts: dict[str, int] = {}
    home_replaced = False
    for mtype, items in ((mavlink.MAV_MISSION_TYPE_MISSION, mfile.items),
                         (mavlink.MAV_MISSION_TYPE_FENCE, mfile.fence),
                         (mavlink.MAV_MISSION_TYPE_RALLY, mfile.rally)):
        name = _TYPE_NAMES[mtype]
        if not items and mtype != mavlink.MAV_MISSION_TYPE_MISSION:
            continue
        await router.upload_mission(sysid, list(items), mission_type=mtype,
                                    timeout_s=min(3.0, timeout_s))
        back = await router.download_mission(sysid, mission_type=mtype,
                                             timeout_s=min(3.0, timeout_s))
        diffs = compare_items(items, back, kind)
        if diffs:
            shown = "; ".join(str(d) for d in diffs[:4])
            more = f" (and {len(diffs) - 4} more)" if len(diffs) > 4 else ""
            raise EcondorError(f"vehicle {sysid}: the {name} read back differs from the file: "
                               f"{shown}{more}")
        if mtype == mavlink.MAV_MISSION_TYPE_MISSION and items and back:
            a, b = items[0], back[0]
            home_replaced = (a.frame, a.x, a.y, a.z) != (b.frame, b.x, b.y, b.z)
        counts[name] = len(items)
    return UploadResult(sysid, kind, counts, home_replaced)


_WHAT = {mavlink.MAV_MISSION_TYPE_MISSION: "mission", mavlink.MAV_MISSION_TYPE_RALLY: "rally points"}


def _clear_partial(station: Station, sysid: int) -> str:
    """After an upload that failed: an ArduPilot left with part of it over what it had (it
    writes mission items and rally points as they come) gets them cleared, so that nothing
    flies a mix of two. Returns what to add to the error ("" when nothing was left)."""
    try:
        cleared = station.call(station.router.clear_partial_missions(sysid), timeout_s=10.0)
    except Exception as exc:  # noqa: BLE001 - reported, with what the vehicle now holds
        left = station.router.vehicles[sysid].partial_missions
        if not left:
            return ""
        names = " and ".join(_WHAT.get(t, str(t)) for t in sorted(left))
        verb = "is" if left == {mavlink.MAV_MISSION_TYPE_MISSION} else "are"
        return (f"; its {names} {verb} now part this upload, part what it had (ArduPilot "
                f"stores items as they come), and clearing failed ({exc}): clear "
                f"{'it' if verb == 'is' else 'them'} before flying")
    if not cleared:
        return ""
    names = " and ".join(_WHAT.get(t, str(t)) for t in cleared)
    verb = "was" if cleared == [mavlink.MAV_MISSION_TYPE_MISSION] else "were"
    return (f"; its {names} {verb} cleared (ArduPilot had stored part of this upload over "
            "what it had)")


def upload_cli(args: argparse.Namespace) -> int:
    """``econdor upload PATH --connect udpin:HOST:PORT [--sysid N] [--start] [--timeout S]``."""
    from econdor_gcs.station.loop import Station

    mfile = read_mission_file(Path(args.path))
    if not mfile.items:
        raise EcondorError(f"{args.path}: the mission is empty")
    if not getattr(args, "force", False):  # before a link is opened: nothing reaches the aircraft
        try:
            check_plausible(mfile, str(args.path))
        except EcondorError as exc:
            raise EcondorError(f"{exc} (--force uploads it anyway)") from None
    station = Station(args.connect, heartbeat_timeout_s=args.timeout)
    try:
        station.start()
        router = station.router
        wanted = [args.sysid] if args.sysid is not None else 1
        sysid = station.call(router.wait_for_vehicles(wanted, args.timeout))[0]
        router.request_data_streams(sysid)
        try:
            result = station.call(upload_verified(router, sysid, mfile, args.timeout))
        except MissionRejected as exc:
            hint = ""
            if exc.command in (mavlink.MAV_CMD_WAYPOINT_USER_1, SENSOR_LAG_COMMAND):
                hint = (" (a stock autopilot flies contours as waypoints: export with "
                        "--style waypoints)")
            raise EcondorError(f"{exc}{hint}{_clear_partial(station, sysid)}") from None
        except EcondorError as exc:
            raise EcondorError(f"{exc}{_clear_partial(station, sysid)}") from None
        except KeyboardInterrupt:
            if note := _clear_partial(station, sysid):
                print(f"econdor: vehicle {sysid}:{note.removeprefix(';')}", file=sys.stderr)
            raise
        parts = [f"{n} {name} item{'' if n == 1 else 's'}" for name, n in result.counts.items()]
        note = " (item 0 replaced by its home, as ArduPilot does)" if result.home_replaced else ""
        print(f"vehicle {sysid} ({result.autopilot.value}): uploaded and verified "
              f"{', '.join(parts)}{note}")
        if args.start:
            station.call(start_mission(router, sysid, 1, args.timeout))
            print(f"vehicle {sysid}: mission started")
    finally:
        station.close()
    return 0
