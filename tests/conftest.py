"""Session set-up shared by the tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session", autouse=True)
def compiled_tracer() -> None:
    """Compile (on a fresh clone) or load the tracer once, before any test: the vehicles
    that tests start as processes then load it from numba's cache within their start-up
    timeout instead of compiling it."""
    from sim_vehicle.tracer import warm_up

    warm_up()
