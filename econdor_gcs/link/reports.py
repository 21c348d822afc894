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

from collections import deque

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

    Only the last ``keep`` changes are remembered: enough for samples that arrive a little
    out of order, not for a replay.
    """

    def __init__(self, keep: int = 64) -> None:
        self._changes: deque[tuple[int, Phase]] = deque(maxlen=keep)

    @property
    def known(self) -> bool:
        """True once the vehicle has reported a phase (a vehicle without our tracer never does)."""
        return bool(self._changes)

    @property
    def latest(self) -> Phase:
        """The last phase reported (TRANSIT before any)."""
        return self._changes[-1][1] if self._changes else Phase.TRANSIT

    def add(self, time_boot_ms: int, phase: Phase) -> None:
        self._changes.append((time_boot_ms, phase))

    def at(self, time_boot_ms: int) -> Phase:
        """The phase in force at ``time_boot_ms`` (TRANSIT before any report)."""
        for t, phase in reversed(self._changes):
            if t <= time_boot_ms:
                return phase
        return Phase.TRANSIT
