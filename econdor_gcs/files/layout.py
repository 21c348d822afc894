"""What a run writes in its directory, and what may be done to it: ``--force`` deletes
only what a run wrote (refusing, naming it, anything else), and a write that fails names
its file and the system's reason in one line."""

from __future__ import annotations

import contextlib
import fnmatch
from collections.abc import Iterator
from enum import StrEnum
from pathlib import Path

from econdor_gcs.errors import RunError

__all__ = ["RESERVE_NAME", "RUN_FILES", "RUN_WRITTEN", "RunDirMode", "disk_error",
           "foreign_files", "prepare_run_dir", "writing"]

RESERVE_NAME = ".space-reserve"
RUN_FILES = ("run.json", "summary.json", "samples.csv", "metrics.csv", "flights.jsonl",
             "telemetry.tlog")
"""Files that only a run directory has (``--force`` replaces only such a directory)."""


class RunDirMode(StrEnum):
    """What to do with an existing, non-empty run directory."""

    NEW = "new"
    """Refuse it (the default: nothing of an earlier run is ever overwritten silently)."""
    FORCE = "force"
    """Replace it, if it is a run directory."""
    RESUME = "resume"
    """Continue it: samples and flights are appended."""


def disk_error(path: Path | str | None, exc: OSError) -> RunError:
    """One line for a failed write: the file, and the system's word for why (``No space
    left on device``, ``Read-only file system``, ...).

    >>> import errno
    >>> str(disk_error(Path("run/samples.csv"), OSError(errno.ENOSPC, "No space left on device")))
    'cannot write run/samples.csv: No space left on device'
    """
    where = path if path is not None else exc.filename
    return RunError(f"cannot write {where}: {exc.strerror or exc}")


@contextlib.contextmanager
def writing(path: Path | str | None) -> Iterator[None]:
    """Turn an :class:`OSError` inside into :func:`disk_error` (a :class:`RunError`)."""
    try:
        yield
    except OSError as exc:
        raise disk_error(path, exc) from exc


RUN_WRITTEN = (
    "run.json", "mission.yaml", "summary.json", "metrics.csv", "iterations.json",
    "samples.csv", "samples_interrupted.csv", "samples_received.csv", "flights.jsonl",
    "fields.npz", "log.jsonl", "telemetry.tlog", "next_batch.json", RESERVE_NAME, "*.tmp",
    "iterations/iter_*.npz", "iterations/*.tmp", "missions/iter*", "figures/*.png",
    "vehicles/v*.log",
)
"""What a run writes in its directory (``fnmatch`` patterns of paths relative to it):
``--force`` deletes these and nothing else."""


def _run_written(rel: str) -> bool:
    """``rel`` (a path relative to the run directory) matches :data:`RUN_WRITTEN`, part by
    part (a ``*`` never reaches into a sub-directory).

    >>> _run_written("figures/maps.png"), _run_written("analysis/maps.png")
    (True, False)
    >>> _run_written("summary.json.tmp"), _run_written("analysis/x.tmp")
    (True, False)
    """
    parts = rel.split("/")
    return any(len(pat.split("/")) == len(parts) and all(
        fnmatch.fnmatchcase(a, b) for a, b in zip(parts, pat.split("/"), strict=True))
        for pat in RUN_WRITTEN)


def foreign_files(path: Path) -> list[Path]:
    """Files (and other entries) under ``path`` that no run writes (:data:`RUN_WRITTEN`),
    in sorted order; a directory counts through what it holds (an empty one is nobody's).
    """
    out: list[Path] = []
    for entry in sorted(path.rglob("*")):
        rel = entry.relative_to(path).as_posix()
        if entry.is_dir() and not entry.is_symlink():
            continue
        if entry.is_symlink() or not _run_written(rel):
            out.append(entry)
    return out


def _remove_run_files(path: Path) -> None:
    """Delete what a run wrote under ``path`` (every entry, checked foreign-free before), then
    the directories left empty."""
    for entry in sorted(path.rglob("*"), key=lambda p: len(p.parts), reverse=True):
        if entry.is_dir() and not entry.is_symlink():
            with contextlib.suppress(OSError):  # not empty: something appeared meanwhile
                entry.rmdir()
        else:
            entry.unlink()


def prepare_run_dir(path: Path, mode: RunDirMode) -> None:
    """Check ``path`` against ``mode`` (see :class:`RunDirMode`); for ``FORCE`` empty it of
    what an earlier run wrote, refusing when it holds anything else.

    Raises :class:`RunError` with one line naming the directory (or the file) and the way
    out.
    """
    if path.exists() and not path.is_dir():
        raise RunError(f"{path}: exists and is not a directory")
    busy = path.is_dir() and any(path.iterdir())
    if mode == RunDirMode.RESUME:
        if not (path / "run.json").is_file():
            raise RunError(f"{path}: nothing to resume (no run.json: not a run directory, or a "
                           "run from before resume existed)")
        return
    if not busy:
        return
    if mode == RunDirMode.NEW:
        raise RunError(f"{path}: not empty (an earlier run?); use --force to replace it or "
                       "--resume to continue it")
    if not any((path / name).exists() for name in RUN_FILES):
        raise RunError(f"{path}: not empty and not a run directory; refusing to replace it "
                       "even with --force")
    foreign = foreign_files(path)
    if foreign:
        more = f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
        raise RunError(f"{foreign[0]}: not written by a run{more}; --force deletes only what "
                       f"a run wrote: move it out of {path} first")
    _remove_run_files(path)
