"""Candidate paths of the adaptive planner: contour pieces of the estimate (traced
onboard), straight exploration legs and full-width lines, and in threshold mode the
pieces through sampled crossings of a level and the probes across the track at sampled
extrema (:mod:`econdor_gcs.core.adaptive` picks among them)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import RegularGridInterpolator
from scipy.signal import find_peaks
from scipy.spatial import cKDTree

from .contours import contour_pieces
from .geometry import FloatArray, Grid, Region, path_length
from .tasks import Phase, SampleLog
from .uncertainty import UncertaintyMap, resample_polyline

WHOLE_TRACE_INSET_M = 2.0
"""A whole component that meets the area's edge is entered this far inside from an end."""


class CandidateKind(StrEnum):
    """What a candidate path is flown as."""

    TRACE = "trace"
    """A contour piece, searched for at its start and traced onboard (``TraceTask``)."""
    LEG = "leg"
    """A straight leg between two waypoints."""


@dataclass(eq=False)
class Candidate:
    """A path the planner may ask for, in flying order (``points_m[0]`` first)."""

    kind: CandidateKind
    points_m: FloatArray
    level: float = math.nan
    reversible: bool = False
    """A leg may be flown either way."""
    closed: bool = False
    """A closed contour: entered at its point nearest the vehicle, traced round."""
    whole: bool = False
    """Trace until the contour closes or meets the area's edge (threshold mode)."""
    entry_m: FloatArray | None = None
    """Where the trace starts, if not at ``points_m[0]`` (a sampled crossing of the level)."""
    first: bool = False
    """Picked before any other candidate (``crossings_first``)."""
    detour_m: float = 0.0
    """Flight beyond ``length_m`` and the transit to the start: a component that meets the
    area's edge, entered at a crossing in its middle, is traced to one edge, flown back
    to the entry, and traced to the other."""

    @property
    def length_m(self) -> float:
        return path_length(self.points_m[:, 0], self.points_m[:, 1])




def _high_on_left(points: FloatArray, slope: Callable[[FloatArray], FloatArray]) -> bool:
    """Whether walking ``points`` keeps higher values on the left (the tracer's sense)."""
    mid = len(points) // 2
    a, b = points[max(mid - 1, 0)], points[min(mid + 1, len(points) - 1)]
    t = b - a
    g = slope(0.5 * (a + b))
    return bool(-t[1] * g[0] + t[0] * g[1] >= 0.0)


def _slope_at(estimate: FloatArray, grid: Grid) -> Callable[[FloatArray], FloatArray]:
    gy, gx = np.gradient(estimate, grid.dy, grid.dx)
    fx = RegularGridInterpolator((grid.y, grid.x), gx, bounds_error=False, fill_value=None)
    fy = RegularGridInterpolator((grid.y, grid.x), gy, bounds_error=False, fill_value=None)

    def slope(p: FloatArray) -> FloatArray:
        q = np.array([[p[1], p[0]]])
        return np.array([float(fx(q)[0]), float(fy(q)[0])])

    return slope


def contour_candidates(estimate: FloatArray, grid: Grid, levels: FloatArray, piece_m: float,
                       min_piece_m: float, whole: bool = False) -> list[Candidate]:
    """Contour pieces of the estimate at ``levels``, oriented so the tracer follows them.

    With ``whole=False`` each piece is cut into equal parts of at most ``piece_m``;
    with ``whole=True`` each connected piece is one candidate (threshold mode). A whole
    piece that meets the area's edge is entered at either end (``reversible``), a little
    inside: the tracer follows it to the far edge, or, entered at the end where its
    sense of tracing leaves the area, turns there and follows it back across. Entered in
    the middle, it would trace one half, fly back to the entry and trace the other.
    """
    slope = _slope_at(estimate, grid)
    out: list[Candidate] = []
    for piece in contour_pieces(estimate, grid, levels, min_piece_m):
        pts = piece.points_m
        if not _high_on_left(pts, slope):
            pts = pts[::-1]
        if whole:
            if not piece.closed:
                pts = trim_ends(pts, WHOLE_TRACE_INSET_M)
            out.append(Candidate(CandidateKind.TRACE, pts, piece.level, closed=piece.closed,
                                 whole=True, reversible=not piece.closed))
            continue
        seg = np.hypot(*np.diff(pts, axis=0).T)
        cum = np.r_[0.0, np.cumsum(seg)]
        n = max(1, int(math.ceil(cum[-1] / piece_m)))
        cuts = np.searchsorted(cum, np.linspace(0.0, cum[-1], n + 1)[1:-1])
        for part in np.split(np.arange(len(pts)), cuts):
            if len(part) < 2:
                continue
            sub = pts[part[0]:part[-1] + 2] if part[-1] + 1 < len(pts) else pts[part[0]:]
            if path_length(sub[:, 0], sub[:, 1]) >= min_piece_m:
                out.append(Candidate(CandidateKind.TRACE, sub, piece.level))
    return out


def trim_ends(points: FloatArray, inset_m: float) -> FloatArray:
    """``points`` without the first and last ``inset_m`` of their length (unchanged when
    shorter than three times that).

    >>> trim_ends(np.array([[0.0, 0.0], [10.0, 0.0]]), 2.0).tolist()
    [[2.0, 0.0], [8.0, 0.0]]
    """
    seg = np.hypot(*np.diff(points, axis=0).T)
    cum = np.r_[0.0, np.cumsum(seg)]
    if cum[-1] < 3.0 * inset_m:
        return points
    lo, hi = inset_m, cum[-1] - inset_m
    inner = (cum > lo) & (cum < hi)
    ends = [np.array([np.interp(t, cum, points[:, 0]), np.interp(t, cum, points[:, 1])])
            for t in (lo, hi)]
    return np.vstack([ends[0], points[inner], ends[1]])


def _flown_on(samples: SampleLog, max_step_m: float) -> NDArray[np.bool_]:
    """For each pair of consecutive samples: both survey or both transit samples of one
    vehicle, at most ``max_step_m`` apart (one straight flight, sampled without a gap)."""
    phase = samples.phase
    return ((phase[:-1] == phase[1:]) & np.isin(phase[:-1], (Phase.SURVEY, Phase.TRANSIT))
            & (samples.vehicle[:-1] == samples.vehicle[1:])
            & (np.hypot(np.diff(samples.x_m), np.diff(samples.y_m)) <= max_step_m))


def level_crossings(samples: SampleLog, levels: FloatArray, max_step_m: float = 2.0
                    ) -> tuple[FloatArray, FloatArray]:
    """Where consecutive survey or transit samples of one vehicle straddle a level:
    the crossing points (interpolated) and their levels.

    Examples
    --------
    >>> import numpy as np
    >>> from econdor_gcs.core.tasks import Phase, SampleLog
    >>> x = np.arange(5.0)
    >>> s = SampleLog(x, x, np.zeros(5), np.array([0.0, 1.0, 3.0, 1.0, 0.0]),
    ...               np.full(5, Phase.SURVEY, dtype=np.int8), np.zeros(5, np.int16))
    >>> pts, lv = level_crossings(s, np.array([2.0]))
    >>> pts[:, 0].tolist(), lv.tolist()
    ([1.5, 2.5], [2.0, 2.0])
    """
    x, y, v = samples.x_m, samples.y_m, samples.value
    if len(x) < 2:
        return np.zeros((0, 2)), np.zeros(0)
    ok = _flown_on(samples, max_step_m)
    pts, lvs = [], []
    for lv in np.asarray(levels, dtype=float):
        a, b = v[:-1] - lv, v[1:] - lv
        # a sample exactly at the level counts once, with the pair that arrives at it
        i = np.nonzero(ok & (((a < 0) & (b >= 0)) | ((a > 0) & (b <= 0))))[0]
        t = a[i] / (a[i] - b[i])
        pts.append(np.column_stack([x[i] + t * (x[i + 1] - x[i]), y[i] + t * (y[i + 1] - y[i])]))
        lvs.append(np.full(i.size, lv))
    return np.vstack(pts), np.concatenate(lvs)


def mark_crossings(cands: list[Candidate], samples: SampleLog, levels: FloatArray,
                   band_m: float, near_m: float = 8.0, open_at_end: bool = False,
                   end_m: float = 0.0) -> list[Candidate]:
    """Whole contour candidates through a sampled, not yet traced crossing of their level
    become ``first`` (``crossings_first``). A closed one is entered at that crossing (the
    iso-line is known to be there). One that meets the area's edge is entered:

    - with ``open_at_end``, at its nearer end (see :func:`contour_candidates`: no flight
      back from the edge, but the estimate's ends are extrapolated and the onboard search
      can miss there);
    - with ``end_m > 0``, at an end with a sampled crossing within ``end_m`` (the
      iso-line is known to reach that end) and no trace or search flown within
      ``end_m`` (not tried there before); where neither end has one, at the crossing
      nearest the end the tracer heads for first (``points_m[-1]``), which is the
      shortest flight back to the entry (``detour_m``), and the piece is listed so that
      it ends where the vehicle then finishes (the other end);
    - otherwise at the crossing nearest the piece.
    """
    pts, lvs = level_crossings(samples, levels)
    if not len(pts):
        return cands
    traced = np.isin(samples.phase, (Phase.TRACE, Phase.SEARCH))
    tried = None
    if traced.any():
        tried = cKDTree(np.column_stack([samples.x_m[traced], samples.y_m[traced]]))
        d, _ = tried.query(pts)
        keep = d > band_m
        pts, lvs = pts[keep], lvs[keep]
    for c in cands:
        if not c.whole or not len(pts):
            continue
        on = np.isclose(lvs, c.level)
        if not on.any():
            continue
        d, _ = cKDTree(resample_polyline(c.points_m, 1.0)).query(pts[on])
        if d.min() > near_m:
            continue
        c.first = True
        if c.closed or (not open_at_end and end_m <= 0.0):
            c.entry_m = pts[on][int(np.argmin(d))].copy()
        elif end_m > 0.0:
            _choose_open_entry(c, pts[on][d <= near_m], end_m, tried)
    return cands


def _choose_open_entry(c: Candidate, crossings: FloatArray, end_m: float,
                       tried: cKDTree | None) -> None:
    """Enter a whole piece that meets the edge (``points_m`` in the tracer's sense) at an
    end known to be on the iso-line and not tried before, else at the crossing nearest
    the end the tracer heads for (:func:`mark_crossings`)."""
    def on_line(p: FloatArray) -> bool:
        near = float(np.min(np.hypot(crossings[:, 0] - p[0], crossings[:, 1] - p[1])))
        return near <= end_m and (tried is None or float(tried.query(p)[0]) > end_m)

    known = on_line(c.points_m[0]), on_line(c.points_m[-1])
    if all(known):
        return  # either end, the nearer one (reversible)
    c.reversible = False
    if known[1]:
        c.points_m = c.points_m[::-1].copy()  # from the known end
    if any(known):
        return
    head = c.points_m[-1]
    k = int(np.argmin(np.hypot(crossings[:, 0] - head[0], crossings[:, 1] - head[1])))
    c.entry_m = crossings[k].copy()
    c.detour_m = float(np.hypot(*(head - c.entry_m)))
    # traced to the head's edge, back to the entry, on to the other edge: it ends there
    c.points_m = c.points_m[::-1].copy()


def _track_runs(samples: SampleLog, max_step_m: float = 2.0) -> list[NDArray[np.intp]]:
    """Index runs of consecutive survey or transit samples of one vehicle (straight flight
    between waypoints or along survey lines; no gap wider than ``max_step_m``)."""
    if len(samples) < 2:
        return []
    cuts = np.nonzero(~_flown_on(samples, max_step_m))[0] + 1
    flying = np.isin(samples.phase, (Phase.SURVEY, Phase.TRANSIT))
    return [r for r in np.split(np.arange(len(samples)), cuts)
            if flying[r[0]] and len(r) >= 5]


def extremum_probes(samples: SampleLog, levels: FloatArray, region: Region, probe_m: float,
                    prominence: float, covered_m: float,
                    not_on: Sequence[FloatArray] = (), reach: float = 0.0) -> list[Candidate]:
    """Legs across the track through the local extrema of the samples along flown lines
    that fall short of a target level: a maximum below some level, a minimum above some.

    Along a line that passes beside a peak, the samples peak where the line is closest
    to it: the field's maximum, and a closed iso-line around it if the peak reaches the
    level, lie on the perpendicular there (exactly so for a round peak). A probe across
    the track finds it or, falling short again, has its own extremum, whose probe runs
    parallel to the first line: a hill-climb that ends on the peak. An extremum within
    ``covered_m`` of a sample of another line (the field was sampled across it already:
    the climb has arrived) is not probed, nor is a probe most of which (80 %) lies
    within ``covered_m`` of a sample. Extrema within 1 m of a segment in ``not_on`` (earlier
    probes, when the climb is off) are not probed.

    With ``reach > 0``, an extremum is probed only if a level it falls short of is within
    ``reach`` times :func:`probe_reach` of it: a round bump as curved along the track as
    the samples are there, its centre anywhere on the probe.

    Examples
    --------
    >>> import numpy as np
    >>> from econdor_gcs.core.tasks import Phase, SampleLog
    >>> x = np.linspace(0.0, 40.0, 51)
    >>> v = 10.0 + np.exp(-((x - 20.0) ** 2) / 50.0)  # a bump beside the line y = 5
    >>> s = SampleLog(x, x, np.full(51, 5.0), v, np.full(51, Phase.SURVEY, dtype=np.int8),
    ...               np.zeros(51, np.int16))
    >>> [c.points_m.round(1).tolist() for c in extremum_probes(
    ...     s, np.array([50.0]), Region(0.0, 40.0, 0.0, 40.0), 20.0, 1e-4, 1.5)]
    [[[20.0, 0.5], [20.0, 15.0]]]
    """
    levels = np.asarray(levels, dtype=float)
    v_all = samples.value
    if len(v_all) < 5 or not len(levels):
        return []
    span = float(np.ptp(v_all)) or 1.0
    inner = Region(region.xmin + 0.5, region.xmax - 0.5, region.ymin + 0.5, region.ymax - 0.5)
    tree = cKDTree(np.column_stack([samples.x_m, samples.y_m]))
    out: list[Candidate] = []
    for run in _track_runs(samples):
        v = v_all[run]
        for sign in (1.0, -1.0):
            peaks, props = find_peaks(sign * v, prominence=prominence * span)
            for j, height in zip(peaks.tolist(), props["prominences"].tolist(), strict=True):
                # a maximum below some level (sign +1), a minimum above some (sign -1)
                short = sign * (levels - v[j]) > 0
                if not np.any(short):
                    continue
                if reach > 0:
                    top = reach * probe_reach(samples, run, j, sign, height, 0.5 * probe_m)
                    if not np.any(sign * (levels[short] - v[j]) <= top):
                        continue
                a, b = run[max(j - 2, 0)], run[min(j + 2, len(run) - 1)]
                t = np.array([samples.x_m[b] - samples.x_m[a], samples.y_m[b] - samples.y_m[a]])
                norm = float(np.hypot(*t))
                if norm < 1e-6:
                    continue
                n = np.array([-t[1], t[0]]) / norm
                c = np.array([samples.x_m[run[j]], samples.y_m[run[j]]])
                if any(_segment_distance(c, seg) <= 1.0 for seg in not_on):
                    continue
                near = np.asarray(tree.query_ball_point(c, covered_m), dtype=np.intp)
                if np.any((near < run[0]) | (near > run[-1])):
                    continue  # sampled across already: a 2-D extremum, nothing off-track
                seg = _clip_segment(inner, c - 0.5 * probe_m * n, c + 0.5 * probe_m * n)
                if seg is None:
                    continue
                pts = resample_polyline(seg, 1.0)
                d, _ = tree.query(pts)
                if np.mean(d <= covered_m) >= 0.8:
                    continue
                out.append(Candidate(CandidateKind.LEG, seg, reversible=True, first=True))
    return out


def probe_reach(samples: SampleLog, run: NDArray[np.intp], j: int, sign: float,
                height: float, half_m: float, window_m: float = 2.0) -> float:
    """How far beyond the extremum ``run[j]`` the field can go within ``half_m`` across
    the track (``inf`` when the samples cannot say).

    Along a line passing at distance ``d`` beside a round Gaussian bump of width ``s``,
    the samples peak at ``h = A exp(-d²/2s²)`` over the bump's base, with curvature
    ``-h/s²``. With ``h = height``, the extremum's prominence along the track (its height
    over the higher of the lowest points either side of it, as ``find_peaks`` gives it)
    and the curvature of a parabola fitted ``window_m`` either side, ``s`` follows, and
    the bump's top is at most ``h exp(half_m²/2s²)`` over the base.

    >>> import numpy as np
    >>> from econdor_gcs.core.tasks import Phase, SampleLog
    >>> x = np.linspace(0.0, 40.0, 81)
    >>> v = 10.0 * np.exp(-((x - 20.0) ** 2 + 36.0) / 50.0)  # 6 m beside a 10-high bump
    >>> s = SampleLog(x, x, np.full(81, 6.0), v, np.full(81, Phase.SURVEY, dtype=np.int8),
    ...               np.zeros(81, np.int16))
    >>> h = float(v[40] - v[0])  # the prominence: over the lower end of the run
    >>> round(float(v[40]) + probe_reach(s, np.arange(81), 40, 1.0, h, 6.0), 1)  # top: 10
    9.7
    """
    x, y = samples.x_m[run], samples.y_m[run]
    h = sign * samples.value[run]
    along = np.r_[0.0, np.cumsum(np.hypot(np.diff(x), np.diff(y)))]
    near = np.abs(along - along[j]) <= window_m
    if np.count_nonzero(near) < 5:
        return math.inf
    curv = 2.0 * float(np.polyfit(along[near] - along[j], h[near], 2)[0])
    if curv >= 0.0 or height <= 0.0:
        return math.inf
    s2 = height / -curv
    return height * math.expm1(min(half_m ** 2 / (2.0 * s2), 50.0))


def _segment_distance(p: FloatArray, seg: FloatArray) -> float:
    """Distance from point ``p`` to the segment ``seg[0]``-``seg[1]``."""
    a, b = seg[0], seg[-1]
    d = b - a
    t = float(np.clip(np.dot(p - a, d) / max(float(np.dot(d, d)), 1e-12), 0.0, 1.0))
    return float(np.hypot(*(p - (a + t * d))))


def _clip_segment(region: Region, a: FloatArray, b: FloatArray) -> FloatArray | None:
    """The part of segment ``a``-``b`` inside ``region`` (Liang-Barsky), or None."""
    d = b - a
    t0, t1 = 0.0, 1.0
    for p, q in ((-d[0], a[0] - region.xmin), (d[0], region.xmax - a[0]),
                 (-d[1], a[1] - region.ymin), (d[1], region.ymax - a[1])):
        if p == 0:
            if q < 0:
                return None
            continue
        r = q / p
        if p < 0:
            t0 = max(t0, r)
        else:
            t1 = min(t1, r)
    if t1 <= t0:
        return None
    return np.array([a + t0 * d, a + t1 * d])


def leg_candidates(umap: UncertaintyMap, cell_value: FloatArray, region: Region, legs: int,
                   leg_m: float) -> list[Candidate]:
    """Straight legs of ``leg_m`` in four directions through the ``legs`` highest-value
    cells, no two centres closer than a third of a leg (non-maximum suppression)."""
    inner = Region(region.xmin + 0.5, region.xmax - 0.5, region.ymin + 0.5, region.ymax - 0.5)
    order = np.argsort(-cell_value, kind="stable")
    centres: list[FloatArray] = []
    min_gap = leg_m / 3.0
    for i in order:
        if cell_value[i] <= 0 or len(centres) >= legs:
            break
        c = np.array([umap.x_m[i], umap.y_m[i]])
        if all(np.hypot(*(c - q)) >= min_gap for q in centres):
            centres.append(c)
    out: list[Candidate] = []
    for c in centres:
        for ang in (0.0, 0.25 * math.pi, 0.5 * math.pi, 0.75 * math.pi):
            u = 0.5 * leg_m * np.array([math.cos(ang), math.sin(ang)])
            seg = _clip_segment(inner, c - u, c + u)
            if seg is not None and np.hypot(*(seg[1] - seg[0])) >= 0.5 * leg_m:
                out.append(Candidate(CandidateKind.LEG, seg, reversible=True))
    return out


def sweep_candidates(umap: UncertaintyMap, uncovered: NDArray[np.bool_], region: Region,
                     spacing_m: float, min_m: float = 5.0) -> list[Candidate]:
    """North-south legs that sweep the uncovered cells: on the centre line of each strip
    ``spacing_m`` wide, one leg over every run of rows in which the strip holds an
    uncovered cell (a boustrophedon over what is left, not over the whole area).

    >>> import numpy as np
    >>> from econdor_gcs.core.geometry import Grid, Region
    >>> from econdor_gcs.core.uncertainty import UncertaintyMap
    >>> g = Grid.with_spacing(Region(0.0, 40.0, 0.0, 40.0), 2.0)
    >>> xx, yy = g.mesh
    >>> n = xx.size
    >>> u = UncertaintyMap(xx.ravel(), yy.ravel(), np.ones(n), np.ones(n), np.zeros(n),
    ...                    "proxy", 5.0, None, g)
    >>> hole = ((xx > 22) & (yy > 10) & (yy < 20)).ravel()  # uncovered: x 24-40, y 12-18
    >>> [c.points_m.tolist() for c in sweep_candidates(u, hole, g.region, 20.0)]
    [[[30.0, 12.0], [30.0, 18.0]]]
    """
    g = umap.grid
    if g is None or not np.any(uncovered):
        return []
    xs = umap.x_m.reshape(g.ny, g.nx)[0]
    ys = umap.y_m.reshape(g.ny, g.nx)[:, 0]
    mask = np.asarray(uncovered, dtype=bool).reshape(g.ny, g.nx)
    lo_y, hi_y = region.ymin + 0.5, region.ymax - 0.5
    out: list[Candidate] = []
    for x in np.arange(region.xmin + 0.5 * spacing_m, region.xmax, spacing_m):
        cols = np.abs(xs - x) <= 0.5 * spacing_m
        need = mask[:, cols].any(axis=1)
        edges = np.flatnonzero(np.diff(np.r_[0, need.astype(np.int8), 0]))
        for a, b in zip(edges[::2], edges[1::2] - 1, strict=True):
            y0, y1 = float(ys[a]), float(ys[b])
            if y1 - y0 < min_m:
                mid = 0.5 * (y0 + y1)
                y0, y1 = mid - 0.5 * min_m, mid + 0.5 * min_m
            y0, y1 = max(y0, lo_y), min(y1, hi_y)
            out.append(Candidate(CandidateKind.LEG, np.array([[x, y0], [x, y1]]),
                                 reversible=True))
    return out


def line_candidates(region: Region, spacing_m: float, orientation: str = "ns") -> list[Candidate]:
    """Full-width lines every ``spacing_m``, 0.5 m inside the area: north-south (``"ns"``),
    east-west (``"ew"``) or both.

    One family is the default: greedy picks from both make a grid, and a grid leaves
    gaps twice as wide as parallel lines of the same total length.
    """
    if spacing_m <= 0:
        return []
    out: list[Candidate] = []
    lo_y, hi_y = region.ymin + 0.5, region.ymax - 0.5
    lo_x, hi_x = region.xmin + 0.5, region.xmax - 0.5
    if orientation in ("ns", "both"):
        for x in np.arange(region.xmin + 0.5 * spacing_m, region.xmax, spacing_m):
            out.append(Candidate(CandidateKind.LEG, np.array([[x, lo_y], [x, hi_y]]),
                                 reversible=True))
    if orientation in ("ew", "both"):
        for y in np.arange(region.ymin + 0.5 * spacing_m, region.ymax, spacing_m):
            out.append(Candidate(CandidateKind.LEG, np.array([[lo_x, y], [hi_x, y]]),
                                 reversible=True))
    return out
