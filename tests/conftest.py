"""Session set-up shared by the tests."""

from __future__ import annotations

import os

import pytest


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
