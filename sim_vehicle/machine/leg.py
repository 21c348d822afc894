"""One trace leg: follow the iso-line one way until the leg ends.

A PID controller on the signed lateral offset ``d = side * (value - level) / |grad|``
steers the heading of a velocity command (higher values on the left for ``side`` +1, on
the right for -1). Its integral state is the path curvature, which also slows the vehicle
in tight bends. ``|grad|`` is re-estimated across the track every few samples
(:func:`~.fits.fit_cross_gradient`). The leg ends (``leg.status``, back to the trace's
``PC_TR_AFTER_LEG``) when the loop closes, the trace comes back onto a track
(:mod:`.track`), the area's boundary is ahead, the length limit or the tick budget is
reached, or the contour is lost (off by more than ``lost_offset_m`` for ``lost_time_s``,
or a full turn within a small radius).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..kinematics import wrap_angle_rad
from .fits import fit_cross_gradient, ring_push
from .noise import alpha_beta_gains, noise_std
from .records import (
    BOUNDARY,
    BUDGET,
    CLOSED,
    LENGTH_LIMIT,
    LOST,
    PC_LEG_MAIN,
    PC_LEG_MAIN_START,
    PC_LEG_START,
    PC_LEG_TURN,
    PC_TR_AFTER_LEG,
    TRACING,
)
from .records import command as _command
from .track import ONTO_PRIOR, track_push
from .vehicle import contains, edge_ahead_m, ground_speed, heading

GAIN_ACCEL_MPS2 = 20.0
"""The offset's unmodelled acceleration the filter's gains are matched to (see post): five
times what the vehicle turns with (``lateral_accel_fraction`` of ``max_accel_mps2``, 4 m/s²
by default), so the filter smooths a noisy offset without lagging the loop into chasing
its own delay."""

LAG_GAIN_ACCEL_MPS2 = 100.0
"""... when the vehicle is told of a lag (``sensor_lag_s``, or ``lag_unknown``): the
sensor's delay already takes the loop's margin, and a filter smoothing as much as
``GAIN_ACCEL_MPS2`` allows adds its own (a told lag of 1 s: more pieces left unmapped in
threshold mode, E-CONDOR's map 2 dB worse; a lag of 1 s the vehicle is not told of while
the station estimates it: E-CONDOR's map 5 dB worse)."""

GOOD_OFFSET_M = 1.0
"""A trace sample within this lateral offset of the level is where a lost trace resumes
(searched for where the vehicle is when it is already within this distance of it)."""

ORBIT_NOISE_M = 0.1
"""Readings whose noise moves the offset by more than this (m; the noise over the
tracer's gradient) can drive the lateral loop round in circles a metre or two across, on
the spot (seen at 0.4-1.3 m: the paper field's middle iso-line at noise 1, a circle at
noise 1-3; the threshold sits well below, as the tracer's gradient can start several
times too steep): then no turn is tighter than an orbit of ``min_loop_radius_m``, and a
trace comes back onto its own track only after going ``closure_min_away_m`` from it (as
it must from its start). A contour that tight is not traced through such noise anyway."""


@njit(cache=True)
def _orbit_prone(b, tr) -> bool:
    """Whether the readings' noise is large beside the gradient (``ORBIT_NOISE_M``)."""
    return noise_std(b) > ORBIT_NOISE_M * tr.grad_mag


@njit(inline="always")
def call(ctl, tr, lg, heading_rad: float, side: float) -> None:
    """Trace a leg setting off along ``heading_rad``, the higher values on the left
    (``side`` +1) or on the right (-1)."""
    lg.heading = heading_rad
    tr.side = side
    ctl.pc = PC_LEG_START


@njit(inline="always")
def call_from_crossing(ctl, params, tr, lg, cr, b, heading_rad: float, side: float) -> None:
    """:func:`call` just after the crossing detector found the level. When it filtered
    noisy readings or knows of a lag, the vehicle is past the crossing by more than a
    reading can tell: the leg starts from the offset the crossing's place and gradient
    give instead."""
    call(ctl, tr, lg, heading_rad, side)
    if cr.gain < 1.0 or params.sensor_lag_s > 0.0:
        g = max(math.hypot(cr.gx, cr.gy), 1e-9)
        lg.d_init = side * ((b.x_m - cr.x_m) * cr.gx + (b.y_m - cr.y_m) * cr.gy) / g
        lg.has_init = 1


@njit(inline="always")
def _end(ctl, lg, status: int) -> None:
    lg.status = status
    ctl.pc = PC_TR_AFTER_LEG


@njit(cache=True)
def _start(ctl, params, task, tr, lg, b, recent: np.ndarray) -> None:
    cruise = min(params.speed_mps, b.max_speed_mps)
    v_floor = min(params.approach_speed_mps, cruise)
    lg.psi = lg.heading
    lg.curvature_1pm = 0.0
    lg.speed_mps = min(max(ground_speed(b), v_floor), cruise)
    e0 = 0.0
    if ctl.rec_len > 0:
        k = (ctl.rec_start + ctl.rec_len - 1) % recent.shape[0]
        e0 = recent[k, 2] - task.level
    lg.d_f = lg.d_init if lg.has_init else tr.side * e0 / tr.grad_mag
    lg.has_init = 0
    lg.onto_prior = 0
    lg.beta = params.filter_beta
    lg.dd_f = 0.0
    lg.lost_s = 0.0
    lg.has_prev_dist = 0
    lg.n_fit = 0
    lg.turned = 0.0
    lg.th_start = 0
    lg.th_len = 0
    lg.win_start = 0
    lg.win_len = 0
    lg.turn_k = 0
    lg.turn_n = int(3.0 / b.dt_s) + 1
    ctl.pc = PC_LEG_TURN


@njit(cache=True)
def _steer(ctl, params, tr, lg, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray) -> bool:
    """The controller's command of this tick."""
    dt = b.dt_s
    cruise = min(params.speed_mps, b.max_speed_mps)
    v_floor = min(params.approach_speed_mps, cruise)
    lat_accel = params.lateral_accel_fraction * b.max_accel_mps2
    turn_max = math.radians(b.max_turn_rate_dps)
    p = min(params.trace_bandwidth_rps, 0.3 / dt)
    # the loop stays inside what the offset's filter follows (its natural frequency
    # sqrt(beta) / dt) and what a known lag leaves of the readings' news
    p = min(p, 0.5 * math.sqrt(lg.beta) / dt)
    if params.sensor_lag_s > 0.0:
        p = min(p, 0.5 / params.sensor_lag_s)
    v = lg.speed_mps
    # --- lateral PID (integral state = path curvature)
    kp = 3.0 * p * p / v
    kd = 3.0 * p / v
    ki = p**3 / v
    d_clip = 1.5 * params.lost_offset_m
    d_c = max(-d_clip, min(d_clip, lg.d_f + params.sensor_lag_s * lg.dd_f))
    w_max = min(turn_max, lat_accel / v)
    if _orbit_prone(b, tr):
        # no turn tighter than an orbit of min_loop_radius_m: slowed in a bend, the
        # loop's turn rate could otherwise grow as the speed falls, and a run of noise
        # drives the curvature's integral round into circles a metre across
        w_max = min(w_max, v / params.min_loop_radius_m)
    omega = v * lg.curvature_1pm - kp * d_c - kd * lg.dd_f
    curv_need = max(abs(lg.curvature_1pm), abs(omega) / v)  # the curvature asked for
    omega = max(-w_max, min(w_max, omega))
    curvature = lg.curvature_1pm - ki / v * d_c * dt
    curv_max = w_max / v
    lg.curvature_1pm = max(-curv_max, min(curv_max, curvature))
    if ground_speed(b) >= 0.5:
        lg.psi = heading(b)
    lg.psi += omega * dt
    ux, uy = math.cos(lg.psi), math.sin(lg.psi)
    # --- speed: cruise, slowed in bends and when the boundary is ahead
    v_target = cruise
    lg.heading_before = heading(b)
    if curv_need > 1e-9:
        v_target = min(v_target, math.sqrt(0.7 * lat_accel / curv_need))
    if ctl.traced_m < tr.slow_until_m:
        v_target = min(v_target, params.recover_speed_mps)
    edge = edge_ahead_m(b, fv, fr, fc, b.x_m, b.y_m, ux, uy)
    v_target = min(v_target, math.sqrt(2.0 * 0.5 * b.max_accel_mps2
                                       * max(edge - params.boundary_margin_m, 0.0)) + 0.5)
    v_target = max(v_target, v_floor if edge > 2.0 * params.boundary_margin_m else 0.5)
    if v_target > v:
        v = min(v_target, v + params.trace_accel_mps2 * dt)
    else:
        v = max(v_target, v - 0.6 * b.max_accel_mps2 * dt)
    lg.speed_mps = v
    lg.ux, lg.uy = ux, uy
    return _command(ctl, v * ux, v * uy, TRACING)


@njit(cache=True)
def pre(ctl, params, task, tr, lg, tk, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray,
        recent: np.ndarray) -> bool:
    """One step of the leg: a command (True), or a move to another step or back to the
    trace (False)."""
    pc = ctl.pc
    if pc == PC_LEG_START:
        _start(ctl, params, task, tr, lg, b, recent)
        return False
    if pc == PC_LEG_TURN:
        # turn onto the initial heading slowly before the controller takes over
        if lg.turn_k >= lg.turn_n or ground_speed(b) < 0.5 or (
                abs(wrap_angle_rad(heading(b) - lg.psi)) < math.radians(15)):
            ctl.pc = PC_LEG_MAIN_START
            return False
        if tr.ticks_left <= 0:
            _end(ctl, lg, BUDGET)
            return False
        tr.ticks_left -= 1
        lg.turn_k += 1
        v_floor = min(params.approach_speed_mps, min(params.speed_mps, b.max_speed_mps))
        return _command(ctl, v_floor * math.cos(lg.psi), v_floor * math.sin(lg.psi), TRACING)
    if pc == PC_LEG_MAIN_START:
        tk.has = 0  # the track breaks here (a search or a flight back came between)
        cruise = min(params.speed_mps, b.max_speed_mps)
        v_floor = min(params.approach_speed_mps, cruise)
        lg.speed_mps = min(max(ground_speed(b), v_floor), cruise)
        ctl.pc = PC_LEG_MAIN
        return False
    # PC_LEG_MAIN
    if tr.ticks_left <= 0:
        _end(ctl, lg, BUDGET)
        return False
    tr.ticks_left -= 1
    return _steer(ctl, params, tr, lg, b, fv, fr, fc)


@njit(cache=True)
def _lost_by_turning(params, lg, b, turns: np.ndarray) -> bool:
    """Keep the heading's turn history over the last orbit of ``min_loop_radius_m``: a
    full turn within it is orbiting off the contour."""
    lg.turned += wrap_angle_rad(heading(b) - lg.heading_before)
    k = lg.th_start + lg.th_len
    if k >= turns.shape[0]:  # compact the history (only its tail is alive)
        turns[: lg.th_len] = turns[lg.th_start: k].copy()
        lg.th_start, k = 0, lg.th_len
    turns[k, 0] = b.odometer_m
    turns[k, 1] = lg.turned
    lg.th_len += 1
    orbit_m = 2.0 * math.pi * params.min_loop_radius_m
    while b.odometer_m - turns[lg.th_start, 0] > orbit_m:
        lg.th_start += 1
        lg.th_len -= 1
    return abs(lg.turned - turns[lg.th_start, 1]) >= 2.0 * math.pi


@njit(cache=True)
def post(ctl, params, task, tr, lg, tk, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray,
         window: np.ndarray, turns: np.ndarray, track: np.ndarray, prior: np.ndarray,
         x: float, y: float, v: float) -> None:
    """What the leg does with the sample its command produced: the offset's update, then
    the tests that end the leg."""
    if ctl.pc == PC_LEG_TURN:
        lg.win_start, lg.win_len = ring_push(window, lg.win_start, lg.win_len, x, y, v)
        lg.d_f = tr.side * (v - task.level) / tr.grad_mag
        return
    # --- measurement update
    lg.win_start, lg.win_len = ring_push(window, lg.win_start, lg.win_len, x, y, v)
    lg.n_fit += 1
    sigma = noise_std(b)
    if lg.n_fit % 4 == 0 and lg.win_len >= max(6, params.gradient_window // 2):
        gn, spread = fit_cross_gradient(window, lg.win_start, lg.win_len)
        if spread >= params.min_spread_m and gn > 0.0:
            # a noisy fit moves the estimate less: weighed by its signal to its error
            se = sigma / (spread * math.sqrt(lg.win_len))
            w = 0.2 if se <= 0.01 * gn else 0.2 * gn * gn / (gn * gn + se * se)
            g_new = (1.0 - w) * tr.grad_mag + w * gn
            tr.grad_mag = min(max(g_new, 0.25 * tr.grad_mag0), 4.0 * tr.grad_mag0)
    dt = b.dt_s
    d_meas = tr.side * (v - task.level) / tr.grad_mag
    # the filter's gains: the tuned ones, lower only when the offset's noise is large
    # beside what a lateral acceleration of GAIN_ACCEL_MPS2 (with a told lag or one of
    # unknown size, LAG_GAIN_ACCEL_MPS2) moves it in a tick (gains matched to the vehicle's own
    # lateral acceleration filter so much that the loop lags and loses the contour:
    # docs/experiments/2026-12-05-tracer-gain.md)
    lagging = params.sensor_lag_s > 0.0 or params.lag_unknown
    accel = LAG_GAIN_ACCEL_MPS2 if lagging else GAIN_ACCEL_MPS2
    alpha, beta = alpha_beta_gains(sigma / tr.grad_mag, accel, dt)
    alpha, beta = min(alpha, params.filter_alpha), min(beta, params.filter_beta)
    lg.beta = beta
    d_pred = lg.d_f + lg.dd_f * dt
    resid = d_meas - d_pred
    lg.d_f = d_pred + alpha * resid
    lg.dd_f += beta / dt * resid
    if sigma > 0.0 or params.sensor_lag_s > 0.0:
        # noisy or lagging readings: the tests take the filtered offset, brought forward
        # by the known lag, not one reading
        d_meas = lg.d_f + params.sensor_lag_s * lg.dd_f
    if abs(d_meas) < GOOD_OFFSET_M:
        tr.has_good, tr.good_x, tr.good_y = 1, x, y
    # --- termination checks
    if task.max_length_m > 0.0 and ctl.traced_m >= task.max_length_m:
        _end(ctl, lg, LENGTH_LIMIT)
        return
    dist = math.hypot(x - tr.start_x, y - tr.start_y)
    tr.away_max = max(tr.away_max, dist)
    if tr.away_max >= max(params.closure_min_away_m, params.closure_radius_m) and (
            dist <= params.closure_radius_m and lg.has_prev_dist and dist > lg.prev_dist):
        _end(ctl, lg, CLOSED)
        return
    lg.has_prev_dist, lg.prev_dist = 1, dist
    away_m = max(params.closure_min_away_m, params.closure_radius_m) if _orbit_prone(b, tr) \
        else 0.0
    onto = track_push(ctl, params, tr, tk, track, prior, x, y, away_m) if (
        params.rejoin_min_m > 0.0) else 0
    if onto:
        lg.onto_prior = onto == ONTO_PRIOR
        _end(ctl, lg, CLOSED)
        return
    if not contains(b.xmin, b.xmax, b.ymin, b.ymax, x, y) or (
            edge_ahead_m(b, fv, fr, fc, x, y, lg.ux, lg.uy) < params.boundary_margin_m):
        _end(ctl, lg, BOUNDARY)
        return
    if _lost_by_turning(params, lg, b, turns):
        _end(ctl, lg, LOST)
        return
    lg.lost_s = lg.lost_s + dt if abs(d_meas) > params.lost_offset_m else 0.0
    if lg.lost_s > params.lost_time_s:
        _end(ctl, lg, LOST)
