"""Jobs for the worker pool's tests (spawned workers import them by name), and whether a
process has ended."""

import os
import threading
from pathlib import Path


def hold(directory: str) -> int:
    """Mark this worker started, wait until told to stop, and mark it cleaned up on the way
    out (the ``finally`` a run directory closes in)."""
    d = Path(directory)
    try:  # the mark inside: a signal while it is written still finds the finally
        (d / f"started-{os.getpid()}").write_text("")
        threading.Event().wait()  # forever: only a signal ends it
    finally:
        (d / f"cleaned-{os.getpid()}").write_text("")
    return os.getpid()


def square(x: int) -> int:
    return x * x


def process_gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (a zombie has too: its parent has not reaped it yet)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    stat = Path(f"/proc/{pid}/stat")
    return stat.exists() and stat.read_text().split()[2] == "Z"
