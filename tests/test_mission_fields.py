"""Mission YAML validation and field models."""

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from econdor_gcs.config import load_mission
from econdor_gcs.core.fields import (
    RasterField,
    authors_field,
    front_field,
    load_raster,
    paper_field,
    plume_field,
)
from econdor_gcs.core.geometry import Grid, Region
from econdor_gcs.errors import FieldError, MissionError

ROOT = Path(__file__).resolve().parents[1]
REGION = Region(0, 100, 0, 100)


@pytest.mark.parametrize("name", ["demo", "paper", "plume", "plume-noisy", "threshold"])
def test_shipped_missions_load(name):
    m = load_mission(ROOT / "missions" / f"{name}.yaml")
    assert m.name == name
    assert m.grid.shape == (101, 101)
    f = m.build_field()
    xx, yy = m.grid.mesh
    z = f(xx, yy)
    assert np.all(np.isfinite(z)) and z.shape == (101, 101)
    assert 0 < z.min() < z.max() < 100


def _write(tmp_path, text):
    p = tmp_path / "m.yaml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("field: {model: paper}\nvehicles: {cont: 3}\n", r"vehicles\.cont: unknown key"),
        ("field: {model: paper}\nbogus: 1\n", r"bogus: unknown key"),
        ("vehicles: {count: 3}\n", r"field: missing required key"),
        ("field: {model: nope}\n", r"field\.model: must be one of"),
        ("field: {model: paper, sigma1_m: -3}\n", r"field\.sigma1_m: must be > 0, got -3"),
        ("field: {model: paper}\nvehicles: {count: two}\n", r"vehicles\.count: expected an integer"),
        ("field: {model: paper}\nvehicles: {speed_mps: 20, max_speed_mps: 10}\n",
         r"vehicles\.speed_mps: must be <= vehicles\.max_speed_mps"),
        ("field: {model: paper}\narea: {width_m: 0}\n", r"area\.width_m: must be >= 10 \(metres\), got 0"),
        ("field: {model: raster}\n", r"field\.path: missing required key"),
        ("field: {model: paper}\nalgorithm: {planner: greedy}\n", r"algorithm\.planner: must be one of"),
        ("field: [1, 2\n", r"malformed YAML at line"),
        ("- 1\n- 2\n", r"expected a mapping at the top level"),
        ("field: {model: paper}\nalgorithm: {min_iterations: 9, max_iterations: 3}\n",
         r"min_iterations: must be <="),
    ],
)
def test_bad_missions_name_the_key(tmp_path, text, message):
    with pytest.raises(MissionError, match=message):
        load_mission(_write(tmp_path, text))


def test_missing_mission_file(tmp_path):
    with pytest.raises(MissionError, match="no such mission file"):
        load_mission(tmp_path / "absent.yaml")


def test_paper_field_is_positive_gaussian_sum_in_range():
    f = paper_field(REGION, seed=4, n1=5, n2=5)
    xx, yy = Grid(REGION, 101, 101).mesh
    z = f(xx, yy)
    assert z.min() > 0 and z.max() == pytest.approx(95.0)
    assert np.all(f.weights > 0)
    # eq. (9) by hand at one centre of a single-Gaussian field
    one = paper_field(REGION, seed=1, n1=1, n2=0)
    cx, cy = one.centres_m[0]
    assert float(one(cx + 10, cy)) == pytest.approx(float(one(cx, cy)) * np.exp(-0.5), rel=1e-9)


def test_authors_field_normalisation_and_seed():
    g = Grid(REGION, 101, 101)
    z = authors_field(REGION, seed=0)(*g.mesh)
    assert np.ptp(z) == pytest.approx(50.0)
    z2 = authors_field(REGION, seed=0)(*g.mesh)
    np.testing.assert_array_equal(z, z2)
    assert not np.allclose(z, authors_field(REGION, seed=1)(*g.mesh))


def test_plume_field_is_sharp():
    f = plume_field(REGION, seed=2, sources=2, background=10.0)
    z = f(*Grid(REGION, 201, 201).mesh)
    assert z.max() == pytest.approx(100.0, rel=0.02)
    assert np.median(z) == pytest.approx(10.0, abs=0.5)


@pytest.mark.parametrize("suffix", [".npy", ".npz", ".mat", ".csv"])
def test_raster_round_trip(tmp_path, suffix):
    g = Grid(REGION, 51, 41)
    xx, yy = g.mesh
    values = 0.3 * xx + 0.1 * yy + 5
    p = tmp_path / f"r{suffix}"
    if suffix == ".npy":
        np.save(p, values)
    elif suffix == ".npz":
        np.savez(p, field=values)
    elif suffix == ".mat":
        scipy.io.savemat(p, {"G": values})
    else:
        np.savetxt(p, values, delimiter=",")
    f = RasterField(REGION, load_raster(p), method="linear")
    assert float(f(33.3, 71.2)) == pytest.approx(0.3 * 33.3 + 0.1 * 71.2 + 5, rel=1e-9)
    assert float(f(-5, -5)) == pytest.approx(5.0)  # clamped to the edge


def test_raster_errors(tmp_path):
    with pytest.raises(FieldError, match="not found"):
        load_raster(tmp_path / "x.npy")
    p = tmp_path / "x.txt"
    p.write_text("1")
    with pytest.raises(FieldError, match="unsupported format"):
        load_raster(p)
    with pytest.raises(FieldError, match="2-D grid"):
        RasterField(REGION, np.zeros(5))


def test_raster_mission_relative_path(tmp_path):
    np.save(tmp_path / "grid.npy", np.arange(100.0).reshape(10, 10))
    m = load_mission(_write(tmp_path, "field: {model: raster, path: grid.npy}\n"))
    f = m.build_field()
    assert float(f(0, 0)) == pytest.approx(0.0)
    assert float(f(100, 100)) == pytest.approx(99.0)


def test_budget_missions_let_the_budget_bind():
    for name in ("plume", "threshold"):
        a = load_mission(ROOT / "missions" / f"{name}.yaml").algorithm
        assert a.planner == "adaptive" and a.flight_budget_m > 0
        # a batch is 400 m: even at 100 m per iteration the cap is out of reach
        assert a.max_iterations * 100.0 > a.flight_budget_m and a.stop_lambda == 0
    assert load_mission(ROOT / "missions" / "threshold.yaml").algorithm.target_levels == (55.0,)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("field: {model: paper}\nalgorithm: {target_levels: 5}\n",
         r"algorithm\.target_levels: expected a list of numbers"),
        ("field: {model: paper}\nalgorithm: {target_levels: [5, x]}\n",
         r"algorithm\.target_levels\[1\]: expected a number"),
        ("field: {model: paper}\nadaptive: {batch: 3}\n", r"adaptive\.batch: unknown key"),
        ("field: {model: paper}\nadaptive: {model: kriging}\n", r"adaptive\.model: must be one of"),
        ("field: {model: paper}\nalgorithm: {lloyd_variant: matlab}\n",
         r"algorithm\.lloyd_variant: must be one of"),
        ("field: {model: front, width_min_m: 3, width_max_m: 1}\n",
         r"field\.width_max_m: must be >= field\.width_min_m"),
    ],
)
def test_new_keys_are_validated(tmp_path, text, message):
    with pytest.raises(MissionError, match=message):
        load_mission(_write(tmp_path, text))


def test_front_field_has_a_sharp_step_and_islands():
    f = front_field(REGION, 3, width_min_m=1.0, width_max_m=1.0)
    xx, yy = Grid(REGION, 201, 201).mesh
    z = f(xx, yy)
    assert z.min() < 10 + 0.06 * 90 and z.max() > 100 - 0.06 * 90  # two plateaus (+- slope)
    assert len(f.islands_m) == 2
    for cx, cy, r in f.islands_m:  # inside an island: the high side; just outside: low
        assert f(cx, cy) > 90 and f(cx + r + 4, cy) < f(cx, cy) - 60
    gy, gx = np.gradient(z, 0.5)
    assert np.hypot(gx, gy).max() > 90 / (2 * 1.0) * 0.9  # the step is ~w wide: 45 / m
