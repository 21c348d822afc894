"""docs/cli.md and docs/missions.md are what `python -m econdor.docs` writes from the parser
and the mission schema: a checked-in page that differs from the code fails here."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import pytest

from econdor import docs
from econdor.cli import build_parser
from econdor_gcs.config import parse_mission
from econdor_gcs.config.schema import FIELD_SCHEMA, SCHEMA, SENSOR_SCHEMA, TOP_LEVEL


@pytest.mark.parametrize("name", sorted(docs.PAGES))
def test_the_checked_in_page_is_what_the_code_generates(name: str) -> None:
    path = docs.DOCS / name
    assert path.is_file(), f"{path} missing: run python -m econdor.docs"
    assert path.read_text(encoding="utf-8") == docs.PAGES[name](), (
        f"{path} is stale: run python -m econdor.docs")


def test_check_names_a_stale_page_and_exits_1(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    for name in docs.PAGES:
        shutil.copy(docs.DOCS / name, tmp_path / name)
    assert docs.main(["--check", "--docs", str(tmp_path)]) == 0
    page = tmp_path / "missions.md"
    page.write_text(page.read_text(encoding="utf-8").replace("`area.width_m`", "`area.w`"),
                    encoding="utf-8")
    assert docs.main(["--check", "--docs", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"{page}: stale; regenerate with python -m econdor.docs"]


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise AssertionError("no subcommands")


def test_every_command_and_argument_is_documented() -> None:
    """Each command and each of its arguments has a help line, and the page lists it."""
    page = docs.cli_markdown()
    for name, sub in _subparsers(build_parser()).items():
        assert f"## econdor {name}" in page
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help, f"econdor {name} {action.option_strings or action.dest}: no help"
            flag = action.option_strings[-1] if action.option_strings else action.dest
            assert f"`{flag}" in page, (name, flag)


def test_every_mission_key_has_a_meaning_and_is_on_the_page() -> None:
    page = docs.missions_markdown()
    rows = [("", TOP_LEVEL), ("vehicles.sensor.", SENSOR_SCHEMA)]
    rows += [(f"{s}.", keys) for s, keys in SCHEMA.items()]
    rows += [("field.", keys) for keys in FIELD_SCHEMA.values()]
    for prefix, keys in rows:
        for key, row in keys.items():
            assert row.doc.strip(), f"{prefix}{key}: no meaning in the schema"
            assert f"| `{prefix}{key}` |" in page


def test_the_documented_defaults_are_the_ones_a_mission_gets() -> None:
    """The schema's defaults are what an empty mission holds (one table, no second copy)."""
    m = parse_mission({"field": {"model": "paper"}})
    assert m.name == TOP_LEVEL["name"].default and m.seed == TOP_LEVEL["seed"].default
    for section in ("initiation", "algorithm", "lawnmower", "adaptive"):
        for key, row in SCHEMA[section].items():
            assert getattr(getattr(m, section), key) == row.default, f"{section}.{key}"
    for key, row in SENSOR_SCHEMA.items():
        assert getattr(m.vehicles.sensor, key) == row.default, f"vehicles.sensor.{key}"
    assert m.region.xmax == SCHEMA["area"]["width_m"].default
