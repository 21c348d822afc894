"""Session set-up shared by the tests."""

from __future__ import annotations

import os
import signal

import pytest

if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    # A suite started in the background (``nohup``, ``&`` in a script) inherits Ctrl-C
    # ignored, and the product rightly keeps an ignored SIGINT ignored: the tests that send
    # it (to themselves or to the processes they start, which inherit the disposition) need
    # it to arrive as at a terminal. Set in every process pytest-xdist starts too.
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session", autouse=True)
def compiled_tracer() -> None:
    """Compile (on a fresh clone) or load the tracer once, before any test: the vehicles
    that tests start as processes then load it from numba's cache within their start-up
    timeout instead of compiling it."""
    from sim_vehicle.tracer import warm_up

    warm_up()


@pytest.fixture(scope="session", autouse=True)
def signing_state_dir(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Signing timestamps (econdor_gcs.link.signing.SigningStore) go to a folder of the test
    session, not the user's ~/.local/state; the vehicles tests start inherit it."""
    from econdor_gcs.link.signing import STATE_DIR_ENV

    os.environ[STATE_DIR_ENV] = str(tmp_path_factory.mktemp("econdor-state"))


TIMING_TIGHT_FILES = frozenset({
    "tests/e2e/test_sitl_run.py",
    "tests/e2e/test_sitl_upload.py",
    "tests/e2e/test_stock_autopilots.py",
})
"""Test files whose timing margins a second heavy run beside them eats: ArduPilot SITL (its
Lua scripts and its MAVLink ports keep their rates only with a core to run on) and stock
ArduPilots at 200x (their 8 s mission-upload timeout is 40 ms of wall time). Under
pytest-xdist they run one after another on one worker; the other worker runs the rest."""


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """``--dist loadfile`` (pyproject's addopts) with :data:`TIMING_TIGHT_FILES` as one unit.

    ``_split_scope`` (nodeid -> unit of work) is the one method pytest-xdist's own
    schedulers differ by; loadfile's is a test's file."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class TimingTightTogether(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            scope = super()._split_scope(nodeid)
            return "timing-tight" if scope in TIMING_TIGHT_FILES else scope

    return TimingTightTogether(config, log)
