"""Where the field is a plateau, average over all of it: a per-place choice of scale.

The local smoothing splines of :mod:`.smoothing` choose one damping per 10 m tile. On a
plateau (the constant background around a plume, a flat stretch of any field) that
damping leaves a plane fitted to the tile's window, whose value still carries the noise
of a window's worth of samples (``sigma sqrt(3 / n)``), although the plateau may extend
tens of metres and hold thousands of samples; on plumes it is most of the area and most of
a noisy map's error. A larger tile cannot fix it: a square of 40 m around a place in the
background reaches a plume, and one that holds a flank keeps its noise over the flat rest.
The plateau has the shape it has, so the samples averaged are chosen by value as well as
by place.

At each sample ``i``, for square windows of growing half-width ``h_1 < h_2 < ...``, the
estimate at scale ``h`` is the mean of the samples in the square whose smoothed value
(the spline's, :mod:`.smoothing`) is within ``delta = similar_sd * sigma`` of sample
``i``'s, to the value bins of ``delta / 2`` the sums are kept in (the "range" weight of
a bilateral filter; Tomasi & Manduchi 1998), with standard deviation ``sigma / sqrt(n_h)``.
Two rules keep it off the field's slopes and peaks:

* **plateau**: a scale counts only while those similar samples are at least
  ``plateau_share`` of the square's. On a slope the samples within ``delta`` of a value
  are a narrow band along its iso-line (a small share), and a band's mean is not the
  place's value; on a plateau they are most of the square.
* **intersection of confidence intervals** (ICI; Goldenshluger & Nemirovski 1997,
  Katkovnik 1999): the intervals ``[m_h - gamma s_h, m_h + gamma s_h]`` are intersected in
  order, and the largest ``h`` whose interval still meets all the smaller ones' is the
  place's scale: a wider square whose similar samples lie higher or lower (the foot of a
  flank) moves its mean by more than the narrower intervals allow.

Where the chosen half-width is at most ``keep_m`` the spline's value stays (on a slope it
follows what a mean cannot); elsewhere the plateau's mean replaces it. The sums come from
summed-area tables over (x, y, value) bins, a bilateral grid (Paris & Durand 2009), so
every width costs the same whatever the number of samples.

References
----------
Goldenshluger, A. & Nemirovski, A. (1997). On spatially adaptive estimation of
nonparametric regression. *Mathematical Methods of Statistics* 6(2), 135-170.
Katkovnik, V. (1999). A new method for varying adaptive bandwidth selection. *IEEE
Transactions on Signal Processing* 47(9), 2567-2571.
Paris, S. & Durand, F. (2009). A fast approximation of the bilateral filter using a signal
processing approach. *International Journal of Computer Vision* 81(1), 24-52.
Tomasi, C. & Manduchi, R. (1998). Bilateral filtering for gray and color images. *ICCV*.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

__all__ = ["ScaleChoice", "ScaleParams", "widen_on_plateaus"]


@dataclass(frozen=True)
class ScaleParams:
    """The widths the rule chooses among and how strict it is (module docstring).

    ``half_widths_m``: the squares' half-widths, growing; ``similar_sd``: ``delta`` in
    noise standard deviations; ``plateau_share``: the least share of a square's samples
    that must be similar; ``gamma``: each interval's half-width in standard deviations;
    ``keep_m``: a place whose chosen half-width is at most this keeps the spline's value.
    The bilateral grid has ``bins_per_half_width`` spatial bins per half-width and value
    bins of ``delta / 2``, coarser where that would make more than ``max_value_bins``
    value bins or more than ``max_cells`` bins in all (its tables' memory).
    """

    half_widths_m: tuple[float, ...] = (5.0, 10.0, 20.0, 40.0, 80.0)
    similar_sd: float = 0.6
    plateau_share: float = 0.3
    gamma: float = 2.0
    keep_m: float = 10.0
    bins_per_half_width: int = 3
    max_value_bins: int = 512
    max_cells: int = 2_000_000

    def __post_init__(self) -> None:
        h = np.asarray(self.half_widths_m, dtype=float)
        if h.size < 2 or not np.all(np.diff(h) > 0) or h[0] <= 0:
            raise ValueError(f"ScaleParams needs at least two growing half-widths > 0: {self}")
        if not (self.similar_sd > 0 and self.gamma > 0 and 0 <= self.plateau_share <= 1):
            raise ValueError(f"ScaleParams needs similar_sd > 0, gamma > 0 and "
                             f"0 <= plateau_share <= 1: {self}")
        if not (self.bins_per_half_width >= 1 and self.max_value_bins >= 8
                and self.max_cells >= 64 * self.max_value_bins):
            raise ValueError(f"ScaleParams needs bins_per_half_width >= 1, max_value_bins >= 8 "
                             f"and max_cells >= 64 max_value_bins: {self}")


@dataclass(frozen=True)
class ScaleChoice:
    """What :func:`widen_on_plateaus` returns.

    Attributes
    ----------
    values : ndarray
        The values at the samples: the plateau's mean at the chosen scale, or the given
        smoothed value where the chosen half-width is at most ``keep_m``.
    half_width_m : ndarray
        The half-width chosen at each sample (0: not even the first one).
    """

    values: FloatArray
    half_width_m: FloatArray


def widen_on_plateaus(x: FloatArray, y: FloatArray, v: FloatArray, counts: FloatArray,
                      smoothed: FloatArray, noise_std: float,
                      params: ScaleParams | None = None) -> ScaleChoice:
    """Average each sample over the plateau it lies on, where it lies on one (module
    docstring).

    Parameters
    ----------
    x, y : ndarray
        Distinct sample positions (m).
    v : ndarray
        The samples' values (cell means of ``counts`` samples: noise variance
        ``noise_std**2 / counts``).
    counts : ndarray
        How many samples each value is the mean of.
    smoothed : ndarray
        The smoothing spline's values at the samples: they decide which samples are alike,
        and stay where the scale is fine.
    noise_std : float
        The noise of one sample (> 0).
    params : ScaleParams, optional

    Returns
    -------
    ScaleChoice

    Examples
    --------
    A plateau at 10 with a narrow peak: the plateau's samples are averaged over all of it,
    the peak's keep their smoothed values.

    >>> rng = np.random.default_rng(0)
    >>> x, y = rng.uniform(0, 100, 6000), rng.uniform(0, 100, 6000)
    >>> truth = 10.0 + 80.0 * np.exp(-((x - 50) ** 2 + (y - 50) ** 2) / 32.0)
    >>> v = truth + rng.normal(0, 1, x.size)
    >>> out = widen_on_plateaus(x, y, v, np.ones(x.size), truth + 0.3, 1.0)
    >>> flat = truth < 10.01
    >>> bool(np.abs(out.values[flat] - 10.0).mean() < 0.05)   # the plateau: averaged
    True
    >>> bool(np.all(out.values[truth > 20] == truth[truth > 20] + 0.3))   # the peak: kept
    True
    """
    if not noise_std > 0:
        raise ValueError(f"noise_std must be > 0, got {noise_std}")
    p = params or ScaleParams()
    m = np.asarray(smoothed, dtype=np.float64)
    w = np.asarray(counts, dtype=np.float64)
    n = x.size
    delta = p.similar_sd * noise_std
    m_lo = float(m.min())
    value_bin = max(0.5 * delta, (float(m.max()) - m_lo) / (p.max_value_bins - 1), 1e-300)
    iq = np.floor((m - m_lo) / value_bin).astype(np.intp)
    nq = int(iq.max()) + 1
    reach = int(math.ceil(delta / value_bin))
    q0 = np.clip(iq - reach, 0, nq)
    q1 = np.clip(iq + reach + 1, 0, nq)
    x0, y0 = float(x.min()), float(y.min())
    extent = max(float(x.max()) - x0, float(y.max()) - y0)

    lower = np.full(n, -np.inf)
    upper = np.full(n, np.inf)
    alive = np.ones(n, dtype=bool)
    values = m.copy()
    chosen = np.zeros(n)
    var0 = noise_std * noise_std
    for h in p.half_widths_m:
        space_bin = max(h / p.bins_per_half_width, extent / math.sqrt(p.max_cells / nq), 1e-9)
        r = int(round(h / space_bin))
        ix = np.floor((x - x0) / space_bin).astype(np.intp)
        iy = np.floor((y - y0) / space_bin).astype(np.intp)
        nx, ny = int(ix.max()) + 1, int(iy.max()) + 1
        cell = (iy * nx + ix) * nq + iq
        tables = np.zeros((2, ny + 1, nx + 1, nq + 1))
        for k, weights in enumerate((w, w * v)):
            tables[k, 1:, 1:, 1:] = np.bincount(cell, weights=weights,
                                                minlength=ny * nx * nq).reshape(ny, nx, nq)
        tables = tables.cumsum(axis=1).cumsum(axis=2).cumsum(axis=3)
        i0, i1 = np.clip(ix - r, 0, nx), np.clip(ix + r + 1, 0, nx)
        j0, j1 = np.clip(iy - r, 0, ny), np.clip(iy + r + 1, 0, ny)
        alike = _box(tables, j0, j1, i0, i1, q0, q1)
        everything = _box(tables[:1], j0, j1, i0, i1, np.zeros_like(q0), np.full_like(q1, nq))
        count, total = alike[0], everything[0]
        ok = count > 0
        mean = np.divide(alike[1], count, out=m.copy(), where=ok)
        sd = np.sqrt(np.divide(var0, count, out=np.full(n, np.inf), where=ok))
        lower = np.maximum(lower, mean - p.gamma * sd)
        upper = np.minimum(upper, mean + p.gamma * sd)
        alive &= ok & (lower <= upper) & (count >= p.plateau_share * total)
        chosen[alive] = h
        wide = alive & (h > p.keep_m)
        values[wide] = mean[wide]
    return ScaleChoice(values, chosen)


def _box(tables: FloatArray, j0: NDArray[np.intp], j1: NDArray[np.intp],
         i0: NDArray[np.intp], i1: NDArray[np.intp], q0: NDArray[np.intp],
         q1: NDArray[np.intp]) -> FloatArray:
    """Sums of each table over the boxes ``[j0, j1) x [i0, i1) x [q0, q1)`` (summed-area
    tables with a leading zero row on every axis)."""
    out = np.zeros((tables.shape[0], j0.size))
    for j, sj in ((j1, 1), (j0, -1)):
        for i, si in ((i1, 1), (i0, -1)):
            for q, sq in ((q1, 1), (q0, -1)):
                out += (sj * si * sq) * tables[:, j, i, q]
    return out
