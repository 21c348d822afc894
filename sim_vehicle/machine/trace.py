"""The trace task: fly to the start, search, then trace the iso-line leg by leg.

The task calls the other parts as subroutines and decides, after each, what comes next:

* after the search: the first leg, higher values on the left (or ``NOT_FOUND``);
* after a leg that lost the contour: back to where the iso-line was last held and a search
  there (then on slowly for ``recover_m``), at most ``max_reacquire`` times in a row;
* after the first leg met the boundary: an edge walk (:mod:`.walk`) for where an iso-line
  comes back in, traced on the same way; otherwise, or when the walk finds none, back to
  the entry and the second leg the other way;
* after the first leg lost the contour for good, or came onto an earlier trace's track
  (the iso-line goes on both ways from the entry, and only one is known to be traced):
  back to the entry and the second leg the other way;
* after any other end: the task's status and its event.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import fly, leg, search, walk
from .records import (
    BOUNDARY,
    BUDGET,
    CLOSED,
    EV_BOUNDARY,
    EV_BOUNDARY_OTHER,
    EV_BUDGET,
    EV_CLOSED,
    EV_EDGE_FOUND,
    EV_EDGE_WALK,
    EV_FOUND,
    EV_LENGTH_LIMIT,
    EV_LOST,
    EV_LOST_OTHER,
    EV_LOST_SEARCHING,
    EV_NOT_FOUND,
    EV_PRIOR_OTHER,
    EV_REACQUIRED,
    LENGTH_LIMIT,
    LOST,
    NOT_FOUND,
    PC_DONE,
    PC_TR_AFTER_BACKUP,
    PC_TR_AFTER_EDGE_FOUND,
    PC_TR_AFTER_LEG,
    PC_TR_AFTER_REACQUIRE,
    PC_TR_AFTER_RETURN,
    PC_TR_AFTER_SEARCH,
    PC_TR_AFTER_WALK,
    PC_TR_END,
    PC_TR_SEARCH,
    PC_TR_START,
    SEARCHING,
    TRANSIT,
)
from .records import emit as _emit
from .vehicle import edge_ahead_m, shrink_m

REACQUIRE_RESET_M = 40.0
"""A lost trace that held the iso-line this far since its last loss gets ``max_reacquire``
attempts afresh."""
WALK_STOP_M = 0.1
"""The vehicle comes back to within this of where the walk found the level before it
turns onto the iso-line (the walk runs on half a metre per sample)."""


@njit(cache=True)
def tick_budget(params, task, b) -> int:
    """Trace tick budget: ``budget_factor`` region perimeters (plus ``max_length_m``) at
    half the cruise speed."""
    perimeter = 2.0 * ((b.xmax - b.xmin) + (b.ymax - b.ymin))
    budget_m = params.budget_factor * perimeter + max(task.max_length_m, 0.0)
    cruise = min(params.speed_mps, b.max_speed_mps)
    return int(budget_m / (0.5 * cruise) / b.dt_s) + 200


@njit(cache=True)
def trace_tick_budget(body: np.ndarray, state: np.ndarray) -> int:
    """The tick budget of the trace task in ``state`` (sizes its turn-history buffer)."""
    s = state[0]
    return tick_budget(s.params, s.task, body[0])


@njit(cache=True)
def heading_from_gradient(gx: float, gy: float, side: float) -> float:
    """Heading along the iso-line with higher values on the left (side=+1) or right."""
    return math.atan2(-side * gx, side * gy)


@njit(cache=True)
def _after_search(ctl, params, task, cr, tr, lg, b, fv: np.ndarray, fr: np.ndarray,
                  fc: np.ndarray, events: np.ndarray) -> None:
    if not cr.found:
        _emit(ctl, events, EV_NOT_FOUND)
        ctl.status = NOT_FOUND
        ctl.pc = PC_DONE
        return
    _emit(ctl, events, EV_FOUND)
    g0 = max(math.hypot(cr.gx, cr.gy), 1e-9)
    tr.start_x, tr.start_y = cr.x_m, cr.y_m
    tr.away_max = 0.0
    tr.grad_mag = g0
    tr.grad_mag0 = g0
    tr.ticks_left = tick_budget(params, task, b)
    tr.heading0 = heading_from_gradient(cr.gx, cr.gy, 1.0)
    # how far the other sense of tracing runs before it leaves the area
    tr.back_edge_m = edge_ahead_m(b, fv, fr, fc, cr.x_m, cr.y_m, -math.cos(tr.heading0),
                                  -math.sin(tr.heading0))
    tr.reacquired = 0
    tr.has_good = 0
    tr.slow_until_m = 0.0
    tr.lost_at_m = 0.0
    tr.walks = 0
    leg.call_from_crossing(ctl, params, tr, lg, cr, b, tr.heading0, 1.0)


@njit(cache=True)
def _other_way(ctl, params, ft, tr, b, events: np.ndarray, code: int) -> bool:
    """After the first leg ended where the iso-line goes on (lost for good, or onto an
    earlier trace's track): back to the entry and the second leg the other way, as after
    the boundary (unless that way leaves the area at once). False on the second leg."""
    if tr.side < 0.0 or tr.back_edge_m <= params.edge_skip_m:
        return False
    _emit(ctl, events, code)
    tr.reacquired = 0
    fly.call(ctl, ft, b, tr.start_x, tr.start_y, TRANSIT, 0.5, params.transit_speed_mps,
             PC_TR_AFTER_RETURN)
    return True


@njit(cache=True)
def _after_leg(ctl, params, task, ft, cr, sr, tr, lg, wk, b, events: np.ndarray) -> None:
    status = lg.status
    if status == CLOSED and lg.onto_prior and _other_way(ctl, params, ft, tr, b, events,
                                                          EV_PRIOR_OTHER):
        return
    if status == LOST:
        if params.recover_m > 0.0 and ctl.traced_m - tr.lost_at_m > REACQUIRE_RESET_M:
            tr.reacquired = 0  # held the iso-line long enough since the last loss
        tr.lost_at_m = ctl.traced_m
        if tr.reacquired < params.max_reacquire:
            tr.reacquired += 1
            _emit(ctl, events, EV_LOST_SEARCHING)
            if params.recover_m > 0.0 and tr.has_good and (
                    math.hypot(b.x_m - tr.good_x, b.y_m - tr.good_y) > leg.GOOD_OFFSET_M):
                # back to where the iso-line was last held, and on from there slowly
                fly.call(ctl, ft, b, tr.good_x, tr.good_y, SEARCHING, 0.5,
                         params.search_speed_mps, PC_TR_AFTER_BACKUP)
                return
            search.call(ctl, cr, sr, task.level, b.x_m, b.y_m, params.reacquire_radius_m,
                        PC_TR_AFTER_REACQUIRE)
            return
        if _other_way(ctl, params, ft, tr, b, events, EV_LOST_OTHER):
            return
    if status == BOUNDARY and tr.side > 0 and tr.back_edge_m > params.edge_skip_m:
        # before the flight back: along the edge, the area's inside on the left as
        # the higher values were, for where the iso-line (or the next one round
        # the same region) comes back in; never farther than the flight it saves
        walk_m = min(params.edge_walk_m, math.hypot(b.x_m - tr.start_x, b.y_m - tr.start_y))
        edge = walk.walk_edge(b, b.x_m, b.y_m, lg.ux, lg.uy)
        _, _, off, _ = walk.walk_frame(b, edge, b.x_m, b.y_m, params.boundary_margin_m)
        if (walk_m >= walk.WALK_MIN_M and off <= 2.0 * params.boundary_margin_m + 1.0
                and tr.walks < walk.WALK_MAX):
            tr.walks += 1
            _emit(ctl, events, EV_EDGE_WALK)
            walk.call(ctl, wk, walk_m, edge)
            return
        _emit(ctl, events, EV_BOUNDARY_OTHER)
        fly.call(ctl, ft, b, tr.start_x, tr.start_y, TRANSIT, 0.5, params.transit_speed_mps,
                 PC_TR_AFTER_RETURN)
        return
    ctl.status = status
    ctl.pc = PC_TR_END


@njit(cache=True)
def _end(ctl, events: np.ndarray) -> None:
    if ctl.status == BUDGET:
        _emit(ctl, events, EV_BUDGET)
        ctl.status = LOST
    code = EV_LOST
    if ctl.status == CLOSED:
        code = EV_CLOSED
    elif ctl.status == BOUNDARY:
        code = EV_BOUNDARY
    elif ctl.status == LENGTH_LIMIT:
        code = EV_LENGTH_LIMIT
    _emit(ctl, events, code)
    ctl.pc = PC_DONE


@njit(cache=True)
def pre(ctl, params, task, ft, cr, sr, tr, lg, wk, b, fv: np.ndarray, fr: np.ndarray,
        fc: np.ndarray, events: np.ndarray) -> bool:
    """One decision of the trace task: always a call of a part or the end (False; the
    trace itself never commands)."""
    pc = ctl.pc
    if pc == PC_TR_START:
        m = shrink_m(b, 0.5)
        sx = min(max(task.task_x_m, b.xmin + m), b.xmax - m)
        sy = min(max(task.task_y_m, b.ymin + m), b.ymax - m)
        sr.cx, sr.cy = sx, sy
        fly.call(ctl, ft, b, sx, sy, TRANSIT, 1.0, params.transit_speed_mps, PC_TR_SEARCH)
    elif pc == PC_TR_SEARCH:
        search.call(ctl, cr, sr, task.level, sr.cx, sr.cy, task.search_radius_m,
                    PC_TR_AFTER_SEARCH)
    elif pc == PC_TR_AFTER_SEARCH:
        _after_search(ctl, params, task, cr, tr, lg, b, fv, fr, fc, events)
    elif pc == PC_TR_AFTER_LEG:
        _after_leg(ctl, params, task, ft, cr, sr, tr, lg, wk, b, events)
    elif pc == PC_TR_AFTER_WALK:
        if cr.found:
            _emit(ctl, events, EV_EDGE_FOUND)
            tr.has_good, tr.good_x, tr.good_y = 1, cr.x_m, cr.y_m
            # back to the crossing, braking: the walk's speed along the edge would
            # carry the turn onto the iso-line out of the area
            fly.call(ctl, ft, b, cr.x_m, cr.y_m, SEARCHING, WALK_STOP_M,
                     params.search_speed_mps, PC_TR_AFTER_EDGE_FOUND)
        else:
            _emit(ctl, events, EV_BOUNDARY_OTHER)
            fly.call(ctl, ft, b, tr.start_x, tr.start_y, TRANSIT, 0.5,
                     params.transit_speed_mps, PC_TR_AFTER_RETURN)
    elif pc == PC_TR_AFTER_EDGE_FOUND:
        leg.call(ctl, tr, lg, heading_from_gradient(cr.gx, cr.gy, tr.side), tr.side)
    elif pc == PC_TR_AFTER_BACKUP:
        search.call(ctl, cr, sr, task.level, tr.good_x, tr.good_y, params.reacquire_radius_m,
                    PC_TR_AFTER_REACQUIRE)
    elif pc == PC_TR_AFTER_REACQUIRE:
        if cr.found:
            _emit(ctl, events, EV_REACQUIRED)
            if params.recover_m > 0.0:
                tr.slow_until_m = ctl.traced_m + params.recover_m
            leg.call_from_crossing(ctl, params, tr, lg, cr, b,
                                   heading_from_gradient(cr.gx, cr.gy, tr.side), tr.side)
        elif not _other_way(ctl, params, ft, tr, b, events, EV_LOST_OTHER):
            ctl.status = LOST
            ctl.pc = PC_TR_END
    elif pc == PC_TR_AFTER_RETURN:
        tr.away_max = 0.0
        tr.has_good = 0
        tr.slow_until_m = 0.0
        leg.call(ctl, tr, lg, tr.heading0 + math.pi, -1.0)
    elif pc == PC_TR_END:
        _end(ctl, events)
    else:
        raise AssertionError("tracer state machine: unknown program counter")
    return False
