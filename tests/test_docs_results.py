"""Every file in ``docs/results`` names the command that made it, and that command still runs.

The benchmarks write their results files with a stamp (``bench/report.py``, :func:`stamp`):
``Command: `python bench/<script>.py ARGS``` and the commit. A results file whose script was
renamed, or whose options changed since, can no longer be made again: this test finds it.
The command is checked without doing its work: the script runs with the stamped arguments
until its argument parser has accepted them (``ArgumentParser.parse_args`` is wrapped to stop
the process there), so a results file that took an hour to make is checked in a second.
Figures (binary files) are checked through the stamped Markdown file that shows them.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
TEXT = {".md", ".txt", ".csv"}
COMMAND = re.compile(r"^Command: `(?P<command>[^`]+)`", re.MULTILINE)
PARSED = "econdor-test: arguments accepted"

# Run SCRIPT as __main__ with ARGV; stop (exit 0, PARSED on stdout) as soon as the outermost
# parse_args returns. argparse itself exits 2 with its one-line usage error on a bad argument.
_PROBE = f"""
import argparse, os, runpy, sys
script, argv = sys.argv[1], sys.argv[2:]
original = argparse.ArgumentParser.parse_args
depth = 0
def parse_args(self, *a, **kw):
    global depth
    depth += 1
    try:
        result = original(self, *a, **kw)
    finally:
        depth -= 1
    if depth == 0:
        print({PARSED!r}, flush=True)
        os._exit(0)
    return result
argparse.ArgumentParser.parse_args = parse_args
sys.argv = [script, *argv]
sys.path.insert(0, os.path.dirname(script))
runpy.run_path(script, run_name="__main__")
print("the script returned without parsing its arguments", file=sys.stderr)
sys.exit(3)
"""


def check_command(command: str) -> str | None:
    """``None`` when ``python SCRIPT ARGS`` names a script of the repository whose argument
    parser accepts ARGS; else what is wrong, in one line."""
    argv = shlex.split(command)
    if len(argv) < 2 or argv[0] not in ("python", "python3") or not argv[1].endswith(".py"):
        return f"not a `python SCRIPT.py ...` command: {command}"
    script = ROOT / argv[1]
    if not script.is_file():
        return f"{argv[1]} does not exist"
    proc = subprocess.run([sys.executable, "-c", _PROBE, str(script), *argv[2:]], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    if proc.returncode != 0 or PARSED not in proc.stdout:
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        return f"{argv[1]} refuses {shlex.join(argv[2:])}: {last}"
    return None


def results_files() -> list[Path]:
    return sorted(p for p in RESULTS.rglob("*") if p.is_file()) if RESULTS.is_dir() else []


@pytest.mark.parametrize("path", [p for p in results_files() if p.suffix in TEXT],
                         ids=lambda p: p.relative_to(RESULTS).as_posix())
def test_a_results_file_names_a_command_that_runs(path: Path) -> None:
    commands = COMMAND.findall(path.read_text(encoding="utf-8"))
    assert commands, f"{path.relative_to(ROOT)} has no `Command:` stamp (bench/report.py stamp)"
    for command in commands:
        problem = check_command(command)
        assert problem is None, f"{path.relative_to(ROOT)}: {problem}"


@pytest.mark.parametrize("path", [p for p in results_files() if p.suffix not in TEXT],
                         ids=lambda p: p.relative_to(RESULTS).as_posix())
def test_a_results_figure_is_shown_by_a_stamped_file(path: Path) -> None:
    stamped = [p for p in results_files() if p.suffix in TEXT
               and COMMAND.search(p.read_text(encoding="utf-8"))
               and path.name in p.read_text(encoding="utf-8")]
    assert stamped, f"{path.relative_to(ROOT)} is not shown by any stamped results file"


def test_the_check_tells_a_runnable_command_from_a_stale_one() -> None:
    """The check itself: the stamp bench/report.py writes passes; a script that does not
    exist, an option the script does not have, and a value it refuses each fail."""
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        import report
    finally:
        sys.path.remove(str(ROOT / "bench"))
    argv = [str(ROOT / "bench" / "efficiency.py"), "--seeds", "0", "--markdown"]
    text = "\n".join(report.stamp(argv))
    command = COMMAND.search(text)
    assert command is not None, text
    assert command["command"] == "python bench/efficiency.py --seeds 0 --markdown"
    assert check_command(command["command"]) is None
    assert "does not exist" in str(check_command("python bench/no_such_bench.py --seeds 0"))
    assert "refuses" in str(check_command("python bench/efficiency.py --no-such-option"))
    assert "refuses" in str(check_command("python bench/efficiency.py --workers many"))


def test_the_readme_results_are_the_results_files() -> None:
    """The README's results block is what scripts/readme_results.py reads from docs/results:
    a number edited by hand, or a results file made again without the README, fails."""
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "readme_results.py"), "--check"],
                          capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
