"""The machine's tick loop: :func:`advance` runs a task for up to ``n`` sensor ticks.

Each tick is :func:`pre` (the parts' steps that take no time, until one issues a velocity
command), the guard, the kinematic sub-steps, the GNSS error's step, a sensor reading and
:func:`post` (what the part that commanded does with the new sample). Both dispatch on the
program counter's tens (``PART_*``) to the part's own ``pre`` and ``post``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from econdor_gcs.core.fields import gaussian_sum_at

from ..sensor import gnss_step, sensed_value
from . import fly, leg, search, trace, walk
from .fits import ring_push
from .guard import guard
from .noise import noise_update
from .records import (
    KIND_TRACE,
    PART_FLY,
    PART_LEG,
    PART_SEARCH,
    PART_TRACE,
    PART_WALK,
    PC_DONE,
    PC_FT_END,
    PC_TR_START,
    TRACING,
)
from .vehicle import body_move


@njit(cache=True)
def pre(s, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray, recent: np.ndarray,
        events: np.ndarray) -> bool:
    """Run the parts' steps until one issues a velocity command (True) or the task ends
    (False)."""
    ctl = s.ctl
    while True:
        part = ctl.pc // 10
        if part == PC_DONE:
            return False
        if part == PART_FLY:
            commanded = fly.pre(ctl, s.task, s.fly, b, events)
        elif part == PART_SEARCH:
            commanded = search.pre(ctl, s.params, s.cross, s.search, b, fv, fr, fc, recent)
        elif part == PART_LEG:
            commanded = leg.pre(ctl, s.params, s.task, s.trace, s.leg, s.track, b, fv, fr, fc,
                                recent)
        elif part == PART_WALK:
            commanded = walk.pre(ctl, s.params, s.task, s.cross, s.trace, s.walk, b, fv, fr,
                                 fc)
        elif part == PART_TRACE:
            commanded = trace.pre(ctl, s.params, s.task, s.fly, s.cross, s.search, s.trace,
                                  s.leg, s.walk, b, fv, fr, fc, events)
        else:
            raise AssertionError("tracer state machine: unknown program counter")
        if commanded:
            return True


@njit(cache=True)
def post(s, b, fv: np.ndarray, fr: np.ndarray, fc: np.ndarray, recent: np.ndarray,
         window: np.ndarray, turns: np.ndarray, track: np.ndarray, prior: np.ndarray,
         x: float, y: float, v: float) -> None:
    """What the part that issued the command does with the new sample."""
    part = s.ctl.pc // 10  # the part that commanded (a fly-to uses no sample)
    if part == PART_SEARCH:
        search.post(s.ctl, s.params, s.cross, s.search, b, recent, x, y, v)
    elif part == PART_WALK:
        walk.post(s.ctl, s.params, s.task, s.cross, s.trace, s.walk, b, recent, x, y, v)
    elif part == PART_LEG:
        leg.post(s.ctl, s.params, s.task, s.trace, s.leg, s.track, b, fv, fr, fc, window, turns,
                 track, prior, x, y, v)


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
        One-record arrays of :data:`~.records.BODY` and :data:`~.records.STATE`.
    field_kind
        1: the field is the Gaussian sum ``foffset + fscale * sum(...)`` of the arrays
        ``fcx, fcy, finv, fw`` (read here); 0: read by the caller (see the package
        docstring).
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
    ctl = s.ctl
    sn = sensor[0]
    ctl.n_out = 0
    ctl.n_events = 0
    n_max = out.shape[0]
    while True:
        if ctl.await_value:
            ctl.await_value = 0
            value = ext_value
        else:
            if ctl.n_out >= n_max:
                break
            if not pre(s, b, fence_verts, fence_rings, fence_circles, recent, events):
                break
            if not (math.isfinite(ctl.cmd_vx) and math.isfinite(ctl.cmd_vy)):
                raise ValueError("tracer: non-finite velocity command")
            guard(ctl, b, fence_verts, fence_rings, fence_circles)
            ctl.odo_before = b.odometer_m
            body_move(b, ctl.cmd_vx, ctl.cmd_vy)
            gnss_step(sn, b, noise, ctl.n_out)
            if field_kind == 0:
                ctl.await_value = 1
                break
            value = foffset + fscale * gaussian_sum_at(b.x_m - sn.ex_m, b.y_m - sn.ey_m, fcx,
                                                       fcy, finv, fw)
        n_out = ctl.n_out
        value = sensed_value(sn, value, noise, n_out)
        noise_update(b, value)
        if ctl.cmd_phase == TRACING:
            ctl.traced_m += b.odometer_m - ctl.odo_before
        ctl.rec_start, ctl.rec_len = ring_push(recent, ctl.rec_start, ctl.rec_len, b.x_m, b.y_m,
                                               value)
        out[n_out, 0] = b.t0_s + b.ticks * b.dt_s
        out[n_out, 1] = b.x_m
        out[n_out, 2] = b.y_m
        out[n_out, 3] = value
        out[n_out, 4] = ctl.cmd_phase
        ctl.n_out = n_out + 1
        post(s, b, fence_verts, fence_rings, fence_circles, recent, window, turns, track, prior,
             b.x_m, b.y_m, value)
    return ctl.n_out, ctl.n_events, min(ctl.n_out, noise.shape[0])


@njit(cache=True)
def start_task(body: np.ndarray, state: np.ndarray) -> None:
    """Begin the task set up in ``state``: a fly-to (``kind`` 1, from the ``wp_*`` and
    ``task_*`` fields) or a trace (``kind`` 2: fly to the start, search, trace)."""
    b = body[0]
    s = state[0]
    ctl = s.ctl
    task = s.task
    ctl.odo0_m = b.odometer_m
    ctl.traced_m = 0.0
    ctl.rec_start = ctl.rec_len = 0
    s.track.len = 0
    s.track.has = 0
    ctl.await_value = 0
    ctl.area_guard = 1 if task.kind == KIND_TRACE else 0
    if task.kind == KIND_TRACE:
        ctl.pc = PC_TR_START
    else:
        fly.call(ctl, s.fly, b, task.task_x_m, task.task_y_m, task.wp_phase,
                 task.wp_tolerance_m, task.wp_speed_mps, PC_FT_END)
