"""What the two adaptive planners share: the start, the uncertainty model, the greedy plan
over the candidates, and how picks become jobs.

:class:`AdaptivePlanner` is the base of :class:`~.full_field.FullFieldPlanner` (the whole
field) and :class:`~.threshold.ThresholdPlanner` (the iso-lines at given levels); each
says what its cells are worth and which candidates it offers (``next_batch``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import RectBivariateSpline
from threadpoolctl import threadpool_limits

from ..candidates import Candidate, CandidateKind, leg_candidates, line_candidates
from ..geometry import FloatArray, Grid, Region, path_length
from ..gp import MaternHyper, fit_matern
from ..planners import Batch, Job, PlanContext, lawnmower_lines_for_budget, survey_jobs
from ..tasks import FlightReport, SampleLog, Task, TraceTask, Waypoint
from ..uncertainty import Footprints, UncertaintyMap, resample_polyline, uncertainty_map
from .greedy import Pick, greedy_plan
from .params import AdaptiveParams, FirstOrder, Model, Start

REFIT_GROWTH = 1.2
"""The factor by which the samples grow before the planner's GP is fitted to noisy
samples again (:meth:`AdaptivePlanner._fit`)."""

WHOLE_TRACE_FACTOR = 2.0
"""A whole-component trace stops after this multiple of the estimated component's length."""
WHOLE_TRACE_MIN_M = 60.0
"""... and never before this length (the estimate's component can be far too short)."""

def estimated_samples(context: PlanContext) -> SampleLog:
    """The samples with the estimate's values at their positions when they are noisy
    (``context.noise_std > 0``), else the samples as they are.

    What the samples *read* along a track -- where two consecutive ones straddle a level,
    where they peak, which of them read a level -- is what the planner looks at to find
    an iso-line; with noise each of those is also found wherever the noise happens to
    cross or peak. The estimate has the noise smoothed out with every sample around
    (:func:`~econdor_gcs.core.spline.fit_field`), so it is read instead; exact samples
    are the estimate's own values there already.
    """
    s = context.samples
    if context.noise_std <= 0 or context.estimate is None or context.grid is None or not len(s):
        return s
    g = context.grid
    spline = RectBivariateSpline(g.y, g.x, context.estimate, kx=3, ky=3)
    x = np.clip(s.x_m, g.region.xmin, g.region.xmax)
    y = np.clip(s.y_m, g.region.ymin, g.region.ymax)
    return dataclasses.replace(s, value=np.asarray(spline.ev(y, x), dtype=float))


CellValue = Callable[[FloatArray, FloatArray, NDArray[np.intp]], FloatArray]
"""``cell_value(v, d, cells)``: the value of planning cells ``cells`` at unit variances
``v`` and distances ``d`` (m) from the nearest sample (what a pick removes is the drop)."""


# -- starts ----------------------------------------------------------------------------------


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


# -- the shared planner ----------------------------------------------------------------------


class AdaptivePlanner:
    """What both adaptive planners do (module docstring); follows the ``Planner`` contract.
    Build one with :func:`~econdor_gcs.core.adaptive.adaptive_planner`.

    Parameters
    ----------
    params : AdaptiveParams
        Kept with every ``auto`` decided (:meth:`AdaptiveParams.resolved`).
    seed : int
        Seed of the GP fit's subsample (reproducible runs).
    """

    name = "adaptive"

    def __init__(self, params: AdaptiveParams = AdaptiveParams(), seed: int = 0  # noqa: B008
                 ) -> None:
        self.params = params.resolved()
        self.seed = seed
        self.hyper: MaternHyper | None = None
        """The GP fitted for the last plan (``model: gp``)."""
        self._fitted: MaternHyper | None = None
        self._fitted_at = self._searched_at = 0
        """The last likelihood fit, and the samples there were at it and at the last
        search from afar (:meth:`_fit`)."""

    def initiation(self, context: PlanContext) -> Batch | None:
        """The first flight, by ``start``: ``None`` (the mission's initiation pattern,
        ``"diagonals"``), the area's boundary (``"perimeter"``: the reconstruction
        extrapolates at the edges, where a survey has its first and last lines), the
        planner's own plan from its prior (``"plan"``), or an even survey of
        ``start_lines`` lines (``"survey"``: on a smooth field the error is set by the
        widest gaps, and lines added one by one are even only at doubling steps)."""
        p = self.params
        if p.start == Start.DIAGONALS:
            return None
        if p.start == Start.PERIMETER:
            return perimeter_batch(context)
        if p.start == Start.SURVEY:
            lines = p.start_lines
            if math.isfinite(context.budget_left_m):  # never more than the budget holds
                lines = min(lines, lawnmower_lines_for_budget(context.region,
                                                              context.budget_left_m))
            return self._start_survey(context, lines)
        return self.next_batch(context)

    def _start_survey(self, context: PlanContext, lines: int) -> Batch:
        """The ``survey`` start: all its lines in the first iteration."""
        return survey_start_batch(context.region, lines)

    def next_batch(self, context: PlanContext) -> Batch:
        raise NotImplementedError  # pragma: no cover - each planner plans its own way

    def observe(self, learning_error: float, reports: Sequence[FlightReport] = ()) -> None:
        """The next plan starts from every sample: nothing else to learn."""

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
        # One BLAS thread, as for the DFC's reconstruction: the planner shares the cores
        # with the vehicles (and a study with its other runs), and idle BLAS threads
        # spinning on a busy machine slow the GP's dense solves down many times.
        with threadpool_limits(limits=1, user_api="blas"):
            if p.model == Model.GP:
                # the nugget is the station's noise estimate: a GP that took noisy samples
                # for exact ones would see structure at the noise's scale everywhere (a
                # short length, a large variance between any two samples) and never judge
                # a place resolved
                self.hyper = self._fit(context)
                if not p.fit_length:
                    self.hyper = dataclasses.replace(self.hyper, length_m=p.length_m)
            umap = uncertainty_map(s.x_m, s.y_m, s.value, context.estimate, context.grid,
                                   plan_grid, model=p.model, length_m=p.length_m,
                                   floor=p.floor or None, gradient_gain_m=p.gradient_gain_m,
                                   hyper=self.hyper, noise_std=context.noise_std)
        return umap, plan_grid

    def _fit(self, context: PlanContext) -> MaternHyper:
        """The GP's hyperparameters for this plan. Exact samples: a search over the
        length alone, every plan. Noisy ones (length and amplitude searched together, the
        noise fixed): fitted again once the samples have grown by :data:`REFIT_GROWTH`
        since the last fit (a few more samples of a field move the optimum less than the
        choice of the subsample it is fitted on; the nugget follows the noise estimate in
        between), from the last optimum (one descent) while they have not doubled since
        the last search from afar (three starting lengths), which a doubling does again."""
        s = context.samples
        noise = context.noise_std
        if noise <= 0.0:
            return fit_matern(s.x_m, s.y_m, s.value, seed=self.seed + context.iteration)
        last = self._fitted
        if last is not None and last.amplitude > 0.0 and len(s) < REFIT_GROWTH * self._fitted_at:
            return dataclasses.replace(last, nugget=(noise / last.amplitude) ** 2)
        warm = last if len(s) < 2 * self._searched_at else None
        self._fitted = fit_matern(s.x_m, s.y_m, s.value, seed=self.seed + context.iteration,
                                  noise_std=noise, start=warm)
        self._fitted_at = len(s)
        if warm is None:
            self._searched_at = len(s)
        return self._fitted

    def floor_reach_m(self) -> float:
        """How far from a path the cells' value may drop without the model seeing it (a
        floor measured in metres): the footprints reach at least that far. None here."""
        return 0.0

    def _plan(self, context: PlanContext, umap: UncertaintyMap, cands: list[Candidate],
              now: FloatArray, cell_value: CellValue, batch_m: float,
              near_m: FloatArray | None = None) -> tuple[list[list[Pick]], float]:
        """The greedy plan over ``cands`` plus the exploration legs and full-width lines:
        each vehicle's picks, and the flight each vehicle was given (``batch_m``, or
        ``batch_growth`` of the distance flown so far, within the budget left)."""
        p = self.params
        cands += leg_candidates(umap, now, context.region, p.legs, p.leg_m)
        cands += line_candidates(context.region, p.line_spacing_m, p.line_orientation)
        share = max(batch_m, p.batch_growth * context.flown_m)
        per_vehicle = min(share, context.budget_left_m / max(1, context.n_vehicles))
        positions = context.positions_or_home_m
        footprints = Footprints(umap, [c.points_m for c in cands],
                                min_radius_m=self.floor_reach_m())
        picks, _ = greedy_plan(cands, footprints, umap.variance, cell_value, positions,
                               [per_vehicle] * len(positions), p.trace_overhead_m,
                               traces_before_legs=p.first_order == FirstOrder.CROSSINGS,
                               distance_m=near_m)
        return picks, per_vehicle

    def _batch(self, picks: list[list[Pick]], levels: FloatArray, whole_cap_m: float = 0.0
               ) -> Batch:
        """The picks as jobs: a trace task per contour candidate (traced onboard, with the
        estimated contour for vehicles that fly it as waypoints), a pair of waypoints per
        leg or line."""
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
