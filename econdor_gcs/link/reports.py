"""What a vehicle reports besides its samples, read from MAVLink (no text parsing).

The conventions (README, "MAVLink conventions"; content defined in :mod:`..core.tasks`):

* ``NAMED_VALUE_INT`` named ``PHASE``: the samples from ``time_boot_ms`` on were taken in
  phase ``value`` (:class:`~econdor_gcs.core.tasks.Phase`); sent before the first sample of
  each new phase. :class:`PhaseTrack` answers "which phase was sample t in".
* ``DEBUG_FLOAT_ARRAY`` named ``TRACE``: a :class:`~econdor_gcs.core.tasks.TraceReport`, the
  outcome of the trace item ``array_id`` (sent before its ``MISSION_ITEM_REACHED``).

STATUSTEXT stays for people; nothing here reads it.
"""

from __future__ import annotations

import bisect

from ..core.tasks import PHASE_NAME, TRACE_REPORT_NAME, Phase, TraceReport
from ..errors import ProtocolError
from .codec import MAVLinkMessage

__all__ = ["PhaseTrack", "phase_change", "trace_report"]


def _name(msg: MAVLinkMessage) -> str:
    name = msg.name
    if isinstance(name, bytes | bytearray):
        name = name.decode("ascii", "replace")
    return str(name).rstrip("\x00")


def trace_report(msg: MAVLinkMessage) -> TraceReport | None:
    """The trace report in ``msg``; None if ``msg`` is not one.

    Raises :class:`~econdor_gcs.errors.ProtocolError` for a ``TRACE`` array that does not
    decode (unknown status code, non-integer piece id, bad distances).
    """
    if msg.get_type() != "DEBUG_FLOAT_ARRAY" or _name(msg) != TRACE_REPORT_NAME:
        return None
    try:
        return TraceReport.from_array(int(msg.array_id), list(msg.data))
    except ValueError as exc:
        raise ProtocolError(f"vehicle {msg.get_srcSystem()}: {exc}") from None


def phase_change(msg: MAVLinkMessage) -> tuple[int, Phase] | None:
    """``(time_boot_ms, phase)`` of a ``PHASE`` message; None if ``msg`` is not one.

    Raises :class:`~econdor_gcs.errors.ProtocolError` for an unknown phase value.
    """
    if msg.get_type() != "NAMED_VALUE_INT" or _name(msg) != PHASE_NAME:
        return None
    try:
        return int(msg.time_boot_ms), Phase(int(msg.value))
    except ValueError:
        raise ProtocolError(f"vehicle {msg.get_srcSystem()}: unknown phase {msg.value}"
                            ) from None


class PhaseTrack:
    """The phase changes a vehicle reported, looked up by sample time.

    >>> t = PhaseTrack()
    >>> t.known, t.at(500)
    (False, <Phase.TRANSIT: 0>)
    >>> t.add(1000, Phase.SEARCH); t.add(2500, Phase.TRACE)
    >>> [t.at(ms).name for ms in (999, 1000, 2400, 2500, 9000)]
    ['TRANSIT', 'SEARCH', 'SEARCH', 'TRACE', 'TRACE']

    Changes may arrive in any order (a resent range repeats its changes); they are kept
    sorted by time, at most ``keep`` of them (the oldest are forgotten first).

    >>> t.add(1800, Phase.TRANSIT); t.at(2000).name
    'TRANSIT'
    """

    def __init__(self, keep: int = 100_000) -> None:
        self.keep = keep
        self._times: list[int] = []
        self._phases: list[Phase] = []

    @property
    def known(self) -> bool:
        """True once the vehicle has reported a phase (a vehicle without our tracer never does)."""
        return bool(self._times)

    @property
    def latest(self) -> Phase:
        """The last phase reported (TRANSIT before any)."""
        return self._phases[-1] if self._phases else Phase.TRANSIT

    def add(self, time_boot_ms: int, phase: Phase) -> None:
        k = bisect.bisect_left(self._times, time_boot_ms)
        if k < len(self._times) and self._times[k] == time_boot_ms:
            self._phases[k] = phase  # the same change again
            return
        self._times.insert(k, time_boot_ms)
        self._phases.insert(k, phase)
        if len(self._times) > self.keep:
            del self._times[0], self._phases[0]

    def at(self, time_boot_ms: int) -> Phase:
        """The phase in force at ``time_boot_ms`` (TRANSIT before any report)."""
        k = bisect.bisect_right(self._times, time_boot_ms)
        return self._phases[k - 1] if k else Phase.TRANSIT
