"""Figures of one run directory and of a multi-seed study (synthetic data)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.image import imread

from econdor_gcs.files import figures
from econdor_gcs.files.figures import RUN_FIGURES, STUDY_FIGURES, plot_run, plot_study

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
METRIC_COLUMNS = (
    "iteration", "levels_planned", "levels_traced", "kappa", "delta", "learning_error",
    "mae", "mae_db", "span_ratio", "contour_distance_m", "flight_distance_m", "samples",
)
SAMPLE_COLUMNS = ("t_s", "x_m", "y_m", "value", "phase", "vehicle")


def _field(xx: np.ndarray, yy: np.ndarray) -> np.ndarray:
    return np.exp(-((xx - 120.0) ** 2 + (yy - 80.0) ** 2) / (2 * 60.0**2)) * 10.0


def _metric_rows(n: int, rng: np.random.Generator, lawnmower: bool = False,
                 with_truth: bool = True) -> list[dict[str, float]]:
    rows = []
    dist = contour = 0.0
    for i in range(n):
        mae = 2.0 * 0.6**i * (1 + 0.1 * rng.random())
        traced = 0 if lawnmower else 2 + i
        dist += 800.0 + 100.0 * rng.random()
        contour += 0.0 if lawnmower else 500.0 + 50.0 * i
        rows.append({
            "iteration": i,
            "levels_planned": 0 if lawnmower else traced + 1,
            "levels_traced": traced,
            "kappa": 0 if lawnmower else 3 + (i % 2),
            "delta": 0.0 if lawnmower else 0.5 * 0.8**i,
            "learning_error": math.nan if i == 0 else 0.5 * 0.7**i,
            "mae": mae if with_truth else math.nan,
            "mae_db": 20 * math.log10(mae) if with_truth else math.nan,
            "span_ratio": (1.0 - 0.3 * 0.5**i) if with_truth else math.nan,
            "contour_distance_m": contour,
            "flight_distance_m": dist,
            "samples": 100 * (i + 1),
        })
    return rows


def _make_run(path: Path, with_truth: bool = True) -> Path:
    """A run directory in the formats of econdor_gcs.files.rundir."""
    rng = np.random.default_rng(1)
    path.mkdir(parents=True)
    with (path / "metrics.csv").open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=METRIC_COLUMNS)
        w.writeheader()
        for r in _metric_rows(5, rng, with_truth=with_truth):
            w.writerow(r)
    # samples: a transit leg, a search leg, then two traced circles (2 vehicles)
    rows = []
    t = 0.0
    for v in range(2):
        for k in range(20):
            rows.append((t, 5.0 * k, 10.0 + 60 * v, 0.0, 0, v))
            t += 1
        for k in range(10):
            rows.append((t, 100.0, 10.0 + 60 * v + 4.0 * k, 0.0, 1, v))
            t += 1
        ang = np.linspace(0, 2 * np.pi, 80)
        r = 40.0 + 30.0 * v
        for a in ang:
            rows.append((t, 120 + r * np.cos(a), 80 + r * np.sin(a), 5.0, 2, v))
            t += 1
        for k in range(10):
            rows.append((t, 20.0 * k, 150.0, 1.0, 3, v))
            t += 1
    with (path / "samples.csv").open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(SAMPLE_COLUMNS)
        for row in rows:
            w.writerow((f"{row[0]:.3f}", f"{row[1]:.3f}", f"{row[2]:.3f}", f"{row[3]:.6g}",
                        int(row[4]), int(row[5])))
    gx = np.linspace(0.0, 240.0, 61)
    gy = np.linspace(0.0, 160.0, 41)
    xx, yy = np.meshgrid(gx, gy)
    truth = _field(xx, yy)
    estimate = truth + 0.3 * np.sin(xx / 30.0) * np.cos(yy / 25.0)
    arrays = {"grid_x": gx, "grid_y": gy, "estimate": estimate}
    if with_truth:
        arrays["truth"] = truth
    np.savez_compressed(path / "fields.npz", **arrays)
    summary = {"planner": "econdor", "seed": 7, "iterations": 5,
               "final_mae": None if not with_truth else 0.2, "vehicles": 2}
    (path / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    return path


def _study_rows(as_strings: bool | str) -> list[dict]:
    """2 seeds x 3 planners x 4 iterations; ``as_strings``: True (all), False (none) or a
    planner name whose rows are strings, as csv.DictReader gives them."""
    rows = []
    for seed in (1, 2):
        rng = np.random.default_rng(seed)
        for planner in ("econdor", "no-sg", "lawnmower"):
            for r in _metric_rows(4, rng, lawnmower=planner == "lawnmower"):
                row = {"seed": seed, "planner": planner, **r}
                if as_strings is True or as_strings == planner:
                    row = {k: ("" if isinstance(v, float) and math.isnan(v) else str(v))
                           for k, v in row.items()}
                rows.append(row)
    return rows


def _assert_png(path: Path, fig: Figure | None = None) -> None:
    """A PNG that decodes, of the figure's size in pixels, and not blank."""
    assert path.exists(), path
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, path
    image = imread(path)
    if fig is not None:
        w, h = fig.get_size_inches() * fig.dpi
        assert image.shape[:2] == (round(h), round(w)), path
    assert np.ptp(image[..., :3]) > 0.5, path  # drawn on, not one colour


@pytest.fixture
def drawn(monkeypatch: pytest.MonkeyPatch) -> dict[str, Figure]:
    """Every figure ``econdor_gcs.files.figures`` saves, by file name (their data are checked)."""
    figs: dict[str, Figure] = {}
    real = figures._save

    def save(fig: Figure, path: Path) -> Path:
        figs[path.name] = fig
        return real(fig, path)

    monkeypatch.setattr(figures, "_save", save)
    return figs


def _xy(ax, k: int = 0) -> np.ndarray:
    return np.asarray(ax.lines[k].get_xydata())


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _make_run(tmp_path_factory.mktemp("figs") / "run")


def test_plot_run_writes_all_figures(run_dir: Path, drawn: dict[str, Figure]) -> None:
    run = run_dir
    paths = plot_run(run)
    assert sorted(p.name for p in paths) == sorted(RUN_FIGURES)
    for name in RUN_FIGURES:
        p = run / "figures" / name
        assert p in paths
        _assert_png(p, drawn[name])


def test_plot_run_draws_the_run_s_numbers(run_dir: Path, drawn: dict[str, Figure]) -> None:
    """Each curve is the metrics.csv column it names; the maps show the run's fields and
    every sample path."""
    plot_run(run_dir)
    with (run_dir / "metrics.csv").open() as f:
        m = {k: np.array([float(r[k]) if r[k] not in ("", "nan") else np.nan for r in rows])
             for rows in [list(csv.DictReader(f))] for k in rows[0]}
    it = m["iteration"]
    ax = drawn["mae_vs_iteration.png"].axes[0]
    np.testing.assert_allclose(_xy(ax), np.c_[it, m["mae_db"]])
    assert "MAE per iteration" in ax.get_title()
    bars = [p.get_height() for p in drawn["mae_vs_iteration.png"].axes[1].patches]
    np.testing.assert_allclose(bars, np.r_[m["levels_planned"], m["levels_traced"]])
    le = drawn["learning_error.png"].axes[0]
    ok = np.isfinite(m["learning_error"])
    np.testing.assert_allclose(_xy(le)[ok, 1], 20 * np.log10(m["learning_error"][ok]))
    np.testing.assert_allclose(_xy(drawn["span_ratio.png"].axes[0]), np.c_[it, m["span_ratio"]])
    fd = drawn["flight_distance.png"].axes[0]
    np.testing.assert_allclose(_xy(fd, 0)[:, 1], m["flight_distance_m"] / 1000)
    np.testing.assert_allclose(_xy(fd, 1)[:, 1], m["contour_distance_m"] / 1000)
    np.testing.assert_allclose(_xy(drawn["mae_vs_distance.png"].axes[0]),
                               np.c_[m["flight_distance_m"] / 1000, m["mae_db"]])
    d = drawn["delta.png"].axes
    np.testing.assert_allclose(_xy(d[0])[:, 1], m["delta"])
    np.testing.assert_allclose(_xy(d[1])[:, 1], m["kappa"])

    maps = drawn["maps.png"]
    titles = [ax.get_title() for ax in maps.axes if ax.get_visible() and ax.get_title()]
    fields = np.load(run_dir / "fields.npz")
    mae = float(np.mean(np.abs(fields["truth"] - fields["estimate"])))
    assert titles[:3] == ["true field", "estimate", f"local absolute error (MAE {mae:.3g})"]
    n = len((run_dir / "samples.csv").read_text().splitlines()) - 1
    assert titles[3] == f"sample paths by phase ({n} samples)"
    paths_ax = next(ax for ax in maps.axes if ax.get_title() == titles[3])
    segs = [c for c in paths_ax.collections if isinstance(c, LineCollection)
            and not hasattr(c, "levels")]
    # 2 vehicles x 120 samples: 119 steps each, of which the jumps to the circle and to
    # the survey line (> 10x the median step) are gaps, not flight
    assert sum(len(c.get_segments()) for c in segs) == 2 * (119 - 2)
    legend = [t.get_text() for t in paths_ax.get_legend().get_texts()]
    assert legend == ["transit", "search", "trace", "survey"]


def test_plot_run_without_truth(tmp_path: Path) -> None:
    run = _make_run(tmp_path / "run", with_truth=False)
    paths = plot_run(run)
    names = {p.name for p in paths}
    # no MAE / span ratio data -> those figures are skipped, the rest are drawn
    assert names == {"learning_error.png", "flight_distance.png", "delta.png", "maps.png"}
    for p in paths:
        _assert_png(p)


def test_plot_run_missing_files(tmp_path: Path) -> None:
    run = tmp_path / "empty"
    run.mkdir()
    assert plot_run(run) == []
    # header-only samples, no summary, metrics only: no maps, curves still drawn
    (run / "samples.csv").write_text(",".join(SAMPLE_COLUMNS) + "\n", encoding="utf-8")
    with (run / "metrics.csv").open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=METRIC_COLUMNS)
        w.writeheader()
        w.writerows(_metric_rows(2, np.random.default_rng(0)))
    names = {p.name for p in plot_run(run)}
    assert "maps.png" not in names and "mae_vs_iteration.png" in names


def test_plot_study(tmp_path: Path, run_dir: Path) -> None:
    out = tmp_path / "study"
    # econdor rows as csv strings, the others as numbers: both must be accepted
    paths = plot_study(_study_rows("econdor"), out, maps={"econdor seed 7": run_dir})
    expected = [*STUDY_FIGURES, "fig9_maps_econdor_seed_7.png"]
    assert sorted(p.name for p in paths) == sorted(expected)
    for name in expected:
        _assert_png(out / name)


def test_plot_study_single_planner(tmp_path: Path) -> None:
    rows = [r for r in _study_rows(True) if r["planner"] == "lawnmower"]
    paths = plot_study(rows, tmp_path)
    names = {p.name for p in paths}
    # the lawnmower has no levels and no delta: only the iteration/distance figures
    assert names == {"fig5_span_ratio.png", "fig6_flight_distance.png",
                     "fig7_mae_vs_distance.png"}
