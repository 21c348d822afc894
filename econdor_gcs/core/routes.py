"""Lines flown in steps, for threshold mapping (:mod:`econdor_gcs.core.adaptive`,
``start_step_m`` and ``explore``).

The start survey is flown a step at a time, each step an iteration of its own, so that a
crossing of the level that a step samples is traced before the next step; once the start
survey is flown, the planner flies the straight line through the most uncovered ground
per metre, in steps too (:func:`best_lines`). A :class:`SteppedRoute` remembers how far
along its line the steps have gone: a trace that crosses the line further on flies a
stretch of it, which the next step skips, but a stretch the vehicle was thrown off before
is not flown again from the start of the line.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree
from scipy.special import ndtr

from .geometry import FloatArray, Region
from .uncertainty import resample_polyline

FLOWN_M = 1.5
"""A point of a route with a sample this close has been flown."""
MIN_RUN_M = 3.0
"""Unflown stretches of a route shorter than this are left out of its steps."""


def route_step(route: FloatArray, samples_xy: FloatArray, step_m: float, from_m: float = 0.0,
               flown_m: float = FLOWN_M) -> tuple[FloatArray, float] | None:
    """The next step of ``route`` from ``from_m`` along it: from the first point on that no
    sample came within ``flown_m`` of, ``step_m`` along the route, ending at its last such
    point in that stretch (the route's corners kept), and how far along the route that
    end is; ``None`` when the rest has been flown (open stretches shorter than
    :data:`MIN_RUN_M` left out).

    >>> line = np.array([[50.0, 0.0], [50.0, 100.0]])
    >>> step, at = route_step(line, np.zeros((0, 2)), 30.0)
    >>> step.tolist(), at
    ([[50.0, 0.0], [50.0, 30.0]], 30.0)
    >>> crossed = np.column_stack([np.full(11, 50.0), np.arange(40.0, 51.0)])  # a trace
    >>> route_step(line, crossed, 30.0, 30.0)[0].tolist()
    [[50.0, 30.0], [50.0, 60.0]]
    >>> route_step(line, np.column_stack([np.full(71, 50.0), np.arange(30.0, 101.0)]),
    ...            30.0, 30.0) is None
    True
    """
    pts = resample_polyline(route, 1.0)
    cum = np.r_[0.0, np.cumsum(np.hypot(*np.diff(pts, axis=0).T))]
    open_ = cum >= from_m - 1e-9
    if len(samples_xy):
        d, _ = cKDTree(samples_xy).query(pts)
        open_ &= d > flown_m
    # runs of open points, the short ones dropped
    edges = np.flatnonzero(np.diff(np.r_[0, open_.astype(np.int8), 0]))
    runs = [(a, b - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)
            if cum[b - 1] - cum[a] >= MIN_RUN_M]
    if not runs:
        return None
    i0 = runs[0][0]
    ends = [b for a, b in runs if cum[a] <= cum[i0] + step_m]
    i1 = min(ends[-1], int(np.searchsorted(cum, cum[i0] + step_m, side="right")) - 1)
    c0, c1 = cum[i0], cum[i1]
    vcum = np.r_[0.0, np.cumsum(np.hypot(*np.diff(route, axis=0).T))]
    inner = [route[k] for k in range(len(route)) if c0 < vcum[k] < c1]
    return np.vstack([pts[i0], *inner, pts[i1]]), float(c1)


class SteppedRoute:
    """A route flown a step at a time (module docstring).

    >>> r = SteppedRoute()
    >>> r.start(np.array([[50.0, 0.0], [50.0, 100.0]]))
    >>> r.next_step(np.zeros((0, 2)), 30.0).tolist()
    [[50.0, 0.0], [50.0, 30.0]]
    >>> r.next_step(np.zeros((0, 2)), math.inf).tolist()  # the rest at once
    [[50.0, 30.0], [50.0, 100.0]]
    >>> r.next_step(np.zeros((0, 2)), 30.0) is None, r.active
    (True, False)
    """

    def __init__(self) -> None:
        self.route: FloatArray | None = None
        self.at_m = 0.0
        """How far along the route the steps have been planned."""

    @property
    def active(self) -> bool:
        return self.route is not None

    def start(self, route: FloatArray) -> None:
        self.route, self.at_m = np.asarray(route, dtype=float), 0.0

    def stop(self) -> None:
        """Give the route up: nothing more of it is flown."""
        self.route = None

    def rest(self, samples_xy: FloatArray) -> FloatArray | None:
        """What is left of a straight route (two points) to be flown, as a segment from
        its first open point on to its end; ``None`` for a route with corners, or none.

        >>> r = SteppedRoute()
        >>> r.start(np.array([[50.0, 0.0], [50.0, 100.0]]))
        >>> _ = r.next_step(np.zeros((0, 2)), 30.0)
        >>> r.rest(np.zeros((0, 2))).tolist()
        [[50.0, 30.0], [50.0, 100.0]]
        """
        if self.route is None or len(self.route) != 2:
            return None
        a, b = self.route
        got = route_step(self.route, samples_xy, math.inf, self.at_m)
        if got is None:
            return None
        return np.array([got[0][0], b]) if np.hypot(*(b - a)) > 0 else None

    def next_step(self, samples_xy: FloatArray, step_m: float) -> FloatArray | None:
        """The next step (``step_m`` may be ``inf``: all the rest), or ``None`` once the
        route has been flown (it is then no longer :attr:`active`)."""
        if self.route is None:
            return None
        got = route_step(self.route, samples_xy, step_m, self.at_m)
        if got is None:
            self.route = None
            return None
        step, self.at_m = got
        return step


def start_line(region: Region, from_m: tuple[float, float], inset_m: float = 0.5
               ) -> FloatArray:
    """Threshold mode's start line: from ``from_m`` (the vehicle, brought ``inset_m``
    inside the area) straight through the area's centre on to its far edge, ``inset_m``
    inside it; from the centre itself, the north-south line through it from its south end.

    The line samples from its first metre (no flight to a line elsewhere) and passes the
    middle of the area, where a mid-range iso-line most often is: from the home corner it
    is the diagonal.

    >>> r = Region(0.0, 100.0, 0.0, 100.0)
    >>> start_line(r, (0.0, 0.0)).tolist()
    [[0.5, 0.5], [99.5, 99.5]]
    >>> start_line(r, (50.0, -20.0)).tolist()
    [[50.0, 0.5], [50.0, 99.5]]
    >>> start_line(r, (50.0, 50.0)).tolist()
    [[50.0, 0.5], [50.0, 99.5]]
    """
    lo, hi = _inner_box(region, inset_m)
    centre = 0.5 * (lo + hi)
    a = np.clip(np.asarray(from_m, dtype=float), lo, hi)
    d = centre - a
    if float(np.hypot(*d)) < 1.0:  # at the centre: no direction to go on in
        a, d = np.array([centre[0], lo[1]]), np.array([0.0, 1.0])
    return np.array([a, a + _reach(a, d, lo, hi) * d])


def _inner_box(region: Region, inset_m: float) -> tuple[FloatArray, FloatArray]:
    """The lower-left and upper-right corners of the area ``inset_m`` inside its edges."""
    return (np.array([region.xmin + inset_m, region.ymin + inset_m]),
            np.array([region.xmax - inset_m, region.ymax - inset_m]))


def _reach(a: FloatArray, d: FloatArray, lo: FloatArray, hi: FloatArray) -> float:
    """How many times ``d`` takes ``a`` (inside the box ``lo``-``hi``) to the box's edge."""
    return min(((hi[k] if d[k] > 0 else lo[k]) - a[k]) / d[k] for k in (0, 1)
               if abs(d[k]) > 1e-9)


def gap_lines(region: Region, spacing_m: float) -> list[FloatArray]:
    """North-south and east-west lines every ``spacing_m`` from the edges (the middle, and
    the middles of the halves, among them when the spacing divides a quarter), running
    0.5 m inside the area: the full width and each half.

    >>> lines = gap_lines(Region(0.0, 100.0, 0.0, 100.0), 5.0)
    >>> len(lines), sorted({float(s[0, 0]) for s in lines[:57:3]})[3:6]
    (114, [20.0, 25.0, 30.0])
    """
    lo_x, hi_x = region.xmin + 0.5, region.xmax - 0.5
    lo_y, hi_y = region.ymin + 0.5, region.ymax - 0.5
    mid_x, mid_y = 0.5 * (region.xmin + region.xmax), 0.5 * (region.ymin + region.ymax)
    out = []
    for x in np.arange(region.xmin + spacing_m, region.xmax - 0.5 * spacing_m, spacing_m):
        for a, b in ((lo_y, hi_y), (lo_y, mid_y), (mid_y, hi_y)):
            out.append(np.array([[x, a], [x, b]]))
    for y in np.arange(region.ymin + spacing_m, region.ymax - 0.5 * spacing_m, spacing_m):
        for a, b in ((lo_x, hi_x), (lo_x, mid_x), (mid_x, hi_x)):
            out.append(np.array([[a, y], [b, y]]))
    return out


def ray_lines(region: Region, from_m: FloatArray, directions: int, inset_m: float = 0.5,
              min_m: float = 10.0) -> list[FloatArray]:
    """Straight lines from ``from_m`` (brought ``inset_m`` inside the area) to the area's
    edge, ``inset_m`` inside it, in ``directions`` directions evenly round from east; those
    shorter than ``min_m`` are left out. A line from where the vehicle is samples from its
    first metre: no transit to it.

    >>> r = Region(0.0, 100.0, 0.0, 100.0)
    >>> [s.round(1).tolist() for s in ray_lines(r, np.array([20.0, 0.0]), 4)]
    [[[20.0, 0.5], [99.5, 0.5]], [[20.0, 0.5], [20.0, 99.5]], [[20.0, 0.5], [0.5, 0.5]]]
    """
    lo, hi = _inner_box(region, inset_m)
    a = np.clip(np.asarray(from_m, dtype=float), lo, hi)
    out = []
    for th in 2.0 * np.pi * np.arange(directions) / max(directions, 1):
        d = np.array([math.cos(th), math.sin(th)])
        reach = _reach(a, d, lo, hi)
        if reach >= min_m:
            out.append(np.array([a, a + reach * d]))
    return out


def segment_distances(points: FloatArray, seg: FloatArray) -> FloatArray:
    """Distance from each of ``points`` to the segment ``seg[0]``-``seg[1]``.

    >>> segment_distances(np.array([[0.0, 3.0], [12.0, 0.0]]), np.array([[0.0, 0.0],
    ...                                                                 [10.0, 0.0]])).tolist()
    [3.0, 2.0]
    """
    a, d = seg[0], seg[1] - seg[0]
    t = np.clip(((points - a) @ d) / max(float(d @ d), 1e-12), 0.0, 1.0)
    return np.hypot(*(points - (a + t[:, None] * d)).T)


def best_lines(cells_xy: FloatArray, near_m: FloatArray, weight: FloatArray, explore_m: float,
               lines: list[FloatArray], pos: FloatArray) -> list[FloatArray]:
    """``lines`` with a gain, best first, each oriented from its end nearer ``pos``.

    A cell farther than ``explore_m`` from every sample (``near_m``: its distance now) has
    a coverage deficit of how much farther it is; a line's gain is the deficit it removes,
    each cell's share times its ``weight``, and its score that gain per metre of the line
    and the transit to it.

    >>> xy = np.array([[10.0, 50.0], [90.0, 50.0]])
    >>> ln = [np.array([[10.0, 0.0], [10.0, 100.0]]), np.array([[90.0, 0.0], [90.0, 100.0]])]
    >>> [s[0].tolist() for s in best_lines(xy, np.array([40.0, 40.0]), np.ones(2), 10.0, ln,
    ...                                   np.array([95.0, 100.0]))]
    [[90.0, 100.0], [10.0, 100.0]]
    """
    deficit = np.maximum(near_m - explore_m, 0.0)
    scored: list[tuple[float, FloatArray]] = []
    for seg in lines:
        after = np.maximum(np.minimum(near_m, segment_distances(cells_xy, seg)) - explore_m, 0.0)
        gain = float(np.sum(weight * (deficit - after)))
        if gain <= 0.0:
            continue
        ta, tb = (float(np.hypot(*(q - pos))) for q in seg)
        if tb < ta:
            seg, ta = seg[::-1], tb
        scored.append((gain / (float(np.hypot(*(seg[1] - seg[0]))) + ta), seg))
    return [seg for _, seg in sorted(scored, key=lambda t: -t[0])]


def misclassification(mean: FloatArray, sd: FloatArray, levels: FloatArray
                      ) -> NDArray[np.float64]:
    """``Phi(-|mean - L| / sd)`` for the nearest level ``L``: the probability that a place
    lies on the other side of the level than the estimate says.

    >>> misclassification(np.array([50.0, 60.0]), np.array([5.0, 5.0]),
    ...                   np.array([50.0])).round(3).tolist()
    [0.5, 0.023]
    """
    off = np.min(np.abs(np.asarray(mean)[:, None] - np.asarray(levels)[None, :]), axis=1)
    return np.asarray(ndtr(-off / np.maximum(np.asarray(sd), 1e-12)), dtype=np.float64)
