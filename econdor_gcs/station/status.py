"""What the station says each vehicle is doing: the one vocabulary of its status.

A :class:`~enum.StrEnum`, so the run log, the JSON of the live page and the checkpoint keep
the plain strings (``"flying"``) they always held, and a string compares equal to its
member.
"""

from __future__ import annotations

from enum import StrEnum


class VehicleStatus(StrEnum):
    """A vehicle's status as the executor tracks it, in the order a sortie passes them."""

    IDLE = "idle"
    """Seen, given nothing yet (or between sorties, before the next upload)."""
    UPLOADING = "uploading"
    """Its mission is being sent (MISSION_COUNT ... MISSION_ACK)."""
    UPLOADED = "uploaded"
    """The autopilot acknowledged the mission; not started yet."""
    STARTING = "starting"
    """Set to its mission mode, armed and told to start (MAV_CMD_MISSION_START)."""
    FLYING = "flying"
    """Flying its mission."""
    HOLDING = "holding"
    """Reached the last item of its mission: it holds there for the next one."""
    INTERRUPTED = "interrupted"
    """Left its mission before the end on its own (a failsafe: RTL, LAND, disarmed,
    paused)."""
    RETURNING = "returning"
    """Sent home at the end of the run (RTL)."""
    LANDED = "landed"
    """On the ground after its return."""
    LOST = "lost"
    """Given up: silent too long, or it refused what it was sent; it gets no more work."""
