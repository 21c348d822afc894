"""A child process that ends with the process that started it.

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

__all__ = ["die_with_parent"]

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
