"""The adaptive planner in threshold mode: only the iso-lines at ``target_levels`` matter.

The per-cell value is the straddle score ``max(1.96 sigma - min_L |mu - L|, 0)`` (Bryan et
al. 2005) and, farther than ``explore_m`` from every sample (``d``: the distance to the
nearest sample, and to the paths planned so far), ``a (d / explore_m - 1)``: a coverage
floor, since an iso-line around a feature narrower than the data can show may hide there
whatever the model says (with the length fitted to a smooth field the GP's variance is
small tens of metres from the nearest sample, so the floor is measured in metres, not
through the model). Cells within ``resolve_m`` of a sample (observed) or within ``band_m``
of a sample that reads a target level (an iso-line already flown on) count for nothing.

Candidates are the estimate's whole contour components at the target levels (each traced
until it closes or meets the area's edge on both sides) plus the exploration legs and
lines, and sweeps over what the floor still scores (``sweeps``). Two kinds go before
anything the greedy would pick (nearest first): a component through a crossing of its
level that a survey or transit leg sampled and no trace has flown yet (``crossings_first``:
the iso-line is known to be there), and a probe across the track through every local
extremum of the samples along a flown line that falls short of a level (``probes``: a peak
beside the line, and a closed iso-line round it, lies on that perpendicular; see
:func:`~econdor_gcs.core.candidates.extremum_probes`); crossings go before probes
(``first_order``). With one vehicle the start line, and (``explore: lines``) each line
through uncovered ground, is flown in steps, so that a crossing a step samples is traced
at once (:class:`~econdor_gcs.core.routes.SteppedRoute`).

The planner reports ``done`` when no open cell scores any more — nowhere is left where an
iso-line could still be, under the model (by default the GP posterior with its length
scale fitted to the samples: its variance shrinks where samples surround a place, which
the distance proxy cannot see, and over a smooth field's longer length more than over a
plume's) — and no such crossing or probe is left: the samples themselves still say an
iso-line is, or may be, there (with ``probes_at_end`` false, probes left then are not
flown). It is done, too, when open cells are left that no candidate
would improve (at the area's edge the model can know more than a pass 0.5 m inside would
add): planning nothing would only stall the run.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from ..candidates import (
    Candidate,
    CandidateKind,
    contour_candidates,
    extremum_probes,
    mark_crossings,
    sweep_candidates,
)
from ..geometry import FloatArray, path_length
from ..planners import Batch, Job, PlanContext
from ..routes import SteppedRoute, best_lines, gap_lines, misclassification, ray_lines, start_line
from ..tasks import FlightReport, OutcomeStatus, TraceTask, Waypoint
from ..uncertainty import Footprints, UncertaintyMap, straddle
from .base import AdaptivePlanner, estimated_samples, start_route
from .greedy import greedy_plan
from .params import AdaptiveParams, Explore, FirstOrder, LineWeight, OpenEntry

ROUTE_LEFT_M = 15.0
"""``explore: lines``: a vehicle this far from where its line was left (a probe took it
away) weighs what is left of the line against the other lines before going on; after a
trace it always does (what the trace found changes what the rest of the line is worth: a
line through the inside of the loop a trace has just closed is worth little)."""
LINE_WEIGHT_FLOOR = 0.02
LINE_WEIGHT_GAIN = 10.0
"""``line_weight: p``: a cell's coverage deficit counts ``min(1, floor + gain p)`` times."""
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


PROBE_NOISE_Z = 1.0
"""With noisy samples an extremum is probed only if it stands out by this many times the
noise of one sample: the estimate read along the track (:func:`~.base.estimated_samples`)
keeps a fraction of the noise, whose wiggles would each be an extremum to probe."""


def probe_prominence(fraction: float, noise_std: float, span: float) -> float:
    """The prominence an extremum needs, as a fraction of the sampled value range
    ``span``: ``fraction``, or :data:`PROBE_NOISE_Z` times the noise if that is more.

    >>> probe_prominence(1e-4, 0.0, 90.0), round(probe_prominence(1e-4, 0.9, 90.0), 6)
    (0.0001, 0.01)
    """
    if noise_std <= 0 or span <= 0:
        return fraction
    return max(fraction, PROBE_NOISE_Z * noise_std / span)


def sweep_spacing_m(params: AdaptiveParams) -> float:
    """Distance between sweep legs: a planning cell less than 2 x ``explore_m``. With legs
    0.5 m inside the area, strips exactly 2 x ``explore_m`` wide leave their corner cells
    just over ``explore_m`` from every leg, open for ever.

    >>> sweep_spacing_m(AdaptiveParams())
    18.0
    """
    return 2.0 * params.explore_m - params.plan_spacing_m


class ThresholdPlanner(AdaptivePlanner):
    """The adaptive planner mapping the iso-lines at ``target_levels`` (module docstring)."""

    def __init__(self, params: AdaptiveParams, seed: int = 0) -> None:
        if not params.target_levels:
            raise ValueError("target_levels: threshold mapping needs at least one level")
        super().__init__(params, seed)
        self.open_cells = 0
        """Planning cells where an iso-line could still be (after the last plan)."""
        self._probed: list[FloatArray] = []
        self._route = SteppedRoute()
        """The line flown in steps (``start_step_m``): the start survey, then (``explore:
        lines``) each line through uncovered ground."""
        self._traced = False
        """``explore: lines``: the last plan was a trace through a sampled crossing."""
        self._spent: list[tuple[float, float]] = []
        """Where trace tasks began that were spent at once (``SPENT_TRACE_M``)."""

    def floor_reach_m(self) -> float:
        """The coverage floor is in metres, not in the model: a path closes the uncovered
        ground within ``explore_m`` of it whatever the model's footprint. A GP fitted to
        noisy samples of a flat background puts all their spread in the noise (no
        amplitude, the length at its bound, a nugget of millions): a line then lowers its
        variance nowhere, its footprint shrinks to nothing, no path would lower any
        cell's floor, and the planner would stop with uncovered ground left."""
        return self.params.explore_m

    # -- the start line, in steps ------------------------------------------------------------

    def _start_survey(self, context: PlanContext, lines: int) -> Batch:
        """With one vehicle the start survey is flown in steps (``start_step_m``); one line
        runs from the vehicle straight through the area's centre
        (:func:`~econdor_gcs.core.routes.start_line`: from the home corner, the diagonal),
        so it samples from its first metre."""
        if not self._stepped(context):
            return super()._start_survey(context, lines)
        r = context.region
        pos = context.positions_or_home_m[0]
        self._route.start(start_line(r, pos) if lines == 1 else start_route(r, lines))
        return self._step_batch(self._next_step(context), 0)

    def _stepped(self, context: PlanContext) -> bool:
        """Whether the start survey is flown in steps (one vehicle)."""
        return self.params.start_step_m > 0 and context.n_vehicles == 1

    def _next_step(self, context: PlanContext) -> FloatArray | None:
        """The next step of the line flown in steps, ``None`` once it has been flown."""
        s = context.samples
        return self._route.next_step(np.column_stack([s.x_m, s.y_m]), self.params.start_step_m)

    @staticmethod
    def _step_batch(step: FloatArray | None, levels_planned: int) -> Batch:
        """One step of the line flown in steps as the iteration's only job."""
        if step is None:
            return Batch([], levels_planned=levels_planned)
        length = path_length(step[:, 0], step[:, 1])
        start = (float(step[0, 0]), float(step[0, 1]))
        end = (float(step[-1, 0]), float(step[-1, 1]))
        job = Job([Waypoint(float(x), float(y)) for x, y in step], start, end, length, vehicle=0)
        return Batch([job], levels_planned=levels_planned, survey_m=length)

    # -- traces spent at once ----------------------------------------------------------------

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
        area's edge, say, which no sample reaches) that the tracer has already traced."""
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

    # -- the plan ----------------------------------------------------------------------------

    def next_batch(self, context: PlanContext) -> Batch:
        p = self.params
        umap, _ = self.uncertainty(context)
        s = estimated_samples(context)  # what the samples read, with any noise smoothed out
        region = context.region
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

        now = cell_value(umap.variance, dist, np.arange(umap.x_m.size))
        self.open_cells = int(np.count_nonzero(now > 10 * eps))
        cands = [] if context.estimate is None or context.grid is None else (
            contour_candidates(context.estimate, context.grid, levels, p.piece_m,
                               p.min_piece_m, whole=True))
        if p.crossings_first:
            cands = mark_crossings(cands, s, levels, p.band_m,
                                   open_at_end=p.open_entry == OpenEntry.END,
                                   end_m=OPEN_END_M if p.open_entry == OpenEntry.AUTO else 0.0)
        cands = self._unspent(cands)
        if p.probes:
            cands += extremum_probes(s, levels, region, p.probe_m,
                                     probe_prominence(p.probe_prominence, context.noise_std, span),
                                     2.0 * p.resolve_m,
                                     () if p.probe_climb else self._probed,
                                     reach=p.probe_reach)
        if p.sweeps:
            uncovered = open_cells & (dist > p.explore_m)
            cands += sweep_candidates(umap, uncovered, region, sweep_spacing_m(p))
        if context.n_vehicles == 1 and (p.explore == Explore.LINES or (
                p.explore == Explore.AUTO and not self._blind_beside(context))):
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
        # crossing or extremum left that says one is (or may be) there (the extrema not
        # asked for: probes_at_end false)
        if self.open_cells == 0 and not any(
                c.first and (p.probes_at_end or c.kind == CandidateKind.TRACE) for c in cands):
            return Batch([], levels_planned=len(levels), done=True)
        picks, per_vehicle = self._plan(context, umap, cands, now, cell_value,
                                        p.threshold_batch_m, near_m=dist)
        self._probed += [k.candidate.points_m for route in picks for k in route
                         if k.candidate.kind == CandidateKind.LEG and k.candidate.first]
        if not any(picks) and per_vehicle > 0:
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
                                   traces_before_legs=p.first_order == FirstOrder.CROSSINGS)
            # the estimate's component can be far too short while lines are still open
            return self._batch(picks, levels, perimeter)

        traces = [c for c in cands if c.first and c.kind == CandidateKind.TRACE]
        after_trace, self._traced = self._traced, bool(traces)
        if traces:
            return fly_first(traces)
        s = context.samples
        samples_xy = np.column_stack([s.x_m, s.y_m])
        weight = np.ones(len(dist))
        if p.line_weight == LineWeight.P and self.hyper is not None:
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
