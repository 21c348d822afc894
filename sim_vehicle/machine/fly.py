"""Fly to a point with a braking profile: the fly-to task, and the subroutine the trace
calls (to its start, back to where it last held the iso-line, back to its entry)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .records import EV_FENCE, KIND_TRACE, PC_DONE, PC_FT, PC_FT_END, REACHED, UNREACHABLE
from .records import command as _command
from .records import emit as _emit

FENCE_STUCK_S = 2.0
"""A fly-to held at the fence this long (command and speed near zero) gives up."""


@njit(inline="always")
def call(ctl, ft, b, x: float, y: float, phase: int, tol: float, speed: float, ret: int
         ) -> None:
    """Fly to ``(x, y)`` (arrived within ``tol``) at up to ``speed``, samples tagged
    ``phase``; then go on at ``ret`` with ``ft.ok`` saying whether it got there."""
    ft.x_m = x
    ft.y_m = y
    ft.phase = phase
    ft.tol_m = tol
    ft.speed_mps = min(speed, b.max_speed_mps)
    dist0 = math.hypot(x - b.x_m, y - b.y_m)
    ft.k_max = int(3.0 * (dist0 / max(ft.speed_mps, 0.1) + 10.0) / b.dt_s) + 100
    ft.k = 0
    ft.ret = ret
    b.fence_stuck = 0
    ctl.pc = PC_FT


@njit(cache=True)
def pre(ctl, task, ft, b, events: np.ndarray) -> bool:
    """One step of the fly-to: a command (True) or a return to the caller (False)."""
    if ctl.pc == PC_FT_END:  # the fly-to task's own end
        ctl.status = REACHED if ft.ok else UNREACHABLE
        ctl.pc = PC_DONE
        return False
    if ft.k >= ft.k_max:
        ft.ok = 1 if math.hypot(ft.x_m - b.x_m, ft.y_m - b.y_m) <= ft.tol_m else 0
        ctl.pc = ft.ret
        return False
    ex, ey = ft.x_m - b.x_m, ft.y_m - b.y_m
    dist = math.hypot(ex, ey)
    if dist <= ft.tol_m:
        ft.ok = 1
        ctl.pc = ft.ret
        return False
    if b.fence_stuck * b.dt_s >= FENCE_STUCK_S:  # held at the fence: give up
        if task.kind == KIND_TRACE:
            _emit(ctl, events, EV_FENCE)
        ft.ok = 0
        ctl.pc = ft.ret
        return False
    # brake so as to stop at the target; small floor so we always get there
    v = min(ft.speed_mps, math.sqrt(2.0 * 0.6 * b.max_accel_mps2 * dist),
            max(2.0 * dist, 0.3))
    v = max(v, min(0.3, ft.speed_mps))
    ft.k += 1
    return _command(ctl, v * ex / dist, v * ey / dist, ft.phase)
