"""A new user's first minutes (issue 34, point 9): no long silence, sensible defaults."""

from __future__ import annotations

import threading

import pytest

from econdor import cli


def test_a_tracer_compilation_is_announced_and_its_progress_printed(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """On a cold numba cache the tracer compiles for ~20 s before any vehicle starts: the
    command says so when it begins, and prints progress while it lasts."""
    import sim_vehicle.tracer

    monkeypatch.setattr(cli, "WARM_UP_QUIET_S", 0.01)
    monkeypatch.setattr(cli, "WARM_UP_PROGRESS_S", 0.05)
    monkeypatch.setattr(sim_vehicle.tracer, "warm_up",
                        lambda: threading.Event().wait(0.3) or 0.3)  # a compilation's length
    cli._warm_up_tracer(quiet=False)
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("econdor: compiling the onboard tracer (once")
    assert any("still compiling" in line for line in err[1:-1])
    assert err[-1].startswith("econdor: compiled in")
    cli._warm_up_tracer(quiet=True)
    assert capsys.readouterr().err == ""


def test_a_failed_compilation_is_raised_not_swallowed(monkeypatch: pytest.MonkeyPatch) -> None:
    import sim_vehicle.tracer

    def broken() -> float:
        raise RuntimeError("numba: no LLVM")

    monkeypatch.setattr(sim_vehicle.tracer, "warm_up", broken)
    with pytest.raises(RuntimeError, match="no LLVM"):
        cli._warm_up_tracer(quiet=True)


def test_run_defaults_suit_vehicles_started_by_hand() -> None:
    """--timeout: three vehicles started by hand on a busy machine took 18 s to be ready;
    --link-timeout: a radio's drop-outs (15 s is ordinary, a minute happens) are waited
    out."""
    parser = cli.build_parser()
    args = parser.parse_args(["run", "m.yaml"])
    cli._check_run_args(parser, args)
    assert args.timeout == 60.0 and args.link_timeout is None  # None: LINK_TIMEOUT_S, 120
    from econdor_gcs.station.losses import LINK_TIMEOUT_S

    assert LINK_TIMEOUT_S == 120.0
    with pytest.raises(SystemExit):
        parser.parse_args(["run", "m.yaml", "--link-timeout", "0"])
