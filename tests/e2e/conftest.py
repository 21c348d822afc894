"""Everything under ``tests/e2e`` starts processes, opens sockets between parts or flies whole
runs: it is marked ``e2e`` here, so that ``pytest -m "not e2e and not slow"`` is the fast loop
without each file having to remember its mark."""

from __future__ import annotations

from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if HERE in item.path.resolve().parents:
            item.add_marker(pytest.mark.e2e)
