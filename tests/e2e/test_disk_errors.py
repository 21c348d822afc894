"""A full disk and a read-only ``--out``: one line, exit 1, nothing received lost, and a
``summary.json`` where the run had begun (issue 34, point 7).

The disk is made full at the write boundary (:class:`tests.helpers.disk.FullDisk`, no root
needed); where this machine lets us mount a tiny tmpfs (root in a container), the same is
also tried on a real file system.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import json
import os
import subprocess
from collections import Counter
from pathlib import Path

import pytest

from econdor import cli
from econdor_gcs.errors import RunError
from econdor_gcs.files.layout import RESERVE_NAME
from econdor_gcs.files.rundir import RunDir
from tests.helpers.disk import FullDisk
from tests.helpers.missions import small_mission

MISSION = small_mission("disk", vehicles=2, iterations=3, min_iterations=3)


@pytest.fixture()
def mission_path(tmp_path: Path) -> Path:
    path = tmp_path / "disk.yaml"
    path.write_text(MISSION)
    return path


def _rows(path: Path) -> Counter[int]:
    with path.open() as f:
        return Counter(int(r["iteration"]) for r in csv.DictReader(f))


@pytest.mark.slow
def test_a_disk_that_fills_up_mid_run_is_one_line_and_keeps_what_arrived(
        tmp_path: Path, mission_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The disk is full once iteration 2 is planned, while it flies: the tlog, the journal
    and the log stop there; the run ends at the end of that flight with one line naming
    the file and ``No space left on device``, exit 1. The space the run held back takes
    the samples of the flight that could not be recorded and ``summary.json``."""
    out = tmp_path / "run"

    def flying_2() -> bool:  # planned, and both vehicles' missions saved (iter02_v*)
        # looked at on every write, so the disk fills at the first write after the last of
        # these (each file is one write), before iteration 2 flies (stats first: cheap)
        return (all((out / "missions" / f"iter02_v{v}.tasks.json").exists() for v in (1, 2))
                and "iteration 2 planned" in (out / "log.jsonl").read_text())

    with FullDisk(out, when=flying_2) as disk:
        code = cli.main(["run", str(mission_path), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1, err
    assert err.startswith("econdor: error: cannot write ") and "No space left on device" in err
    assert disk.refused  # it did fill up
    summary = json.loads((out / "summary.json").read_text())
    assert "No space left on device" in summary["error"]
    assert summary["error_path"], summary  # which files stopped being written, and where
    assert not (out / RESERVE_NAME).exists()
    rows = _rows(out / "samples.csv")
    assert rows[0] > 0 and rows[1] > 0 and rows[2] > 0, rows  # the refused flight's too
    assert summary["samples_recorded"] == sum(rows.values())
    assert sum(rows.values()) == sum(r["received"] for r in
                                     summary["sample_recovery"].values())


def test_run_directory_writes_fail_in_one_line(tmp_path: Path) -> None:
    """Every write of the run directory names its file and the system's reason."""
    out = tmp_path / "run"
    with FullDisk(out) as disk:
        rd = RunDir(out, received=True)
        disk.fill()
        with pytest.raises(RunError, match=r"^cannot write .*run/run\.json: No space left"):
            rd.write_run_config({"a": 1}, None)
        with pytest.raises(RunError, match=r"metrics\.csv: No space left on device$"):
            rd.write_metrics([])
        rd.journal([(1.0, 2.0, 3.0, 4.0, 0)], 0, 0)  # on the link's thread: kept, not raised
        assert rd.journal_error is not None and "samples_received.csv" in rd.journal_error
        rd.salvage()  # the reserve freed: the error path can write again
        rd.write_partial([], {"error": "full"})
        rd.close()
    assert json.loads((out / "summary.json").read_text()) == {"error": "full"}


def test_out_on_a_read_only_file_system_is_one_line(tmp_path: Path, mission_path: Path,
                                                    capsys: pytest.CaptureFixture[str],
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """OSError 30 used to be a traceback. Nothing had begun: no summary either."""
    real_mkdir = Path.mkdir
    ro = tmp_path / "ro"

    def mkdir(self: Path, *args: object, **kwargs: object) -> None:
        if self == ro or ro in self.parents:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))
        real_mkdir(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(Path, "mkdir", mkdir)
    code = cli.main(["run", str(mission_path), "--out", str(ro / "run"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1, err
    assert err == f"econdor: error: cannot write {ro / 'run'}: Read-only file system\n"


# -- the same on real file systems, where this machine lets us mount them ------------------


@contextlib.contextmanager
def _tmpfs(where: Path, options: str) -> Path:
    where.mkdir()
    try:
        proc = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                              capture_output=True, text=True)
    except FileNotFoundError:
        pytest.skip("no mount command here")
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (not root?): {proc.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=False)


def test_out_on_a_real_read_only_mount(tmp_path: Path, mission_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    with _tmpfs(tmp_path / "ro", "ro,size=1m") as ro:
        code = cli.main(["run", str(mission_path), "--out", str(ro / "run"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1 and err == f"econdor: error: cannot write {ro / 'run'}: " \
                                "Read-only file system\n"


@pytest.mark.slow
def test_a_real_tmpfs_that_fills_up(tmp_path: Path, mission_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    """2.6 MB: the run starts (2 MiB held back), its tlog and samples fill the rest in the
    first flight."""
    with _tmpfs(tmp_path / "small", "size=2600k") as small:
        out = small / "run"
        code = cli.main(["run", str(mission_path), "--out", str(out), "--quiet"])
        err = capsys.readouterr().err
        assert code == 1 and err.count("\n") == 1 and "No space left on device" in err, err
        summary = json.loads((out / "summary.json").read_text())
        assert "No space left on device" in summary["error"]
        rows = _rows(out / "samples.csv")
        assert summary["samples_recorded"] == sum(rows.values()) > 0
