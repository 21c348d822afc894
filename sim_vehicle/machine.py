"""The onboard tracer as a compiled state machine (numba, cached on disk).

This is the one implementation of the vehicle's flight logic: fly to a point, search
for a level near a start point, trace the iso-line (see :mod:`sim_vehicle.tracer` for
what the controller does and :class:`~sim_vehicle.tracer.TracerParams` for its tuning).
:func:`advance` runs a task for up to ``n`` sensor ticks and stops, keeping everything
it needs to go on in two numpy records:

``body`` (:data:`BODY`)
    The simulated vehicle: point-mass state, sim clock, limits and region. It belongs
    to a :class:`~sim_vehicle.body.SimBody` and outlives tasks.
``st`` (:data:`STATE`)
    One task: its parameters, the program counter ``pc`` and the locals of the search,
    trace and fly-to loops, plus four sample buffers passed beside it (the task's
    recent samples, the trace leg's window, the leg's turn history, the trace's track).

Each tick is ``_pre`` (checks and transitions that take no time, ending in a velocity
command), the kinematic sub-steps, a sensor reading and ``_post`` (what the loop does
with the new sample). The reading comes from the compiled Gaussian sum when the field
is one; for any other field ``advance`` returns after moving with ``st.await_value``
set, the caller reads the field at the body's position and calls again with the value.
The Python generators of :mod:`sim_vehicle.tracer` drive this one tick at a time (the
MAVLink vehicle); the in-process executor drives it thousands of ticks per call.

Events (contour found, lost, ...) are written to an ``events`` buffer as
``(code, samples produced before it)`` so an adapter can replay them between the
samples where they happened.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numba import njit
from numba.core.registry import CPUDispatcher

from econdor_gcs.core import fields as _fields
from econdor_gcs.core.fields import gaussian_sum_at

from . import fence as _fence
from . import kinematics as _kinematics
from . import sensor as _sensor
from .fence import FENCE_HARD_MARGIN_M, fence_contains, fence_ray_exit
from .kinematics import point_step, wrap_angle_rad
from .sensor import gnss_step, sensed_value

log = logging.getLogger(__name__)

# ----------------------------------------------------------------------------- records

BODY = np.dtype([
    ("x_m", "f8"), ("y_m", "f8"), ("vx_mps", "f8"), ("vy_mps", "f8"), ("odometer_m", "f8"),
    ("last_heading_rad", "f8"), ("ticks", "i8"), ("t0_s", "f8"), ("dt_s", "f8"), ("n_sub", "i8"),
    ("max_speed_mps", "f8"), ("max_accel_mps2", "f8"), ("max_turn_rate_dps", "f8"),
    ("xmin", "f8"), ("xmax", "f8"), ("ymin", "f8"), ("ymax", "f8"),
    # the guard (see _guard): fence margin, breach attempts and breaches, hard brakes
    ("fence_margin_m", "f8"), ("fence_limited", "i8"), ("fence_attempts", "i8"),
    ("fence_last_tick", "i8"), ("fence_outside", "i8"), ("fence_breaches", "i8"),
    ("fence_event_tick", "i8"), ("fence_stuck", "i8"), ("guard_brakes", "i8"),
])
"""The simulated vehicle's state (one record, shared by Python and compiled code)."""

_F = "f8"
_I = "i8"
STATE = np.dtype([
    # the task
    ("kind", _I), ("level", _F), ("task_x_m", _F), ("task_y_m", _F), ("search_radius_m", _F),
    ("max_length_m", _F), ("wp_phase", _I), ("wp_tolerance_m", _F), ("wp_speed_mps", _F),
    # TracerParams
    ("speed_mps", _F), ("transit_speed_mps", _F), ("closure_radius_m", _F),
    ("closure_min_away_m", _F), ("search_speed_mps", _F), ("approach_speed_mps", _F),
    ("approach_gain_hz", _F), ("probe_leg_m", _F), ("spiral_spacing_m", _F),
    ("trace_bandwidth_rps", _F), ("trace_accel_mps2", _F), ("lateral_accel_fraction", _F),
    ("filter_alpha", _F), ("filter_beta", _F), ("gradient_window", _I), ("min_spread_m", _F),
    ("boundary_margin_m", _F), ("lost_offset_m", _F), ("lost_time_s", _F),
    ("reacquire_radius_m", _F), ("max_reacquire", _I), ("min_loop_radius_m", _F),
    ("budget_factor", _F), ("edge_skip_m", _F), ("recover_speed_mps", _F), ("recover_m", _F),
    ("edge_walk_m", _F), ("rejoin_min_m", _F),
    # control
    ("pc", _I), ("status", _I), ("await_value", _I), ("cmd_vx", _F), ("cmd_vy", _F),
    ("cmd_phase", _I), ("odo_before", _F), ("area_guard", _I),
    # meter: the whole task
    ("odo0_m", _F), ("traced_m", _F), ("rec_start", _I), ("rec_len", _I),
    # fly_to
    ("ft_x", _F), ("ft_y", _F), ("ft_phase", _I), ("ft_tol", _F), ("ft_speed", _F),
    ("ft_k", _I), ("ft_max", _I), ("ft_ok", _I), ("ft_ret", _I),
    # search
    ("sr_level", _F), ("sr_cx", _F), ("sr_cy", _F), ("sr_radius", _F), ("sr_ret", _I),
    ("has_prev", _I), ("prev_x", _F), ("prev_y", _F), ("prev_v", _F),
    ("v_search", _F), ("v_min", _F), ("probe_k", _I), ("arrival", _F), ("probe_ux", _F),
    ("probe_uy", _F), ("probe_x0", _F), ("probe_y0", _F), ("v_probe", _F), ("probe_j", _I),
    ("probe_n", _I), ("best", _F), ("since_best", _I), ("path0", _F), ("max_path", _F),
    ("pitch", _F), ("phi0", _F), ("theta", _F), ("sp_k", _I), ("sp_max", _I),
    ("found", _I), ("f_x", _F), ("f_y", _F), ("f_gx", _F), ("f_gy", _F),
    # trace leg (LegState and the leg's locals)
    ("start_x", _F), ("start_y", _F), ("away_max", _F), ("grad_mag", _F), ("grad_mag0", _F),
    ("ticks_left", _I), ("leg_heading", _F), ("side", _F), ("psi", _F), ("kappa", _F),
    ("lspeed", _F), ("d_f", _F), ("dd_f", _F), ("lost_s", _F), ("has_prev_dist", _I),
    ("prev_dist", _F), ("n_fit", _I), ("turned", _F), ("th_start", _I), ("th_len", _I),
    ("turn_k", _I), ("turn_n", _I), ("ux", _F), ("uy", _F), ("heading_before", _F),
    ("leg_status", _I), ("win_start", _I), ("win_len", _I),
    # trace orchestration
    ("heading0", _F), ("reacquired", _I), ("back_edge_m", _F),
    ("has_good", _I), ("good_x", _F), ("good_y", _F), ("slow_until_m", _F), ("lost_at_m", _F),
    # edge walk
    ("wk_edge", _I), ("wk_len", _F), ("wk_odo", _F), ("wk_k", _I), ("wk_max", _I),
    ("wk_emax", _F), ("wk_smax", _F), ("wk_cross", _I), ("wk_cx", _F), ("wk_cy", _F),
    ("wk_gx", _F), ("wk_gy", _F), ("wk_count", _I), ("wk_e", _F), ("wk_de", _F),
    # the trace's track (see _track_push)
    ("tk_len", _I), ("tk_has", _I), ("tk_x", _F), ("tk_y", _F), ("tk_m", _F),
])
"""One task's state (parameters, program counter, loop locals)."""

RECENT_SAMPLES = 40
"""Recent samples a task keeps for its gradient fits (``x, y, value`` rows)."""

# task kinds
KIND_FLY_TO = 1
KIND_TRACE = 2

# statuses (see STATUS_NAMES)
REACHED, UNREACHABLE, CLOSED, BOUNDARY, LENGTH_LIMIT, NOT_FOUND, LOST, BUDGET = range(1, 9)
STATUS_NAMES = {REACHED: "reached", UNREACHABLE: "unreachable", CLOSED: "closed",
                BOUNDARY: "boundary", LENGTH_LIMIT: "length_limit", NOT_FOUND: "not_found",
                LOST: "lost", BUDGET: "budget"}

# events (see sim_vehicle.tracer.TracerEvent)
(EV_FOUND, EV_NOT_FOUND, EV_LOST_SEARCHING, EV_REACQUIRED, EV_BOUNDARY_OTHER, EV_BUDGET,
 EV_CLOSED, EV_BOUNDARY, EV_LENGTH_LIMIT, EV_LOST, EV_FENCE, EV_EDGE_WALK,
 EV_EDGE_FOUND) = range(1, 14)

# the guard
GUARD_SOFT_ACCEL_FRACTION = 0.7
"""The guard's soft limit slows a command so that the vehicle could stop before the
boundary ahead with this fraction of its acceleration limit (the fly-to brakes with 0.6,
so a fly-to to a point inside is never slowed by it)."""
AREA_HARD_MARGIN_M = 1e-3
"""A trace task can always stop at least this far inside the mission area."""
FENCE_STUCK_S = 2.0
"""A fly-to held at the fence this long (command and speed near zero) gives up."""
PROBE_BLOCKED_M = 0.1
"""A probe leg ends this close to the area boundary (or the fence margin) ahead."""
REACQUIRE_RESET_M = 40.0
"""A lost trace that held the iso-line this far since its last loss gets ``max_reacquire``
attempts afresh."""
GOOD_OFFSET_M = 1.0
"""A trace sample within this lateral offset of the level is where a lost trace resumes
(searched for where the vehicle is when it is already within this distance of it)."""
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
WALK_STOP_M = 0.1
"""The vehicle comes back to within this of where the walk found the level before it
turns onto the iso-line (the walk runs on half a metre per sample)."""
WALK_GAIN_HZ = 1.0
"""Gain of the edge walk's hold on its inset from the edge (m/s per m)."""
TRACK_STEP_M = 1.0
"""The trace keeps a point of its track every this many metres traced (with the
direction it was flown in) to tell when it comes back onto it."""
REJOIN_MIN_COS = 0.5
"""A trace rejoins its track where it comes back within ``closure_radius_m`` of it
flying within 60 degrees of the direction the track was flown in (the other way along
it is the trace's other sense, or the far side of a thin tongue)."""
FENCE_EPISODE_GAP_S = 1.0
"""Fence limiting after this long without any counts as a new breach attempt."""

# program counter
PC_DONE = 0
PC_FT = 1
PC_SR_PROBE_START = 10
PC_SR_PROBE = 11
PC_SR_DESCENT_START = 12
PC_SR_DESCENT = 13
PC_SR_SPIRAL_START = 14
PC_SR_SPIRAL = 15
PC_LEG_START = 20
PC_LEG_TURN = 21
PC_LEG_MAIN_START = 22
PC_LEG_MAIN = 23
PC_TR_START = 30
PC_TR_SEARCH = 31
PC_TR_AFTER_SEARCH = 32
PC_TR_AFTER_LEG = 33
PC_TR_AFTER_REACQUIRE = 34
PC_TR_AFTER_RETURN = 35
PC_TR_END = 36
PC_FT_END = 37
PC_TR_AFTER_BACKUP = 38
PC_WK_START = 40
PC_WK = 41
PC_TR_AFTER_WALK = 42
PC_TR_AFTER_EDGE_FOUND = 43

# phases (econdor_gcs.core.tasks.Phase)
_TRANSIT, _SEARCH, _TRACE = 0, 1, 2

_TWO_PI = 2.0 * math.pi


# ----------------------------------------------------------------------------- body


@njit(cache=True)
def body_move(b, vx_cmd_mps: float, vy_cmd_mps: float) -> None:
    """Fly one sensor period (``n_sub`` kinematic sub-steps) with a held command."""
    sub_dt_s = b.dt_s / b.n_sub
    x, y, vx, vy, odo, hdg = b.x_m, b.y_m, b.vx_mps, b.vy_mps, b.odometer_m, b.last_heading_rad
    for _ in range(b.n_sub):
        x, y, vx, vy, odo, hdg = point_step(x, y, vx, vy, odo, hdg, sub_dt_s, vx_cmd_mps,
                                            vy_cmd_mps, b.max_speed_mps, b.max_accel_mps2,
                                            b.max_turn_rate_dps)
    b.x_m, b.y_m, b.vx_mps, b.vy_mps, b.odometer_m, b.last_heading_rad = x, y, vx, vy, odo, hdg
    b.ticks += 1


@njit(cache=True)
def _speed(b) -> float:
    return math.hypot(b.vx_mps, b.vy_mps)


@njit(cache=True)
def _heading(b) -> float:
    if b.vx_mps != 0.0 or b.vy_mps != 0.0:
        return math.atan2(b.vy_mps, b.vx_mps)
    return b.last_heading_rad


@njit(cache=True)
def _contains(xmin: float, xmax: float, ymin: float, ymax: float, x: float, y: float) -> bool:
    return xmin <= x <= xmax and ymin <= y <= ymax


@njit(cache=True)
def _shrink_m(b, margin_m: float) -> float:
    return min(margin_m, 0.25 * (b.xmax - b.xmin), 0.25 * (b.ymax - b.ymin))


@njit(cache=True)
def _ray_to_edge_m(xmin: float, xmax: float, ymin: float, ymax: float, x_m: float, y_m: float,
                   ux: float, uy: float) -> float:
    """Distance from an inside point to the region boundary along unit vector ``(ux, uy)``."""
    if not _contains(xmin, xmax, ymin, ymax, x_m, y_m):
        return 0.0
    dist = math.inf
    if ux > 1e-12:
        dist = min(dist, (xmax - x_m) / ux)
    elif ux < -1e-12:
        dist = min(dist, (xmin - x_m) / ux)
    if uy > 1e-12:
        dist = min(dist, (ymax - y_m) / uy)
    elif uy < -1e-12:
        dist = min(dist, (ymin - y_m) / uy)
    return dist


@njit(cache=True)
def _edge_ahead_m(b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray, x_m: float, y_m: float,
                  ux: float, uy: float) -> float:
    """Distance along ``(ux, uy)`` to the area boundary or to ``fence_margin_m`` before
    the fence, whichever comes first (0 outside the area)."""
    edge = _ray_to_edge_m(b.xmin, b.xmax, b.ymin, b.ymax, x_m, y_m, ux, uy)
    if fr.shape[0] > 0 or fc.shape[0] > 0:
        edge = min(edge, fence_ray_exit(fv, fr, fc, x_m, y_m, ux, uy) - b.fence_margin_m)
    return edge


# ----------------------------------------------------------------------------- guard


@njit(cache=True)
def _predict(b, vx_cmd_mps: float, vy_cmd_mps: float) -> tuple[float, float, float, float]:
    """Position and velocity after one tick with the command (:func:`body_move` without
    moving)."""
    sub_dt_s = b.dt_s / b.n_sub
    x, y, vx, vy, odo, hdg = b.x_m, b.y_m, b.vx_mps, b.vy_mps, 0.0, b.last_heading_rad
    for _ in range(b.n_sub):
        x, y, vx, vy, odo, hdg = point_step(x, y, vx, vy, odo, hdg, sub_dt_s, vx_cmd_mps,
                                            vy_cmd_mps, b.max_speed_mps, b.max_accel_mps2,
                                            b.max_turn_rate_dps)
    return x, y, vx, vy


@njit(cache=True)
def _stops_in_area(b, x: float, y: float, vx: float, vy: float) -> bool:
    """Braking from ``(x, y)`` at ``(vx, vy)`` stops inside the area (a zero command brakes
    along a straight line with the full acceleration limit)."""
    if not _contains(b.xmin, b.xmax, b.ymin, b.ymax, x, y):
        return False
    v = math.hypot(vx, vy)
    if v < 1e-9:
        return True
    return (_ray_to_edge_m(b.xmin, b.xmax, b.ymin, b.ymax, x, y, vx / v, vy / v)
            >= v * v / (2.0 * b.max_accel_mps2) + AREA_HARD_MARGIN_M)


@njit(cache=True)
def _stops_in_fence(b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray, x: float, y: float,
                    vx: float, vy: float) -> bool:
    """Braking from ``(x, y)`` at ``(vx, vy)`` stops ``FENCE_HARD_MARGIN_M`` inside the
    fence."""
    v = math.hypot(vx, vy)
    if v < 1e-9:
        return fence_contains(fv, fr, fc, x, y)
    return (fence_ray_exit(fv, fr, fc, x, y, vx / v, vy / v)
            >= v * v / (2.0 * b.max_accel_mps2) + FENCE_HARD_MARGIN_M)


@njit(cache=True)
def _guard(s, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray) -> None:
    """Change the command in ``s`` so the vehicle stays inside the fence (always) and the
    mission area (during a trace task, while it is inside it).

    Two stages, for each boundary the vehicle is inside of:

    * soft (in the spirit of ArduPilot's AC_Avoid): the command's speed is limited to
      ``sqrt(2 a d)`` with ``a`` = ``GUARD_SOFT_ACCEL_FRACTION`` of the acceleration limit
      and ``d`` the distance along the command to the area boundary or to
      ``fence_margin_m`` before the fence, so the vehicle slows down smoothly;
    * hard: one tick with the (limited) command is predicted with the kinematics
      themselves; if braking from there (a zero command: a straight line at the full
      acceleration limit) would not stop inside (``AREA_HARD_MARGIN_M`` /
      ``FENCE_HARD_MARGIN_M``), the vehicle brakes now instead. Braking from a state that
      passed this check passes it again, so a vehicle that starts a task able to stop
      inside never leaves.

    Outside a boundary nothing is limited (so a vehicle can fly back in; AC_Avoid does the
    same). Fence limiting is counted (``fence_attempts``, one per episode), so is being
    outside (``fence_breaches``); ``fence_stuck`` counts the ticks the fence has held a
    vehicle still.
    """
    vx, vy = s.cmd_vx, s.cmd_vy
    x, y = b.x_m, b.y_m
    area_on = s.area_guard != 0 and _contains(b.xmin, b.xmax, b.ymin, b.ymax, x, y)
    fence_on = False
    if fr.shape[0] > 0 or fc.shape[0] > 0:
        fence_on = fence_contains(fv, fr, fc, x, y)
        if not fence_on and b.fence_outside == 0:
            b.fence_breaches += 1
            b.fence_event_tick = b.ticks
        b.fence_outside = 0 if fence_on else 1
    fence_limited = False
    if area_on or fence_on:
        speed = math.hypot(vx, vy)
        if speed > 0.0:
            ux, uy = vx / speed, vy / speed
            a_soft = GUARD_SOFT_ACCEL_FRACTION * b.max_accel_mps2
            v_max = speed
            if area_on:
                d = _ray_to_edge_m(b.xmin, b.xmax, b.ymin, b.ymax, x, y, ux, uy)
                v_max = min(v_max, math.sqrt(2.0 * a_soft * d))
            if fence_on:
                d = fence_ray_exit(fv, fr, fc, x, y, ux, uy) - b.fence_margin_m
                v_fence = math.sqrt(2.0 * a_soft * max(d, 0.0))
                if v_fence < speed - 1e-6:
                    fence_limited = True
                v_max = min(v_max, v_fence)
            if v_max < speed:
                vx, vy = vx * (v_max / speed), vy * (v_max / speed)
        px, py, pvx, pvy = _predict(b, vx, vy)
        brake = area_on and not _stops_in_area(b, px, py, pvx, pvy)
        if fence_on and not _stops_in_fence(b, fv, fr, fc, px, py, pvx, pvy):
            brake = True
            fence_limited = True
        if brake:
            vx = vy = 0.0
            b.guard_brakes += 1
    if fence_limited:
        if (b.ticks - b.fence_last_tick) * b.dt_s > FENCE_EPISODE_GAP_S:
            b.fence_attempts += 1
            b.fence_event_tick = b.ticks
        b.fence_last_tick = b.ticks
        if math.hypot(vx, vy) < 0.1 and _speed(b) < 0.2:
            b.fence_stuck += 1
        else:
            b.fence_stuck = 0
    else:
        b.fence_stuck = 0
    b.fence_limited = 1 if fence_limited else 0
    s.cmd_vx, s.cmd_vy = vx, vy


# ----------------------------------------------------------------------------- fits


@njit(cache=True)
def _ring_push(buf: np.ndarray, start: int, length: int, x: float, y: float, v: float
               ) -> tuple[int, int]:
    cap = buf.shape[0]
    if length < cap:
        k = (start + length) % cap
        length += 1
    else:
        k = start
        start = (start + 1) % cap
    buf[k, 0] = x
    buf[k, 1] = y
    buf[k, 2] = v
    return start, length


@njit(cache=True)
def fit_gradient(buf: np.ndarray, start: int, length: int, count: int,
                 ridge: float = 1e-4) -> tuple[float, float, float]:
    """Least-squares plane ``v = a + g . (p - mean p)`` through the last ``count`` samples.

    Returns
    -------
    gx, gy, spread_m
        The gradient and the smallest standard deviation of the positions (how well
        the plane is determined across the track).
    """
    n = min(count, length)
    if n < 3:
        return 0.0, 0.0, 0.0
    cap = buf.shape[0]
    first = start + length - n
    mx = my = mv = 0.0
    for i in range(n):
        k = (first + i) % cap
        mx += buf[k, 0]
        my += buf[k, 1]
        mv += buf[k, 2]
    mx /= n
    my /= n
    mv /= n
    sxx = syy = sxy = sxv = syv = 0.0
    for i in range(n):
        k = (first + i) % cap
        dx = buf[k, 0] - mx
        dy = buf[k, 1] - my
        dv = buf[k, 2] - mv
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
        sxv += dx * dv
        syv += dy * dv
    sxx /= n
    syy /= n
    sxy /= n
    tr = sxx + syy
    det0 = sxx * syy - sxy * sxy
    lam_min = max(0.5 * tr - math.sqrt(max(0.25 * tr * tr - det0, 0.0)), 0.0)
    a = sxx + ridge
    d = syy + ridge
    det = a * d - sxy * sxy
    if det <= 0.0:
        return 0.0, 0.0, 0.0
    bx = sxv / n
    by = syv / n
    gx = (d * bx - sxy * by) / det
    gy = (a * by - sxy * bx) / det
    return gx, gy, math.sqrt(lam_min)


@njit(cache=True)
def _dot(a: np.ndarray, b: np.ndarray, n: int) -> float:
    acc = 0.0
    for i in range(n):
        acc += a[i] * b[i]
    return acc


@njit(cache=True)
def _project_out(q: np.ndarray, rank: int, r: np.ndarray, n: int) -> None:
    """``r -= Q Q^T r`` twice (re-orthogonalised), ``Q`` the first ``rank`` rows of ``q``."""
    for _ in range(2):
        for c in range(rank):
            proj = _dot(q[c], r, n)
            for i in range(n):
                r[i] -= proj * q[c, i]


@njit(cache=True)
def fit_cross_gradient(buf: np.ndarray, start: int, length: int) -> tuple[float, float]:
    """Cross-track gradient magnitude from samples along a (curved) track.

    The samples are expressed in a local frame (``s`` along the chord of the window,
    ``n`` across it) and fitted with ``v = a + b s + c s^2 + g n``: the quadratic term
    absorbs the curvature of a contour that is being followed, so ``g`` is only
    determined by genuine excursions across the iso-line. ``g`` is computed by
    Frisch-Waugh-Lovell: with ``r_n`` and ``r_v`` the residuals of ``n`` and ``v`` after
    projecting out the trend ``(1, s, s^2)`` (an orthonormal basis by modified
    Gram-Schmidt, re-orthogonalised; a column below 1e-10 of its norm is dropped, as a
    least-squares solve with a rank cutoff would), ``g = <r_n, r_v> / <r_n, r_n>``.

    Returns
    -------
    g_abs, spread_m
        ``|g|`` and the standard deviation of ``n`` left after removing a quadratic
        trend in ``s`` (how well ``g`` is determined).
    """
    n = length
    if n < 6:
        return 0.0, 0.0
    cap = buf.shape[0]
    k0 = start % cap
    k1 = (start + n - 1) % cap
    mx = my = 0.0
    for i in range(n):
        k = (start + i) % cap
        mx += buf[k, 0]
        my += buf[k, 1]
    mx /= n
    my /= n
    chord_x, chord_y = buf[k1, 0] - buf[k0, 0], buf[k1, 1] - buf[k0, 1]
    chord = math.hypot(chord_x, chord_y)
    if chord < 1e-6:
        return 0.0, 0.0
    ux, uy = chord_x / chord, chord_y / chord
    work = np.empty((6, n))  # rows: q0, q1, q2, along, r_n, r_v
    q = work[:3]
    along, r_n, r_v = work[3], work[4], work[5]
    for i in range(n):
        k = (start + i) % cap
        cx = buf[k, 0] - mx
        cy = buf[k, 1] - my
        along[i] = cx * ux + cy * uy
        r_n[i] = -cx * uy + cy * ux
        r_v[i] = buf[k, 2]
    rank = 0
    for j in range(3):
        col = q[rank]
        for i in range(n):
            col[i] = 1.0 if j == 0 else (along[i] if j == 1 else along[i] * along[i])
        norm0 = math.sqrt(_dot(col, col, n))
        _project_out(q, rank, col, n)
        norm = math.sqrt(_dot(col, col, n))
        if norm > 1e-10 * norm0 and norm > 0.0:
            for i in range(n):
                col[i] /= norm
            rank += 1
    _project_out(q, rank, r_n, n)
    nn = _dot(r_n, r_n, n)
    spread = math.sqrt(nn / n)
    if spread <= 1e-9:
        return 0.0, spread
    _project_out(q, rank, r_v, n)
    return abs(_dot(r_n, r_v, n) / nn), spread


# ----------------------------------------------------------------------------- tasks


@njit(inline="always")
def _call_fly_to(s, b, x: float, y: float, phase: int, tol: float, speed: float, ret: int
                 ) -> None:
    s.ft_x = x
    s.ft_y = y
    s.ft_phase = phase
    s.ft_tol = tol
    s.ft_speed = min(speed, b.max_speed_mps)
    dist0 = math.hypot(x - b.x_m, y - b.y_m)
    s.ft_max = int(3.0 * (dist0 / max(s.ft_speed, 0.1) + 10.0) / b.dt_s) + 100
    s.ft_k = 0
    s.ft_ret = ret
    b.fence_stuck = 0
    s.pc = PC_FT


@njit(inline="always")
def _call_search(s, level: float, cx: float, cy: float, radius: float, ret: int) -> None:
    s.sr_level = level
    s.sr_cx = cx
    s.sr_cy = cy
    s.sr_radius = max(radius, 0.0)
    s.sr_ret = ret
    s.found = 0
    s.probe_k = 0
    s.pc = PC_SR_PROBE_START


@njit(inline="always")
def _call_leg(s, heading: float, side: float) -> None:
    s.leg_heading = heading
    s.side = side
    s.pc = PC_LEG_START


@njit(inline="always")
def _emit(events: np.ndarray, n_events: int, code: int, n_out: int) -> int:
    if n_events < events.shape[0]:
        events[n_events, 0] = code
        events[n_events, 1] = n_out
        return n_events + 1
    return n_events


@njit(inline="always")
def _command(s, vx: float, vy: float, phase: int) -> bool:
    s.cmd_vx = vx
    s.cmd_vy = vy
    s.cmd_phase = phase
    return True


@njit(cache=True)
def _heading_from_gradient(gx: float, gy: float, side: float) -> float:
    """Heading along the iso-line with higher values on the left (side=+1) or right."""
    return math.atan2(-side * gx, side * gy)


@njit(cache=True)
def _crossing_gradient(s, recent: np.ndarray, cur_x: float, cur_y: float, cur_v: float
                       ) -> tuple[float, float]:
    """The gradient where the level was crossed between the previous and this sample."""
    gx, gy, _ = fit_gradient(recent, s.rec_start, s.rec_len, s.gradient_window)
    if s.has_prev:
        # the bracketing pair gives the derivative along the last step: trust its sign
        sx, sy = cur_x - s.prev_x, cur_y - s.prev_y
        step = math.hypot(sx, sy)
        dv = cur_v - s.prev_v
        if step > 1e-9:
            ux, uy = sx / step, sy / step
            along = dv / step
            gfit_along = gx * ux + gy * uy
            if math.hypot(gx, gy) < 1e-12 or gfit_along * along <= 0.0:
                # the fit disagrees with the crossing itself: use the step direction
                gx, gy = along * ux, along * uy
    return gx, gy


@njit(cache=True)
def _found_at(s, x: float, y: float, gx: float, gy: float) -> None:
    """Record where the level was found and the gradient there; return from the search."""
    s.found = 1
    s.f_x = x
    s.f_y = y
    s.f_gx = gx
    s.f_gy = gy
    s.pc = s.sr_ret


@njit(cache=True)
def _found(s, recent: np.ndarray, cur_x: float, cur_y: float, cur_v: float,
           cross_x: float, cross_y: float) -> None:
    """Record where the level was crossed and the gradient there; return from the search."""
    gx, gy = _crossing_gradient(s, recent, cur_x, cur_y, cur_v)
    _found_at(s, cross_x, cross_y, gx, gy)


@njit(cache=True)
def _bracketed(s, recent: np.ndarray, x: float, y: float, v: float) -> bool:
    """If the level lies between the previous and this sample: found (True)."""
    if s.has_prev:
        level = s.sr_level
        e0, e1 = s.prev_v - level, v - level
        if e1 == 0.0:
            _found(s, recent, x, y, v, x, y)
            return True
        if e0 * e1 < 0.0:
            t = e0 / (e0 - e1)
            _found(s, recent, x, y, v, s.prev_x + t * (x - s.prev_x),
                   s.prev_y + t * (y - s.prev_y))
            return True
    return False


@njit(cache=True)
def _tick_budget(s, b) -> int:
    """Trace tick budget: ``budget_factor`` region perimeters (plus ``max_length_m``) at
    half the cruise speed."""
    perimeter = 2.0 * ((b.xmax - b.xmin) + (b.ymax - b.ymin))
    budget_m = s.budget_factor * perimeter + max(s.max_length_m, 0.0)
    cruise = min(s.speed_mps, b.max_speed_mps)
    return int(budget_m / (0.5 * cruise) / b.dt_s) + 200


@njit(cache=True)
def trace_tick_budget(body: np.ndarray, state: np.ndarray) -> int:
    """The tick budget of the trace task in ``state`` (sizes its turn-history buffer)."""
    return _tick_budget(state[0], body[0])


@njit(cache=True)
def _spiral_point(s, b, th: float) -> tuple[float, float]:
    m = _shrink_m(b, 0.5)
    r = s.pitch * th
    x = s.sr_cx + r * math.cos(th + s.phi0)
    y = s.sr_cy + r * math.sin(th + s.phi0)
    return min(max(x, b.xmin + m), b.xmax - m), min(max(y, b.ymin + m), b.ymax - m)


@njit(cache=True)
def _walk_edge(b, x: float, y: float, ux: float, uy: float) -> int:
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
def _walk_frame(b, edge: int, x: float, y: float, inset: float
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


@njit(cache=True)
def _pre(s, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray, recent: np.ndarray,
         window: np.ndarray, events: np.ndarray, n_events: int, n_out: int
         ) -> tuple[bool, int]:
    """Run the state machine until it issues a velocity command (True) or the task ends.

    Returns ``(commanded, n_events)``.
    """
    while True:
        pc = s.pc
        if pc == PC_DONE:
            return False, n_events

        # ---------------------------------------------------------------- fly to
        if pc == PC_FT:
            if s.ft_k >= s.ft_max:
                s.ft_ok = 1 if math.hypot(s.ft_x - b.x_m, s.ft_y - b.y_m) <= s.ft_tol else 0
                s.pc = s.ft_ret
                continue
            ex, ey = s.ft_x - b.x_m, s.ft_y - b.y_m
            dist = math.hypot(ex, ey)
            if dist <= s.ft_tol:
                s.ft_ok = 1
                s.pc = s.ft_ret
                continue
            if b.fence_stuck * b.dt_s >= FENCE_STUCK_S:  # held at the fence: give up
                if s.kind == KIND_TRACE:
                    n_events = _emit(events, n_events, EV_FENCE, n_out)
                s.ft_ok = 0
                s.pc = s.ft_ret
                continue
            # brake so as to stop at the target; small floor so we always get there
            v = min(s.ft_speed, math.sqrt(2.0 * 0.6 * b.max_accel_mps2 * dist),
                    max(2.0 * dist, 0.3))
            v = max(v, min(0.3, s.ft_speed))
            s.ft_k += 1
            return _command(s, v * ex / dist, v * ey / dist, s.ft_phase), n_events
        if pc == PC_FT_END:
            s.status = REACHED if s.ft_ok else UNREACHABLE
            s.pc = PC_DONE
            continue

        # ---------------------------------------------------------------- search
        if pc == PC_SR_PROBE_START:
            if s.probe_k == 0:
                v_search = min(s.search_speed_mps, b.max_speed_mps)
                s.v_search = v_search
                s.v_min = min(s.approach_speed_mps, v_search)
                if s.rec_len > 0:
                    k = (s.rec_start + s.rec_len - 1) % recent.shape[0]
                    s.has_prev = 1
                    s.prev_x, s.prev_y, s.prev_v = recent[k, 0], recent[k, 1], recent[k, 2]
                else:
                    s.has_prev = 0
                # probe: a short leg across the arrival direction (two if still degenerate)
                s.arrival = 0.0
                if s.rec_len >= 2:
                    k1 = (s.rec_start + s.rec_len - 1) % recent.shape[0]
                    k0 = (s.rec_start + s.rec_len - 2) % recent.shape[0]
                    dx = recent[k1, 0] - recent[k0, 0]
                    dy = recent[k1, 1] - recent[k0, 1]
                    if math.hypot(dx, dy) > 1e-6:
                        s.arrival = math.atan2(dy, dx)
            elif s.probe_k >= 2:
                s.pc = PC_SR_DESCENT_START
                continue
            else:
                _, _, spread = fit_gradient(recent, s.rec_start, s.rec_len, s.gradient_window)
                if spread >= s.min_spread_m:
                    s.pc = PC_SR_DESCENT_START
                    continue
            ang = s.arrival + 0.5 * math.pi if s.probe_k == 0 else s.arrival
            ux, uy = math.cos(ang), math.sin(ang)
            # turn toward the interior if the leg would leave the region (unless the other
            # way has even less room: just outside the shrunk region both are 0)
            m = _shrink_m(b, 0.5)
            ahead = _ray_to_edge_m(b.xmin + m, b.xmax - m, b.ymin + m, b.ymax - m, b.x_m,
                                   b.y_m, ux, uy)
            if fr.shape[0] > 0 or fc.shape[0] > 0:
                ahead = min(ahead, fence_ray_exit(fv, fr, fc, b.x_m, b.y_m, ux, uy)
                            - b.fence_margin_m)
            if ahead < 2.0 * s.probe_leg_m and (
                    _edge_ahead_m(b, fv, fr, fc, b.x_m, b.y_m, -ux, -uy)
                    >= _edge_ahead_m(b, fv, fr, fc, b.x_m, b.y_m, ux, uy)):
                ux, uy = -ux, -uy
            s.probe_ux, s.probe_uy = ux, uy
            s.probe_x0, s.probe_y0 = b.x_m, b.y_m
            s.v_probe = max(s.v_min, 0.5 * s.v_search)
            s.probe_j = 0
            s.probe_n = int(10.0 / b.dt_s)
            s.pc = PC_SR_PROBE
            continue
        if pc == PC_SR_PROBE:
            if s.probe_j >= s.probe_n or (
                    math.hypot(b.x_m - s.probe_x0, b.y_m - s.probe_y0) >= s.probe_leg_m) or (
                    _edge_ahead_m(b, fv, fr, fc, b.x_m, b.y_m, s.probe_ux, s.probe_uy)
                    < PROBE_BLOCKED_M):
                s.probe_k += 1
                s.pc = PC_SR_PROBE_START
                continue
            s.probe_j += 1
            return _command(s, s.v_probe * s.probe_ux, s.v_probe * s.probe_uy,
                            _SEARCH), n_events
        if pc == PC_SR_DESCENT_START:
            # gradient descent toward the level
            s.best = math.inf
            s.since_best = 0
            s.path0 = b.odometer_m - s.odo0_m
            s.max_path = 3.0 * s.sr_radius + 10.0
            s.pc = PC_SR_DESCENT
            continue
        if pc == PC_SR_DESCENT:
            if not s.has_prev:
                s.pc = PC_SR_SPIRAL_START
                continue
            gx, gy, _ = fit_gradient(recent, s.rec_start, s.rec_len, max(s.gradient_window, 30))
            gn = math.hypot(gx, gy)
            e = s.prev_v - s.sr_level
            if gn < 1e-9:
                s.pc = PC_SR_SPIRAL_START
                continue
            sgn = -1.0 if e > 0 else 1.0
            ux, uy = sgn * gx / gn, sgn * gy / gn
            pred_m = abs(e) / gn
            v = min(max(s.approach_gain_hz * pred_m, s.v_min), s.v_search)
            return _command(s, v * ux, v * uy, _SEARCH), n_events
        if pc == PC_SR_SPIRAL_START:
            # expanding Archimedean spiral around the start point, one turn from
            # r = step out to r = 2 step, ...; the step never more than half the search
            # radius, so a disc narrower than two spiral spacings still gets a turn
            r = s.sr_radius
            step = min(s.spiral_spacing_m, 0.5 * r)
            if step <= 0.0:  # a search radius of 0: no disc to search
                s.found = 0
                s.pc = s.sr_ret
                continue
            s.pitch = step / (2.0 * math.pi)
            s.phi0 = math.atan2(b.y_m - s.sr_cy, b.x_m - s.sr_cx)
            s.theta = 2.0 * math.pi
            s.sp_max = int((math.pi * r**2 / step + 4.0 * r + 50.0)
                           / (0.5 * s.v_min) / b.dt_s) + 100
            s.sp_k = 0
            s.pc = PC_SR_SPIRAL
            continue
        if pc == PC_SR_SPIRAL:
            lookahead_m = 2.0
            if s.sp_k >= s.sp_max or s.pitch * s.theta > s.sr_radius:
                s.found = 0
                s.pc = s.sr_ret
                continue
            s.sp_k += 1
            px, py = _spiral_point(s, b, s.theta)
            while (math.hypot(px - b.x_m, py - b.y_m) < lookahead_m
                   and s.pitch * s.theta <= s.sr_radius):
                r = s.pitch * s.theta
                s.theta += 0.3 / math.hypot(r, s.pitch)
                px, py = _spiral_point(s, b, s.theta)
            r = s.pitch * s.theta
            v = min(s.v_search, max(s.v_min, math.sqrt(0.5 * b.max_accel_mps2 * r)))
            ex, ey = px - b.x_m, py - b.y_m
            dist = math.hypot(ex, ey)
            if dist < 1e-9:
                s.theta += 0.3 / math.hypot(r, s.pitch)
                continue
            return _command(s, v * ex / dist, v * ey / dist, _SEARCH), n_events

        # ---------------------------------------------------------------- trace leg
        if pc == PC_LEG_START:
            cruise = min(s.speed_mps, b.max_speed_mps)
            v_floor = min(s.approach_speed_mps, cruise)
            s.psi = s.leg_heading
            s.kappa = 0.0
            s.lspeed = min(max(_speed(b), v_floor), cruise)
            e0 = 0.0
            if s.rec_len > 0:
                k = (s.rec_start + s.rec_len - 1) % recent.shape[0]
                e0 = recent[k, 2] - s.level
            s.d_f = s.side * e0 / s.grad_mag
            s.dd_f = 0.0
            s.lost_s = 0.0
            s.has_prev_dist = 0
            s.n_fit = 0
            s.turned = 0.0
            s.th_start = 0
            s.th_len = 0
            s.win_start = 0
            s.win_len = 0
            s.turn_k = 0
            s.turn_n = int(3.0 / b.dt_s) + 1
            s.pc = PC_LEG_TURN
            continue
        if pc == PC_LEG_TURN:
            # turn onto the initial heading slowly before the controller takes over
            if s.turn_k >= s.turn_n or _speed(b) < 0.5 or (
                    abs(wrap_angle_rad(_heading(b) - s.psi)) < math.radians(15)):
                s.pc = PC_LEG_MAIN_START
                continue
            if s.ticks_left <= 0:
                s.leg_status = BUDGET
                s.pc = PC_TR_AFTER_LEG
                continue
            s.ticks_left -= 1
            s.turn_k += 1
            v_floor = min(s.approach_speed_mps, min(s.speed_mps, b.max_speed_mps))
            return _command(s, v_floor * math.cos(s.psi), v_floor * math.sin(s.psi),
                            _TRACE), n_events
        if pc == PC_LEG_MAIN_START:
            s.tk_has = 0  # the track breaks here (a search or a flight back came between)
            cruise = min(s.speed_mps, b.max_speed_mps)
            v_floor = min(s.approach_speed_mps, cruise)
            s.lspeed = min(max(_speed(b), v_floor), cruise)
            s.pc = PC_LEG_MAIN
            continue
        if pc == PC_LEG_MAIN:
            if s.ticks_left <= 0:
                s.leg_status = BUDGET
                s.pc = PC_TR_AFTER_LEG
                continue
            s.ticks_left -= 1
            dt = b.dt_s
            cruise = min(s.speed_mps, b.max_speed_mps)
            v_floor = min(s.approach_speed_mps, cruise)
            lat_accel = s.lateral_accel_fraction * b.max_accel_mps2
            turn_max = math.radians(b.max_turn_rate_dps)
            p = min(s.trace_bandwidth_rps, 0.3 / dt)
            speed = s.lspeed
            # --- lateral PID (integral state = path curvature)
            kp = 3.0 * p * p / speed
            kd = 3.0 * p / speed
            ki = p**3 / speed
            d_clip = 1.5 * s.lost_offset_m
            d_c = max(-d_clip, min(d_clip, s.d_f))
            w_max = min(turn_max, lat_accel / speed)
            omega = speed * s.kappa - kp * d_c - kd * s.dd_f
            k_need = max(abs(s.kappa), abs(omega) / speed)  # curvature the controller asks for
            omega = max(-w_max, min(w_max, omega))
            kappa = s.kappa - ki / speed * d_c * dt
            k_max = w_max / speed
            s.kappa = max(-k_max, min(k_max, kappa))
            if _speed(b) >= 0.5:
                s.psi = _heading(b)
            s.psi += omega * dt
            ux, uy = math.cos(s.psi), math.sin(s.psi)
            # --- speed: cruise, slowed in bends and when the boundary is ahead
            v_target = cruise
            s.heading_before = _heading(b)
            if k_need > 1e-9:
                v_target = min(v_target, math.sqrt(0.7 * lat_accel / k_need))
            if s.traced_m < s.slow_until_m:
                v_target = min(v_target, s.recover_speed_mps)
            edge = _edge_ahead_m(b, fv, fr, fc, b.x_m, b.y_m, ux, uy)
            v_target = min(v_target, math.sqrt(2.0 * 0.5 * b.max_accel_mps2
                                               * max(edge - s.boundary_margin_m, 0.0)) + 0.5)
            v_target = max(v_target, v_floor if edge > 2.0 * s.boundary_margin_m else 0.5)
            if v_target > speed:
                speed = min(v_target, speed + s.trace_accel_mps2 * dt)
            else:
                speed = max(v_target, speed - 0.6 * b.max_accel_mps2 * dt)
            s.lspeed = speed
            s.ux, s.uy = ux, uy
            return _command(s, speed * ux, speed * uy, _TRACE), n_events

        # ---------------------------------------------------------------- trace task
        if pc == PC_TR_START:
            m = _shrink_m(b, 0.5)
            sx = min(max(s.task_x_m, b.xmin + m), b.xmax - m)
            sy = min(max(s.task_y_m, b.ymin + m), b.ymax - m)
            s.sr_cx, s.sr_cy = sx, sy
            _call_fly_to(s, b, sx, sy, _TRANSIT, 1.0, s.transit_speed_mps, PC_TR_SEARCH)
            continue
        if pc == PC_TR_SEARCH:
            _call_search(s, s.level, s.sr_cx, s.sr_cy, s.search_radius_m, PC_TR_AFTER_SEARCH)
            continue
        if pc == PC_TR_AFTER_SEARCH:
            if not s.found:
                n_events = _emit(events, n_events, EV_NOT_FOUND, n_out)
                s.status = NOT_FOUND
                s.pc = PC_DONE
                continue
            n_events = _emit(events, n_events, EV_FOUND, n_out)
            g0 = max(math.hypot(s.f_gx, s.f_gy), 1e-9)
            s.start_x, s.start_y = s.f_x, s.f_y
            s.away_max = 0.0
            s.grad_mag = g0
            s.grad_mag0 = g0
            s.ticks_left = _tick_budget(s, b)
            s.heading0 = _heading_from_gradient(s.f_gx, s.f_gy, 1.0)
            # how far the other sense of tracing runs before it leaves the area
            s.back_edge_m = _edge_ahead_m(b, fv, fr, fc, s.f_x, s.f_y,
                                          -math.cos(s.heading0), -math.sin(s.heading0))
            s.reacquired = 0
            s.has_good = 0
            s.slow_until_m = 0.0
            s.lost_at_m = 0.0
            s.wk_count = 0
            _call_leg(s, s.heading0, 1.0)
            continue
        if pc == PC_TR_AFTER_LEG:
            status = s.leg_status
            if status == LOST:
                if s.recover_m > 0.0 and s.traced_m - s.lost_at_m > REACQUIRE_RESET_M:
                    s.reacquired = 0  # held the iso-line long enough since the last loss
                s.lost_at_m = s.traced_m
                if s.reacquired < s.max_reacquire:
                    s.reacquired += 1
                    n_events = _emit(events, n_events, EV_LOST_SEARCHING, n_out)
                    if s.recover_m > 0.0 and s.has_good and (
                            math.hypot(b.x_m - s.good_x, b.y_m - s.good_y) > GOOD_OFFSET_M):
                        # back to where the iso-line was last held, and on from there slowly
                        _call_fly_to(s, b, s.good_x, s.good_y, _SEARCH, 0.5,
                                     s.search_speed_mps, PC_TR_AFTER_BACKUP)
                        continue
                    _call_search(s, s.level, b.x_m, b.y_m, s.reacquire_radius_m,
                                 PC_TR_AFTER_REACQUIRE)
                    continue
            if status == BOUNDARY and s.side > 0 and s.back_edge_m > s.edge_skip_m:
                # before the flight back: along the edge, the area's inside on the left as
                # the higher values were, for where the iso-line (or the next one round
                # the same region) comes back in; never farther than the flight it saves
                walk = min(s.edge_walk_m, math.hypot(b.x_m - s.start_x, b.y_m - s.start_y))
                edge = _walk_edge(b, b.x_m, b.y_m, s.ux, s.uy)
                _, _, off, _ = _walk_frame(b, edge, b.x_m, b.y_m, s.boundary_margin_m)
                if (walk >= WALK_MIN_M and off <= 2.0 * s.boundary_margin_m + 1.0
                        and s.wk_count < WALK_MAX):
                    s.wk_count += 1
                    n_events = _emit(events, n_events, EV_EDGE_WALK, n_out)
                    s.wk_len = walk
                    s.wk_edge = edge
                    s.pc = PC_WK_START
                    continue
                n_events = _emit(events, n_events, EV_BOUNDARY_OTHER, n_out)
                _call_fly_to(s, b, s.start_x, s.start_y, _TRANSIT, 0.5, s.transit_speed_mps,
                             PC_TR_AFTER_RETURN)
                continue
            s.status = status
            s.pc = PC_TR_END
            continue
        if pc == PC_WK_START:
            s.wk_odo = b.odometer_m
            s.wk_k = 0
            v_walk = min(s.search_speed_mps, b.max_speed_mps)
            s.wk_max = int(3.0 * (s.wk_len / max(v_walk, 0.1) + 10.0) / b.dt_s) + 100
            s.has_prev = 0
            s.found = 0
            s.sr_level = s.level
            s.sr_ret = PC_TR_AFTER_WALK
            s.wk_emax = 0.0
            s.wk_smax = 0.0
            s.wk_cross = 0
            s.wk_de = 0.0
            s.pc = PC_WK
            continue
        if pc == PC_WK:
            inset = s.boundary_margin_m
            tx, ty, off, ahead = _walk_frame(b, s.wk_edge, b.x_m, b.y_m, inset)
            if ahead <= WALK_CORNER_M:  # round the corner
                s.wk_edge = (s.wk_edge + 1) % 4
                tx, ty, off, ahead = _walk_frame(b, s.wk_edge, b.x_m, b.y_m, inset)
            blocked = False
            if fr.shape[0] > 0 or fc.shape[0] > 0:  # the fence across the way
                blocked = (fence_ray_exit(fv, fr, fc, b.x_m, b.y_m, tx, ty) - b.fence_margin_m
                           < min(ahead, 2.0 * inset))
            if (blocked or b.odometer_m - s.wk_odo >= s.wk_len or s.wk_k >= s.wk_max
                    or s.ticks_left <= 0):
                s.found = 0
                s.pc = PC_TR_AFTER_WALK
                continue
            s.wk_k += 1
            s.ticks_left -= 1
            v = min(s.search_speed_mps, b.max_speed_mps,
                    math.sqrt(2.0 * 0.5 * b.max_accel_mps2 * max(ahead, 0.0)) + 0.5)
            if s.has_prev and s.wk_de < 0.0:  # coming down to the level: slow, as a search
                v = min(v, max(s.approach_speed_mps, s.approach_gain_hz * s.wk_e / -s.wk_de))
            lat = max(-v, min(v, WALK_GAIN_HZ * (inset - off)))  # > 0: inward
            return _command(s, v * tx - lat * ty, v * ty + lat * tx, _SEARCH), n_events
        if pc == PC_TR_AFTER_WALK:
            if s.found:
                n_events = _emit(events, n_events, EV_EDGE_FOUND, n_out)
                s.has_good, s.good_x, s.good_y = 1, s.f_x, s.f_y
                # back to the crossing, braking: the walk's speed along the edge would
                # carry the turn onto the iso-line out of the area
                _call_fly_to(s, b, s.f_x, s.f_y, _SEARCH, WALK_STOP_M, s.search_speed_mps,
                             PC_TR_AFTER_EDGE_FOUND)
                continue
            n_events = _emit(events, n_events, EV_BOUNDARY_OTHER, n_out)
            _call_fly_to(s, b, s.start_x, s.start_y, _TRANSIT, 0.5, s.transit_speed_mps,
                         PC_TR_AFTER_RETURN)
            continue
        if pc == PC_TR_AFTER_EDGE_FOUND:
            _call_leg(s, _heading_from_gradient(s.f_gx, s.f_gy, s.side), s.side)
            continue
        if pc == PC_TR_AFTER_BACKUP:
            _call_search(s, s.level, s.good_x, s.good_y, s.reacquire_radius_m,
                         PC_TR_AFTER_REACQUIRE)
            continue
        if pc == PC_TR_AFTER_REACQUIRE:
            if s.found:
                n_events = _emit(events, n_events, EV_REACQUIRED, n_out)
                if s.recover_m > 0.0:
                    s.slow_until_m = s.traced_m + s.recover_m
                _call_leg(s, _heading_from_gradient(s.f_gx, s.f_gy, s.side), s.side)
                continue
            s.status = LOST
            s.pc = PC_TR_END
            continue
        if pc == PC_TR_AFTER_RETURN:
            s.away_max = 0.0
            s.has_good = 0
            s.slow_until_m = 0.0
            _call_leg(s, s.heading0 + math.pi, -1.0)
            continue
        if pc == PC_TR_END:
            if s.status == BUDGET:
                n_events = _emit(events, n_events, EV_BUDGET, n_out)
                s.status = LOST
            code = EV_LOST
            if s.status == CLOSED:
                code = EV_CLOSED
            elif s.status == BOUNDARY:
                code = EV_BOUNDARY
            elif s.status == LENGTH_LIMIT:
                code = EV_LENGTH_LIMIT
            n_events = _emit(events, n_events, code, n_out)
            s.pc = PC_DONE
            continue
        raise AssertionError("tracer state machine: unknown program counter")


@njit(inline="always")
def _leg_end(s, status: int) -> None:
    s.leg_status = status
    s.pc = PC_TR_AFTER_LEG


@njit(cache=True)
def _track_push(s, track: np.ndarray, prior: np.ndarray, x: float, y: float) -> bool:
    """Keep a point of the trace's track every ``TRACK_STEP_M`` traced; True when the new
    one comes onto ``prior`` (an earlier trace of the level flew there, either way), or
    rejoins the trace's own track flown at least ``rejoin_min_m`` before, the same way,
    away from its start (that closure is the start's own test): the trace has gone round
    a loop that does not pass its start (past a saddle, or after a loss)."""
    if s.tk_has and s.traced_m - s.tk_m < TRACK_STEP_M:
        return False
    if s.tk_len >= track.shape[0]:
        return False
    ux, uy = 0.0, 0.0  # the first point after a break has no direction
    if s.tk_has:
        step = math.hypot(x - s.tk_x, y - s.tk_y)
        if step > 1e-9:
            ux, uy = (x - s.tk_x) / step, (y - s.tk_y) / step
    k = s.tk_len
    track[k, 0], track[k, 1], track[k, 2], track[k, 3], track[k, 4] = x, y, s.traced_m, ux, uy
    s.tk_len += 1
    s.tk_has, s.tk_x, s.tk_y, s.tk_m = 1, x, y, s.traced_m
    if ux == 0.0 and uy == 0.0:
        return False
    r = s.closure_radius_m
    for i in range(prior.shape[0]):  # a track an earlier trace of this level flew
        if (math.hypot(prior[i, 0] - x, prior[i, 1] - y) <= r
                and abs(prior[i, 3] * ux + prior[i, 4] * uy) >= REJOIN_MIN_COS):
            return True
    before_m = s.traced_m - s.rejoin_min_m
    for i in range(k):
        if track[i, 2] > before_m:
            break
        if (math.hypot(track[i, 0] - x, track[i, 1] - y) <= r
                and track[i, 3] * ux + track[i, 4] * uy >= REJOIN_MIN_COS
                and math.hypot(track[i, 0] - s.start_x, track[i, 1] - s.start_y) > r):
            return True
    return False


@njit(cache=True)
def _post(s, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray, recent: np.ndarray,
          window: np.ndarray, turns: np.ndarray, track: np.ndarray, prior: np.ndarray,
          x: float, y: float, v: float) -> None:
    """What the loop that issued the command does with the new sample."""
    pc = s.pc
    if pc in (PC_SR_PROBE, PC_SR_SPIRAL):
        if not _bracketed(s, recent, x, y, v):
            s.has_prev, s.prev_x, s.prev_y, s.prev_v = 1, x, y, v
        return
    if pc == PC_SR_DESCENT:
        if _bracketed(s, recent, x, y, v):
            return
        s.has_prev, s.prev_x, s.prev_y, s.prev_v = 1, x, y, v
        err = abs(v - s.sr_level)
        if err < s.best * 0.999:
            s.best, s.since_best = err, 0
        else:
            s.since_best += 1
        m = _shrink_m(b, 0.5)
        if (s.since_best > 20 or math.hypot(x - s.sr_cx, y - s.sr_cy) > s.sr_radius
                or (b.odometer_m - s.odo0_m) - s.path0 > s.max_path
                or not _contains(b.xmin + m, b.xmax - m, b.ymin + m, b.ymax - m, x, y)):
            s.pc = PC_SR_SPIRAL_START
        return
    if pc == PC_WK:
        # the walk runs inside the region the trace kept on its left: where the field
        # falls through the level again (and not within WALK_MIN_M / 2 of where the
        # walk began, where it crosses the level the trace left), an iso-line comes in
        walked = b.odometer_m - s.wk_odo
        e1 = s.side * (v - s.level)
        if s.has_prev:
            e0 = s.side * (s.prev_v - s.level)
            sx, sy = x - s.prev_x, y - s.prev_y
            step = math.hypot(sx, sy)
            if step > 1e-9:
                s.wk_de = (e1 - e0) / step
            if e0 > 0.0 and e1 <= 0.0:  # down through the level: an iso-line comes in
                t = e0 / (e0 - e1)
                cx, cy = s.prev_x + t * sx, s.prev_y + t * sy
                # the walk's samples lie on one line: a plane fit cannot tell the gradient
                # across it, so the derivative along the last step stands for it (the
                # trace then sets off square to the edge and the controller turns it)
                step = max(step, 1e-9)
                along = (v - s.prev_v) / step
                gx, gy = along * sx / step, along * sy / step
                if walked >= WALK_MIN_M:
                    _found_at(s, cx, cy, gx, gy)
                    return
                # this near where the walk began it may be the level the trace left,
                # read again through noise: taken once the walk stays below it
                s.wk_cross, s.wk_cx, s.wk_cy, s.wk_gx, s.wk_gy = 1, cx, cy, gx, gy
            elif e0 <= 0.0 < e1:
                s.wk_cross = 0
        s.wk_e = e1
        s.has_prev, s.prev_x, s.prev_y, s.prev_v = 1, x, y, v
        if walked >= WALK_MIN_M and e1 <= 0.0:
            if s.wk_cross:
                _found_at(s, s.wk_cx, s.wk_cy, s.wk_gx, s.wk_gy)
            elif walked >= 2.0 * WALK_MIN_M:  # below the level all along: not this side
                s.found = 0
                s.pc = PC_TR_AFTER_WALK
            return
        # Where will the field along the edge come back down to the level? Past its
        # highest point the profile is taken for a parabola through that top: a bump's
        # edge comes back in soon, a plateau's (a front, a wide high ground) not within
        # the walk, which then gives up instead of running out its length.
        if e1 >= s.wk_emax:
            s.wk_emax, s.wk_smax = e1, walked
            ret = 2.0 * walked  # still rising: at least as far again
        elif walked - s.wk_smax >= WALK_PEAK_M:
            drop = s.wk_emax - e1
            ret = s.wk_smax + (walked - s.wk_smax) * math.sqrt(s.wk_emax / drop)
        else:
            ret = 0.0
        if ret > s.wk_len:
            s.found = 0
            s.pc = PC_TR_AFTER_WALK
        return
    if pc == PC_LEG_TURN:
        s.win_start, s.win_len = _ring_push(window, s.win_start, s.win_len, x, y, v)
        s.d_f = s.side * (v - s.level) / s.grad_mag
        return
    if pc != PC_LEG_MAIN:
        return
    # --- measurement update
    s.win_start, s.win_len = _ring_push(window, s.win_start, s.win_len, x, y, v)
    s.n_fit += 1
    if s.n_fit % 4 == 0 and s.win_len >= max(6, s.gradient_window // 2):
        gn, spread = fit_cross_gradient(window, s.win_start, s.win_len)
        if spread >= s.min_spread_m and gn > 0.0:
            g_new = 0.8 * s.grad_mag + 0.2 * gn
            s.grad_mag = min(max(g_new, 0.25 * s.grad_mag0), 4.0 * s.grad_mag0)
    dt = b.dt_s
    d_meas = s.side * (v - s.level) / s.grad_mag
    d_pred = s.d_f + s.dd_f * dt
    resid = d_meas - d_pred
    s.d_f = d_pred + s.filter_alpha * resid
    s.dd_f += s.filter_beta / dt * resid
    if abs(d_meas) < GOOD_OFFSET_M:
        s.has_good, s.good_x, s.good_y = 1, x, y
    # --- termination checks
    if s.max_length_m > 0.0 and s.traced_m >= s.max_length_m:
        _leg_end(s, LENGTH_LIMIT)
        return
    dist = math.hypot(x - s.start_x, y - s.start_y)
    s.away_max = max(s.away_max, dist)
    if s.away_max >= max(s.closure_min_away_m, s.closure_radius_m) and (
            dist <= s.closure_radius_m and s.has_prev_dist and dist > s.prev_dist):
        _leg_end(s, CLOSED)
        return
    s.has_prev_dist, s.prev_dist = 1, dist
    if s.rejoin_min_m > 0.0 and _track_push(s, track, prior, x, y):
        _leg_end(s, CLOSED)
        return
    if not _contains(b.xmin, b.xmax, b.ymin, b.ymax, x, y) or (
            _edge_ahead_m(b, fv, fr, fc, x, y, s.ux, s.uy) < s.boundary_margin_m):
        _leg_end(s, BOUNDARY)
        return
    s.turned += wrap_angle_rad(_heading(b) - s.heading_before)
    k = s.th_start + s.th_len
    if k >= turns.shape[0]:  # compact the history (only its tail is alive)
        turns[: s.th_len] = turns[s.th_start: k].copy()
        s.th_start, k = 0, s.th_len
    turns[k, 0] = b.odometer_m
    turns[k, 1] = s.turned
    s.th_len += 1
    orbit_m = 2.0 * math.pi * s.min_loop_radius_m
    while b.odometer_m - turns[s.th_start, 0] > orbit_m:
        s.th_start += 1
        s.th_len -= 1
    if abs(s.turned - turns[s.th_start, 1]) >= 2.0 * math.pi:
        _leg_end(s, LOST)
        return
    s.lost_s = s.lost_s + dt if abs(d_meas) > s.lost_offset_m else 0.0
    if s.lost_s > s.lost_time_s:
        _leg_end(s, LOST)


@njit(cache=True)
def advance(body: np.ndarray, state: np.ndarray, field_kind: int, fcx: np.ndarray,
            fcy: np.ndarray, finv: np.ndarray, fw: np.ndarray, fscale: float, foffset: float,
            fence_verts: np.ndarray, fence_rings: np.ndarray, fence_circles: np.ndarray,
            recent: np.ndarray, window: np.ndarray, turns: np.ndarray, track: np.ndarray,
            prior: np.ndarray, out: np.ndarray, noise: np.ndarray, sensor: np.ndarray,
            ext_value: float, events: np.ndarray) -> tuple[int, int, int]:
    """Run the task in ``state`` on ``body`` for at most ``out.shape[0]`` ticks.

    Parameters
    ----------
    body, state
        One-record arrays of :data:`BODY` and :data:`STATE`.
    field_kind
        1: the field is the Gaussian sum ``foffset + fscale * sum(...)`` of the arrays
        ``fcx, fcy, finv, fw`` (read here); 0: read by the caller (see module docstring).
    fence_verts, fence_rings, fence_circles
        The geofence (:attr:`sim_vehicle.fence.Fence.arrays`; empty arrays for none).
    recent, window, turns, track
        The task's sample buffers: ``(RECENT_SAMPLES, 3)``, ``(gradient_window, 3)``,
        ``(n, 2)`` with ``n`` more than the trace's tick budget and ``(n, 5)`` (a point
        ``x, y, traced_m, ux, uy`` every ``TRACK_STEP_M`` traced; a full buffer keeps no
        more).
    prior
        ``(m, 5)``: the tracks of the vehicle's earlier traces of this level, as ``track``
        (:meth:`sim_vehicle.body.SimBody.traced_track`); a trace ends where it comes onto
        one.
    out
        ``(n, 5)``: one row ``t_s, x_m, y_m, value, phase`` per tick.
    noise
        ``(n, 3)``: the random numbers of each tick of this call (the reading's noise, the
        GNSS error's innovations; :meth:`sim_vehicle.body.SimBody.noise_ahead`), empty
        for none.
    sensor
        One-record array of :data:`sim_vehicle.sensor.SENSOR`: the body's sensor. The
        machine flies and fits on the believed position (the record's); the field is read
        at the true one.
    ext_value
        The field value at the body's true position when resuming with ``await_value``
        set.
    events
        ``(m, 2)`` buffer for ``(code, samples before it)``.

    Returns
    -------
    n_out, n_events, noise_used
        Rows written to ``out``, events written, noise values used.
    """
    b = body[0]
    s = state[0]
    sn = sensor[0]
    n_out = 0
    n_events = 0
    n_max = out.shape[0]
    while True:
        if s.await_value:
            s.await_value = 0
            value = ext_value
        else:
            if n_out >= n_max:
                break
            commanded, n_events = _pre(s, b, fence_verts, fence_rings, fence_circles,
                                       recent, window, events, n_events, n_out)
            if not commanded:
                break
            if not (math.isfinite(s.cmd_vx) and math.isfinite(s.cmd_vy)):
                raise ValueError("tracer: non-finite velocity command")
            _guard(s, b, fence_verts, fence_rings, fence_circles)
            s.odo_before = b.odometer_m
            body_move(b, s.cmd_vx, s.cmd_vy)
            gnss_step(sn, b, noise, n_out)
            if field_kind == 0:
                s.await_value = 1
                break
            value = foffset + fscale * gaussian_sum_at(b.x_m - sn.ex_m, b.y_m - sn.ey_m, fcx,
                                                       fcy, finv, fw)
        value = sensed_value(sn, value, noise, n_out)
        if s.cmd_phase == _TRACE:
            s.traced_m += b.odometer_m - s.odo_before
        s.rec_start, s.rec_len = _ring_push(recent, s.rec_start, s.rec_len, b.x_m, b.y_m,
                                            value)
        out[n_out, 0] = b.t0_s + b.ticks * b.dt_s
        out[n_out, 1] = b.x_m
        out[n_out, 2] = b.y_m
        out[n_out, 3] = value
        out[n_out, 4] = s.cmd_phase
        n_out += 1
        _post(s, b, fence_verts, fence_rings, fence_circles, recent, window, turns, track,
              prior, b.x_m, b.y_m, value)
    return n_out, n_events, min(n_out, noise.shape[0])


@njit(cache=True)
def start_task(body: np.ndarray, state: np.ndarray) -> None:
    """Begin the task set up in ``state``: a fly-to (``kind`` 1, from the ``wp_*`` and
    ``task_*`` fields) or a trace (``kind`` 2: fly to the start, search, trace)."""
    b = body[0]
    s = state[0]
    s.odo0_m = b.odometer_m
    s.traced_m = 0.0
    s.rec_start = s.rec_len = 0
    s.tk_len = 0
    s.tk_has = 0
    s.await_value = 0
    s.area_guard = 1 if s.kind == KIND_TRACE else 0
    if s.kind == KIND_TRACE:
        s.pc = PC_TR_START
    else:
        _call_fly_to(s, b, s.task_x_m, s.task_y_m, s.wp_phase, s.wp_tolerance_m,
                     s.wp_speed_mps, PC_FT_END)


@contextlib.contextmanager
def cache_lock() -> Iterator[None]:
    """Hold an exclusive lock on the compiled cache (processes starting together take
    turns: one compiles, the others load its result). No lock where the cache directory
    cannot be written."""
    cache_path = advance.stats.cache_path
    try:
        f = (Path(cache_path) / "machine.lock").open("a") if cache_path else None
    except OSError:
        f = None
    if f is None:
        yield
        return
    with f:
        fcntl.flock(f, fcntl.LOCK_EX)
        yield


def _drop_stale_cache() -> None:
    """Forget this module's cached machine code when a kernel it inlines has changed.

    numba checks a cached function against its own source file only, but the code here
    inlines :func:`~econdor_gcs.core.fields.gaussian_sum_at`, the kinematics, the fence
    tests and the sensor: after an edit of those files alone the cache would still hand out
    the old code. A digest of the five files, kept beside the cache, decides.
    """
    sources = (Path(__file__), Path(_kinematics.__file__), Path(_fields.__file__),
               Path(_fence.__file__), Path(_sensor.__file__))
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in sources)).hexdigest()
    caches = [getattr(d, "_cache", None) for d in globals().values()
              if isinstance(d, CPUDispatcher)]
    if advance.stats.cache_path is None:
        return
    stamp = Path(advance.stats.cache_path) / "machine-sources.sha256"
    try:
        with cache_lock():
            if stamp.is_file() and stamp.read_text(encoding="ascii") == digest:
                return
            for cache in caches:
                if cache is not None:
                    cache.flush()
            stamp.write_text(digest, encoding="ascii")
    except OSError as exc:  # a read-only cache: numba itself then compiles in memory
        log.warning("tracer: cannot check the compiled cache at %s: %s", stamp.parent, exc)


_drop_stale_cache()
