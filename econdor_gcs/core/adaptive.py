"""The adaptive planner: fly where the estimate is most uncertain, per metre.

It starts (``start: auto``) with an even survey of ``start_lines`` north-south lines: 16
when mapping the whole field, one in threshold mode. Each iteration after that the planner

1. models how uncertain the estimate still is (:mod:`econdor_gcs.core.uncertainty`): a
   unit posterior variance ``v(x)`` from where the samples are, times an amplitude that
   grows with the local steepness of the estimate and never falls below a floor;
2. lists candidate paths: contour pieces of the estimate at many levels (traced onboard,
   like E-CONDOR's pieces), straight legs through the most uncertain places, and
   full-width lines (see :func:`contour_candidates`, :func:`leg_candidates`,
   :func:`line_candidates`);
3. picks greedily, vehicle by vehicle (the least loaded first), the candidate with the
   most uncertainty removed per metre,

   .. math:: \\frac{\\sum_x w(x) \\left[f(v(x)) - f(\\min(v(x), v_{line}(d_c(x))))\\right]}
                  {\\text{length}_c + \\text{transit}_c + \\text{overhead}_c},

   where ``d_c(x)`` is the distance from cell ``x`` to the candidate and
   ``f(v) = a^2 v`` (expected squared error: integrated variance) by default. After each
   pick the variance map is updated with the pick *and* the transit to it (the vehicle
   samples all the way), so redundancy is judged in space, not in value;
4. stops an iteration when every vehicle has its share of the per-iteration flight
   (``batch_m``), never planning beyond the flight budget left.

**Threshold mode** (``target_levels``): only the iso-lines at those levels matter. The
per-cell value is the straddle score ``max(1.96 sigma - min_L |mu - L|, 0)`` (Bryan et al.
2005) and, farther than ``explore_m`` from every sample (``d``: the distance to the nearest
sample, and to the paths planned so far), ``a (d / explore_m - 1)``: a coverage floor,
since an iso-line around a feature narrower than the data can show may hide there whatever
the model says (with the length fitted to a smooth field the GP's variance is small tens
of metres from the nearest sample, so the floor is measured in metres, not through the
model). Cells within ``resolve_m`` of a sample (observed) or within ``band_m`` of a sample
that reads a target level (an iso-line already flown on) count for nothing. Candidates are
the estimate's whole contour components at the target levels (each traced until it closes
or meets the area's edge on both sides) plus the exploration legs and lines, and sweeps
over what the floor still scores (``sweeps``). Two kinds go
before anything the greedy would pick (nearest first): a component through a crossing of
its level that a survey or transit leg sampled and no trace has flown yet
(``crossings_first``: the iso-line is known to be there), and a probe across the track
through every local extremum of the samples along a flown line that falls short of a
level (``probes``: a peak beside the line, and a closed iso-line round it, lies on that
perpendicular; see :func:`~econdor_gcs.core.candidates.extremum_probes`); crossings go
before probes (``first_order``). The planner reports ``done`` when no open cell scores any
more — nowhere is left where an iso-line could still be, under the model (by default the
GP posterior with its length scale fitted to the samples: its variance shrinks where
samples surround a place, which the distance proxy cannot see, and over a smooth field's
longer length more than over a plume's) — and no such crossing or probe is left: the
samples themselves still say an iso-line is, or may be, there. It is done, too, when open
cells are left that no candidate would improve (at the area's edge the model can know more
than a pass 0.5 m inside would add): planning nothing would only stall the run.

Every job is an ordinary trace task (``TraceTask``) or a pair of waypoints, so the plan
flies over MAVLink exactly like E-CONDOR's; contour pieces are traced by the vehicle's
own tracer, not flown as planned polylines.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from .candidates import (
    Candidate,
    CandidateKind,
    contour_candidates,
    extremum_probes,
    leg_candidates,
    line_candidates,
    mark_crossings,
    sweep_candidates,
)
from .geometry import FloatArray, Grid, Region, path_length
from .gp import MaternHyper, fit_matern
from .planners import Batch, Job, PlanContext, lawnmower_lines_for_budget, survey_jobs
from .routes import SteppedRoute, best_lines, gap_lines, misclassification, ray_lines, start_line
from .tasks import FlightReport, OutcomeStatus, Task, TraceTask, Waypoint
from .uncertainty import (
    Footprints,
    UncertaintyMap,
    expected_error,
    resample_polyline,
    straddle,
    uncertainty_map,
)

ROUTE_LEFT_M = 15.0
"""``explore: lines``: a vehicle this far from where its line was left (a probe took it
away) weighs what is left of the line against the other lines before going on; after a
trace it always does (what the trace found changes what the rest of the line is worth: a
line through the inside of the loop a trace has just closed is worth little)."""
LINE_WEIGHT_FLOOR = 0.02
LINE_WEIGHT_GAIN = 10.0
"""``line_weight: p``: a cell's coverage deficit counts ``min(1, floor + gain p)`` times."""
WHOLE_TRACE_FACTOR = 2.0
"""A whole-component trace stops after this multiple of the estimated component's length."""
WHOLE_TRACE_MIN_M = 60.0
"""... and never before this length (the estimate's component can be far too short)."""
SPENT_TRACE_M = 10.0
"""A trace task that found the level but ended closed or at the edge within this was
spent where it began: the iso-line there was traced before (the tracer ends where it
comes onto a track it traced) or runs straight out of the area. No trace is planned to
begin near there again. (One that found nothing may find it later, when the estimate
has moved: that is not counted.)"""
SPENT_NEAR_M = 5.0
"""... within this of such a start."""
OPEN_END_M = 6.0
"""``open_entry: auto``: an end of a component at the edge is entered when a sampled
crossing lies this close to it (and nothing was traced or searched this close)."""


@dataclass(frozen=True)
class AdaptiveParams:
    """Settings of the adaptive planner (the mission's ``adaptive`` section).

    Parameters
    ----------
    batch_m : float
        Flight planned per vehicle and iteration (m), transit included.
    batch_growth : float
        The batch grows to this fraction of the distance flown so far, if larger.
    levels : int
        Levels of the estimate whose contour pieces are candidates (MAE mode).
    piece_m : float
        Contour pieces are cut to at most this length (m).
    min_piece_m : float
        Shorter pieces are no candidates.
    leg_m : float
        Length of the exploration legs (m).
    legs : int
        Number of most uncertain places the legs pass through (four directions each).
    line_spacing_m : float
        Spacing of the full-width line candidates (0: none).
    line_orientation : {"ns", "ew", "both"}
        Their direction(s).
    start : {"auto", "diagonals", "perimeter", "plan", "survey"}
        The first flight: the mission's initiation pattern, the area's boundary, the
        planner's own plan from its prior (uniform uncertainty: spread-out lines), or an
        even survey of ``start_lines`` north-south lines. ``auto``: the survey (it
        measured best in both modes).
    start_lines : int
        Lines of the ``survey`` start, at the centres of equal strips (the first and last
        half a spacing inside the edges, as the best survey flies them). 0 (``auto``): 16
        when mapping the whole field; one in threshold mode (a line through the middle
        costs 0.15 km against the diagonals' 0.38, and the iso-line is then found from its
        crossings and extrema). Flown in steps (one vehicle, ``start_step_m``), that one
        line runs from the vehicle straight through the area's centre
        (:func:`~econdor_gcs.core.routes.start_line`: from the home corner, the
        diagonal), so it samples from its first metre.
    start_step_m : float
        Threshold mode: the start survey is flown in steps of this length (m; 0: in one
        piece), each an iteration of its own, and a component through a crossing that a
        step sampled is traced before the next step: a start that meets the iso-line
        early traces it at once, and when that was all there was, the rest of the
        survey is never flown. Until the survey is whole a trace may run the area's
        perimeter (the estimate's component, from a part of the line, can be far too
        short for the twice-its-length cap). The lines through uncovered ground
        (``explore: lines``) are flown in these steps too. A vehicle cannot stop at a
        crossing a step samples: what the step flies beyond it is flown again on the way
        back to the trace's start, so short steps cost iterations, not distance (5 m
        against 10 m: paper 0.50x against 0.52x of the survey over 80 seeds, 22 seeds
        better and 7 worse; 10 m against 30 m: 0.51x against 0.55x; README).
    model : {"auto", "proxy", "gp"}
        Variance model (:mod:`econdor_gcs.core.uncertainty`). ``auto``: the distance
        proxy when mapping the whole field (it measured best there), the GP posterior
        in threshold mode (its variance shrinks where samples surround a place, so the
        planner knows when nothing is left to find; with the length fitted it knows
        that on smooth fields too).
    length_m : float
        Length of the ``proxy`` model, and of the ``gp`` model unless ``fit_length``.
    fit_length : bool
        The ``gp`` model's length scale is fitted to the samples (else ``length_m``).
    floor : float
        Amplitude floor ``s0``; 0 picks it from the data (``sigma_f`` of the GP).
    gradient_gain_m : float
        ``l_g``: weight of the estimate's steepness in the amplitude.
    power : float
        ``f(v) = a^p v^(p/2)``: 2 integrates the variance, 1 the standard deviation.
    plan_spacing_m : float
        Spacing of the planning cells (m).
    search_radius_m : float
        Search radius of the trace tasks (m).
    trace_overhead_m : float
        Extra flight charged to a trace candidate for the onboard search (m).
    resolve_m : float
        Threshold mode: a cell within this distance of a sample is observed.
    explore_m : float
        Threshold mode: a place farther than this from every sample may hide an iso-line
        whatever the model says (the smallest feature worth looking for, in metres).
    band_m : float
        Threshold mode: cells within this distance of a sample that reads a target level
        (within ``level_tol`` of the sampled value range) are resolved: the iso-line was
        flown on there.
    level_tol : float
        See ``band_m``.
    threshold_batch_m : float
        Threshold mode: flight planned per vehicle and iteration (m), in place of
        ``batch_m``.
    crossings_first : bool
        Threshold mode: before anything else, trace the estimate's components at a target
        level that pass through a crossing of that level already sampled (where two
        consecutive survey or transit samples straddle it) and not yet traced: the iso-line
        is known to be there.
    first_order : {"crossings", "nearest"}
        Threshold mode: the order of the candidates that go first. ``crossings``: every
        trace through a sampled crossing (nearest first) before any probe (nearest
        first): a known iso-line removes error for sure, a probe only may find one.
        ``nearest``: the nearest of either kind next.
    open_entry : {"auto", "end", "crossing"}
        Threshold mode: where a component through a sampled crossing that meets the
        area's edge is entered (:func:`mark_crossings`). ``auto``: at an end with a
        sampled crossing within ``OPEN_END_M`` (no flight back: the onboard tracer ends
        a trace begun at the edge at the far edge), else at the crossing nearest the end
        the tracer heads for (the shortest flight back to the entry, counted in the
        cost); ``crossing``: at the crossing nearest the estimate; ``end``: at its
        nearer end.
    probes : bool
        Threshold mode: before anything else, fly a leg across the track through every
        local extremum of the samples along a flown line that falls short of a target
        level (a maximum below it, a minimum above it): the field's extremum, and a
        closed iso-line around it, may lie off the track on that perpendicular (see
        :func:`extremum_probes`).
    probe_climb : bool
        Probe the extrema of probes too (a hill-climb); else only those of other lines.
    probe_m : float
        Length of those legs (m), centred on the extremum.
    probe_prominence : float
        An extremum counts when it stands out from its surroundings along the track
        (``scipy.signal.find_peaks`` prominence) by this fraction of the sampled value
        range. The simulated sensor is noise-free; with sensor noise it must exceed the
        noise several times over.
    probe_reach : float
        Probe only the extrema a level is within this many times the rise of a round
        bump, as curved along the track as the samples there, on the probe
        (:func:`~econdor_gcs.core.candidates.probe_reach`); 0: every such extremum.
    sweeps : bool
        Threshold mode: offer north-south legs over what is still farther than
        ``explore_m`` from every sample, on the centre lines of strips ``2 explore_m``
        wide less one planning cell (:func:`~econdor_gcs.core.candidates.sweep_candidates`).
    explore : {"auto", "legs", "lines"}
        Threshold mode: how the planner looks for what is not found yet. ``legs``: the
        greedy over exploration legs, lines, sweeps and traces, scored by the straddle and
        the coverage floor, after the probes. ``lines`` (one vehicle): after every trace
        through a sampled crossing, the line flown in steps (``start_step_m``) goes on;
        then the probes, where the model is blind beside the tracks (``probe_length_m``);
        then the straight line through the most uncovered ground per metre (north-south
        or east-west, the area's full width or half of it, every ``line_step_m``; the
        coverage floor alone scores it, weighted by ``line_weight``), flown in steps too,
        so that a crossing it samples is traced at once. Once every place is within
        ``explore_m`` of a sample, what the model still scores is planned as with
        ``legs``. ``auto``: ``lines`` where the model sees beside the tracks (a smooth
        field: the fitted length is at least ``probe_length_m``), else ``legs`` (a
        narrow feature beside a track shows only as an extremum along it). Either way
        the start line is flown in steps to its end: whether the model sees beside the
        tracks cannot be told from a GP fitted to its first few metres.
    line_step_m : float
        ``explore: lines``: spacing of the lines on offer (m).
    rays : int
        ``explore: lines``: beside those, the straight lines from the vehicle to the area's
        edge in this many directions (:func:`~econdor_gcs.core.routes.ray_lines`): no
        transit to them, so a line that samples from where a trace ended competes with one
        that must be flown to first. 0: none.
    line_weight : {"none", "p"}
        ``explore: lines``: each cell's coverage deficit counts in full (``none``) or
        weighted by ``min(1, LINE_WEIGHT_FLOOR + LINE_WEIGHT_GAIN p)``, where ``p =
        Phi(-|mu - L| / sigma)`` is the GP's probability that the cell lies on the other
        side of the level than the estimate says (``p``): lines go first where an
        iso-line the estimate does not show is likely.
    probe_length_m : float
        ``explore: lines``: probes (``probes``) go first only while the model cannot see
        beside a track: no GP fitted, one with no amplitude yet, or a fitted length scale
        below this (m); ``explore: auto`` is ``legs`` then. With a longer length (a smooth
        field) the GP-weighted lines look beside the tracks themselves. 0: always.
    target_levels : tuple of float
        Threshold mode when not empty.
    """

    batch_m: float = 200.0
    batch_growth: float = 0.0
    levels: int = 30
    piece_m: float = 30.0
    min_piece_m: float = 4.0
    leg_m: float = 30.0
    legs: int = 40
    line_spacing_m: float = 2.0
    line_orientation: str = "ns"
    start: str = "auto"
    start_lines: int = 0
    start_step_m: float = 5.0
    model: str = "auto"
    length_m: float = 5.0
    fit_length: bool = True
    floor: float = 0.0
    gradient_gain_m: float = 5.0
    power: float = 2.0
    plan_spacing_m: float = 2.0
    search_radius_m: float = 3.0
    trace_overhead_m: float = 5.0
    resolve_m: float = 1.5
    explore_m: float = 10.0
    band_m: float = 3.0
    level_tol: float = 0.01
    threshold_batch_m: float = 80.0
    crossings_first: bool = True
    first_order: str = "crossings"
    open_entry: str = "auto"
    probes: bool = True
    probe_climb: bool = True
    probe_m: float = 30.0
    probe_prominence: float = 1e-4
    probe_reach: float = 2.0
    sweeps: bool = True
    explore: str = "auto"
    line_step_m: float = 5.0
    rays: int = 32
    line_weight: str = "p"
    probe_length_m: float = 20.0
    target_levels: tuple[float, ...] = ()


# -- starts ----------------------------------------------------------------------------------


def sweep_spacing_m(params: AdaptiveParams) -> float:
    """Distance between sweep legs: a planning cell less than 2 x ``explore_m``. With legs
    0.5 m inside the area, strips exactly 2 x ``explore_m`` wide leave their corner cells
    just over ``explore_m`` from every leg, open for ever.

    >>> sweep_spacing_m(AdaptiveParams())
    18.0
    """
    return 2.0 * params.explore_m - params.plan_spacing_m


def survey_start_batch(region: Region, lines: int) -> Batch:
    """``lines`` north-south lines at the centres of ``lines`` equal strips.

    >>> b = survey_start_batch(Region(0.0, 100.0, 0.0, 100.0), 4)
    >>> [job.start_m[0] for job in b.jobs]
    [12.5, 37.5, 62.5, 87.5]
    """
    xs = region.xmin + (np.arange(lines) + 0.5) * region.width_m / lines
    return Batch(survey_jobs(region, xs), levels_planned=0)


def start_route(region: Region, lines: int) -> FloatArray:
    """The start survey (:func:`survey_start_batch`) as one polyline in flying order."""
    jobs = survey_start_batch(region, lines).jobs
    return np.array([p for j in jobs for p in (j.start_m, j.end_m)], dtype=float)


def perimeter_batch(context: PlanContext, inset_m: float = 0.5) -> Batch:
    """The area's boundary, ``inset_m`` inside, split into one loop share per vehicle."""
    r = context.region
    corners = np.array([[r.xmin, r.ymin], [r.xmax, r.ymin], [r.xmax, r.ymax], [r.xmin, r.ymax],
                        [r.xmin, r.ymin]]) + inset_m * np.array([[1, 1], [-1, 1], [-1, -1],
                                                                 [1, -1], [1, 1]])
    n = max(1, context.n_vehicles)
    loop = resample_polyline(corners, 1.0)
    cum = np.r_[0.0, np.cumsum(np.hypot(*np.diff(loop, axis=0).T))]
    cuts = np.linspace(0.0, cum[-1], n + 1)
    jobs: list[Job] = []
    for k in range(n):
        keep = (cum >= cuts[k] - 1e-9) & (cum <= cuts[k + 1] + 1e-9)
        part = loop[keep]
        # waypoints at the corners inside this share (and its ends)
        corner_idx = [0] + [i for i in range(1, len(part) - 1)
                            if np.any(np.all(np.isclose(part[i], corners), axis=1))] + [len(part) - 1]
        pts = part[corner_idx]
        tasks: list[Task] = [Waypoint(float(x), float(y)) for x, y in pts]
        length = path_length(pts[:, 0], pts[:, 1])
        jobs.append(Job(tasks, (float(pts[0, 0]), float(pts[0, 1])),
                        (float(pts[-1, 0]), float(pts[-1, 1])), length, vehicle=k))
    return Batch(jobs, levels_planned=0, survey_m=sum(j.length_m for j in jobs))


# -- greedy selection ------------------------------------------------------------------------


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
        after = np.minimum(before, fp.line_var)
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
        v[fp.cells[sl]] = np.minimum(v[fp.cells[sl]], fp.line_var[sl])
        d[fp.cells[sl]] = np.minimum(d[fp.cells[sl]], fp.dist_m[sl])
        if t_m > 1.0:
            cells, dist = fp.cells_near(np.array([pos, begin]))
            v[cells] = np.minimum(v[cells], fp.umap.line_variance(dist))
            d[cells] = np.minimum(d[cells], dist)
        g = gains()
    return fleet.picks, v


# -- the planner -----------------------------------------------------------------------------


class AdaptivePlanner:
    """Uncertainty-driven planner (module docstring); follows the ``Planner`` contract.

    Parameters
    ----------
    params : AdaptiveParams
    seed : int
        Seed of the GP fit's subsample (reproducible runs).
    """

    name = "adaptive"

    def __init__(self, params: AdaptiveParams = AdaptiveParams(), seed: int = 0  # noqa: B008
                 ) -> None:
        if params.model not in ("auto", "gp", "proxy"):
            raise ValueError(f"model: must be auto, gp or proxy, got {params.model!r}")
        if params.model == "auto":
            params = dataclasses.replace(params, model="gp" if params.target_levels else "proxy")
        if params.line_orientation not in ("ns", "ew", "both"):
            raise ValueError(f"line_orientation: must be ns, ew or both, got {params.line_orientation!r}")
        if params.first_order not in ("crossings", "nearest"):
            raise ValueError(f"first_order: must be crossings or nearest, got {params.first_order!r}")
        if params.open_entry not in ("auto", "end", "crossing"):
            raise ValueError(f"open_entry: must be auto, end or crossing, "
                             f"got {params.open_entry!r}")
        if params.start not in ("auto", "diagonals", "perimeter", "plan", "survey"):
            raise ValueError(f"start: must be auto, diagonals, perimeter, plan or survey, "
                             f"got {params.start!r}")
        if params.explore not in ("auto", "legs", "lines"):
            raise ValueError(f"explore: must be auto, legs or lines, got {params.explore!r}")
        if params.line_weight not in ("none", "p"):
            raise ValueError(f"line_weight: must be none or p, got {params.line_weight!r}")
        if params.start == "auto":
            params = dataclasses.replace(params, start="survey")
        if params.start_lines == 0:
            params = dataclasses.replace(params, start_lines=1 if params.target_levels else 16)
        self.params = params
        self.seed = seed
        self.hyper: MaternHyper | None = None
        self.open_cells = 0
        """Threshold mode: planning cells where an iso-line could still be (after the last plan)."""
        self._probed: list[FloatArray] = []
        self._route = SteppedRoute()
        """The line flown in steps (``start_step_m``): the start survey, then (``explore:
        lines``) each line through uncovered ground."""
        self._traced = False
        """``explore: lines``: the last plan was a trace through a sampled crossing."""
        self._spent: list[tuple[float, float]] = []
        """Where trace tasks began that were spent at once (``SPENT_TRACE_M``)."""

    def initiation(self, context: PlanContext) -> Batch | None:
        """The first flight, by ``start``: ``None`` (the mission's initiation pattern,
        ``"diagonals"``), the area's boundary (``"perimeter"``: the reconstruction
        extrapolates at the edges, where a survey has its first and last lines), the
        planner's own plan from its prior (``"plan"``), or an even survey of
        ``start_lines`` lines (``"survey"``: on a smooth field the error is set by the
        widest gaps, and lines added one by one are even only at doubling steps)."""
        if self.params.start == "diagonals":
            return None
        if self.params.start == "perimeter":
            return perimeter_batch(context)
        if self.params.start == "survey":
            r = context.region
            lines = self.params.start_lines
            if math.isfinite(context.budget_left_m):  # never more than the budget holds
                lines = min(lines, lawnmower_lines_for_budget(r, context.budget_left_m))
            if self._stepped(context):
                pos = context.positions_or_home_m[0]
                self._route.start(start_line(r, pos) if lines == 1 else start_route(r, lines))
                return self._step_batch(self._next_step(context), 0)
            return survey_start_batch(r, lines)
        return self.next_batch(context)

    def _stepped(self, context: PlanContext) -> bool:
        """Whether the start survey is flown in steps (threshold mode, one vehicle)."""
        p = self.params
        return bool(p.target_levels) and p.start_step_m > 0 and context.n_vehicles == 1

    def _next_step(self, context: PlanContext) -> FloatArray | None:
        """The next step of the line flown in steps, ``None`` once it has been flown."""
        s = context.samples
        return self._route.next_step(np.column_stack([s.x_m, s.y_m]), self.params.start_step_m)

    @staticmethod
    def _step_batch(step: FloatArray | None, levels_planned: int) -> Batch:
        """One step of the start survey as the iteration's only job."""
        if step is None:
            return Batch([], levels_planned=levels_planned)
        length = path_length(step[:, 0], step[:, 1])
        start = (float(step[0, 0]), float(step[0, 1]))
        end = (float(step[-1, 0]), float(step[-1, 1]))
        job = Job([Waypoint(float(x), float(y)) for x, y in step], start, end, length, vehicle=0)
        return Batch([job], levels_planned=levels_planned, survey_m=length)

    def observe(self, learning_error: float, reports: Sequence[FlightReport] = ()) -> None:
        """Where a trace task was spent at once (``SPENT_TRACE_M``); otherwise the next
        plan starts from every sample."""
        for report in reports:
            for o in report.outcomes:
                if isinstance(o.task, TraceTask) and o.traced_m < SPENT_TRACE_M and (
                        o.status in (OutcomeStatus.CLOSED, OutcomeStatus.BOUNDARY)):
                    self._spent.append((o.task.x_m, o.task.y_m))

    def _unspent(self, cands: list[Candidate]) -> list[Candidate]:
        """``cands`` without the traces that would begin within ``SPENT_NEAR_M`` of where a
        trace was spent: the estimate can keep offering a piece there (its end at the
        area's edge, say, which no sample reaches) that the tracer has already traced.
        Threshold mode only (where it was measured; the levels of the other modes move
        from one plan to the next)."""
        if not self._spent:
            return cands
        spent = cKDTree(np.asarray(self._spent))

        def starts(c: Candidate) -> list[FloatArray]:
            if c.entry_m is not None:
                return [c.entry_m]
            if c.closed:  # entered anywhere
                return []
            return [c.points_m[0], c.points_m[-1]] if c.reversible else [c.points_m[0]]

        return [c for c in cands if c.kind != CandidateKind.TRACE or not any(
            spent.query(p)[0] <= SPENT_NEAR_M for p in starts(c))]

    def uncertainty(self, context: PlanContext) -> tuple[UncertaintyMap, Grid]:
        """The uncertainty of the current estimate on the planning grid (the prior —
        uniform — before there is an estimate)."""
        p = self.params
        s = context.samples
        plan_grid = Grid.with_spacing(context.region, p.plan_spacing_m)
        if context.estimate is None or context.grid is None or len(s) < 3:
            xx, yy = plan_grid.mesh
            n = xx.size
            return UncertaintyMap(xx.ravel(), yy.ravel(), np.ones(n), np.full(n, p.floor or 1.0),
                                  np.zeros(n), "proxy", p.length_m, None, plan_grid), plan_grid
        if p.model == "gp":
            self.hyper = fit_matern(s.x_m, s.y_m, s.value, seed=self.seed + context.iteration)
            if not p.fit_length:
                self.hyper = dataclasses.replace(self.hyper, length_m=p.length_m)
        umap = uncertainty_map(s.x_m, s.y_m, s.value, context.estimate, context.grid, plan_grid,
                               model=p.model, length_m=p.length_m, floor=p.floor or None,
                               gradient_gain_m=p.gradient_gain_m, hyper=self.hyper)
        return umap, plan_grid

    def next_batch(self, context: PlanContext) -> Batch:
        p = self.params
        umap, _ = self.uncertainty(context)
        s = context.samples
        region = context.region
        near_m: FloatArray | None = None  # threshold mode: each cell's nearest sample (m)
        whole_cap_m = 0.0  # threshold mode: a whole trace may run this far at least
        if p.target_levels:
            levels = np.asarray(p.target_levels, dtype=float)
            gap = np.min(np.abs(umap.mean[:, None] - levels[None, :]), axis=1)
            cells_xy = np.column_stack([umap.x_m, umap.y_m])
            dist = np.full(umap.x_m.size, np.inf)
            band = np.full(umap.x_m.size, np.inf)
            span = float(np.ptp(s.value)) if len(s) else 1.0
            if len(s):
                dist, _ = cKDTree(np.column_stack([s.x_m, s.y_m])).query(cells_xy)
                on_level = np.min(np.abs(s.value[:, None] - levels[None, :]), axis=1) <= (
                    p.level_tol * span)
                if on_level.any():
                    band, _ = cKDTree(np.column_stack([s.x_m[on_level], s.y_m[on_level]])).query(
                        cells_xy)
            # Closed: observed cells, and the band along an iso-line already flown on (its
            # samples read the level: the iso-line is there, to within the tracking error).
            open_cells = (dist > p.resolve_m) & (band > p.band_m)
            # Coverage floor: farther than explore_m from every sample the iso-line could
            # be anywhere (features narrower than the data can show), whatever the model
            # says: such places score in proportion to how much farther they are.
            eps = 1e-3 * max(span, 1e-9)
            amp = umap.amplitude

            def cell_value(var: FloatArray, near: FloatArray, cells: NDArray[np.intp]
                           ) -> FloatArray:
                model = straddle(amp[cells], var, gap[cells], open_cells[cells])
                far = near / p.explore_m - 1.0
                cover = np.where(open_cells[cells], amp[cells] * np.maximum(far, 0.0), 0.0)
                return np.maximum(model, cover)

            near_m = dist
            now = cell_value(umap.variance, dist, np.arange(umap.x_m.size))
            self.open_cells = int(np.count_nonzero(now > 10 * eps))
            cands = [] if context.estimate is None or context.grid is None else (
                contour_candidates(context.estimate, context.grid, levels, p.piece_m,
                                   p.min_piece_m, whole=True))
            if p.crossings_first:
                cands = mark_crossings(cands, s, levels, p.band_m,
                                       open_at_end=p.open_entry == "end",
                                       end_m=OPEN_END_M if p.open_entry == "auto" else 0.0)
            cands = self._unspent(cands)
            if p.probes:
                cands += extremum_probes(s, levels, region, p.probe_m, p.probe_prominence,
                                         2.0 * p.resolve_m,
                                         () if p.probe_climb else self._probed,
                                         reach=p.probe_reach)
            if p.sweeps:
                uncovered = open_cells & (dist > p.explore_m)
                cands += sweep_candidates(umap, uncovered, region, sweep_spacing_m(p))
            if context.n_vehicles == 1 and (p.explore == "lines" or (
                    p.explore == "auto" and not self._blind_beside(context))):
                lines = self._lines_batch(context, umap, levels, cands, dist, open_cells,
                                          cells_xy)
                if lines is not None:
                    return lines
            # the start survey in steps: a trace through a crossing first, then the next step
            if self._route.active and not any(c.first and c.kind == CandidateKind.TRACE
                                              for c in cands):
                step = self._next_step(context)
                if step is not None:
                    return self._step_batch(step, len(levels))
            whole_cap_m = 2.0 * (region.width_m + region.height_m) if (
                self._route.active) else 0.0
            # done: nowhere left where the model says an iso-line could be, and no sampled
            # crossing or extremum left that says one is (or may be) there
            if self.open_cells == 0 and not any(c.first for c in cands):
                return Batch([], levels_planned=len(levels), done=True)
        else:
            amp = umap.amplitude

            def cell_value(var: FloatArray, near: FloatArray, cells: NDArray[np.intp]
                           ) -> FloatArray:
                return expected_error(amp[cells], var, p.power)

            now = expected_error(amp, umap.variance, p.power)
            levels = np.zeros(0)
            cands = []
            if context.estimate is not None and context.grid is not None:
                lo, hi = np.quantile(context.estimate, [0.005, 0.995])
                levels = np.linspace(lo, hi, p.levels + 2)[1:-1]
                cands = contour_candidates(context.estimate, context.grid, levels, p.piece_m,
                                           p.min_piece_m)
        cands += leg_candidates(umap, now, region, p.legs, p.leg_m)
        cands += line_candidates(region, p.line_spacing_m, p.line_orientation)
        batch_m = p.threshold_batch_m if p.target_levels else p.batch_m
        share = max(batch_m, p.batch_growth * context.flown_m)
        per_vehicle = min(share, context.budget_left_m / max(1, context.n_vehicles))
        positions = context.positions_or_home_m
        footprints = Footprints(umap, [c.points_m for c in cands])
        picks, _ = greedy_plan(cands, footprints, umap.variance, cell_value, positions,
                               [per_vehicle] * len(positions), p.trace_overhead_m,
                               traces_before_legs=p.first_order == "crossings",
                               distance_m=near_m)
        self._probed += [k.candidate.points_m for route in picks for k in route
                         if k.candidate.kind == CandidateKind.LEG and k.candidate.first]
        if p.target_levels and not any(picks) and per_vehicle > 0:
            # Open cells are left, but no flight on offer would lower their score (at the
            # area's edge, say, where the model already knows more than a pass 0.5 m
            # inside would add): nothing left to do is done, not a stall.
            return Batch([], levels_planned=len(levels), done=True)
        return self._batch(picks, levels, whole_cap_m)

    def _lines_batch(self, context: PlanContext, umap: UncertaintyMap, levels: FloatArray,
                     cands: list[Candidate], dist: FloatArray, open_cells: NDArray[np.bool_],
                     cells_xy: FloatArray) -> Batch | None:
        """``explore: lines`` (one vehicle; see :class:`AdaptiveParams`): the traces through
        sampled crossings and the probes, nearest first; else the next step of the line
        being flown; else the line through the most uncovered ground per metre; ``None``
        once every place is within ``explore_m`` of a sample (what the model still
        scores near the samples is then planned as with ``legs``)."""
        p = self.params
        region = context.region
        perimeter = 2.0 * (region.width_m + region.height_m)
        pos = np.asarray(context.positions_or_home_m[0], dtype=float)
        def fly_first(first: list[Candidate]) -> Batch:
            footprints = Footprints(umap, [c.points_m for c in first])
            picks, _ = greedy_plan(first, footprints, umap.variance,
                                   lambda v, d, cells: np.zeros(len(cells)), [tuple(pos)],
                                   [p.threshold_batch_m], p.trace_overhead_m,
                                   traces_before_legs=p.first_order == "crossings")
            # the estimate's component can be far too short while lines are still open
            return self._batch(picks, levels, perimeter)

        traces = [c for c in cands if c.first and c.kind == CandidateKind.TRACE]
        after_trace, self._traced = self._traced, bool(traces)
        if traces:
            return fly_first(traces)
        s = context.samples
        samples_xy = np.column_stack([s.x_m, s.y_m])
        weight = np.ones(len(dist))
        if p.line_weight == "p" and self.hyper is not None:
            sd = self.hyper.amplitude * np.sqrt(np.maximum(umap.variance, 1e-12))
            weight = np.minimum(1.0, LINE_WEIGHT_FLOOR + LINE_WEIGHT_GAIN * misclassification(
                umap.mean, sd, levels))
        near = np.where(open_cells, dist, 0.0)  # closed cells have nothing to cover
        lines = gap_lines(region, p.line_step_m) + ray_lines(region, pos, p.rays)
        rest = self._route.rest(samples_xy)
        if rest is not None and not best_lines(cells_xy, near, weight, p.explore_m, [rest], pos):
            self._route.stop()  # every place along the rest is covered: nothing to fly it for
        elif rest is not None and (after_trace
                                   or float(np.hypot(*(rest[0] - pos))) > ROUTE_LEFT_M):
            # a trace interrupted the line, or a probe took the vehicle away from it: what is
            # left of that line (from either end) competes with the lines through uncovered
            # ground
            ranked = best_lines(cells_xy, near, weight, p.explore_m,
                                [rest, *lines], pos)
            if ranked:
                self._route.start(ranked[0])
        step = self._next_step(context)
        if step is not None:
            return self._step_batch(step, len(levels))
        probes = [c for c in cands if c.first] if self._blind_beside(context) else []
        if probes:
            return fly_first(probes)
        for seg in best_lines(cells_xy, near, weight, p.explore_m, lines, pos):
            self._route.start(seg)
            step = self._route.next_step(samples_xy, p.start_step_m)
            if step is not None:  # (a line flown along already has no step left)
                return self._step_batch(step, len(levels))
        return None

    def _blind_beside(self, context: PlanContext) -> bool:
        """``explore: lines``: whether the model cannot see what lies beside a flown track:
        no fitted GP, one that has learnt no amplitude (every sample alike), or one whose
        length scale is below ``probe_length_m`` — a peak a probe's reach off the track
        then shows in the samples only as an extremum along it, so it is probed; with a
        longer length the GP-weighted lines look there by themselves."""
        p, h = self.params, self.hyper
        if p.probe_length_m <= 0 or h is None:
            return True
        span = float(np.ptp(context.samples.value)) if len(context.samples) else 0.0
        return h.length_m < p.probe_length_m or h.amplitude <= 0.05 * span

    def _batch(self, picks: list[list[Pick]], levels: FloatArray, whole_cap_m: float = 0.0
               ) -> Batch:
        p = self.params
        jobs: list[Job] = []
        survey_m = 0.0
        traced: set[float] = set()
        for route in picks:
            for pick in route:
                c, path = pick.candidate, pick.path_m
                begin = c.entry_m if c.entry_m is not None else path[0]
                start = (float(begin[0]), float(begin[1]))
                end = start if c.closed else (float(path[-1, 0]), float(path[-1, 1]))
                length = path_length(path[:, 0], path[:, 1])
                if c.kind == CandidateKind.TRACE:
                    # a whole component: until it closes or meets the edge, but never
                    # more than WHOLE_TRACE_FACTOR x the estimate's length (a lost
                    # tracer does not wander the area)
                    max_len = (max(WHOLE_TRACE_FACTOR * length, WHOLE_TRACE_MIN_M, whole_cap_m)
                               if c.whole else length)
                    # the estimated contour, for vehicles that fly it as waypoints
                    contour = tuple((float(x), float(y)) for x, y in path)
                    task = TraceTask(c.level, start[0], start[1], p.search_radius_m, max_len, 0,
                                     route_m=contour)
                    jobs.append(Job([task], start, end, length, vehicle=pick.vehicle))
                    traced.add(c.level)
                else:
                    jobs.append(Job([Waypoint(*start), Waypoint(*end)], start, end, length,
                                    vehicle=pick.vehicle))
                    survey_m += length
        return Batch(jobs, levels_planned=len(levels), levels=np.array(sorted(traced)),
                     survey_m=survey_m)
