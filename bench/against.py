"""``--against REF`` for the benchmarks: measure another git revision in the same run.

The revision is exported with ``git archive`` into a temporary directory and the calling
benchmark script is run again as a subprocess with ``--tree DIR --json`` (it puts ``DIR``
first on ``sys.path`` and prints its results as one JSON line last), so before and after
are measured on the same machine, one right after the other.
"""

from __future__ import annotations

import argparse
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


def parser(description: str, settings: str, seeds: str) -> argparse.ArgumentParser:
    """The arguments every ``--against`` benchmark takes: ``--settings``, ``--seeds``,
    ``--quick`` (seed 0 only), ``--against REF`` and the hidden ``--tree`` / ``--json`` of
    the run on another revision (:func:`run_tree`)."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--settings", default=settings)
    p.add_argument("--seeds", default=seeds, help="A:B (Python slice) or a comma list")
    p.add_argument("--quick", action="store_true", help="seed 0 only")
    p.add_argument("--against", metavar="REF", help="also measure git revision REF")
    p.add_argument("--tree", help=argparse.SUPPRESS)  # measure the code in this directory
    p.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    return p


def parse(p: argparse.ArgumentParser) -> argparse.Namespace:
    """Parse; ``--quick`` means seed 0, and the tree measured goes first on ``sys.path``."""
    a = p.parse_args()
    if a.quick:
        a.seeds = "0"
    sys.path.insert(0, a.tree or str(REPO))
    return a
