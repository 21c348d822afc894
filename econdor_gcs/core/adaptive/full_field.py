"""The adaptive planner for the whole field: fly where the estimate is most uncertain, per
metre.

Each iteration it models how uncertain the estimate still is (a unit posterior variance
``v(x)`` from where the samples are, times an amplitude that grows with the local
steepness of the estimate and never falls below a floor), lists candidate paths — contour
pieces of the estimate at ``levels`` levels (traced onboard), exploration legs through
the most uncertain places and full-width lines — and picks greedily by expected squared
error removed per metre (:func:`~.greedy.greedy_plan`), ``f(v) = a^2 v`` by default.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..candidates import Candidate, contour_candidates
from ..geometry import FloatArray
from ..planners import Batch, PlanContext
from ..uncertainty import expected_error
from .base import AdaptivePlanner


class FullFieldPlanner(AdaptivePlanner):
    """The adaptive planner mapping the whole field (``target_levels`` empty)."""

    def next_batch(self, context: PlanContext) -> Batch:
        p = self.params
        umap, _ = self.uncertainty(context)
        amp = umap.amplitude

        def cell_value(var: FloatArray, near: FloatArray, cells: NDArray[np.intp]
                       ) -> FloatArray:
            return expected_error(amp[cells], var, p.power)

        now = expected_error(amp, umap.variance, p.power)
        levels = np.zeros(0)
        cands: list[Candidate] = []
        if context.estimate is not None and context.grid is not None:
            lo, hi = np.quantile(context.estimate, [0.005, 0.995])
            levels = np.linspace(lo, hi, p.levels + 2)[1:-1]
            cands = contour_candidates(context.estimate, context.grid, levels, p.piece_m,
                                       p.min_piece_m)
        picks, _ = self._plan(context, umap, cands, now, cell_value, p.batch_m)
        return self._batch(picks, levels)
