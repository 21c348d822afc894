"""The vehicle's own estimate of its readings' noise, and what the parts make of it.

The vehicle is not told how noisy its sensor is (the sensor's parameters in a mission are
the simulation's truth, not the vehicle's knowledge). It estimates the noise from its own
readings: the fourth difference of consecutive readings ``y[k] - 4 y[k-1] + 6 y[k-2] -
4 y[k-3] + y[k-4]`` is the residual of a cubic through five samples. Along a flight at
constant speed the field's part of it is of the order of its fourth derivative times the
step to the fourth (a few parts in 100,000 of the field's range on the benchmark fields
at 0.8 m steps); white noise of standard deviation ``sigma`` gives it the variance ``70 sigma^2``. A lagging
sensor smooths the field's part further and leaves the read-out noise as it is. The
running mean of its square over 70 is the noise's variance; a single difference more than
25 times the estimate (a kink of the path, a sharp feature of the field) counts as 25
times. The mean square of the first difference gives the signal's own change per sample,
what :func:`filter_gain` weighs the noise against. That the residual is noise, not the
field's shape, is told by the fifth difference (variance ``252 sigma^2``): white noise
gives it the same mean square over 252 as the fourth over 70, a noise-free reading
about half of it (:data:`_WHITE`).

The estimate lives in the body record (the vehicle keeps it from task to task) and is
updated on every reading, in transit too.
"""

from __future__ import annotations

import math

from numba import njit

_C4 = 70.0
"""Variance of the fourth difference of white noise of unit variance."""
_C5 = 252.0
"""... and of its fifth difference."""
_WHITE = 0.8
"""White noise gives the fifth and fourth differences, each over its variance, the same
mean square (a ratio of 1); what a noise-free reading leaves in them (the field's shape,
the kinks of the path where the commanded acceleration jumps) gives about half: below
this ratio it is not noise."""
_WARM = 1000
"""Readings after which the running means forget at a constant rate (1 / _WARM)."""
_CLIP = 25.0


@njit(cache=True)
def noise_update(b, v: float) -> None:
    """Take reading ``v`` into the estimate."""
    n = b.noise_n
    if n >= 5:
        d4 = v - 4.0 * b.nh1 + 6.0 * b.nh2 - 4.0 * b.nh3 + b.nh4
        d5 = d4 - (b.nh1 - 4.0 * b.nh2 + 6.0 * b.nh3 - 4.0 * b.nh4 + b.nh5)
        sq4 = d4 * d4 / _C4
        sq5 = d5 * d5 / _C5
        if n > 24:
            sq4 = min(sq4, _CLIP * b.noise_var)
            sq5 = min(sq5, _CLIP * b.noise_var5)
        w = 1.0 / min(n - 4, _WARM)
        b.noise_var += w * (sq4 - b.noise_var)
        b.noise_var5 += w * (sq5 - b.noise_var5)
        d1 = v - b.nh1
        b.diff_var += w * (d1 * d1 - b.diff_var)
    b.nh5, b.nh4, b.nh3, b.nh2, b.nh1 = b.nh4, b.nh3, b.nh2, b.nh1, v
    b.noise_n = n + 1


@njit(inline="always")
def noise_std(b) -> float:
    """The readings' noise as the vehicle estimates it (field units): 0 before 25 readings
    and while the differences are not white (the field's own shape, not noise)."""
    if b.noise_n <= 24 or b.noise_var5 < _WHITE * b.noise_var:
        return 0.0
    return math.sqrt(b.noise_var)


@njit(cache=True)
def filter_gain(b) -> float:
    """The gain of an exponential filter of the readings along the track: 1 (no filter)
    when the noise is small beside the signal's change per sample, less the noisier.

    A gain ``a`` delays the filtered value by ``(1 - a) / a`` samples and leaves
    ``sigma sqrt(a / (2 - a))`` of the noise; their sum (in the signal's change per
    sample) is least near ``a = (2 sqrt 2 s / sigma)^(2/3)``, ``s`` that change.
    """
    sigma = noise_std(b)
    if sigma <= 0.0:
        return 1.0
    s2 = b.diff_var - 2.0 * sigma * sigma
    if s2 <= 0.0:
        return 0.05
    a = (2.0 * math.sqrt(2.0) * math.sqrt(s2) / sigma) ** (2.0 / 3.0)
    return 1.0 if a >= 1.0 else max(a, 0.05)


@njit(cache=True)
def alpha_beta_gains(sigma_m: float, accel_mps2: float, dt_s: float) -> tuple[float, float]:
    """Steady-state gains of an alpha-beta filter (Kalata's tracking index): position noise
    ``sigma_m``, unmodelled acceleration ``accel_mps2``, sample interval ``dt_s``."""
    if sigma_m <= 0.0:
        return 1.0, 2.0
    lam = accel_mps2 * dt_s * dt_s / sigma_m
    r = (4.0 + lam - math.sqrt(8.0 * lam + lam * lam)) / 4.0
    alpha = 1.0 - r * r
    beta = 2.0 * (2.0 - alpha) - 4.0 * math.sqrt(1.0 - alpha)
    return alpha, beta
