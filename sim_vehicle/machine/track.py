"""The trace's track: a point every metre traced, to tell when the trace comes back onto
its own track or onto an earlier trace's of the same level (see :func:`track_push`)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

TRACK_STEP_M = 1.0
"""The trace keeps a point of its track every this many metres traced (with the
direction it was flown in) to tell when it comes back onto it."""
REJOIN_MIN_COS = 0.5
"""A trace rejoins its track where it comes back within ``closure_radius_m`` of it
flying within 60 degrees of the direction the track was flown in (the other way along
it is the trace's other sense, or the far side of a thin tongue)."""
ONTO_PRIOR = 1
""":func:`track_push`: the trace came onto an earlier trace's track."""
ONTO_OWN = 2
"""... it rejoined its own track."""


@njit(cache=True)
def track_push(ctl, params, tr, tk, track: np.ndarray, prior: np.ndarray, x: float, y: float,
               away_m: float) -> int:
    """Keep a point of the trace's track every ``TRACK_STEP_M`` traced; :data:`ONTO_PRIOR`
    when the new one comes onto ``prior`` (an earlier trace of the level flew there, either
    way), :data:`ONTO_OWN` when it rejoins the trace's own track flown at least
    ``rejoin_min_m`` before, the same way, away from its start (that closure is the start's
    own test), and farther than ``away_m`` from that point since (a trace whose noise could
    circle it on the spot must have left a point to come back to it): the trace has gone
    round a loop that does not pass its start (past a saddle, or after a loss); else 0."""
    if tk.has and ctl.traced_m - tk.m < TRACK_STEP_M:
        return 0
    if tk.len >= track.shape[0]:
        return 0
    ux, uy = 0.0, 0.0  # the first point after a break has no direction
    if tk.has:
        step = math.hypot(x - tk.x, y - tk.y)
        if step > 1e-9:
            ux, uy = (x - tk.x) / step, (y - tk.y) / step
    k = tk.len
    track[k, 0], track[k, 1], track[k, 2], track[k, 3], track[k, 4] = (x, y, ctl.traced_m,
                                                                       ux, uy)
    tk.len += 1
    tk.has, tk.x, tk.y, tk.m = 1, x, y, ctl.traced_m
    if ux == 0.0 and uy == 0.0:
        return 0
    r = params.closure_radius_m
    for i in range(prior.shape[0]):  # a track an earlier trace of this level flew
        if (math.hypot(prior[i, 0] - x, prior[i, 1] - y) <= r
                and abs(prior[i, 3] * ux + prior[i, 4] * uy) >= REJOIN_MIN_COS):
            return ONTO_PRIOR
    before_m = ctl.traced_m - params.rejoin_min_m
    for i in range(k):
        if track[i, 2] > before_m:
            break
        if (math.hypot(track[i, 0] - x, track[i, 1] - y) <= r
                and track[i, 3] * ux + track[i, 4] * uy >= REJOIN_MIN_COS
                and math.hypot(track[i, 0] - tr.start_x, track[i, 1] - tr.start_y) > r
                and (away_m <= 0.0 or _went_away(track, i, k, away_m))):
            return ONTO_OWN
    return 0


@njit(cache=True)
def _went_away(track: np.ndarray, i: int, k: int, away_m: float) -> bool:
    """Whether the track went farther than ``away_m`` from its point ``i`` between it and
    point ``k`` (a trace circling on the spot passes its own track again and again
    without going round anything)."""
    for j in range(i + 1, k):
        if math.hypot(track[j, 0] - track[i, 0], track[j, 1] - track[i, 1]) > away_m:
            return True
    return False
