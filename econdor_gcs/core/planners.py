"""Planners: what the fleet flies in each iteration.

All planners share the DFC loop, the reconstruction and the cost accounting; they
differ only in what they ask the vehicles to fly. Every planner follows one contract
(:class:`Planner`, after scikit-learn's estimator contract: the loop asks, never checks
which planner it has):

* ``initiation(context)`` -> the first batch, or ``None`` to fly the mission's
  initiation pattern (two diagonals, or a survey);
* ``next_batch(context)`` -> the :class:`Batch` of the next iteration, from a
  :class:`PlanContext` (the estimate, its grid, every sample so far, where the vehicles
  are, what is left of the flight budget);
* ``observe(learning_error, reports)`` -> learn from the iteration just flown.

The planners:

* ``econdor`` — the paper's dual SG: ``M_n = M_{n-1} + kappa_n`` Lloyd-Max levels of the
  current estimate, minus the levels within ``delta_n`` of an already traced level.
  ``lloyd_variant="authors"`` uses the authors' ``Lloyd_Max_2.m`` instead of the
  textbook eqs. 4-5 (outer thresholds recomputed, 500 bins for the first batch; see
  :mod:`econdor_gcs.core.levels`).
  When *every* new level is redundant, the ``kappa_n`` least redundant ones (farthest
  from any traced level) are flown instead (counted in ``Batch.forced``). An empty
  iteration would feed a learning error of exactly 0 into eqs. (6)-(7): the next real
  iteration's error then reads as a rise, which triples delta (eq. 7) and the method
  stalls for good (it happens on the paper's field).
  With noisy samples (``PlanContext.noise_std``) the levels are those of the smoothed
  estimate and a level within the noise of a traced one is redundant whatever
  ``delta_n`` is. Every piece is still traced, however flat the field under it: the
  tracer's own averaging along a piece maps it better than leaving it unflown.
* ``no-sg`` — the paper's baseline: ``kappa = 1`` (one more level per iteration), every
  level re-traced, nothing dropped.
* ``lawnmower`` — a boustrophedon survey; each iteration halves the line spacing by
  flying the lines in between (or one survey of ``lines`` lines, or sized for
  ``budget_m`` with its turns counted, after which it is done).
* ``adaptive`` — uncertainty-driven candidates picked by uncertainty removed per metre,
  or threshold mapping of given levels (:mod:`econdor_gcs.core.adaptive`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from .contours import ContourPiece, contour_pieces
from .geometry import FloatArray, Grid, Region
from .levels import lloyd_max
from .sg import drop_redundant, initial_delta, update_delta, update_kappa
from .tasks import FlightReport, SampleLog, Task, TraceTask, Waypoint
from .waypoints import piece_route

PLANNER_NAMES = ("econdor", "no-sg", "lawnmower", "adaptive")
"""The planners a mission or the command line may name (built by ``econdor_gcs.dfc.loop``)."""

AUTHORS_FIRST_BINS = 500
"""Histogram bins of the first batch's Lloyd-Max levels in the authors' code."""


@dataclass
class Job:
    """A unit of work for one vehicle: a contour piece to trace or a survey line."""

    tasks: list[Task]
    start_m: tuple[float, float]
    end_m: tuple[float, float]
    length_m: float
    piece: ContourPiece | None = None
    vehicle: int | None = None
    """The vehicle the planner routed this job to. When every job of a batch names its
    vehicle, the assignment keeps the planner's routing and order (and its entry points)."""

    def retarget(self, x_m: float, y_m: float, search_radius_m: float, max_len: float,
                 piece_id: int) -> None:
        """For a contour piece: start at the piece point nearest to ``(x_m, y_m)``."""
        if self.piece is None:
            return
        sx, sy = self.piece.nearest_point(x_m, y_m)
        self.start_m = (sx, sy)
        if self.piece.closed:
            self.end_m = (sx, sy)
        else:
            ends = self.piece.points_m[[0, -1]]
            far = int(np.argmax(np.hypot(ends[:, 0] - sx, ends[:, 1] - sy)))
            self.end_m = (float(ends[far, 0]), float(ends[far, 1]))
        route = piece_route(self.piece.points_m, self.piece.closed, (x_m, y_m))
        self.tasks = [TraceTask(self.piece.level, sx, sy, search_radius_m, max_len, piece_id,
                                route_m=tuple(map(tuple, route.tolist())))]


@dataclass
class Batch:
    """What one iteration flies, and the bookkeeping the reports need."""

    jobs: list[Job]
    levels_planned: int
    levels: FloatArray = field(default_factory=lambda: np.zeros(0))
    dropped: FloatArray = field(default_factory=lambda: np.zeros(0))
    kappa: int = 0
    delta: float = 0.0
    survey_m: float = 0.0
    """Planned length of survey lines in this batch (counted as 'contour' distance: it is
    the planner's productive flight, as traced length is for contour planners)."""
    forced: int = 0
    done: bool = False
    """The planner has nothing left to learn (with no jobs: the run stops, reason
    ``planner_done``), e.g. threshold mapping found no place left where an iso-line
    could still be."""


@dataclass(frozen=True)
class PlanContext:
    """What a planner may look at when it plans an iteration (never the true field)."""

    iteration: int
    region: Region
    n_vehicles: int
    grid: Grid | None = None
    estimate: FloatArray | None = None
    samples: SampleLog = field(default_factory=SampleLog)
    positions_m: Sequence[tuple[float, float]] = ()
    budget_left_m: float = math.inf
    """Flight distance left of ``algorithm.flight_budget_m`` (inf without a budget)."""
    flown_m: float = 0.0
    """Flight distance so far (all vehicles, everything counted)."""
    noise_std: float = 0.0
    """The samples' noise as the station's reconstruction estimated it from the samples
    themselves (field units; :func:`~econdor_gcs.core.spline.fit_field`), never the
    simulation's: 0 when they read as exact (or before any estimate)."""

    @property
    def positions_or_home_m(self) -> list[tuple[float, float]]:
        """``positions_m``, or, before any is known, every vehicle at the area's home
        corner (its south-west corner, where the in-process executor starts them)."""
        home = (self.region.xmin, self.region.ymin)
        return list(self.positions_m) or [home] * self.n_vehicles


class Planner(Protocol):
    """The contract every planner follows (see the module docstring)."""

    name: str

    def initiation(self, context: PlanContext) -> Batch | None: ...

    def next_batch(self, context: PlanContext) -> Batch: ...

    def observe(self, learning_error: float, reports: Sequence[FlightReport]) -> None: ...


def diagonal_jobs(region: Region, n_vehicles: int) -> list[Job]:
    """The two main diagonals, cut into ``n_vehicles`` pieces of equal length."""
    diag = [((region.xmin, region.ymin), (region.xmax, region.ymax)),
            ((region.xmax, region.ymin), (region.xmin, region.ymax))]
    d = math.hypot(region.width_m, region.height_m)
    total = 2 * d
    cuts = np.linspace(0.0, total, n_vehicles + 1)
    jobs: list[Job] = []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        pts: list[tuple[float, float]] = []
        for k, (p, q) in enumerate(diag):
            lo, hi = max(a, k * d), min(b, (k + 1) * d)
            if hi <= lo:
                continue
            for s in (lo, hi):
                t = (s - k * d) / d
                pts.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
        tasks: list[Task] = [Waypoint(*pt) for pt in pts]
        length = sum(math.dist(u, v) for u, v in zip(pts[:-1], pts[1:], strict=True))
        jobs.append(Job(tasks, pts[0], pts[-1], length))
    return jobs


def survey_jobs(region: Region, xs: FloatArray) -> list[Job]:
    """North-south survey lines at the given eastings, alternating direction."""
    jobs = []
    for i, x in enumerate(np.sort(np.asarray(xs, dtype=float))):
        a, b = (region.ymin, region.ymax) if i % 2 == 0 else (region.ymax, region.ymin)
        jobs.append(Job([Waypoint(float(x), a), Waypoint(float(x), b)], (float(x), a),
                        (float(x), b), region.height_m))
    return jobs


TURN_BRAKING_SHARE = 0.4
"""A survey's turn is charged this share of the vehicle's braking distance ``v^2 / 2a``
(:func:`survey_turn_m`): the simulated vehicle flies up to a third of it beyond a
right-angle corner, at every speed, acceleration and turn rate tried (the experiment log
of 2026-12-04, ``docs/experiments/``)."""


def survey_turn_m(speed_mps: float, max_accel_mps2: float) -> float:
    """What one turn at a survey line's end is charged beyond the planned corner (m).

    >>> round(survey_turn_m(8.0, 5.0), 2)
    2.56
    """
    return TURN_BRAKING_SHARE * speed_mps**2 / (2.0 * max_accel_mps2)


def survey_length_m(region: Region, lines: int, turn_m: float = 0.0) -> float:
    """The flight of a survey of ``lines`` north-south lines from the area's west to its
    east edge (:func:`survey_jobs` at even eastings), entered at its first line's start:
    the lines, the cross-track legs and ``turn_m`` for each of the two turns per leg.

    >>> survey_length_m(Region(0.0, 100.0, 0.0, 100.0), 9, 2.5)
    1040.0
    """
    if lines < 1:
        return 0.0
    legs = lines - 1
    return lines * region.height_m + (region.width_m if legs else 0.0) + 2 * legs * turn_m


def lawnmower_lines_for_budget(region: Region, budget_m: float, turn_m: float = 0.0) -> int:
    """The most north-south lines whose survey (:func:`survey_length_m`, each turn charged
    ``turn_m``) fits a flight budget; never fewer than two.

    >>> lawnmower_lines_for_budget(Region(0.0, 100.0, 0.0, 100.0), 1000.0)
    9
    >>> lawnmower_lines_for_budget(Region(0.0, 100.0, 0.0, 100.0), 1000.0, turn_m=2.56)
    8
    """
    n = max(2, int((budget_m - region.width_m) // region.height_m))
    while n > 2 and survey_length_m(region, n, turn_m) > budget_m:
        n -= 1
    return n


class ContourPlanner:
    """E-CONDOR (``sg=True``) or the no-SG baseline (``sg=False``)."""

    def __init__(
        self,
        m0: int = 3,
        sg: bool = True,
        lloyd_bins: int | None = 200,
        lloyd_iterations: int = 100,
        min_piece_length_m: float = 2.0,
        search_radius_m: float = 10.0,
        max_trace_length_m: float = 0.0,
        lloyd_variant: str = "textbook",
    ) -> None:
        if lloyd_variant not in ("textbook", "authors"):
            raise ValueError(f"lloyd_variant: must be 'textbook' or 'authors', got {lloyd_variant!r}")
        self.lloyd_variant = lloyd_variant
        self.m0 = m0
        self.sg = sg
        self.lloyd_bins = lloyd_bins
        self.lloyd_iterations = lloyd_iterations
        self.min_piece_length_m = min_piece_length_m
        self.search_radius_m = search_radius_m
        self.max_trace_length_m = max_trace_length_m
        self.name = "econdor" if sg else "no-sg"
        self.m = 0
        self.kappa = 1
        self.delta = 0.0
        self.errors: list[float] = []
        self.traced: list[float] = []
        self.batches = 0

    def initiation(self, context: PlanContext) -> Batch | None:
        """``None``: E-CONDOR starts from the mission's initiation pattern (the diagonals)."""
        return None

    def observe(self, learning_error: float, reports: Sequence[FlightReport] = ()) -> None:
        """Record the learning error of the iteration just finished (eq. 3)."""
        self.errors.append(float(learning_error))

    def _levels(self, estimate: FloatArray) -> FloatArray:
        bins = self.lloyd_bins
        if self.lloyd_variant == "authors" and self.batches == 1:
            bins = AUTHORS_FIRST_BINS
        return lloyd_max(estimate, self.m, bins, self.lloyd_iterations, variant=self.lloyd_variant)

    def next_batch(self, context: PlanContext) -> Batch:
        """Levels and contour pieces for the next iteration.

        As in the authors' implementation: batch 1 traces ``m0`` levels and sets the
        initial ``delta`` to their smallest gap; batch 2 adds one level (``kappa = 1``,
        only one learning error exists yet) and drops nothing; from batch 3 on, kappa and
        delta follow eqs. (6)-(7) and redundant levels are dropped. Without SG every batch
        adds one level and re-traces all of them.
        """
        if context.estimate is None or context.grid is None:
            raise ValueError("context: a contour planner needs the estimate and its grid")
        estimate, grid = context.estimate, context.grid
        noise = context.noise_std

        def pieces_at(levels: FloatArray) -> list[ContourPiece]:
            return contour_pieces(estimate, grid, levels, self.min_piece_length_m)

        self.batches += 1
        forced = 0
        if self.batches == 1:
            self.m = self.m0
            levels = self._levels(estimate)
            self.delta = initial_delta(levels[:3])
        elif not self.sg or self.batches == 2:
            self.m += 1
            levels = self._levels(estimate)
        if not self.sg or self.batches <= 2:
            keep, dropped = levels, np.zeros(0)
            pieces = pieces_at(keep)
        else:
            e2 = self.errors[-2] if len(self.errors) >= 2 else None
            e1 = self.errors[-1] if self.errors else None
            self.kappa = update_kappa(self.kappa, e2, e1)
            self.delta = update_delta(self.delta, e2, e1)
            self.m += self.kappa
            levels = self._levels(estimate)
            # levels closer than the noise to a traced one are its iso-line again, to
            # within what the noise moves either by
            keep, dropped = drop_redundant(levels, self.traced, max(self.delta, noise))
            pieces = pieces_at(keep)
            if not pieces and len(dropped):
                # Every new level is redundant: fly the kappa least redundant ones
                # rather than an empty iteration (see the module docstring).
                gap = np.min(np.abs(dropped[:, None] - np.asarray(self.traced)[None, :]), axis=1)
                chosen = np.zeros(len(dropped), dtype=bool)
                chosen[np.argsort(-gap, kind="stable")[: self.kappa]] = True
                keep, dropped = dropped[chosen], dropped[~chosen]
                pieces = pieces_at(keep)
                forced = len(keep)
        jobs = []
        for p in pieces:
            max_len = self.max_trace_length_m or max(4.0 * p.length_m, 100.0)
            job = Job([], (0.0, 0.0), (0.0, 0.0), p.length_m, piece=p)
            job.retarget(*p.midpoint(), self.search_radius_m, max_len, 0)
            jobs.append(job)
        self.traced.extend(float(v) for v in keep)
        return Batch(jobs, levels_planned=len(levels), levels=keep, dropped=dropped,
                     kappa=self.kappa, delta=self.delta, forced=forced)


class LawnmowerPlanner:
    """Boustrophedon survey refined each iteration (spacing halves), or one survey of a
    given number of lines or sized for a budget.

    Parameters
    ----------
    region : Region
    spacing_m : float
        Line spacing of the first survey, halved each iteration (0: a quarter of the
        area's width).
    budget_m : float
        One survey, of the most lines whose flight fits this (m), each turn charged
        ``turn_m``: then the planner is done.
    lines : int
        One survey of this many lines (from the west edge to the east edge), then done.
    turn_m : float
        What a turn at a line's end is charged beyond the planned corner
        (:func:`survey_turn_m`: the vehicle overshoots each corner a little).
    """

    name = "lawnmower"

    def __init__(self, region: Region, spacing_m: float = 0.0, budget_m: float = 0.0,
                 lines: int = 0, turn_m: float = 0.0) -> None:
        if lines and budget_m:
            raise ValueError("lawnmower: give lines or budget_m, not both")
        if lines == 1 or lines < 0:
            raise ValueError(f"lawnmower.lines: a survey needs at least 2 lines, got {lines}")
        if budget_m and survey_length_m(region, 2, turn_m) > budget_m:
            raise ValueError(f"lawnmower.budget_m: {budget_m:g} m holds no survey (two lines "
                             f"need {survey_length_m(region, 2, turn_m):.0f} m with the turns)")
        self.region = region
        self.budget_m = budget_m
        self.turn_m = turn_m
        self.fixed_lines = lines or (
            lawnmower_lines_for_budget(region, budget_m, turn_m) if budget_m > 0 else 0)
        """The line count of a single survey (``lines`` or sized for ``budget_m``); 0 when
        the survey is refined each iteration."""
        self.spacing_m = spacing_m or region.width_m / 4
        self.flown_x: set[float] = set()
        self.iteration = 0

    def initiation(self, context: PlanContext) -> Batch | None:
        """The survey starts at once: its first (coarsest) lines are the initiation."""
        return self.next_batch(context)

    def observe(self, learning_error: float, reports: Sequence[FlightReport] = ()) -> None:
        """A fixed survey learns nothing from what it measured."""

    def lines(self) -> FloatArray:
        r = self.region
        if self.fixed_lines:
            if self.iteration > 0:
                return np.zeros(0)
            return np.linspace(r.xmin, r.xmax, self.fixed_lines)
        s = self.spacing_m / 2**self.iteration
        xs = np.arange(r.xmin, r.xmax + 1e-9, s)
        if xs[-1] < r.xmax - 1e-9:
            xs = np.r_[xs, r.xmax]
        return np.array([x for x in np.round(xs, 6) if x not in self.flown_x])

    def next_batch(self, context: PlanContext | None = None) -> Batch:
        """The next lines; a single survey, once flown, is done (the loop stops with
        ``planner_done``, not with empty iterations until it stalls)."""
        xs = self.lines()
        self.iteration += 1
        self.flown_x.update(float(x) for x in xs)
        jobs = survey_jobs(self.region, xs)
        return Batch(jobs, levels_planned=0, survey_m=sum(j.length_m for j in jobs),
                     done=bool(self.fixed_lines) and not jobs)
