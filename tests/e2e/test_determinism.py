"""A run is a function of its mission and seed: two processes give bit-identical results.

What a study reports must not depend on hash randomisation, set order, threads or the
clock. (Across machines the last bits of BLAS and of numpy's vectorised ``exp``/``log`` may
differ, and the tracer turns those into other paths: see tests/dfc/test_regression.py. On one
machine, nothing may.)
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow


def _study(tmp: Path, hashseed: str) -> list[dict[str, str]]:
    mission = tmp / "m.yaml"
    text = (ROOT / "missions" / "demo.yaml").read_text(encoding="utf-8")
    mission.write_text(text.replace("max_iterations: 5", "max_iterations: 2")
                       .replace("min_iterations: 3", "min_iterations: 2"), encoding="utf-8")
    out = tmp / f"out-{hashseed}"
    env = {**os.environ, "PYTHONHASHSEED": hashseed}
    proc = subprocess.run(
        [sys.executable, "-m", "econdor", "study", str(mission), "--seeds", "1", "--workers",
         "1", "--out", str(out), "--quiet", "--no-figures"],
        env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    with (out / "runs" / "econdor-1" / "samples.csv").open(encoding="utf-8") as f:
        samples = list(csv.DictReader(f))
    with (out / "study.csv").open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert len(samples) > 1000 and len(rows) == 3
    return [*rows, *samples]


def test_two_processes_give_identical_runs(tmp_path: Path) -> None:
    a = _study(tmp_path, "1")
    b = _study(tmp_path, "2")
    assert a == b
