"""The sensor noise of a sample set, estimated from the samples themselves.

A vehicle samples its sensor every few decimetres along its track, and the field varies
over metres: over a few consecutive samples the field is close to a low-order polynomial
of time, so a difference operator that annihilates such polynomials leaves mostly the
noise (Rice 1984; von Neumann 1941; Hall, Kay & Titterington 1990). With the ``k``-th
order difference normalised to unit gain on white noise,

.. math::

    d_i = \\sum_{j=0}^{k} c_j v_{i+j}, \\qquad
    c_j = (-1)^{k-j} \\binom{k}{j} \\Big/ \\sqrt{\\tbinom{2k}{k}},

``d_i`` has the noise's standard deviation ``sigma`` wherever the field's own ``k``-th
derivative along the track is small. The estimate is the normalised median absolute
difference ``1.4826 median |d_i|``, so the few windows over a steep plume peak, a turn or
a gap do not count.

A vehicle that weaves about a contour (the tracer's controller) moves a little off a
smooth path between samples, and the field changes with that move; such a change is not
noise. Each difference is therefore taken net of the same difference of the positions
times the field's gradient fitted over the window: ``d_v - g . d_p``. On exact samples
of flown tracks this leaves a few parts per million of the field's span.

Consecutive samples are taken in the order given: the order a vehicle sampled them (the
station keeps its samples in arrival order, each vehicle's flight in one piece). Windows
with a step longer than ``max_step_m`` are not used: they span a jump between flights or
vehicles, or come from samples that are not along a track at all (scattered points), of
which nothing is estimated.

References
----------
Rice, J. (1984). Bandwidth choice for nonparametric regression. *Annals of Statistics*
12(4), 1215-1230.
von Neumann, J. (1941). Distribution of the ratio of the mean square successive
difference to the variance. *Annals of Mathematical Statistics* 12(4), 367-395.
Hall, P., Kay, J. W. & Titterington, D. M. (1990). Asymptotically optimal
difference-based estimation of variance in nonparametric regression. *Biometrika* 77(3),
521-528.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray

__all__ = ["NOISE_FLOOR_REL", "NoiseEstimate", "estimate_noise"]

FloatArray = NDArray[np.float64]

#: Noise below this fraction of the samples' spread (their 1st to 99th percentile) is
#: taken as none: the samples are interpolated exactly, as without noise. Exact samples
#: of flown tracks, in process or over MAVLink (float32 values, positions to the
#: centimetre), come out two orders of magnitude lower.
NOISE_FLOOR_REL = 1e-3

#: Fewer usable windows than this and nothing is estimated (noise taken as none).
MIN_DIFFERENCES = 30

# 1 / Phi^-1(3/4): the median absolute value of a standard normal variate is 1/1.4826.
_MAD_TO_STD = 1.482602218505602


@dataclass(frozen=True)
class NoiseEstimate:
    """The noise of a sample set as :func:`estimate_noise` found it.

    Attributes
    ----------
    noise_std : float
        Standard deviation of the noise in field units; ``0.0`` when it is below
        :data:`NOISE_FLOOR_REL` of the samples' spread or could not be estimated.
    raw_std : float
        The estimator's value before that floor (``nan`` when not estimated).
    n_differences : int
        Windows of consecutive samples the estimate rests on.
    spread : float
        The samples' 1st-to-99th-percentile range the floor is relative to.
    """

    noise_std: float
    raw_std: float
    n_differences: int
    spread: float

    @property
    def detected(self) -> bool:
        """Whether the samples are noisy enough to be smoothed rather than interpolated."""
        return self.noise_std > 0.0


def _difference_weights(order: int) -> FloatArray:
    c = np.array([(-1.0) ** (order - j) * math.comb(order, j) for j in range(order + 1)])
    return c / math.sqrt(math.comb(2 * order, order))


def estimate_noise(x: ArrayLike, y: ArrayLike, v: ArrayLike, *, order: int = 4,
                   half_window: int = 4, max_step_m: float = 2.5,
                   floor_rel: float = NOISE_FLOOR_REL) -> NoiseEstimate:
    """Estimate the standard deviation of the noise on samples taken along tracks.

    Parameters
    ----------
    x, y : array_like
        Sample positions in metres, in the order they were taken.
    v : array_like
        Sample values.
    order : int
        Order ``k`` of the differences (they annihilate polynomials of degree < k).
    half_window : int
        The field's gradient is fitted over ``2 half_window + 1`` consecutive samples
        centred on each difference (``half_window >= order / 2``).
    max_step_m : float
        Longest step between consecutive samples of one window.
    floor_rel : float
        Noise below this fraction of the samples' spread is reported as ``0``.

    Returns
    -------
    NoiseEstimate

    Examples
    --------
    >>> t = np.arange(5000) * 0.1                      # 10 Hz along a line at 8 m/s
    >>> x, y = 8.0 * t % 100.0, np.floor(8.0 * t / 100.0) * 2.5
    >>> v = 50.0 * np.exp(-((x - 50.0) ** 2 + (y - 50.0) ** 2) / 200.0)
    >>> estimate_noise(x, y, v).noise_std               # exact samples
    0.0
    >>> noisy = v + np.random.default_rng(0).normal(0.0, 0.5, v.size)
    >>> round(estimate_noise(x, y, noisy).noise_std, 1)
    0.5
    """
    xa = np.asarray(x, dtype=np.float64).ravel()
    ya = np.asarray(y, dtype=np.float64).ravel()
    va = np.asarray(v, dtype=np.float64).ravel()
    if order < 1 or 2 * half_window < order:
        raise ValueError(f"need order >= 1 and 2 half_window >= order, got {order}, "
                         f"{half_window}")
    width = 2 * half_window + 1
    spread = float(np.subtract(*np.percentile(va, [99.0, 1.0]))) if va.size else 0.0
    if va.size < width:
        return NoiseEstimate(0.0, math.nan, 0, spread)
    short = np.hypot(np.diff(xa), np.diff(ya)) <= max_step_m
    # windows of `width` samples whose width - 1 steps are all short
    usable = np.convolve(short, np.ones(width - 1), "valid") > width - 1.5
    n = int(np.count_nonzero(usable))
    if n < MIN_DIFFERENCES:
        return NoiseEstimate(0.0, math.nan, n, spread)
    xw, yw, vw = (sliding_window_view(a, width)[usable] for a in (xa, ya, va))
    c = _difference_weights(order)
    first = half_window - order // 2
    part = slice(first, first + order + 1)
    dv = vw[:, part] @ c
    dx = xw[:, part] @ c
    dy = yw[:, part] @ c
    gx, gy = _window_gradients(xw, yw, vw)
    d = dv - gx * dx - gy * dy
    raw = _MAD_TO_STD * float(np.median(np.abs(d)))
    noise = raw if raw > floor_rel * spread else 0.0
    return NoiseEstimate(noise, raw, n, spread)


def _window_gradients(xw: FloatArray, yw: FloatArray, vw: FloatArray
                      ) -> tuple[FloatArray, FloatArray]:
    """Least-squares plane ``v ~ a + gx x + gy y`` over each window (rows).

    Along a straight track only the gradient's component along it is determined; a ridge
    of a millionth of the positions' spread picks the smallest gradient that fits, and the
    positions' differences are then along the track too.
    """
    xc = xw - xw.mean(axis=1, keepdims=True)
    yc = yw - yw.mean(axis=1, keepdims=True)
    vc = vw - vw.mean(axis=1, keepdims=True)
    sxx = np.einsum("ij,ij->i", xc, xc)
    syy = np.einsum("ij,ij->i", yc, yc)
    sxy = np.einsum("ij,ij->i", xc, yc)
    sxv = np.einsum("ij,ij->i", xc, vc)
    syv = np.einsum("ij,ij->i", yc, vc)
    ridge = 1e-12 + 1e-6 * (sxx + syy)
    sxx += ridge
    syy += ridge
    det = sxx * syy - sxy * sxy
    return (syy * sxv - sxy * syv) / det, (sxx * syv - sxy * sxv) / det
