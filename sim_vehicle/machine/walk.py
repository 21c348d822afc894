"""The edge walk: at the area's boundary, along the edge for where an iso-line comes back in.

On the first leg of a trace that meets the boundary the vehicle walks along the edge,
``boundary_margin_m`` inside, counterclockwise round the area (the higher values stay on
its left, inside the region the trace kept there), for where the field falls through the
level again: an iso-line comes in there (the same one when the region above the level
only bulges over the edge), and the trace goes on from that crossing. The walk goes no
farther than the flight back to the entry it would save, and gives up when a parabola
through the highest value it read along the edge reaches the level only beyond that (a
front's plateau).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..fence import fence_ray_exit
from .crossing import found_at, remember
from .fits import fit_gradient
from .noise import noise_std
from .records import PC_TR_AFTER_WALK, PC_WK, PC_WK_START, SEARCHING
from .records import command as _command

WALK_MIN_M = 2.0
"""An edge walk shorter than this (the flight back it would save is that short) is not
begun."""
WALK_PEAK_M = 2.0
"""The edge walk judges where the field comes back down to the level once it has walked
this far past the highest value it read."""
WALK_CORNER_M = 0.5
"""The edge walk turns the corner this close to it (along the inset edge)."""
WALK_MAX = 6
"""Edge walks a trace task may make (each found piece can lead to the next edge; on a
field at the level everywhere, noise would keep finding it)."""
WALK_GAIN_HZ = 1.0
"""Gain of the edge walk's hold on its inset from the edge (m/s per m)."""


@njit(cache=True)
def walk_edge(b, x: float, y: float, ux: float, uy: float) -> int:
    """The edge of the area that heading ``(ux, uy)`` from ``(x, y)`` runs into (0 south,
    1 east, 2 north, 3 west); the nearest edge for a heading along none."""
    best, edge = math.inf, -1
    if uy < -1e-12 and (b.ymin - y) / uy < best:
        best, edge = (b.ymin - y) / uy, 0
    if ux > 1e-12 and (b.xmax - x) / ux < best:
        best, edge = (b.xmax - x) / ux, 1
    if uy > 1e-12 and (b.ymax - y) / uy < best:
        best, edge = (b.ymax - y) / uy, 2
    if ux < -1e-12 and (b.xmin - x) / ux < best:
        best, edge = (b.xmin - x) / ux, 3
    if edge < 0:
        off = (y - b.ymin, b.xmax - x, b.ymax - y, x - b.xmin)
        edge = 0
        for k in range(1, 4):
            if off[k] < off[edge]:
                edge = k
    return edge


@njit(cache=True)
def walk_frame(b, edge: int, x: float, y: float, inset: float
               ) -> tuple[float, float, float, float]:
    """Along ``edge``, counterclockwise round the area (its inside on the left): the unit
    tangent, the distance from the edge and how far ahead the walk's inset line meets
    the next edge's."""
    if edge == 0:
        return 1.0, 0.0, y - b.ymin, b.xmax - inset - x
    if edge == 1:
        return 0.0, 1.0, b.xmax - x, b.ymax - inset - y
    if edge == 2:
        return -1.0, 0.0, b.ymax - y, x - (b.xmin + inset)
    return 0.0, -1.0, x - b.xmin, y - (b.ymin + inset)


@njit(inline="always")
def call(ctl, wk, walk_m: float, edge: int) -> None:
    """Walk along ``edge`` for up to ``walk_m``; then on at the trace's ``PC_TR_AFTER_WALK``
    with ``cross.found`` saying whether an iso-line came in."""
    wk.len_m = walk_m
    wk.edge = edge
    ctl.pc = PC_WK_START


@njit(cache=True)
def pre(ctl, params, task, cr, tr, wk, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray
        ) -> bool:
    """One step of the walk: a command (True), or its start or end (False)."""
    if ctl.pc == PC_WK_START:
        wk.odo0_m = b.odometer_m
        wk.k = 0
        v_walk = min(params.search_speed_mps, b.max_speed_mps)
        wk.k_max = int(3.0 * (wk.len_m / max(v_walk, 0.1) + 10.0) / b.dt_s) + 100
        cr.has_prev = 0
        cr.found = 0
        cr.level = task.level
        cr.ret = PC_TR_AFTER_WALK
        wk.emax = 0.0
        wk.smax = 0.0
        wk.cross = 0
        wk.de = 0.0
        ctl.pc = PC_WK
        return False
    inset = params.boundary_margin_m
    tx, ty, off, ahead = walk_frame(b, wk.edge, b.x_m, b.y_m, inset)
    if ahead <= WALK_CORNER_M:  # round the corner
        wk.edge = (wk.edge + 1) % 4
        tx, ty, off, ahead = walk_frame(b, wk.edge, b.x_m, b.y_m, inset)
    blocked = False
    if fr.shape[0] > 0 or fc.shape[0] > 0:  # the fence across the way
        blocked = (fence_ray_exit(fv, fr, fc, b.x_m, b.y_m, tx, ty) - b.fence_margin_m
                   < min(ahead, 2.0 * inset))
    if (blocked or b.odometer_m - wk.odo0_m >= wk.len_m or wk.k >= wk.k_max
            or tr.ticks_left <= 0):
        cr.found = 0
        ctl.pc = PC_TR_AFTER_WALK
        return False
    wk.k += 1
    tr.ticks_left -= 1
    v = min(params.search_speed_mps, b.max_speed_mps,
            math.sqrt(2.0 * 0.5 * b.max_accel_mps2 * max(ahead, 0.0)) + 0.5)
    if cr.has_prev and wk.de < 0.0:  # coming down to the level: slow, as a search
        v = min(v, max(params.approach_speed_mps, params.approach_gain_hz * wk.e / -wk.de))
    lat = max(-v, min(v, WALK_GAIN_HZ * (inset - off)))  # > 0: inward
    return _command(ctl, v * tx - lat * ty, v * ty + lat * tx, SEARCHING)


@njit(cache=True)
def post(ctl, params, task, cr, tr, wk, b, recent: np.ndarray, x: float, y: float, v: float
         ) -> None:
    """What the walk does with the sample its command produced."""
    # the walk runs inside the region the trace kept on its left: where the field
    # falls through the level again (and not within WALK_MIN_M / 2 of where the
    # walk began, where it crosses the level the trace left), an iso-line comes in
    walked = b.odometer_m - wk.odo0_m
    e1 = tr.side * (v - task.level)
    if cr.has_prev:
        e0 = tr.side * (cr.prev_v - task.level)
        sx, sy = x - cr.prev_x, y - cr.prev_y
        step = math.hypot(sx, sy)
        if step > 1e-9:
            wk.de = (e1 - e0) / step
        if e0 > 0.0 and e1 <= 0.0:  # down through the level: an iso-line comes in
            t = e0 / (e0 - e1)
            cx, cy = cr.prev_x + t * sx, cr.prev_y + t * sy
            # the walk's samples lie on one line: a plane fit cannot tell the gradient
            # across it, so the derivative along the walk stands for it (the trace then
            # sets off square to the edge and the controller turns it): the last step's,
            # or with noisy readings the slope fitted over the recent samples (one step's
            # difference is mostly noise), where it agrees with the crossing's sense
            step = max(step, 1e-9)
            along = (v - cr.prev_v) / step
            noise = noise_std(b)
            if noise > 0.0:
                fx, fy, _ = fit_gradient(recent, ctl.rec_start, ctl.rec_len,
                                         params.gradient_window, 1e-4, noise)
                along_fit = (fx * sx + fy * sy) / step
                if along_fit * along > 0.0:
                    along = along_fit
            gx, gy = along * sx / step, along * sy / step
            if walked >= WALK_MIN_M:
                found_at(ctl, cr, cx, cy, gx, gy)
                return
            # this near where the walk began it may be the level the trace left,
            # read again through noise: taken once the walk stays below it
            wk.cross, wk.cx, wk.cy, wk.gx, wk.gy = 1, cx, cy, gx, gy
        elif e0 <= 0.0 < e1:
            wk.cross = 0
    wk.e = e1
    remember(cr, x, y, v)
    if walked >= WALK_MIN_M and e1 <= 0.0:
        if wk.cross:
            found_at(ctl, cr, wk.cx, wk.cy, wk.gx, wk.gy)
        elif walked >= 2.0 * WALK_MIN_M:  # below the level all along: not this side
            cr.found = 0
            ctl.pc = PC_TR_AFTER_WALK
        return
    # Where will the field along the edge come back down to the level? Past its
    # highest point the profile is taken for a parabola through that top: a bump's
    # edge comes back in soon, a plateau's (a front, a wide high ground) not within
    # the walk, which then gives up instead of running out its length.
    if e1 >= wk.emax:
        wk.emax, wk.smax = e1, walked
        ret = 2.0 * walked  # still rising: at least as far again
    elif walked - wk.smax >= WALK_PEAK_M:
        drop = wk.emax - e1
        ret = wk.smax + (walked - wk.smax) * math.sqrt(wk.emax / drop)
    else:
        ret = 0.0
    if ret > wk.len_m:
        cr.found = 0
        ctl.pc = PC_TR_AFTER_WALK
