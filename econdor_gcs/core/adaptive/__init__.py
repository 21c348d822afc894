"""The adaptive planner: fly where the estimate is most uncertain, per metre.

It starts (``start: auto``) with an even survey of ``start_lines`` north-south lines: 16
when mapping the whole field, one in threshold mode. Each iteration after that the planner

1. models how uncertain the estimate still is (:mod:`econdor_gcs.core.uncertainty`): a
   unit posterior variance ``v(x)`` from where the samples are, times an amplitude that
   grows with the local steepness of the estimate and never falls below a floor;
2. lists candidate paths: contour pieces of the estimate at many levels (traced onboard,
   like E-CONDOR's pieces), straight legs through the most uncertain places, and
   full-width lines (see :mod:`econdor_gcs.core.candidates`);
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

Two planners share that loop (:class:`~.base.AdaptivePlanner`): :class:`FullFieldPlanner`
maps the whole field, by expected squared error (:mod:`.full_field`);
:class:`ThresholdPlanner` maps the iso-lines at ``target_levels`` only, by the straddle
score and a coverage floor (:mod:`.threshold`). :func:`adaptive_planner` builds the one
the settings (:class:`AdaptiveParams`, :mod:`.params`) ask for; the greedy selection is
:mod:`.greedy`.

Every job is an ordinary trace task (``TraceTask``) or a pair of waypoints, so the plan
flies over MAVLink exactly like E-CONDOR's; contour pieces are traced by the vehicle's
own tracer, not flown as planned polylines.
"""

from __future__ import annotations

from .base import AdaptivePlanner, perimeter_batch, start_route, survey_start_batch
from .full_field import FullFieldPlanner
from .greedy import Pick, greedy_plan, shorten_route
from .params import (
    MODES,
    AdaptiveParams,
    Explore,
    FirstOrder,
    LineOrientation,
    LineWeight,
    Model,
    OpenEntry,
    Start,
)
from .threshold import ThresholdPlanner, sweep_spacing_m

__all__ = [
    "MODES", "AdaptiveParams", "AdaptivePlanner", "Explore", "FirstOrder", "FullFieldPlanner",
    "LineOrientation", "LineWeight", "Model", "OpenEntry", "Pick", "Start", "ThresholdPlanner",
    "adaptive_planner", "greedy_plan", "perimeter_batch", "shorten_route", "start_route",
    "survey_start_batch", "sweep_spacing_m",
]


def adaptive_planner(params: AdaptiveParams = AdaptiveParams(), seed: int = 0  # noqa: B008
                     ) -> AdaptivePlanner:
    """The adaptive planner ``params`` ask for: threshold mapping when they give
    ``target_levels``, else the whole field.

    >>> type(adaptive_planner(AdaptiveParams(target_levels=(55.0,)))).__name__
    'ThresholdPlanner'
    >>> adaptive_planner().params.start_lines  # start: auto, a survey of 16 lines
    16
    """
    if params.target_levels:
        return ThresholdPlanner(params, seed)
    return FullFieldPlanner(params, seed)
