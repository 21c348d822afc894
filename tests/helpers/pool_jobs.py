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


def hold_through_cleanup(directory: str) -> int:
    """:func:`hold`, whose clean-up marks itself begun and then waits on the FIFO
    ``directory/release`` until the test writes to it (a clean-up that takes a while)."""
    d = Path(directory)
    try:
        (d / f"started-{os.getpid()}").write_text("")
        threading.Event().wait()
    finally:
        (d / f"cleaning-{os.getpid()}").write_text("")
        (d / "release").read_text()  # blocks until the test opens the FIFO for writing
        (d / f"cleaned-{os.getpid()}").write_text("")
    return os.getpid()


def signal_pending(pid: int, signum: int) -> bool:
    """Whether signal ``signum`` sent to process ``pid`` has not been delivered yet (Linux)."""
    bit = 1 << (signum - 1)
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(("SigPnd:", "ShdPnd:")) and int(line.split()[1], 16) & bit:
            return True
    return False


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
