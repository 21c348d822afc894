"""``--against REF`` for the benchmarks: measure another git revision in the same run.

The revision is exported with ``git archive`` into a temporary directory and the calling
benchmark script is run again as a subprocess with ``--tree DIR --json`` (it puts ``DIR``
first on ``sys.path`` and prints its results as one JSON line last), so before and after
are measured on the same machine, one right after the other.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


def run_tree(script: str | Path, ref: str, *args: str) -> dict[str, Any]:
    """Run ``script --tree <ref's tree> --json *args``; the JSON of its last output line."""
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(REPO), "archive", ref], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        out = subprocess.run(
            [sys.executable, str(Path(script).resolve()), "--tree", tmp, "--json", *args],
            check=True, capture_output=True, text=True)
        return json.loads(out.stdout.strip().splitlines()[-1])
