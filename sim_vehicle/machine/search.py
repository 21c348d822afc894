"""The search for a level near a point: probe legs, a descent along the fitted gradient,
and an Archimedean spiral when that fails.

After flying to its start the vehicle takes a short probe leg across its arrival direction
(two if the samples are still on a line), fits a plane to its recent samples and flies
down (or up) the gradient toward the level, slowing as the predicted distance shrinks.
If that fails (flat field, wrong way, left the search disc) it flies a spiral round the
start point out to the search radius. The level is found by the crossing detector
(:mod:`.crossing`) on every sample of all three.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..fence import fence_ray_exit
from .crossing import bracketed, remember
from .fits import fit_gradient
from .records import (
    PC_SR_DESCENT,
    PC_SR_DESCENT_START,
    PC_SR_PROBE,
    PC_SR_PROBE_START,
    PC_SR_SPIRAL,
    PC_SR_SPIRAL_START,
    SEARCHING,
)
from .records import command as _command
from .vehicle import contains, edge_ahead_m, ray_to_edge_m, shrink_m

PROBE_BLOCKED_M = 0.1
"""A probe leg ends this close to the area boundary (or the fence margin) ahead."""


@njit(inline="always")
def call(ctl, cr, sr, level: float, cx: float, cy: float, radius: float, ret: int) -> None:
    """Search for ``level`` round ``(cx, cy)`` within ``radius``; then go on at ``ret``
    with ``cr.found`` saying whether it was found."""
    cr.level = level
    sr.cx = cx
    sr.cy = cy
    sr.radius_m = max(radius, 0.0)
    cr.ret = ret
    cr.found = 0
    cr.gain = 1.0
    sr.probe_k = 0
    ctl.pc = PC_SR_PROBE_START


@njit(cache=True)
def _spiral_point(sr, b, th: float) -> tuple[float, float]:
    m = shrink_m(b, 0.5)
    r = sr.pitch * th
    x = sr.cx + r * math.cos(th + sr.phi0)
    y = sr.cy + r * math.sin(th + sr.phi0)
    return min(max(x, b.xmin + m), b.xmax - m), min(max(y, b.ymin + m), b.ymax - m)


@njit(cache=True)
def _probe_start(ctl, params, cr, sr, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray,
                 recent: np.ndarray) -> None:
    if sr.probe_k == 0:
        v_search = min(params.search_speed_mps, b.max_speed_mps)
        sr.v_search = v_search
        sr.v_min = min(params.approach_speed_mps, v_search)
        if ctl.rec_len > 0:
            k = (ctl.rec_start + ctl.rec_len - 1) % recent.shape[0]
            cr.has_prev = 1
            cr.prev_x, cr.prev_y, cr.prev_v = recent[k, 0], recent[k, 1], recent[k, 2]
            cr.prev_vf = cr.prev_v
        else:
            cr.has_prev = 0
        # probe: a short leg across the arrival direction (two if still degenerate)
        sr.arrival = 0.0
        if ctl.rec_len >= 2:
            k1 = (ctl.rec_start + ctl.rec_len - 1) % recent.shape[0]
            k0 = (ctl.rec_start + ctl.rec_len - 2) % recent.shape[0]
            dx = recent[k1, 0] - recent[k0, 0]
            dy = recent[k1, 1] - recent[k0, 1]
            if math.hypot(dx, dy) > 1e-6:
                sr.arrival = math.atan2(dy, dx)
    elif sr.probe_k >= 2:
        ctl.pc = PC_SR_DESCENT_START
        return
    else:
        _, _, spread = fit_gradient(recent, ctl.rec_start, ctl.rec_len,
                                    params.gradient_window)
        if spread >= params.min_spread_m:
            ctl.pc = PC_SR_DESCENT_START
            return
    ang = sr.arrival + 0.5 * math.pi if sr.probe_k == 0 else sr.arrival
    ux, uy = math.cos(ang), math.sin(ang)
    # turn toward the interior if the leg would leave the region (unless the other
    # way has even less room: just outside the shrunk region both are 0)
    m = shrink_m(b, 0.5)
    ahead = ray_to_edge_m(b.xmin + m, b.xmax - m, b.ymin + m, b.ymax - m, b.x_m, b.y_m, ux, uy)
    if fr.shape[0] > 0 or fc.shape[0] > 0:
        ahead = min(ahead, fence_ray_exit(fv, fr, fc, b.x_m, b.y_m, ux, uy) - b.fence_margin_m)
    if ahead < 2.0 * params.probe_leg_m and (
            edge_ahead_m(b, fv, fr, fc, b.x_m, b.y_m, -ux, -uy)
            >= edge_ahead_m(b, fv, fr, fc, b.x_m, b.y_m, ux, uy)):
        ux, uy = -ux, -uy
    sr.probe_ux, sr.probe_uy = ux, uy
    sr.probe_x0, sr.probe_y0 = b.x_m, b.y_m
    sr.v_probe = max(sr.v_min, 0.5 * sr.v_search)
    sr.probe_j = 0
    sr.probe_n = int(10.0 / b.dt_s)
    ctl.pc = PC_SR_PROBE


@njit(cache=True)
def _spiral_start(ctl, params, cr, sr, b) -> None:
    # expanding Archimedean spiral around the start point, one turn from r = step out to
    # r = 2 step, ...; the step never more than half the search radius, so a disc
    # narrower than two spiral spacings still gets a turn
    r = sr.radius_m
    step = min(params.spiral_spacing_m, 0.5 * r)
    if step <= 0.0:  # a search radius of 0: no disc to search
        cr.found = 0
        ctl.pc = cr.ret
        return
    sr.pitch = step / (2.0 * math.pi)
    sr.phi0 = math.atan2(b.y_m - sr.cy, b.x_m - sr.cx)
    sr.theta = 2.0 * math.pi
    sr.sp_max = int((math.pi * r**2 / step + 4.0 * r + 50.0) / (0.5 * sr.v_min) / b.dt_s) + 100
    sr.sp_k = 0
    ctl.pc = PC_SR_SPIRAL


@njit(cache=True)
def pre(ctl, params, cr, sr, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray,
        recent: np.ndarray) -> bool:
    """One step of the search: a command (True), or a move to another step or back to
    the caller (False)."""
    pc = ctl.pc
    if pc == PC_SR_PROBE_START:
        _probe_start(ctl, params, cr, sr, b, fv, fr, fc, recent)
        return False
    if pc == PC_SR_PROBE:
        if sr.probe_j >= sr.probe_n or (
                math.hypot(b.x_m - sr.probe_x0, b.y_m - sr.probe_y0) >= params.probe_leg_m) or (
                edge_ahead_m(b, fv, fr, fc, b.x_m, b.y_m, sr.probe_ux, sr.probe_uy)
                < PROBE_BLOCKED_M):
            sr.probe_k += 1
            ctl.pc = PC_SR_PROBE_START
            return False
        sr.probe_j += 1
        return _command(ctl, sr.v_probe * sr.probe_ux, sr.v_probe * sr.probe_uy, SEARCHING)
    if pc == PC_SR_DESCENT_START:
        # gradient descent toward the level
        sr.best = math.inf
        sr.since_best = 0
        sr.path0 = b.odometer_m - ctl.odo0_m
        sr.max_path = 3.0 * sr.radius_m + 10.0
        ctl.pc = PC_SR_DESCENT
        return False
    if pc == PC_SR_DESCENT:
        if not cr.has_prev:
            ctl.pc = PC_SR_SPIRAL_START
            return False
        gx, gy, _ = fit_gradient(recent, ctl.rec_start, ctl.rec_len,
                                 max(params.gradient_window, 30))
        gn = math.hypot(gx, gy)
        e = cr.prev_vf - cr.level
        if gn < 1e-9:
            ctl.pc = PC_SR_SPIRAL_START
            return False
        sgn = -1.0 if e > 0 else 1.0
        ux, uy = sgn * gx / gn, sgn * gy / gn
        pred_m = abs(e) / gn
        v = min(max(params.approach_gain_hz * pred_m, sr.v_min), sr.v_search)
        return _command(ctl, v * ux, v * uy, SEARCHING)
    if pc == PC_SR_SPIRAL_START:
        _spiral_start(ctl, params, cr, sr, b)
        return False
    # PC_SR_SPIRAL
    lookahead_m = 2.0
    if sr.sp_k >= sr.sp_max or sr.pitch * sr.theta > sr.radius_m:
        cr.found = 0
        ctl.pc = cr.ret
        return False
    sr.sp_k += 1
    px, py = _spiral_point(sr, b, sr.theta)
    while (math.hypot(px - b.x_m, py - b.y_m) < lookahead_m
           and sr.pitch * sr.theta <= sr.radius_m):
        r = sr.pitch * sr.theta
        sr.theta += 0.3 / math.hypot(r, sr.pitch)
        px, py = _spiral_point(sr, b, sr.theta)
    r = sr.pitch * sr.theta
    v = min(sr.v_search, max(sr.v_min, math.sqrt(0.5 * b.max_accel_mps2 * r)))
    ex, ey = px - b.x_m, py - b.y_m
    dist = math.hypot(ex, ey)
    if dist < 1e-9:
        sr.theta += 0.3 / math.hypot(r, sr.pitch)
        return False
    return _command(ctl, v * ex / dist, v * ey / dist, SEARCHING)


@njit(cache=True)
def post(ctl, params, cr, sr, b, recent: np.ndarray, x: float, y: float, v: float) -> None:
    """What the search does with the sample its command produced."""
    if ctl.pc != PC_SR_DESCENT:  # probe legs and the spiral
        if not bracketed(ctl, params, cr, b, recent, x, y, v):
            remember(cr, x, y, v)
        return
    if bracketed(ctl, params, cr, b, recent, x, y, v):
        return
    remember(cr, x, y, v)
    err = abs(cr.vf - cr.level)
    if err < sr.best * 0.999:
        sr.best, sr.since_best = err, 0
    else:
        sr.since_best += 1
    m = shrink_m(b, 0.5)
    if (sr.since_best > 20 or math.hypot(x - sr.cx, y - sr.cy) > sr.radius_m
            or (b.odometer_m - ctl.odo0_m) - sr.path0 > sr.max_path
            or not contains(b.xmin + m, b.xmax - m, b.ymin + m, b.ymax - m, x, y)):
        ctl.pc = PC_SR_SPIRAL_START
