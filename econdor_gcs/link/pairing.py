"""Samples placed where they were taken: each vehicle's position track, interpolated in time.

A payload sends its measurement as ``NAMED_VALUE_FLOAT("FIELD")`` stamped with the
autopilot's clock (``time_boot_ms``); the autopilot sends its position as
``GLOBAL_POSITION_INT`` on the same clock. Only our simulated vehicles send the two with one
stamp; an ArduPilot Lua script stamps the moment it sends, and a companion computer the time
it estimates on the autopilot's clock. So the station keeps each vehicle's position track and
places a sample at its ``time_boot_ms`` (:class:`SamplePairer`):

* a position with the sample's very stamp: that position (``exact``);
* positions before and after it, at most :data:`MAX_GAP_MS` apart: linear interpolation in
  time between the two (``interpolated``); farther apart (up to :data:`STILL_GAP_MS`) only
  when the two are within :data:`STILL_M` of each other: the vehicle held its place across
  the gap (ArduCopter pauses its position stream for seconds while it takes a mission
  upload, hovering, and its Lua script samples on);
* otherwise the sample waits (a later position, or a late or resent one, may come) up to
  :data:`HOLD_S` of wall time, then is dropped and counted by reason: ``gap`` (the positions
  around it are too far apart), ``no_position_before`` or ``no_position_after``.

Sans-IO: the shell gives each message and the time (``now``, wall seconds of any monotonic
clock); positions and samples may arrive in any order, resent ones included.
"""

from __future__ import annotations

import bisect
import math
from array import array
from collections import Counter
from dataclasses import dataclass
from enum import StrEnum

from ..core.geodesy import Origin
from .codec import MAVLinkMessage

__all__ = ["HOLD_S", "MAX_GAP_MS", "STILL_GAP_MS", "STILL_M", "DropReason", "Placement",
           "PositionTrack", "Sample", "SamplePairer"]

SAMPLE_NAME = "FIELD"
MAX_GAP_MS = 1000
"""Widest span of vehicle time between two positions that a sample is interpolated in: at
8 m/s, 8 m of straight flight (linear interpolation is exact there; in a turn of 10 m radius
the chord is at most 0.8 m off the arc). Positions at the sensor's rate lose ten in a row
before a sample is dropped."""
STILL_GAP_MS = 10_000
"""Widest gap a sample is interpolated in when the vehicle kept its place across it."""
STILL_M = 1.0
"""Positions this close (horizontally and vertically) on either side of a gap of up to
:data:`STILL_GAP_MS`: the vehicle held its place, and a sample in the gap is placed to
about this much."""
HOLD_S = 2.0
"""Wall time a sample waits for the positions that would place it."""
REBOOT_MS = 10_000
"""A position this far behind the newest means the autopilot restarted: a new clock."""
TRACK_KEEP = 200_000
"""Positions kept per vehicle (5.5 hours at 10 Hz); the oldest go first."""
MAX_HELD = 100_000
"""Samples waiting at most, over all vehicles (then the oldest are dropped, ``overflow``)."""


class Placement(StrEnum):
    EXACT = "exact"
    INTERPOLATED = "interpolated"


class DropReason(StrEnum):
    GAP = "gap"
    NO_POSITION_BEFORE = "no_position_before"
    NO_POSITION_AFTER = "no_position_after"
    OVERFLOW = "overflow"


@dataclass(frozen=True)
class Sample:
    """One field measurement placed on the map: ``NAMED_VALUE_FLOAT("FIELD")`` at the
    vehicle's position at its ``time_boot_ms``. ``rel_alt_m`` is above home; ``compid`` the
    component that sent the value (the payload: the autopilot's Lua, or a companion)."""

    sysid: int
    time_boot_ms: int
    lat_deg: float
    lon_deg: float
    rel_alt_m: float
    value: float
    placement: Placement = Placement.EXACT
    compid: int = 1


class PositionTrack:
    """One vehicle's positions by ``time_boot_ms`` (sorted; a resent one goes in its place).

    >>> t = PositionTrack()
    >>> t.add(1000, 47.0, 8.0, 10.0), t.add(2000, 47.0, 8.004, 20.0)
    (False, False)
    >>> t.at(1250, 1000)
    (47.0, 8.001, 12.5, False)
    >>> t.at(2000, 1000)
    (47.0, 8.004, 20.0, True)
    >>> t.at(2500, 1000) is None, t.newest_ms
    (True, 2000)
    """

    def __init__(self, keep: int = TRACK_KEEP) -> None:
        self.keep = keep
        self._ms = array("q")
        self._lat = array("d")
        self._lon = array("d")
        self._alt = array("d")

    def __len__(self) -> int:
        return len(self._ms)

    @property
    def newest_ms(self) -> int | None:
        return self._ms[-1] if self._ms else None

    @property
    def oldest_ms(self) -> int | None:
        return self._ms[0] if self._ms else None

    def add(self, ms: int, lat_deg: float, lon_deg: float, rel_alt_m: float) -> bool:
        """Insert a position; True if the track was restarted (the autopilot rebooted)."""
        restarted = False
        if self._ms and ms < self._ms[-1] - REBOOT_MS:
            self.clear()
            restarted = True
        if not self._ms or ms > self._ms[-1]:
            k = len(self._ms)
        else:
            k = bisect.bisect_left(self._ms, ms)
            if k < len(self._ms) and self._ms[k] == ms:
                self._lat[k], self._lon[k], self._alt[k] = lat_deg, lon_deg, rel_alt_m
                return restarted
        for arr, v in ((self._ms, ms), (self._lat, lat_deg), (self._lon, lon_deg),
                       (self._alt, rel_alt_m)):
            if k == len(arr):
                arr.append(v)  # type: ignore[arg-type]
            else:
                arr.insert(k, v)  # type: ignore[arg-type]
        if len(self._ms) > self.keep + self.keep // 8:  # trim in chunks, not per position
            cut = len(self._ms) - self.keep
            for arr in (self._ms, self._lat, self._lon, self._alt):
                del arr[:cut]
        return restarted

    def clear(self) -> None:
        for arr in (self._ms, self._lat, self._lon, self._alt):
            del arr[:]

    def at(self, ms: int, max_gap_ms: int) -> tuple[float, float, float, bool] | None:
        """``(lat, lon, rel_alt, exact)`` at ``ms``, or None when no position has that
        stamp and none pair around it lies within ``max_gap_ms``."""
        k = bisect.bisect_left(self._ms, ms)
        n = len(self._ms)
        if k < n and self._ms[k] == ms:
            return self._lat[k], self._lon[k], self._alt[k], True
        if k == 0 or k == n:
            return None
        t0, t1 = self._ms[k - 1], self._ms[k]
        if t1 - t0 > max_gap_ms and not (t1 - t0 <= STILL_GAP_MS and self._still(k - 1, k)):
            return None
        w = (ms - t0) / (t1 - t0)
        lat = self._lat[k - 1] + w * (self._lat[k] - self._lat[k - 1])
        lon = self._lon[k - 1] + w * (self._lon[k] - self._lon[k - 1])
        alt = self._alt[k - 1] + w * (self._alt[k] - self._alt[k - 1])
        return lat, lon, alt, False

    def _still(self, i: int, j: int) -> bool:
        """Whether positions ``i`` and ``j`` are within :data:`STILL_M` of each other."""
        east, north, up = Origin(self._lat[i], self._lon[i]).to_local(
            self._lat[j], self._lon[j], self._alt[j] - self._alt[i])
        return math.hypot(east, north) <= STILL_M and abs(up) <= STILL_M

    def why_not(self, ms: int) -> DropReason:
        """Why :meth:`at` found nothing for ``ms``."""
        if not self._ms or ms < self._ms[0]:
            return DropReason.NO_POSITION_BEFORE
        if ms > self._ms[-1]:
            return DropReason.NO_POSITION_AFTER
        return DropReason.GAP


@dataclass
class _Held:
    since: float
    sysid: int
    compid: int
    ms: int
    value: float


class SamplePairer:
    """Places ``FIELD`` samples on each vehicle's position track (module docstring).

    Counters: ``exact``, ``interpolated``, ``dropped`` (a :class:`Counter` by
    :class:`DropReason`), :attr:`pending` (samples waiting).
    """

    def __init__(self, max_gap_ms: int = MAX_GAP_MS, hold_s: float = HOLD_S,
                 name: str = SAMPLE_NAME, max_held: int = MAX_HELD) -> None:
        self.max_gap_ms = max_gap_ms
        self.hold_s = hold_s
        self.name = name
        self.max_held = max_held
        self.exact = 0
        self.interpolated = 0
        self.dropped: Counter[str] = Counter()
        self.tracks: dict[int, PositionTrack] = {}
        self._held: list[_Held] = []  # in arrival order

    @property
    def pending(self) -> int:
        return len(self._held)

    @property
    def dropped_total(self) -> int:
        return sum(self.dropped.values())

    def track(self, sysid: int) -> PositionTrack:
        t = self.tracks.get(sysid)
        if t is None:
            t = self.tracks[sysid] = PositionTrack()
        return t

    def add(self, sysid: int, msg: MAVLinkMessage, now: float, *,
            position_source: bool = True) -> list[Sample]:
        """Offer one message of vehicle ``sysid``; return the samples it places.

        ``position_source``: whether a ``GLOBAL_POSITION_INT`` in ``msg`` is the
        autopilot's (another component's positions are on another clock and are ignored).
        """
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            if not position_source or (msg.lat == 0 and msg.lon == 0):
                return []  # another clock, or no position yet (ArduPilot before its EKF has one)
            return self.position(sysid, int(msg.time_boot_ms), msg.lat / 1e7, msg.lon / 1e7,
                                 msg.relative_alt / 1000.0, now)
        if kind == "NAMED_VALUE_FLOAT" and _text(msg.name) == self.name:
            return self.value(sysid, int(msg.time_boot_ms), float(msg.value), now,
                              compid=msg.get_srcComponent())
        return []

    def position(self, sysid: int, ms: int, lat_deg: float, lon_deg: float,
                 rel_alt_m: float, now: float) -> list[Sample]:
        """A position of ``sysid``; the waiting samples it places."""
        track = self.track(sysid)
        track.add(ms, lat_deg, lon_deg, rel_alt_m)
        if not self._held:
            return []
        out: list[Sample] = []
        keep: list[_Held] = []
        for h in self._held:
            placed = self._place(h, track) if h.sysid == sysid else None
            if placed is None:
                keep.append(h)
            else:
                out.append(placed)
        self._held = keep
        return out

    def value(self, sysid: int, ms: int, value: float, now: float,
              compid: int = 1) -> list[Sample]:
        """A measurement of ``sysid`` at ``ms``: placed now, or held."""
        h = _Held(now, sysid, compid, ms, value)
        placed = self._place(h, self.track(sysid))
        if placed is not None:
            return [placed]
        self._held.append(h)
        if len(self._held) > self.max_held:
            del self._held[0]
            self.dropped[DropReason.OVERFLOW] += 1
        return []

    def _place(self, h: _Held, track: PositionTrack) -> Sample | None:
        where = track.at(h.ms, self.max_gap_ms)
        if where is None:
            return None
        lat, lon, alt, exact = where
        if exact:
            self.exact += 1
        else:
            self.interpolated += 1
        return Sample(h.sysid, h.ms, lat, lon, alt, h.value,
                      Placement.EXACT if exact else Placement.INTERPOLATED, h.compid)

    def expire(self, now: float) -> int:
        """Drop the samples that waited longer than ``hold_s``; return how many."""
        limit = now - self.hold_s
        n = 0
        while self._held and self._held[0].since < limit:
            h = self._held.pop(0)
            self.dropped[self.track(h.sysid).why_not(h.ms)] += 1
            n += 1
        return n

    def counts(self) -> dict[str, object]:
        """For ``summary.json``: placed exactly, interpolated, dropped by reason, waiting."""
        return {"exact": self.exact, "interpolated": self.interpolated,
                "dropped": dict(sorted(self.dropped.items())), "pending": self.pending,
                "max_gap_ms": self.max_gap_ms}


def _text(value: object) -> str:
    if isinstance(value, bytes | bytearray):
        value = value.decode("utf-8", "replace")
    return str(value).rstrip("\x00")
