"""The vehicle status is one vocabulary: every value the station sets is a
:class:`VehicleStatus` member, and every member is set somewhere (no documented value that
never occurs)."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import econdor_gcs
from econdor_gcs.station.status import VehicleStatus
from econdor_gcs.station.telemetry import VehicleState

PACKAGE = Path(econdor_gcs.__file__).resolve().parent


def _status_assignments() -> list[tuple[str, ast.expr]]:
    """``<x>.status = <value>`` anywhere in the station and its apps, and a record's
    ``status: ... = <default>``: (where, value)."""
    out = []
    for path in sorted([*(PACKAGE / "station").rglob("*.py"), *(PACKAGE / "app").rglob("*.py")]):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign):
                for target in node.targets:
                    if isinstance(target, ast.Attribute) and target.attr == "status":
                        out.append((f"{path.relative_to(PACKAGE)}:{node.lineno}", node.value))
            elif (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                  and node.target.id == "status" and node.value is not None):
                out.append((f"{path.relative_to(PACKAGE)}:{node.lineno}", node.value))
    return out


def test_every_status_set_is_a_member_and_every_member_is_set() -> None:
    set_names = set()
    for where, value in _status_assignments():
        assert (isinstance(value, ast.Attribute) and isinstance(value.value, ast.Name)
                and value.value.id == "VehicleStatus"), (
            f"{where}: a vehicle status must be a VehicleStatus member, got "
            f"{ast.unparse(value)}")
        set_names.add(value.attr)
    assert set_names == {m.name for m in VehicleStatus}


def test_the_status_keeps_its_string_in_files_and_json() -> None:
    v = VehicleState(sysid=1, index=0)
    assert v.status == "idle" and v.status is VehicleStatus.IDLE
    v.status = VehicleStatus.FLYING
    assert json.dumps({"status": v.status}) == '{"status": "flying"}'
    assert f"{v.status}" == "flying" and VehicleStatus("landed") is VehicleStatus.LANDED
