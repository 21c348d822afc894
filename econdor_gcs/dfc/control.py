"""An operator's pause / resume / stop of a running DFC loop.

The DFC asks its :data:`~econdor_gcs.dfc.loop.Checkpoint` between iterations;
:meth:`RunControl.checkpoint` is one. Requests come from any thread (the web page's
server thread, a signal handler, a test) and take effect there, never in the middle of a
flight:

* **pause** — the loop holds before the next iteration (the vehicles hover where their
  missions ended) until **resume**;
* **stop** — the loop ends before the next iteration; the DFC then has the executor bring
  every vehicle home (``executor.finish()``: return to launch, land, disarm). ``econdor run
  --web`` also ends the flight in progress at once (the MAVLink executor's
  ``abort_flight``): the vehicles leave their missions for home and the DFC takes in what
  was flown before it stops.

States (:class:`ControlState`)::

    running --pause--> pausing --checkpoint--> paused --resume--> running
       ^                  |                                          |
       +------resume------+        any but finished --stop--> stopping --checkpoint--> stopped
    (the loop's end, whatever the reason, makes it finished unless it was stopped)

>>> c = RunControl()
>>> c.request(ControlAction.STOP)
<ControlState.STOPPING: 'stopping'>
>>> c.checkpoint(3)
False
>>> c.state
<ControlState.STOPPED: 'stopped'>
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from enum import StrEnum

from econdor_gcs.errors import ControlError

__all__ = ["ControlAction", "ControlError", "ControlState", "RunControl"]


class ControlAction(StrEnum):
    """What an operator may ask for."""

    PAUSE = "pause"
    RESUME = "resume"
    STOP = "stop"


class ControlState(StrEnum):
    """Where the run stands with respect to the operator's requests."""

    RUNNING = "running"
    PAUSING = "pausing"
    """Pause asked for; the iteration in flight finishes first."""
    PAUSED = "paused"
    STOPPING = "stopping"
    """Stop asked for; the loop ends at its next checkpoint, then every vehicle returns (the
    web page also ends the flight in progress through the executor)."""
    STOPPED = "stopped"
    FINISHED = "finished"
    """The loop ended on its own (stop rule, error); requests are refused."""


_NEXT: dict[tuple[ControlState, ControlAction], ControlState] = {
    (ControlState.RUNNING, ControlAction.PAUSE): ControlState.PAUSING,
    (ControlState.PAUSING, ControlAction.PAUSE): ControlState.PAUSING,
    (ControlState.PAUSED, ControlAction.PAUSE): ControlState.PAUSED,
    (ControlState.PAUSING, ControlAction.RESUME): ControlState.RUNNING,
    (ControlState.PAUSED, ControlAction.RESUME): ControlState.RUNNING,
    (ControlState.RUNNING, ControlAction.STOP): ControlState.STOPPING,
    (ControlState.PAUSING, ControlAction.STOP): ControlState.STOPPING,
    (ControlState.PAUSED, ControlAction.STOP): ControlState.STOPPING,
    (ControlState.STOPPING, ControlAction.STOP): ControlState.STOPPING,
}


class RunControl:
    """Thread-safe pause / resume / stop for :class:`~econdor_gcs.dfc.loop.Dfc` (``checkpoint=``).

    Parameters
    ----------
    on_change:
        Called with ``(state, iteration)`` after every change of state, on the thread that
        caused it and with the control's (re-entrant) lock held, so the calls come in the
        order of the changes (keep it quick: it may be the DFC's).
    poll_s:
        How often a paused checkpoint wakes up (so Ctrl-C in the main thread is seen).
    """

    def __init__(self, on_change: Callable[[ControlState, int], None] | None = None,
                 poll_s: float = 0.2) -> None:
        self._cond = threading.Condition()
        self._state = ControlState.RUNNING
        self._iteration = 0
        self._on_change = on_change
        self._poll_s = poll_s

    @property
    def state(self) -> ControlState:
        with self._cond:
            return self._state

    @property
    def iteration(self) -> int:
        """The iteration the DFC asked about last (the next one it wants to fly)."""
        with self._cond:
            return self._iteration

    def _set(self, state: ControlState) -> None:
        """Change state (the condition's lock held); report outside the lock."""
        self._state = state
        self._cond.notify_all()

    def _report(self, state: ControlState, iteration: int) -> None:
        if self._on_change is not None:
            self._on_change(state, iteration)

    def request(self, action: ControlAction | str) -> ControlState:
        """Ask for ``action``; returns the new state.

        Raises
        ------
        ControlError
            When the action does not apply (unknown action, resume while running, anything
            once the run is stopped or finished).
        """
        try:
            action = ControlAction(action)
        except ValueError:
            raise ControlError(f"unknown control action {action!r} (one of "
                               f"{', '.join(a.value for a in ControlAction)})") from None
        with self._cond:
            new = _NEXT.get((self._state, action))
            if new is None:
                raise ControlError(f"cannot {action.value}: the run is {self._state.value}")
            changed = new != self._state
            self._set(new)
            if changed:  # under the lock: reports arrive in the order of the changes
                self._report(new, self._iteration)
        return new

    def checkpoint(self, iteration: int) -> bool:
        """The DFC's :data:`~econdor_gcs.dfc.loop.Checkpoint`: block while paused, ``False`` to stop."""
        with self._cond:
            self._iteration = iteration
            if self._state is ControlState.PAUSING:
                self._set(ControlState.PAUSED)
                self._report(ControlState.PAUSED, iteration)
            while self._state is ControlState.PAUSED:
                self._cond.wait(self._poll_s)
            stop = self._state is ControlState.STOPPING
            if stop:
                self._set(ControlState.STOPPED)
                self._report(ControlState.STOPPED, iteration)
        return not stop

    def finish(self) -> None:
        """The loop has ended (any reason): later requests are refused."""
        with self._cond:
            if self._state in (ControlState.STOPPED, ControlState.FINISHED):
                return
            if self._state is ControlState.STOPPING:
                self._set(ControlState.STOPPED)
            else:
                self._set(ControlState.FINISHED)
            self._report(self._state, self._iteration)
