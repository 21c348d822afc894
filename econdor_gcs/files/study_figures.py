"""PNG figures of a multi-seed study (E-CONDOR paper, Figs. 3-9, across seeds).

:func:`plot_study` draws the paper's figures across seeds (median + 25-75 % band per
planner) from the rows of a ``study.csv``, plus ``fig9_maps_<name>.png`` for chosen runs
(the maps of :func:`~.figures.plot_run`). Same rules as :mod:`.figures`: no pyplot, missing
data skip the affected figures.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.ticker import MaxNLocator

from econdor_gcs.files.figures import (
    PLANNER_COLORS,
    PLANNER_LABELS,
    PLANNER_ORDER,
    _col,
    _db,
    _draw_maps,
    _load_fields,
    _load_samples,
    _load_summary,
    _new_figure,
    _num,
    _run_title,
    _save,
    _style,
    _with_sub,
)

STUDY_FIGURES = (
    "fig3_mae_db_vs_levels.png",
    "fig4_learning_error_vs_levels.png",
    "fig5_span_ratio.png",
    "fig6_flight_distance.png",
    "fig7_mae_vs_distance.png",
    "fig8_delta.png",
)


def _group(rows: Iterable[Mapping[str, Any]]) -> dict[str, list[list[dict[str, Any]]]]:
    """planner -> list of per-seed row lists, each sorted by iteration."""
    by: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for r in rows:
        planner = str(r.get("planner", "")).strip() or "?"
        seed = str(r.get("seed", "")).strip()
        by.setdefault(planner, {}).setdefault(seed, []).append(dict(r))
    out: dict[str, list[list[dict[str, Any]]]] = {}
    for planner, seeds in by.items():
        out[planner] = [sorted(v, key=lambda r: _num(r.get("iteration"))) for _, v in
                        sorted(seeds.items())]
    return out


def _ordered(planners: Iterable[str]) -> list[str]:
    ps = list(planners)
    return [p for p in PLANNER_ORDER if p in ps] + sorted(p for p in ps if p not in PLANNER_ORDER)


def _band_by_iteration(seeds: list[list[dict[str, Any]]], key: str,
                       transform: Callable[[np.ndarray], np.ndarray] | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    table: dict[float, list[float]] = {}
    for rows in seeds:
        it = _col(rows, "iteration")
        y = _col(rows, key)
        if transform is not None:
            y = transform(y)
        for i, v in zip(it, y, strict=True):
            if math.isfinite(i) and math.isfinite(v):
                table.setdefault(i, []).append(v)
    xs = np.array(sorted(table))
    if xs.size == 0:
        return xs, xs, xs, xs
    q = np.array([np.percentile(table[x], [50, 25, 75]) for x in xs])
    return xs, q[:, 0], q[:, 1], q[:, 2]


def _band_interp(curves: list[tuple[np.ndarray, np.ndarray]], n: int = 200
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Median and 25-75 % band of curves y(x) interpolated on a common x axis.

    The axis runs from the latest start (where every seed has data) to the furthest end;
    past its own end a curve holds its final value (a finished run stays at its final
    error), so every seed counts everywhere and the median has no coverage jumps."""
    clean: list[tuple[np.ndarray, np.ndarray]] = []
    for x, y in curves:
        ok = np.isfinite(x) & np.isfinite(y)
        x, y = x[ok], y[ok]
        if x.size == 0:
            continue
        order = np.argsort(x, kind="stable")
        x, y = x[order], y[order]
        # keep the last value at repeated x (the state after that x was reached)
        last = np.append(x[1:] != x[:-1], True)
        clean.append((x[last], y[last]))
    if not clean:
        e = np.zeros(0)
        return e, e, e, e
    lo = max(float(x[0]) for x, _ in clean)
    hi = max(float(x[-1]) for x, _ in clean)
    grid = np.array([lo]) if hi <= lo else np.linspace(lo, hi, n)
    stack = np.array([np.interp(grid, x, y) for x, y in clean])
    q = np.percentile(stack, [50, 25, 75], axis=0)
    return grid, q[0], q[1], q[2]


def _plot_band(ax: Axes, x: np.ndarray, med: np.ndarray, lo: np.ndarray, hi: np.ndarray,
               planner: str, label: str | None = None, ls: str = "-", marker: str | None = "o",
               band: bool = True) -> None:
    if x.size == 0:
        return
    color = PLANNER_COLORS.get(planner)
    lines = ax.plot(x, med, ls=ls, marker=marker if x.size <= 40 else None, ms=4, color=color,
                    label=label if label is not None else PLANNER_LABELS.get(planner, planner))
    if band and x.size > 1:
        ax.fill_between(x, lo, hi, color=lines[0].get_color(), alpha=0.2, lw=0)


def _km(v: np.ndarray) -> np.ndarray:
    return v / 1000.0


def _cum_levels(rows: list[dict[str, Any]]) -> np.ndarray:
    return np.cumsum(np.nan_to_num(_col(rows, "levels_traced")))


def _band_note(groups: Mapping[str, list[list[dict[str, Any]]]]) -> str:
    n = max((len(v) for v in groups.values()), default=0)
    return f"median and 25–75 % band over {n} seed{'s' if n != 1 else ''}"


def plot_study(rows: list[dict[str, Any]], out_dir: str | Path,
               maps: Mapping[str, str | Path] | None = None) -> list[Path]:
    """Draw the paper's Figs. 3-8 across seeds from ``study.csv`` rows into ``out_dir`` (see
    :data:`STUDY_FIGURES`), plus ``fig9_maps_<name>.png`` for each ``maps`` entry
    (name -> run directory). Values may be strings or numbers. Returns the paths written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    groups = _group(rows)
    note = _band_note(groups)
    planners = _ordered(groups)
    contour_planners = [p for p in planners if p != "lawnmower"]
    written: list[Path] = []

    def vs_levels(key: str, transform: Callable[[np.ndarray], np.ndarray] | None,
                  ylabel: str, title: str, name: str) -> None:
        fig = _new_figure()
        ax = fig.subplots()
        drawn = False
        for p in contour_planners:
            curves = []
            for seed_rows in groups[p]:
                y = _col(seed_rows, key)
                if transform is not None:
                    y = transform(y)
                curves.append((_cum_levels(seed_rows), y))
            x, med, lo, hi = _band_interp(curves)
            if x.size:
                _plot_band(ax, x, med, lo, hi, p, marker=None)
                drawn = True
        if drawn:
            _style(ax, "cumulative number of contour levels traced", ylabel,
                   _with_sub(title, note))
            ax.legend()
            written.append(_save(fig, out / name))

    vs_levels("mae_db", None, "MAE (dB, 20·log10)", "Fig. 3 — MAE vs number of levels",
              "fig3_mae_db_vs_levels.png")
    vs_levels("learning_error", _db, "learning error (dB, 20·log10)",
              "Fig. 4 — learning error vs number of levels", "fig4_learning_error_vs_levels.png")

    # Fig. 5: span ratio vs iteration
    fig = _new_figure()
    ax = fig.subplots()
    drawn = False
    for p in planners:
        x, med, lo, hi = _band_by_iteration(groups[p], "span_ratio")
        if x.size:
            _plot_band(ax, x, med, lo, hi, p)
            drawn = True
    if drawn:
        ax.axhline(1.0, color="k", ls=":", lw=1, label="ideal (1)")
        _style(ax, "iteration", "span ratio $SP_n / SP_{actual}$ (–)",
               _with_sub("Fig. 5 — signal span ratio", note))
        ax.legend()
        written.append(_save(fig, out / "fig5_span_ratio.png"))

    # Fig. 6: flight distance vs iteration (total solid, contour-only dashed)
    fig = _new_figure()
    ax = fig.subplots()
    drawn = False
    for p in planners:
        x, med, lo, hi = _band_by_iteration(groups[p], "flight_distance_m", _km)
        if x.size:
            _plot_band(ax, x, med, lo, hi, p,
                       label=f"{PLANNER_LABELS.get(p, p)} — total")
            drawn = True
        x, med, lo, hi = _band_by_iteration(groups[p], "contour_distance_m", _km)
        if x.size and np.nanmax(med) > 0:
            _plot_band(ax, x, med, lo, hi, p, label=f"{PLANNER_LABELS.get(p, p)} — contours",
                       ls="--", marker=None, band=False)
            drawn = True
    if drawn:
        _style(ax, "iteration", "cumulative flight distance (km)",
               _with_sub("Fig. 6 — flight distance (cost)", note))
        ax.legend(fontsize=8)
        written.append(_save(fig, out / "fig6_flight_distance.png"))

    # Fig. 7: MAE dB vs total flight distance, all planners
    fig = _new_figure()
    ax = fig.subplots()
    drawn = False
    for p in planners:
        curves = [(_col(r, "flight_distance_m") / 1000.0, _col(r, "mae_db")) for r in groups[p]]
        x, med, lo, hi = _band_interp(curves)
        if x.size:
            _plot_band(ax, x, med, lo, hi, p, marker=None)
            drawn = True
    if drawn:
        _style(ax, "total flight distance (km)", "MAE (dB, 20·log10)",
               _with_sub("Fig. 7 — MAE vs flight distance", note))
        ax.legend()
        written.append(_save(fig, out / "fig7_mae_vs_distance.png"))

    # Fig. 8: delta (and kappa) vs iteration, econdor only
    if "econdor" in groups:
        x, med, lo, hi = _band_by_iteration(groups["econdor"], "delta")
        xk, mk, lk, hk = _band_by_iteration(groups["econdor"], "kappa")
        if x.size or xk.size:
            fig = _new_figure()
            ax = fig.subplots()
            handles = []
            if x.size:
                _plot_band(ax, x, med, lo, hi, "econdor", label="δ (drop threshold)")
            ax2 = ax.twinx()
            if xk.size:
                ax2.plot(xk, mk, "s--", color="tab:red", ms=4, label="κ (new levels)")
                if xk.size > 1:
                    ax2.fill_between(xk, lk, hk, color="tab:red", alpha=0.12, lw=0)
            ax2.set_ylabel("κ (levels)")
            ax2.yaxis.set_major_locator(MaxNLocator(integer=True))
            handles = ax.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
            _style(ax, "iteration", "δ", _with_sub("Fig. 8 — δ and κ (E-CONDOR)", note))
            ax.legend(handles=handles, loc="best")
            written.append(_save(fig, out / "fig8_delta.png"))

    for name, run_dir in (maps or {}).items():
        run_dir = Path(run_dir)
        summary = _load_summary(run_dir)
        title = f"Fig. 9 — {name}"
        sub = _run_title(summary)
        if sub:
            title += f" ({sub})"
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in str(name))
        path = _draw_maps(out / f"fig9_maps_{safe}.png", _load_fields(run_dir),
                          _load_samples(run_dir), title)
        if path is not None:
            written.append(path)
    return written
