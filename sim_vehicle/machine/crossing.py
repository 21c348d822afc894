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
from .noise import filter_gain, noise_std

_SQRT2 = math.sqrt(2.0)
"""The noise of a difference of two readings over the readings' own."""


@njit(cache=True)
def crossing_gradient(ctl, params, cr, recent: np.ndarray, cur_x: float, cur_y: float,
                      cur_v: float, sigma: float, noise: float) -> tuple[float, float]:
    """The gradient where the level was crossed between the previous and this sample
    (``sigma``: the noise of the pair's difference; ``noise``: the readings' own, what
    the plane fit over the recent samples is shrunk for)."""
    gx, gy, _ = fit_gradient(recent, ctl.rec_start, ctl.rec_len, params.gradient_window,
                             1e-4, noise)
    if cr.has_prev:
        # the bracketing pair gives the derivative along the last step: trust its sign
        # (unless the difference is within the noise)
        sx, sy = cur_x - cr.prev_x, cur_y - cr.prev_y
        step = math.hypot(sx, sy)
        dv = cur_v - cr.prev_v
        if step > 1e-9 and abs(dv) > 3.0 * sigma:
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
           cross_x: float, cross_y: float, sigma: float, noise: float) -> None:
    """Record where the level was crossed and the gradient there; return to the caller."""
    gx, gy = crossing_gradient(ctl, params, cr, recent, cur_x, cur_y, cur_v, sigma, noise)
    found_at(ctl, cr, cross_x, cross_y, gx, gy)


@njit(cache=True)
def position_back(ctl, recent: np.ndarray, back: float) -> tuple[float, float]:
    """The position ``back`` samples (fractional) before the newest of the recent ones."""
    cap = recent.shape[0]
    newest = ctl.rec_start + ctl.rec_len - 1
    back = min(max(back, 0.0), ctl.rec_len - 1.0)
    i = int(back)
    f = back - i
    k0 = (newest - i) % cap
    k1 = (newest - min(i + 1, ctl.rec_len - 1)) % cap
    return (recent[k0, 0] + f * (recent[k1, 0] - recent[k0, 0]),
            recent[k0, 1] + f * (recent[k1, 1] - recent[k0, 1]))


@njit(cache=True)
def _bracketed_filtered(ctl, params, cr, b, recent: np.ndarray, x: float, y: float, v: float,
                        a: float) -> bool:
    """:func:`bracketed` on the value filtered along the track (gain ``a``), the crossing
    put back by the filter's delay and the sensor's known lag."""
    cr.vf = cr.prev_vf + a * (v - cr.prev_vf) if cr.has_prev else v
    if not cr.has_prev:
        return False
    e0, e1 = cr.prev_vf - cr.level, cr.vf - cr.level
    if e1 != 0.0 and e0 * e1 >= 0.0:
        return False
    t = 1.0 if e1 == 0.0 else e0 / (e0 - e1)
    back = (1.0 - t) + (1.0 - a) / a + params.sensor_lag_s / b.dt_s
    px, py = position_back(ctl, recent, back)
    noise = noise_std(b)
    sigma = noise * math.sqrt(2.0 * a / (2.0 - a))
    # the pair's values for the gradient's sign: the filtered ones
    prev_v = cr.prev_v
    cr.prev_v = cr.prev_vf
    _found(ctl, params, cr, recent, x, y, cr.vf, px, py, sigma, noise)
    cr.prev_v = prev_v
    return True


@njit(cache=True)
def bracketed(ctl, params, cr, b, recent: np.ndarray, x: float, y: float, v: float) -> bool:
    """If the level lies between the previous and this sample: found (True).

    Noise-free readings without a lag are taken as they are; noisy ones are filtered along
    the track first (:func:`~.noise.filter_gain`) and the crossing is put where the
    filter's delay and a known lag say the vehicle was when it crossed.
    """
    a = filter_gain(b)
    cr.gain = a
    if a < 1.0 or params.sensor_lag_s > 0.0:
        return _bracketed_filtered(ctl, params, cr, b, recent, x, y, v, a)
    cr.vf = v
    if cr.has_prev:
        level = cr.level
        e0, e1 = cr.prev_v - level, v - level
        if e1 == 0.0:
            px, py = x, y
        elif e0 * e1 < 0.0:
            t = e0 / (e0 - e1)
            px, py = cr.prev_x + t * (x - cr.prev_x), cr.prev_y + t * (y - cr.prev_y)
        else:
            return False
        noise = noise_std(b)
        _found(ctl, params, cr, recent, x, y, v, px, py, _SQRT2 * noise, noise)
        return True
    return False


@njit(inline="always")
def remember(cr, x: float, y: float, v: float) -> None:
    """This sample is the previous one for the next."""
    cr.has_prev, cr.prev_x, cr.prev_y, cr.prev_v = 1, x, y, v
    cr.prev_vf = cr.vf
