"""The suite's pytest-xdist schedule (tests/conftest.py) names files that exist."""

from __future__ import annotations

from pathlib import Path

from tests.conftest import TIMING_TIGHT_FILES

ROOT = Path(__file__).resolve().parents[1]


def test_the_timing_tight_files_exist() -> None:
    """A renamed file would silently leave the one-worker unit and run beside the others."""
    missing = sorted(f for f in TIMING_TIGHT_FILES if not (ROOT / f).is_file())
    assert not missing, missing
