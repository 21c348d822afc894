"""Jobs for the worker pool's tests (spawned workers import them by name)."""

import os
import threading
from pathlib import Path


def hold(directory: str) -> int:
    """Mark this worker started, wait until told to stop, and mark it cleaned up on the way
    out (the ``finally`` a run directory closes in)."""
    d = Path(directory)
    (d / f"started-{os.getpid()}").write_text("")
    try:
        threading.Event().wait()  # forever: only a signal ends it
    finally:
        (d / f"cleaned-{os.getpid()}").write_text("")
    return os.getpid()


def square(x: int) -> int:
    return x * x
