"""Absurd numbers in a mission are refused in one line naming the key (issue 34, point 8)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from econdor import cli
from econdor_gcs.config import parse_mission
from econdor_gcs.config.schema import FIELD_SCHEMA as _FIELD_SCHEMA
from econdor_gcs.config.schema import SCHEMA as _SCHEMA
from econdor_gcs.errors import MissionError

BASE = {"field": {"model": "paper"}}


def _numeric_keys() -> list[tuple[str, str, type]]:
    keys = [(section, key, typ) for section, rows in _SCHEMA.items()
            for key, (typ, _, _) in rows.items() if typ in (int, float)]
    keys += [(f"field:{model}", key, typ) for model, rows in _FIELD_SCHEMA.items()
             for key, (typ, _, _) in rows.items() if typ in (int, float)]
    return keys


def _mission_with(section: str, key: str, value: object) -> dict:
    if section.startswith("field:"):
        return {"field": {"model": section.split(":")[1], key: value}}
    return {**BASE, section: {key: value}}


@pytest.mark.parametrize(("section", "key", "typ"), _numeric_keys(),
                         ids=[f"{s}.{k}" for s, k, _ in _numeric_keys()])
def test_every_number_of_a_mission_has_bounds(section: str, key: str, typ: type) -> None:
    """No number in a mission is taken whatever its size: +-1e15 (or +-10**15) is refused
    with the key named."""
    name = f"{section.split(':')[0]}.{key}"
    big = 10**15 if typ is int else 1e15
    for value in (big, -big):
        with pytest.raises(MissionError, match=rf"^{name}: must be"):
            parse_mission(_mission_with(section, key, value))


@pytest.mark.parametrize(("mission", "message"), [
    ({**BASE, "area": {"width_m": 0.5}}, r"area\.width_m: must be >= 10 \(metres\), got 0\.5"),
    ({**BASE, "area": {"width_m": 100000000}}, r"area\.width_m: must be <= 10000"),
    ({**BASE, "origin": {"alt_m": 4.88e8}}, r"origin\.alt_m: must be <= 9000 \(metres above "
                                            r"mean sea level\)"),
    ({**BASE, "vehicles": {"altitude_m": -30}}, r"vehicles\.altitude_m: must be >= 1"),
    ({**BASE, "area": {"width_m": 10, "height_m": 10}, "algorithm": {"grid_spacing_m": 6}},
     r"algorithm\.grid_spacing_m: must be <= half the area's shorter side \(5 m"),
    ({**BASE, "area": {"width_m": 10000, "height_m": 10000}},
     r"algorithm\.grid_spacing_m: 1 m makes a grid of 100,020,001 nodes"),
    ({**BASE, "seed": 2**40}, r"seed: must be within 0\.\.4294967295"),
])
def test_the_absurd_inputs_of_issue_34(mission: dict, message: str) -> None:
    with pytest.raises(MissionError, match=message):
        parse_mission(mission)


def test_a_tiny_area_is_one_line_and_exit_1(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """``area: {width_m: 0.5}`` used to pass validation and then fail with a traceback in the
    grid ("grid needs at least 2 x 2 nodes")."""
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump({**BASE, "area": {"width_m": 0.5, "height_m": 0.5}}))
    for argv in (["run", str(path), "--out", str(tmp_path / "run"), "--quiet"],
                 ["export", str(path), "--format", "wpl", "--out", str(tmp_path / "x.txt")],
                 ["study", str(path), "--seeds", "0:1", "--out", str(tmp_path / "study")]):
        assert cli.main(argv) == 1
        err = capsys.readouterr().err
        assert err.strip().count("\n") == 0, err
        assert "area.width_m: must be >= 10 (metres), got 0.5" in err
    assert not (tmp_path / "run").exists()  # refused before anything was written


# -- econdor import: plausibility -----------------------------------------------------------------


@pytest.fixture()
def exported_plan(tmp_path: Path) -> dict:
    """The demo's diagonals as a .plan (home, takeoff, speed, 5 waypoints, RTL; a fence 10 m
    outside the area), as ``econdor export`` writes it."""
    import json

    from tests.helpers.vehicles import DEMO

    path = tmp_path / "first.plan"
    assert cli.main(["export", str(DEMO), "--format", "plan", "--out", str(path)]) == 0
    return json.loads(path.read_text())


def _import(tmp_path: Path, doc: dict, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    import json

    path = tmp_path / "edited.plan"
    path.write_text(json.dumps(doc))
    capsys.readouterr()
    code = cli.main(["import", str(path)])
    out = capsys.readouterr()
    return code, (out.err if code else out.out)


def _waypoints(doc: dict) -> list[dict]:
    return [it for it in doc["mission"]["items"] if it["command"] == 16]


@pytest.mark.parametrize(("edit", "message"), [
    (lambda wp: wp.__setitem__(6, 3e10), r"altitude 3e\+10 m above home is more than 1000 m"),
    (lambda wp: wp.__setitem__(6, -30.0), r"altitude -30 m is below home"),
    # 1,300 km north: beyond any aircraft's range (and outside the file's own fence)
    (lambda wp: wp.__setitem__(4, wp[4] + 11.7), r"mission item 3 is 1,29\d km from home"),
    # 200 m north of the home corner, 90 m beyond the fence the file itself carries
    (lambda wp: wp.__setitem__(4, wp[4] + 0.0018),
     r"mission item 3 \(NAV_WAYPOINT\) is 90 m outside the file's own inclusion geofence"),
])
def test_import_refuses_an_implausible_mission(tmp_path: Path, exported_plan: dict, edit,
                                                message: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    code, text = _import(tmp_path, exported_plan, capsys)
    assert code == 0 and "a valid mission file" in text  # as exported
    edit(_waypoints(exported_plan)[0]["params"])
    code, text = _import(tmp_path, exported_plan, capsys)
    assert code == 1 and text.strip().count("\n") == 0, text
    assert re.search(message, text), text


def test_upload_refuses_an_implausible_mission_before_opening_a_link(
        tmp_path: Path, exported_plan: dict, capsys: pytest.CaptureFixture[str]) -> None:
    import json
    import socket

    _waypoints(exported_plan)[0]["params"][6] = -30.0  # below home
    path = tmp_path / "edited.plan"
    path.write_text(json.dumps(exported_plan))
    # the port is held, so opening the link would fail with another message
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:
        held.bind(("127.0.0.1", 0))
        port = held.getsockname()[1]
        capsys.readouterr()
        code = cli.main(["upload", str(path), "--connect", f"udpin:127.0.0.1:{port}",
                         "--timeout", "1"])
    err = capsys.readouterr().err
    assert code == 1 and err.strip().count("\n") == 0, err
    assert re.search(r"altitude -30 m is below home.*\(--force uploads it anyway\)$", err.strip()), err


def test_import_refuses_an_amsl_altitude_off_the_earth(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    from tests.helpers.vehicles import DEMO

    path = tmp_path / "first.wpl"
    assert cli.main(["export", str(DEMO), "--format", "wpl", "--out", str(path)]) == 0
    lines = path.read_text().splitlines()
    cols = lines[4].split("\t")
    cols[2], cols[10] = "0", "4.88e8"  # frame 0: AMSL
    lines[4] = "\t".join(cols)
    path.write_text("\n".join(lines) + "\n")
    capsys.readouterr()
    assert cli.main(["import", str(path)]) == 1
    err = capsys.readouterr().err
    assert "mission item 3 (NAV_WAYPOINT): altitude 4.88e+08 m above mean sea level is off " \
           "the Earth's surface" in err
