"""How a process ends: a child with the process that started it, and a command stopped by a
signal through its clean-up, once.

A process killed outright (SIGKILL: an out-of-memory killer, a scheduler, ``kill -9``) runs no
clean-up, and the processes it started run on: simulated vehicles flying for a ground
station that is gone, study workers waiting for work that will not come. On Linux a child
can ask the kernel for a signal when its parent ends (``prctl(PR_SET_PDEATHSIG)``);
:func:`die_with_parent` asks for SIGTERM, which the child handles as its own stop.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["Terminated", "die_with_parent", "sigterm_as_interrupt"]

_PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int) -> bool:
    """Ask for SIGTERM when the parent ends (Linux; elsewhere nothing is asked).

    ``parent_pid`` is the process that started this one: if it has ended already (before
    the request could be made), this process is an orphan and the answer is ``False``; the
    caller should stop. (The kernel sends the signal when the *thread* that started the
    child ends: start such children from the main thread.)
    """
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    return os.getppid() == parent_pid


class Terminated(KeyboardInterrupt):
    """SIGTERM, delivered like Ctrl-C so every ``finally`` runs."""


_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class _Stopping:
    """Process-wide: how deep the :func:`sigterm_as_interrupt` scopes are nested, and
    whether a stop signal has been acted on in them."""

    depth = 0
    taken = False


def _on_stop_signal(signum: int, frame: Any) -> None:
    if _Stopping.taken:  # stopping already: its finally blocks are writing the run's files
        return
    _Stopping.taken = True
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM delivered like Ctrl-C, and only the first of them acted on.

    The first SIGTERM or Ctrl-C raises in the main thread (:class:`Terminated`, a
    :class:`KeyboardInterrupt`), so every ``finally`` runs; one that comes while they run
    (Ctrl-C pressed again, a scheduler repeating its SIGTERM) is ignored, so that the
    run's files are written whole and its one line printed (the clean-up is bounded: a
    vehicle or worker that does not stop is killed). SIGKILL still ends it at once; the
    samples received are in the run's journal then. Scopes nest (one for the command,
    one for the run): the signals are handled so until the outermost ends. A SIGINT the
    process was told to ignore stays ignored. Outside the main thread nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.getsignal(s) for s in _STOP_SIGNALS}
    for s in _STOP_SIGNALS:
        if not (s == signal.SIGINT and old[s] == signal.SIG_IGN):
            signal.signal(s, _on_stop_signal)
    _Stopping.depth += 1
    try:
        yield
    finally:
        _Stopping.depth -= 1
        if _Stopping.depth == 0:
            _Stopping.taken = False
        for s, handler in old.items():
            if handler is not None:  # (None: set outside Python; left as it is)
                signal.signal(s, handler)
