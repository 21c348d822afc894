"""Property-based tests (hypothesis) of what users hand us: mission YAML and mission files.

Whatever the input, the loaders either return a valid result or raise the library's own
error with one line naming the problem -- never another exception, never a traceback.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from econdor_gcs.config import Mission, load_mission, parse_mission
from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.tasks import TraceTask, Waypoint
from econdor_gcs.errors import EcondorError, MissionError
from econdor_gcs.files.autopilot_files import items_to_plan, items_to_wpl, read_plan, read_wpl
from econdor_gcs.link.transfer import MissionItemSpec, build_mission

ROOT = Path(__file__).resolve().parents[1]
DEMO = yaml.safe_load((ROOT / "missions" / "demo.yaml").read_text())
PAPER = yaml.safe_load((ROOT / "missions" / "paper.yaml").read_text())
FUZZ = settings(max_examples=200, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])

# any YAML-able value, nested a little
scalars = (st.none() | st.booleans() | st.integers(-10**12, 10**12)
           | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=12))
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=3)
                      | st.dictionaries(st.text(max_size=8), inner, max_size=3), max_leaves=6)


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    return out


@st.composite
def mutated_missions(draw: st.DrawFn) -> Any:
    """A valid mission with a few keys replaced by anything, deleted, or added."""
    doc = copy.deepcopy(draw(st.sampled_from([DEMO, PAPER])))
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(doc)
        path = draw(st.sampled_from(paths))
        if not path:
            continue
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        action = draw(st.sampled_from(["replace", "delete", "add"]))
        if action == "replace":
            parent[path[-1]] = draw(values)
        elif action == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.text(max_size=8))] = draw(values)
    return doc


def _valid(m: Mission) -> None:
    """What a mission that loads promises the rest of the code."""
    assert m.region.width_m > 0 and m.region.height_m > 0
    assert math.isfinite(m.region.width_m) and math.isfinite(m.region.height_m)
    assert -90 <= m.origin.lat_deg <= 90 and -180 <= m.origin.lon_deg <= 180
    assert m.vehicles.count >= 1
    assert 0 < m.vehicles.speed_mps <= m.vehicles.max_speed_mps
    assert math.isfinite(m.vehicles.max_speed_mps)
    assert m.algorithm.min_iterations <= m.algorithm.max_iterations


@FUZZ
@given(mutated_missions())
def test_mission_loader_accepts_or_names_the_problem(doc: Any) -> None:
    try:
        m = parse_mission(doc, source="fuzz.yaml")
    except MissionError as exc:
        text = str(exc)
        assert text and "\n" not in text
        return
    _valid(m)


@FUZZ
@given(values)
def test_mission_loader_on_any_document(doc: Any) -> None:
    try:
        _valid(parse_mission(doc, source="fuzz.yaml"))
    except MissionError as exc:
        assert "\n" not in str(exc)


@FUZZ
@given(st.binary(max_size=300) | st.text(max_size=300).map(str.encode))
def test_mission_file_of_any_bytes(tmp_path_factory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("m") / "fuzz.yaml"
    path.write_bytes(data)
    try:
        _valid(load_mission(path))
    except MissionError as exc:
        assert "\n" not in str(exc)


# -- mission files: QGC WPL 110 and QGroundControl .plan ------------------------------------

ORIGIN = Origin(47.397742, 8.545594, 488.0)
coords = st.floats(-200.0, 200.0, allow_nan=False)
finite = st.floats(-1e6, 1e6, allow_nan=False)


@st.composite
def missions(draw: st.DrawFn) -> list[MissionItemSpec]:
    tasks: list[Waypoint | TraceTask] = []
    for pid in range(draw(st.integers(0, 5))):
        if draw(st.booleans()):
            tasks.append(Waypoint(draw(coords), draw(coords)))
        else:
            tasks.append(TraceTask(draw(finite), draw(coords), draw(coords),
                                   draw(st.floats(0.1, 100)), draw(st.floats(0, 1e4)), pid))
    return build_mission(ORIGIN, tasks, draw(st.floats(1.0, 500.0)),
                         end=draw(st.sampled_from(["rtl", "loiter", "none"])))


def _sendable(items: list[MissionItemSpec]) -> None:
    """Every item read fits a MISSION_ITEM_INT (the reader hands over nothing unsendable)."""
    from econdor_gcs.link.codec import Codec

    codec = Codec()
    for it in items:
        codec.encode(it.to_message(1, 1))


@FUZZ
@given(missions())
def test_wpl_and_plan_round_trip(items: list[MissionItemSpec]) -> None:
    assert read_wpl(items_to_wpl(items), int_frames=True) == items
    assert read_plan(items_to_plan(items), int_frames=True) == items


def _mutate_text(text: str, data: st.DataObject) -> str:
    lines = text.splitlines()
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.integers(0, max(0, len(lines) - 1)))
        if not lines:
            break
        cols = lines[i].split("\t")
        j = data.draw(st.integers(0, len(cols) - 1))
        cols[j] = data.draw(st.sampled_from(["nan", "inf", "-inf", "1e999", "", "x", "-1",
                                             "99999999999", "1e300", "0.5", "65536"])
                            | st.text(max_size=6))
        lines[i] = "\t".join(cols)
    return "\n".join(lines) + "\n"


@FUZZ
@given(missions(), st.data())
def test_wpl_reader_on_mutated_files(items: list[MissionItemSpec], data: st.DataObject) -> None:
    text = _mutate_text(items_to_wpl(items), data)
    try:
        got = read_wpl(text)
    except EcondorError as exc:
        assert "\n" not in str(exc)
        return
    _sendable(got)


@FUZZ
@given(st.text(max_size=400))
def test_wpl_reader_on_any_text(text: str) -> None:
    try:
        _sendable(read_wpl("QGC WPL 110\n" + text + "\n"))
    except EcondorError as exc:
        assert "\n" not in str(exc)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**20, 10**20)
    | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=8) | st.dictionaries(st.text(max_size=12), inner,
                                                                max_size=4), max_leaves=12)


@FUZZ
@given(missions(), st.data())
def test_plan_reader_on_mutated_documents(items: list[MissionItemSpec],
                                          data: st.DataObject) -> None:
    doc = items_to_plan(items)
    for _ in range(data.draw(st.integers(1, 3))):
        paths = [p for p in _paths(doc) if p]
        path = data.draw(st.sampled_from(paths))
        parent: Any = doc
        for k in path[:-1]:
            parent = parent[k]
        parent[path[-1]] = data.draw(json_values | st.sampled_from([1e999, -1e999, None]))
        if data.draw(st.booleans()) and isinstance(parent.get("params"), list):
            k = data.draw(st.integers(0, max(0, len(parent["params"]) - 1)))
            if parent["params"]:
                parent["params"][k] = data.draw(json_values)
    try:
        got = read_plan(json.loads(json.dumps(doc)))
    except EcondorError as exc:
        assert "\n" not in str(exc)
        return
    _sendable(got)
