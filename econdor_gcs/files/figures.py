"""PNG figures of one run (E-CONDOR paper, Figs. 3-9, per iteration), and the drawing
helpers the study's figures (:mod:`.study_figures`) share.

Only :class:`matplotlib.figure.Figure` is used (no pyplot, no global state), so the
functions are safe to call from threads and worker processes; output goes through the
Agg canvas.

:func:`plot_run` draws the per-iteration curves and the maps of one run directory into
``RUN_DIR/figures/``.

Missing data (no truth, NaN MAE columns, empty samples) skip the affected figures
instead of failing.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Mapping
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
