"""PNG figures of one run and of a multi-seed study (E-CONDOR paper, Figs. 3-9).

Only :class:`matplotlib.figure.Figure` is used (no pyplot, no global state), so the
functions are safe to call from threads and worker processes; output goes through the
Agg canvas.

* :func:`plot_run` draws the per-iteration curves and the maps of one run directory
  into ``RUN_DIR/figures/``.
* :func:`plot_study` draws the paper's figures across seeds (median + 25-75 % band per
  planner) from the rows of a ``study.csv``, plus ``fig9_maps_<name>.png`` for chosen runs.

Missing data (no truth, NaN MAE columns, empty samples) skip the affected figures
instead of failing.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from econdor_gcs.core.tasks import Phase, SampleLog
from econdor_gcs.files.rundir import read_metrics, read_samples

DPI = 110

PLANNER_ORDER = ("econdor", "no-sg", "lawnmower")
PLANNER_LABELS = {
    "econdor": "E-CONDOR (dual SG)",
    "no-sg": "without dual SG",
    "lawnmower": "lawnmower",
}
PLANNER_COLORS = {"econdor": "tab:blue", "no-sg": "tab:orange", "lawnmower": "tab:green"}
PHASE_COLORS = {
    Phase.TRANSIT: "0.55",
    Phase.SEARCH: "tab:orange",
    Phase.TRACE: "tab:red",
    Phase.SURVEY: "tab:green",
}

RUN_FIGURES = (
    "mae_vs_iteration.png",
    "learning_error.png",
    "span_ratio.png",
    "flight_distance.png",
    "mae_vs_distance.png",
    "delta.png",
    "maps.png",
)
STUDY_FIGURES = (
    "fig3_mae_db_vs_levels.png",
    "fig4_learning_error_vs_levels.png",
    "fig5_span_ratio.png",
    "fig6_flight_distance.png",
    "fig7_mae_vs_distance.png",
    "fig8_delta.png",
)


# --------------------------------------------------------------------------- helpers


def _num(value: Any) -> float:
    """A float from a csv string or a number; '', None, 'nan', +-inf -> NaN."""
    if value is None:
        return math.nan
    if isinstance(value, str):
        value = value.strip()
        if value == "" or value.lower() in ("nan", "none", "null"):
            return math.nan
    try:
        x = float(value)
    except (TypeError, ValueError):
        return math.nan
    return x if math.isfinite(x) else math.nan


def _col(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    return np.array([_num(r.get(key)) for r in rows], dtype=float)


def _has(y: np.ndarray) -> bool:
    return bool(np.isfinite(y).any())


def _db(values: np.ndarray) -> np.ndarray:
    """``20 log10`` (paper eq. 11); non-positive -> NaN."""
    out = np.full(values.shape, math.nan)
    ok = np.isfinite(values) & (values > 0)
    out[ok] = 20.0 * np.log10(values[ok])
    return out


def _new_figure(figsize: tuple[float, float] = (7.0, 4.5), constrained: bool = False) -> Figure:
    """A figure on an Agg canvas. Line plots get fixed margins (room for a twin axis and a
    two-line title), which is much cheaper than a layout engine; maps use constrained
    layout for their colorbars."""
    if constrained:
        fig = Figure(figsize=figsize, dpi=DPI, layout="constrained")
    else:
        fig = Figure(figsize=figsize, dpi=DPI)
        fig.subplots_adjust(left=0.11, right=0.88, bottom=0.12, top=0.86)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, format="png")
    return path


def _style(ax: Axes, xlabel: str, ylabel: str, title: str) -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    if xlabel == "iteration":
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def _run_title(summary: Mapping[str, Any]) -> str:
    parts = []
    if summary.get("planner"):
        parts.append(str(summary["planner"]))
    if summary.get("seed") is not None:
        parts.append(f"seed {summary['seed']}")
    return " / ".join(parts)


def _with_sub(title: str, sub: str) -> str:
    return f"{title}\n{sub}" if sub else title


# --------------------------------------------------------------------------- maps


def _load_fields(run_dir: Path) -> dict[str, np.ndarray] | None:
    path = run_dir / "fields.npz"
    if not path.exists():
        return None
    with np.load(path) as z:
        return {k: np.asarray(z[k]) for k in z.files}


def _load_samples(run_dir: Path) -> SampleLog:
    path = run_dir / "samples.csv"
    if not path.exists():
        return SampleLog()
    try:
        with warnings.catch_warnings():  # numpy warns on a header-only file
            warnings.simplefilter("ignore", UserWarning)
            return read_samples(path)
    except (ValueError, OSError):
        return SampleLog()


def _load_summary(run_dir: Path) -> dict[str, Any]:
    path = run_dir / "summary.json"
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, OSError):
        return {}
    return data if isinstance(data, dict) else {}


def _mesh(fields: Mapping[str, np.ndarray], shape: tuple[int, ...]
          ) -> tuple[np.ndarray, np.ndarray]:
    gx = np.asarray(fields["grid_x"], dtype=float)
    gy = np.asarray(fields["grid_y"], dtype=float)
    if gx.ndim == 1 and gy.ndim == 1:
        xx, yy = np.meshgrid(gx, gy)
    else:
        xx, yy = gx, gy
    if xx.shape != shape:
        raise ValueError(f"grid shape {xx.shape} does not match field shape {shape}")
    return xx, yy


def _path_segments(samples: SampleLog) -> tuple[np.ndarray, np.ndarray]:
    """Segments between consecutive samples of each vehicle (gaps removed), and the phase
    of the sample ending each segment."""
    segs: list[np.ndarray] = []
    phases: list[np.ndarray] = []
    for v in np.unique(samples.vehicle):
        idx = np.flatnonzero(samples.vehicle == v)
        if len(idx) < 2:
            continue
        idx = idx[np.argsort(samples.t_s[idx], kind="stable")]
        x, y = samples.x_m[idx], samples.y_m[idx]
        step = np.hypot(np.diff(x), np.diff(y))
        positive = step[step > 0]
        limit = 10.0 * float(np.median(positive)) if positive.size else math.inf
        keep = step <= limit
        pts = np.column_stack([x, y])
        s = np.stack([pts[:-1], pts[1:]], axis=1)[keep]
        segs.append(s)
        phases.append(samples.phase[idx][1:][keep])
    if not segs:
        return np.zeros((0, 2, 2)), np.zeros(0, dtype=int)
    return np.concatenate(segs), np.concatenate(phases)


def _phase_color(p: int) -> str:
    return PHASE_COLORS.get(Phase(p), "k") if p in Phase._value2member_map_ else "k"


def _phase_name(p: int) -> str:
    return Phase(p).name.lower() if p in Phase._value2member_map_ else f"phase {p}"


def _draw_paths(ax: Axes, samples: SampleLog) -> None:
    segs, phases = _path_segments(samples)
    present = sorted({int(p) for p in np.unique(samples.phase)})
    if len(segs):
        colors = [_phase_color(int(p)) for p in phases]
        ax.add_collection(LineCollection(list(segs), colors=colors, linewidths=1.2, zorder=3))
    else:
        for p in present:
            m = samples.phase == p
            ax.plot(samples.x_m[m], samples.y_m[m], ".", ms=2, color=_phase_color(p), zorder=3)
    handles = [Line2D([], [], color=_phase_color(p), lw=2, label=_phase_name(p))
               for p in present]
    if handles:
        ax.legend(handles=handles, title="phase", loc="upper right", fontsize=8,
                  title_fontsize=8, framealpha=0.85)


def _draw_maps(out_path: Path, fields: Mapping[str, np.ndarray] | None,
               samples: SampleLog, title: str = "") -> Path | None:
    """Truth (if known), estimate, local |truth - estimate| (paper Fig. 9) and the sampled
    paths coloured by phase over the estimate's contours. Returns None without an estimate."""
    if fields is None or "estimate" not in fields or "grid_x" not in fields:
        return None
    est = np.asarray(fields["estimate"], dtype=float)
    if est.ndim != 2:
        return None
    xx, yy = _mesh(fields, est.shape)
    truth = fields.get("truth")
    if truth is not None:
        truth = np.asarray(truth, dtype=float)
        if truth.shape != est.shape or truth.ndim != 2:
            truth = None

    panels: list[str] = (["truth"] if truth is not None else []) + ["estimate"]
    if truth is not None:
        panels.append("error")
    panels.append("paths")
    n = len(panels)
    ncols = 2 if n == 4 else n
    nrows = math.ceil(n / ncols)
    # fixed margins: a layout engine doubles the drawing time of this figure
    fig = _new_figure((5.4 * ncols, 4.4 * nrows + 0.5))
    fig.subplots_adjust(left=0.07, right=0.97, bottom=0.08, top=0.9 if nrows == 2 else 0.84,
                        wspace=0.25, hspace=0.35)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()

    values = [est] + ([truth] if truth is not None else [])
    vmin = float(min(np.nanmin(v) for v in values))
    vmax = float(max(np.nanmax(v) for v in values))
    if not vmax > vmin:
        vmax = vmin + 1.0
    levels = MaxNLocator(nbins=20).tick_values(vmin, vmax)

    for ax, kind in zip(axes, panels, strict=False):
        if kind in ("truth", "estimate"):
            data = truth if kind == "truth" else est
            cf = ax.contourf(xx, yy, data, levels=levels, cmap="viridis", extend="both")
            fig.colorbar(cf, ax=ax, label="field value")
            ax.set_title("true field" if kind == "truth" else "estimate")
        elif kind == "error":
            err = np.abs(truth - est)
            top = float(np.nanmax(err)) if np.isfinite(err).any() else 1.0
            cf = ax.contourf(xx, yy, err, levels=MaxNLocator(nbins=20).tick_values(
                0.0, max(top, 1e-12)), cmap="magma")
            fig.colorbar(cf, ax=ax, label="|truth − estimate|")
            ax.set_title(f"local absolute error (MAE {np.nanmean(err):.3g})")
        else:
            cs = ax.contour(xx, yy, est, levels=levels[::2], cmap="viridis",
                            linewidths=0.8, zorder=2)
            fig.colorbar(cs, ax=ax, label="estimate contour level")
            if len(samples):
                _draw_paths(ax, samples)
            ax.set_title(f"sample paths by phase ({len(samples)} samples)")
        ax.set_aspect("equal")
        ax.set_xlim(float(np.min(xx)), float(np.max(xx)))
        ax.set_ylim(float(np.min(yy)), float(np.max(yy)))
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    for ax in axes[n:]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title)
    return _save(fig, out_path)


# --------------------------------------------------------------------------- one run


def plot_run(run_dir: str | Path) -> list[Path]:
    """Draw the figures of one run directory into ``run_dir/figures/``; returns the paths
    written (see :data:`RUN_FIGURES`). Figures whose data are missing are skipped."""
    run_dir = Path(run_dir)
    out = run_dir / "figures"
    out.mkdir(parents=True, exist_ok=True)
    summary = _load_summary(run_dir)
    sub = _run_title(summary)
    metrics_path = run_dir / "metrics.csv"
    rows: list[dict[str, Any]] = read_metrics(metrics_path) if metrics_path.exists() else []
    rows = sorted(rows, key=lambda r: _num(r.get("iteration")))
    written: list[Path] = []

    def emit(path: Path | None) -> None:
        if path is not None:
            written.append(path)

    if rows:
        it = _col(rows, "iteration")
        mae_db = _col(rows, "mae_db")
        le_db = _db(_col(rows, "learning_error"))
        span = _col(rows, "span_ratio")
        dist = _col(rows, "flight_distance_m")
        cdist = _col(rows, "contour_distance_m")
        delta = _col(rows, "delta")
        kappa = _col(rows, "kappa")
        planned = _col(rows, "levels_planned")
        traced = _col(rows, "levels_traced")

        if _has(mae_db):
            fig = _new_figure()
            ax = fig.subplots()
            ax.plot(it, mae_db, "o-", color="tab:blue", label="MAE")
            _style(ax, "iteration", "MAE (dB, 20·log10)", _with_sub("MAE per iteration", sub))
            handles, labels = ax.get_legend_handles_labels()
            if _has(planned) or _has(traced):
                ax2 = ax.twinx()
                w = 0.38
                ax2.bar(it - w / 2, np.nan_to_num(planned), width=w, alpha=0.25,
                        color="tab:gray", label="levels planned")
                ax2.bar(it + w / 2, np.nan_to_num(traced), width=w, alpha=0.35,
                        color="tab:red", label="levels traced")
                ax2.set_ylabel("number of levels")
                h2, l2 = ax2.get_legend_handles_labels()
                handles, labels = handles + h2, labels + l2
                ax.set_zorder(ax2.get_zorder() + 1)
                ax.patch.set_visible(False)
            ax.legend(handles, labels, loc="upper right")
            emit(_save(fig, out / "mae_vs_iteration.png"))

        if _has(le_db):
            fig = _new_figure()
            ax = fig.subplots()
            ax.plot(it, le_db, "o-", color="tab:purple", label="learning error $E_n$")
            _style(ax, "iteration", "learning error (dB, 20·log10)",
                   _with_sub("learning error (mean |estimate change|)", sub))
            ax.legend()
            emit(_save(fig, out / "learning_error.png"))

        if _has(span):
            fig = _new_figure()
            ax = fig.subplots()
            ax.plot(it, span, "o-", color="tab:blue", label="span ratio")
            ax.axhline(1.0, color="k", ls=":", lw=1, label="ideal (1)")
            _style(ax, "iteration", "span ratio $SP_n / SP_{actual}$ (–)",
                   _with_sub("signal span ratio", sub))
            ax.legend()
            emit(_save(fig, out / "span_ratio.png"))

        if _has(dist) or _has(cdist):
            fig = _new_figure()
            ax = fig.subplots()
            if _has(dist):
                ax.plot(it, dist / 1000.0, "o-", color="tab:blue", label="total flown")
            if _has(cdist):
                ax.plot(it, cdist / 1000.0, "s--", color="tab:red", label="contour tracing only")
            _style(ax, "iteration", "cumulative distance (km)",
                   _with_sub("flight distance (cost)", sub))
            ax.legend()
            emit(_save(fig, out / "flight_distance.png"))

        if _has(mae_db) and _has(dist):
            fig = _new_figure()
            ax = fig.subplots()
            ax.plot(dist / 1000.0, mae_db, "o-", color="tab:blue", label="MAE")
            for x, y, i in zip(dist, mae_db, it, strict=True):
                if math.isfinite(x) and math.isfinite(y):
                    ax.annotate(f"{int(i)}", (x / 1000.0, y), textcoords="offset points",
                                xytext=(3, 4), fontsize=7, color="0.3")
            _style(ax, "total flight distance (km)", "MAE (dB, 20·log10)",
                   _with_sub("MAE vs flight distance (labels: iteration)", sub))
            ax.legend()
            emit(_save(fig, out / "mae_vs_distance.png"))

        if _has(delta) or _has(kappa):
            fig = _new_figure()
            ax = fig.subplots()
            handles = []
            if _has(delta):
                handles += ax.plot(it, delta, "o-", color="tab:blue", label="δ (drop threshold)")
            ax2 = ax.twinx()
            if _has(kappa):
                handles += ax2.plot(it, kappa, "s--", color="tab:red", label="κ (new levels)")
            ax2.set_ylabel("κ (levels)")
            ax2.yaxis.set_major_locator(MaxNLocator(integer=True))
            _style(ax, "iteration", "δ", _with_sub("dual SG parameters δ and κ", sub))
            ax.legend(handles=handles, loc="best")
            emit(_save(fig, out / "delta.png"))

    emit(_draw_maps(out / "maps.png", _load_fields(run_dir), _load_samples(run_dir),
                    _with_sub("maps", sub).replace("\n", " — ")))
    return written


# --------------------------------------------------------------------------- study


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
