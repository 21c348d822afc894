"""The level-crossing detector of the search and the edge walk.

The level is found where two consecutive samples bracket it (:func:`bracketed`); the
crossing point is interpolated between them and the gradient there comes from a plane fit
over the recent samples, checked against the bracketing pair (:func:`crossing_gradient`).
A finding returns to where the caller asked (``cross.ret``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .fits import fit_gradient


@njit(cache=True)
def crossing_gradient(ctl, params, cr, recent: np.ndarray, cur_x: float, cur_y: float,
                      cur_v: float) -> tuple[float, float]:
    """The gradient where the level was crossed between the previous and this sample."""
    gx, gy, _ = fit_gradient(recent, ctl.rec_start, ctl.rec_len, params.gradient_window)
    if cr.has_prev:
        # the bracketing pair gives the derivative along the last step: trust its sign
        sx, sy = cur_x - cr.prev_x, cur_y - cr.prev_y
        step = math.hypot(sx, sy)
        dv = cur_v - cr.prev_v
        if step > 1e-9:
            ux, uy = sx / step, sy / step
            along = dv / step
            gfit_along = gx * ux + gy * uy
            if math.hypot(gx, gy) < 1e-12 or gfit_along * along <= 0.0:
                # the fit disagrees with the crossing itself: use the step direction
                gx, gy = along * ux, along * uy
    return gx, gy


@njit(cache=True)
def found_at(ctl, cr, x: float, y: float, gx: float, gy: float) -> None:
    """Record where the level was found and the gradient there; return to the caller."""
    cr.found = 1
    cr.x_m = x
    cr.y_m = y
    cr.gx = gx
    cr.gy = gy
    ctl.pc = cr.ret


@njit(cache=True)
def _found(ctl, params, cr, recent: np.ndarray, cur_x: float, cur_y: float, cur_v: float,
           cross_x: float, cross_y: float) -> None:
    """Record where the level was crossed and the gradient there; return to the caller."""
    gx, gy = crossing_gradient(ctl, params, cr, recent, cur_x, cur_y, cur_v)
    found_at(ctl, cr, cross_x, cross_y, gx, gy)


@njit(cache=True)
def bracketed(ctl, params, cr, recent: np.ndarray, x: float, y: float, v: float) -> bool:
    """If the level lies between the previous and this sample: found (True)."""
    if cr.has_prev:
        level = cr.level
        e0, e1 = cr.prev_v - level, v - level
        if e1 == 0.0:
            _found(ctl, params, cr, recent, x, y, v, x, y)
            return True
        if e0 * e1 < 0.0:
            t = e0 / (e0 - e1)
            _found(ctl, params, cr, recent, x, y, v, cr.prev_x + t * (x - cr.prev_x),
                   cr.prev_y + t * (y - cr.prev_y))
            return True
    return False


@njit(inline="always")
def remember(cr, x: float, y: float, v: float) -> None:
    """This sample is the previous one for the next."""
    cr.has_prev, cr.prev_x, cr.prev_y, cr.prev_v = 1, x, y, v
