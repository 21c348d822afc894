"""Run directories are never clobbered, and an interrupted run resumes to the same result.

In-process, a resumed run must end exactly where an uninterrupted run of the same seed
ends: the finished flights are replayed from ``flights.jsonl`` and ``samples.csv``, the
vehicles (position, velocity, clock, the sensor's state and its generators) restored. The
mission's sensor is noisy, lags and is mispositioned, so a resume that did not restore the
generators, the lagged reading or the GNSS error would end elsewhere.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from econdor import cli
from econdor_gcs.config import load_mission
from econdor_gcs.dfc.loop import IterationDone
from econdor_gcs.errors import RunError
from econdor_gcs.files.checkpoint import read_checkpoint
from econdor_gcs.files.layout import RunDirMode
from econdor_gcs.files.rundir import RunDir
from econdor_lab.inprocess import run_inprocess
from tests.helpers.missions import small_mission

MISSION = small_mission("resume", seed=5, vehicles=2, iterations=3, min_iterations=3,
                        speedup=None, max_trace_length_m=200,
                        sensor="{noise_std: 0.2, lag_s: 0.3, position_std_m: 0.5, position_tau_s: 5}")

SAME = ("planner", "seed", "iterations", "final_mae", "final_mae_db", "span_ratio",
        "flight_distance_m", "contour_distance_m", "samples", "samples_recorded", "converged",
        "stop_reason", "sim_s")


@pytest.fixture(scope="module")
def mission_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("mission") / "resume.yaml"
    path.write_text(MISSION, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def reference(mission_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ref") / "run"
    run_inprocess(load_mission(mission_path), out)
    return out


def summary(run: Path) -> dict:
    return json.loads((run / "summary.json").read_text())


def metrics(run: Path) -> list[dict[str, str]]:
    with (run / "metrics.csv").open() as f:
        return list(csv.DictReader(f))


def assert_same_result(run: Path, reference: Path) -> None:
    got, want = summary(run), summary(reference)
    assert {k: got[k] for k in SAME} == {k: want[k] for k in SAME}
    assert metrics(run) == metrics(reference)
    assert (run / "samples.csv").read_bytes() == (reference / "samples.csv").read_bytes()
    levels = [r["levels"] for r in json.loads((run / "iterations.json").read_text())]
    assert levels == [r["levels"] for r in json.loads((reference / "iterations.json").read_text())]


class _Interrupt(KeyboardInterrupt):
    pass


def _stop_after_iteration_1(event: object) -> None:
    if isinstance(event, IterationDone) and event.record.iteration == 1:
        raise _Interrupt


def test_resume_after_an_interrupt_ends_with_the_uninterrupted_result(
        mission_path: Path, reference: Path, tmp_path: Path) -> None:
    mission = load_mission(mission_path)
    out = tmp_path / "run"

    with pytest.raises(_Interrupt):
        run_inprocess(mission, out, progress=_stop_after_iteration_1)
    assert [r.iteration for r in read_checkpoint(out)] == [0, 1]
    assert not (out / "summary.json").exists()
    run_inprocess(mission, out, mode=RunDirMode.RESUME)
    assert_same_result(out, reference)
    assert summary(out)["resumed"] == {"flights_replayed": 2, "samples_interrupted": 0}
    # a finished run resumed again replays everything, flies nothing, ends the same
    run_inprocess(mission, out, mode=RunDirMode.RESUME)
    assert_same_result(out, reference)


def test_a_resumed_run_estimating_the_lag_ends_with_the_uninterrupted_result(
        tmp_path: Path) -> None:
    """``lag_correction: estimate``: the replayed flights' samples are taken in as received
    and the lag estimated again from all of them, so the resume ends where the uninterrupted
    run does, with the same estimate."""
    path = tmp_path / "estimate.yaml"
    path.write_text(MISSION.replace("position_tau_s: 5}", "position_tau_s: 5, "
                                    "lag_correction: estimate}"), encoding="utf-8")
    mission = load_mission(path)
    assert mission.vehicles.sensor.lag_correction == "estimate"
    ref = tmp_path / "ref"
    run_inprocess(mission, ref)
    out = tmp_path / "run"

    with pytest.raises(_Interrupt):
        run_inprocess(mission, out, progress=_stop_after_iteration_1)
    run_inprocess(mission, out, mode=RunDirMode.RESUME)
    assert_same_result(out, ref)
    assert summary(out)["lag_s"] == summary(ref)["lag_s"] > 0.0


_KILLABLE = """\
import sys
from econdor_gcs.config import load_mission
from econdor_lab.inprocess import run_inprocess
run_inprocess(load_mission(sys.argv[1]), sys.argv[2])
"""


def test_resume_after_sigkill_ends_with_the_uninterrupted_result(
        mission_path: Path, reference: Path, tmp_path: Path) -> None:
    """SIGKILL wherever it lands after the second flight: the resume ends the same."""
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-c", _KILLABLE, str(mission_path), str(out)])
    try:
        deadline = time.monotonic() + 120
        flights = out / "flights.jsonl"
        while not (flights.exists() and flights.read_text().count("\n") >= 2):
            assert proc.poll() is None, "the run ended before it could be killed"
            assert time.monotonic() < deadline
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    run_inprocess(load_mission(mission_path), out, mode=RunDirMode.RESUME)
    assert_same_result(out, reference)


def test_resume_refuses_a_changed_mission(mission_path: Path, reference: Path,
                                          tmp_path: Path) -> None:
    import shutil

    out = tmp_path / "run"
    shutil.copytree(reference, out)
    changed = load_mission(mission_path).with_overrides(search_radius_m=12)
    with pytest.raises(RunError, match="plans of iteration 1 differ"):
        run_inprocess(changed, out, mode=RunDirMode.RESUME)


# -- run directories ------------------------------------------------------------------------


def test_a_non_empty_run_directory_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    with pytest.raises(RunError, match=r"not empty \(an earlier run\?\); use --force to "
                                       r"replace it or --resume to continue it"):
        RunDir(out)
    assert (out / "summary.json").read_text() == "{}"  # untouched


def test_force_replaces_a_run_directory_but_nothing_else(tmp_path: Path) -> None:
    out = tmp_path / "run"
    (out / "figures").mkdir(parents=True)
    (out / "summary.json").write_text("{}")
    (out / "figures" / "maps.png").write_bytes(b"png")
    RunDir(out, RunDirMode.FORCE).close()
    assert (out / "samples.csv").exists() and (out / "summary.json").exists() is False
    assert not (out / "figures" / "maps.png").exists()
    other = tmp_path / "home"
    other.mkdir()
    (other / "thesis.tex").write_text("years of work")
    with pytest.raises(RunError, match="not a run directory; refusing to replace it"):
        RunDir(other, RunDirMode.FORCE)
    assert (other / "thesis.tex").exists()


@pytest.mark.parametrize("added", ["notes.txt", "analysis/plot.py", "figures/mine.svg",
                                   "missions/site.plan"])
def test_force_never_deletes_a_file_the_run_did_not_write(tmp_path: Path, mission_path: Path,
                                                          added: str,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    """A user's notes or analysis in an earlier run directory: ``--force`` refuses in one
    line naming the file, and deletes nothing (not even the run's own files)."""
    out = tmp_path / "run"
    (out / "figures").mkdir(parents=True)
    (out / "summary.json").write_text("{}")
    (out / "samples.csv").write_text("t_s\n")
    mine = out / added
    mine.parent.mkdir(parents=True, exist_ok=True)
    mine.write_text("my work")
    code = cli.main(["run", str(mission_path), "--out", str(out), "--quiet", "--force"])
    err = capsys.readouterr().err
    assert code == 1 and err.strip().count("\n") == 0, err
    assert f"{mine}: not written by a run" in err and "move it out of" in err
    assert mine.read_text() == "my work"
    assert (out / "summary.json").read_text() == "{}" and (out / "samples.csv").exists()


def test_resume_sets_the_samples_of_an_unfinished_flight_aside(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "run.json").write_text("{}")
    rows = ["t_s,x_m,y_m,value,phase,vehicle,iteration"]
    rows += [f"{k}.0,1.0,2.0,3.0,0,0,{it}" for it, k in ((0, 1), (0, 2), (1, 3), (2, 4), (2, 5))]
    (out / "samples.csv").write_text("\n".join(rows) + "\n")
    (out / "flights.jsonl").write_text(
        json.dumps({"iteration": 0}) + "\n" + json.dumps({"iteration": 1}) + "\n"
        + '{"iteration": 2, "pla')  # torn by the crash: flight 2 never finished
    rd = RunDir(out, RunDirMode.RESUME)
    rd.close()
    assert (rd.n_samples, rd.interrupted_samples) == (3, 2)
    kept = (out / "samples.csv").read_text().splitlines()
    aside = (out / "samples_interrupted.csv").read_text().splitlines()
    assert kept == rows[:4] and aside == [rows[0], *rows[4:]]


def test_run_refuses_a_non_empty_out_in_one_line(tmp_path: Path, mission_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    code = cli.main(["run", str(mission_path), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1
    assert err.strip().splitlines() == [
        f"econdor: error: {out}: not empty (an earlier run?); use --force to replace it or "
        "--resume to continue it"]
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


@pytest.mark.parametrize(("argv", "message"), [
    (["run"], "a MISSION.yaml is needed (or --resume RUN_DIR)"),
    (["run", "m.yaml", "--resume", "r"], "MISSION.yaml cannot change it"),
    (["run", "--resume", "r", "--seed", "3", "--force"], "--seed, --force cannot change it"),
])
def test_run_usage_errors_around_resume(argv: list[str], message: str,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_resume_of_a_directory_without_a_run(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", "--resume", str(tmp_path)]) == 1
    assert capsys.readouterr().err.strip() == (
        f"econdor: error: {tmp_path}: nothing to resume (no run.json)")
