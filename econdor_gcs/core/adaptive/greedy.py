"""Greedy selection: candidates picked vehicle by vehicle by value removed per metre.

A vehicle (the least loaded first) takes the candidate with the most value removed per
metre of its length, the transit to it and its overhead; after each pick the variance and
the distance to the nearest sample are updated with the pick *and* the transit to it (the
vehicle samples all the way), so redundancy is judged in space, not in value. Candidates
marked ``first`` go before anything the greedy would pick, the nearest first. When nothing
more fits a vehicle's share, its picks are reordered for less transit and what that frees
is used.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..candidates import Candidate, CandidateKind
from ..geometry import FloatArray
from ..uncertainty import Footprints


@dataclass
class Pick:
    """A chosen candidate, how it is entered and which vehicle flies it."""

    candidate: Candidate
    vehicle: int
    path_m: FloatArray
    transit_m: float


@dataclass
class _Fleet:
    positions: list[FloatArray]
    loads: list[float]
    budgets: list[float]
    picks: list[list[Pick]] = field(default_factory=list)


def _entry(c: Candidate, pos: FloatArray) -> tuple[FloatArray, float]:
    """The path as flown from ``pos`` (a leg from its nearer end, a loop from its nearest
    point) and the transit to its start."""
    pts = c.points_m
    if c.entry_m is not None:
        return pts, float(np.hypot(*(c.entry_m - pos)))
    if c.reversible:
        d0, d1 = np.hypot(*(pts[0] - pos)), np.hypot(*(pts[-1] - pos))
        return (pts, float(d0)) if d0 <= d1 else (pts[::-1], float(d1))
    if c.closed:
        i = int(np.argmin(np.hypot(pts[:, 0] - pos[0], pts[:, 1] - pos[1])))
        loop = np.vstack([pts[i:-1], pts[:i + 1]]) if i > 0 else pts
        return loop, float(np.hypot(*(pts[i] - pos)))
    return pts, float(np.hypot(*(pts[0] - pos)))


def _walk(order: Sequence[Candidate], start: FloatArray) -> tuple[list[Pick], float]:
    """Fly ``order`` from ``start``: the picks (entries chosen on the way) and the transit."""
    pos, total, out = start, 0.0, []
    for c in order:
        path, t_m = _entry(c, pos)
        out.append(Pick(c, 0, path, t_m))
        total += t_m
        pos = path[0] if c.closed else path[-1]
    return out, total


def shorten_route(picks: list[Pick], start: FloatArray, rounds: int = 3) -> list[Pick]:
    """The same picks in an order with less transit (2-opt and single moves, from the
    greedy's order; legs may be flown either way, loops entered anywhere)."""
    if len(picks) < 2:
        return picks
    vehicle = picks[0].vehicle
    best = [p.candidate for p in picks]
    _, best_cost = _walk(best, start)
    for _ in range(rounds):
        improved = False
        n = len(best)
        for i in range(n - 1):
            for j in range(i + 1, n):
                for trial in (best[:i] + best[i:j + 1][::-1] + best[j + 1:],
                              best[:i] + best[i + 1:j + 1] + [best[i]] + best[j + 1:]):
                    _, cost = _walk(trial, start)
                    if cost < best_cost - 1e-6:
                        best, best_cost, improved = trial, cost, True
        if not improved:
            break
    route, _ = _walk(best, start)
    for p in route:
        p.vehicle = vehicle
    return route


def greedy_plan(
    candidates: Sequence[Candidate],
    footprints: Footprints,
    variance: FloatArray,
    cell_value: Callable[[FloatArray, FloatArray, NDArray[np.intp]], FloatArray],
    positions_m: Sequence[tuple[float, float]],
    budgets_m: Sequence[float],
    trace_overhead_m: float = 5.0,
    traces_before_legs: bool = False,
    distance_m: FloatArray | None = None,
) -> tuple[list[list[Pick]], FloatArray]:
    """Pick candidates for each vehicle by uncertainty removed per metre (module docstring).

    Parameters
    ----------
    candidates : sequence of Candidate
    footprints : Footprints
        Cells near each candidate and their distances (same order as ``candidates``).
    variance : ndarray
        Unit variance of the planning cells now; updated in a copy as picks are made.
    cell_value : callable
        ``cell_value(v, d, cells)`` -> the value of cells ``cells`` at variances ``v`` and
        distances ``d`` (m) from the nearest sample.
    positions_m : sequence of (x, y)
        Where each vehicle is.
    budgets_m : sequence of float
        Flight each vehicle may plan (transit included).
    trace_overhead_m : float
        Charged on top of a trace candidate's length (the onboard search).
    traces_before_legs : bool
        Of the candidates that go ``first``, every trace before any leg (else the
        nearest of either kind next).
    distance_m : ndarray, optional
        Distance (m) from each planning cell to the nearest sample now (``inf``: none);
        updated, like the variance, with each pick and its transit (within the
        footprint radius).

    Returns
    -------
    picks : list of list of Pick
        Per vehicle, in flying order.
    variance : ndarray
        The variance expected after the plan is flown.
    """
    v = variance.copy()
    d = np.full(v.shape, np.inf) if distance_m is None else np.asarray(distance_m, float).copy()
    fleet = _Fleet([np.asarray(p, dtype=float) for p in positions_m], [0.0] * len(positions_m),
                   list(budgets_m), [[] for _ in positions_m])
    n = len(candidates)
    lengths = np.array([c.length_m for c in candidates])
    overhead = np.array([(trace_overhead_m if c.kind == CandidateKind.TRACE else 0.0)
                         + c.detour_m for c in candidates])
    ends = np.array([[*c.points_m[0], *c.points_m[-1]] for c in candidates]).reshape(n, 4)
    reversible = np.array([c.reversible for c in candidates], dtype=bool)
    closed = np.array([c.closed for c in candidates], dtype=bool)
    first = np.array([c.first for c in candidates], dtype=bool)
    rank = np.where(first & np.array([traces_before_legs and c.kind == CandidateKind.TRACE
                                      for c in candidates], dtype=bool), 2e12, 1e12)
    has_entry = np.array([c.entry_m is not None for c in candidates], dtype=bool)
    entry = np.array([c.entry_m if c.entry_m is not None else c.points_m[0]
                      for c in candidates]).reshape(n, 2)
    used = np.zeros(n, dtype=bool)
    active = [b > 0 for b in fleet.budgets]
    starts = [p.copy() for p in fleet.positions]
    fp = footprints

    def gains() -> FloatArray:
        cells = fp.cells
        before = v[cells]
        after = fp.umap.combine(before, fp.line_var)
        near = d[cells]
        diff = (cell_value(before, near, cells)
                - cell_value(after, np.minimum(near, fp.dist_m), cells))
        return np.bincount(fp.owner, weights=diff, minlength=n).astype(float)

    g = gains()
    while any(active):
        k = min((i for i in range(len(active)) if active[i]), key=lambda i: fleet.loads[i])
        pos = fleet.positions[k]
        transit = np.hypot(ends[:, 0] - pos[0], ends[:, 1] - pos[1])
        back = np.hypot(ends[:, 2] - pos[0], ends[:, 3] - pos[1])
        transit = np.where(reversible, np.minimum(transit, back), transit)
        if closed.any():
            for i in np.nonzero(closed & ~used)[0].tolist():
                pts = candidates[i].points_m
                transit[i] = float(np.min(np.hypot(pts[:, 0] - pos[0], pts[:, 1] - pos[1])))
        if has_entry.any():
            transit = np.where(has_entry, np.hypot(entry[:, 0] - pos[0], entry[:, 1] - pos[1]),
                               transit)
        cost = lengths + transit + overhead
        left = fleet.budgets[k] - fleet.loads[k]
        fits = (cost <= left) | (not fleet.picks[k])  # a vehicle's first pick may overrun
        score = np.where(~used & fits & (g > 0), g / np.maximum(cost, 1e-6), -np.inf)
        # crossings (and probes) first: the nearest one, before anything the greedy would pick
        score = np.where(first & ~used & fits, rank - transit, score)
        best = int(np.argmax(score))
        if not np.isfinite(score[best]):
            # nothing fits: fly the picks in a shorter order, and use what that frees
            route = shorten_route(fleet.picks[k], starts[k])
            before = sum(p.transit_m for p in fleet.picks[k])
            saved = before - sum(p.transit_m for p in route)
            fleet.picks[k] = route
            if saved > 1.0:
                fleet.loads[k] -= saved
                last = route[-1]
                fleet.positions[k] = last.path_m[0] if last.candidate.closed else last.path_m[-1]
            else:
                active[k] = False
            continue
        c = candidates[int(best)]
        path, t_m = _entry(c, pos)
        used[best] = True
        fleet.picks[k].append(Pick(c, k, path, t_m))
        fleet.loads[k] += float(cost[best])
        begin = c.entry_m if c.entry_m is not None else path[0]
        fleet.positions[k] = begin if c.closed else path[-1]
        # what this pick (and the transit to it) will observe
        sl = slice(fp.start[best], fp.start[best + 1])
        v[fp.cells[sl]] = fp.umap.combine(v[fp.cells[sl]], fp.line_var[sl])
        d[fp.cells[sl]] = np.minimum(d[fp.cells[sl]], fp.dist_m[sl])
        if t_m > 1.0:
            cells, dist = fp.cells_near(np.array([pos, begin]))
            v[cells] = fp.umap.combine(v[cells], fp.umap.line_variance(dist))
            d[cells] = np.minimum(d[cells], dist)
        g = gains()
    return fleet.picks, v
