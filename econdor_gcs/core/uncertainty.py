"""How uncertain the estimate still is, and how much a path not yet flown would remove.

The adaptive planner (:mod:`econdor_gcs.core.adaptive`) scores candidate paths by the
uncertainty they remove per metre. This module holds the two halves of that score:

* an :class:`UncertaintyMap` on a coarse planning grid: the unit posterior variance
  ``v(x)`` in [0, 1] (where the samples are), an amplitude ``a(x)`` (how much the field
  can vary there), so that the expected error is ``sigma(x) = a(x) sqrt(v(x))``;
* :class:`Footprints`: for each candidate path, the planning cells near it and their
  distance to it, so the variance after flying it is ``min(v(x), v_line(d(x)))``, with
  ``v_line(d)`` the unit variance at distance ``d`` from a densely sampled line.

Two variance models share that interface:

``proxy`` (the feasibility study's)
    ``v(x) = 1 - exp(-D(x)^2 / l^2)``, ``D`` the distance to the nearest sample: the
    variance a single sample leaves under a squared-exponential covariance.
``gp``
    the kriging variance of a Matérn process with hyperparameters fitted to the samples
    (:mod:`econdor_gcs.core.gp`), and ``v_line`` from the same process along a line.

The amplitude weights the variance by the local steepness of the estimate, with a floor
``s0`` that keeps unexplored flat areas worth visiting (a source the first flights
missed shows no gradient at all):

.. math:: a(\\mathbf{x}) = s_0 + \\ell_g \\max_{|\\mathbf{y} - \\mathbf{x}| \\le w}
          |\\nabla \\mu(\\mathbf{y})| .

Both choices came out of the feasibility study in ``docs``: with a constant amplitude the
planner lost to a survey on plumes; with too low a floor it missed sources.

References
----------
Krause, A., Singh, A. & Guestrin, C. (2008). Near-optimal sensor placements in Gaussian
processes. *JMLR* 9, 235-284 (greedy variance reduction).
Bryan, B. et al. (2005). Active learning for identifying function threshold boundaries.
*NIPS* 18 (the straddle score ``1.96 sigma - |mu - L|``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import RegularGridInterpolator
from scipy.ndimage import maximum_filter
from scipy.spatial import cKDTree

from .geometry import FloatArray, Grid
from .gp import Kriging, MaternHyper

__all__ = ["Footprints", "UncertaintyMap", "expected_error", "line_variance",
           "resample_polyline", "straddle", "uncertainty_map"]

STRADDLE_Z = 1.96
"""Half-width of the straddle score's interval: ``1.96 sigma`` (95 %)."""


def resample_polyline(points_m: FloatArray, step_m: float) -> FloatArray:
    """Points every ``step_m`` (or closer) along a polyline, both ends included.

    Examples
    --------
    >>> import numpy as np
    >>> resample_polyline(np.array([[0.0, 0.0], [3.0, 0.0]]), 1.0)[:, 0].tolist()
    [0.0, 1.0, 2.0, 3.0]
    """
    p = np.asarray(points_m, dtype=float).reshape(-1, 2)
    if len(p) < 2:
        return p.copy()
    seg = np.hypot(*np.diff(p, axis=0).T)
    cum = np.r_[0.0, np.cumsum(seg)]
    if cum[-1] <= 0:
        return p[:1].copy()
    n = max(2, int(math.ceil(cum[-1] / step_m)) + 1)
    s = np.linspace(0.0, cum[-1], n)
    return np.column_stack([np.interp(s, cum, p[:, 0]), np.interp(s, cum, p[:, 1])])


def line_variance(d_m: FloatArray, model: str, length_m: float,
                  hyper: MaternHyper | None = None, spacing_m: float = 1.0) -> FloatArray:
    """Unit posterior variance at distance ``d_m`` from a straight, densely sampled line.

    ``proxy``: ``1 - exp(-d^2 / l^2)``. ``gp``: the exact kriging variance of the Matérn
    process ``hyper`` with samples every ``spacing_m`` along a line (computed once on a
    table of distances and interpolated).
    """
    d = np.asarray(d_m, dtype=float)
    if model == "proxy" or hyper is None:
        return 1.0 - np.exp(-(d * d) / (length_m * length_m))
    table_d, table_v = _gp_line_table(hyper.length_m, hyper.nu, hyper.nugget, spacing_m)
    return np.interp(d, table_d, table_v)


_LINE_TABLES: dict[tuple[float, float, float, float], tuple[FloatArray, FloatArray]] = {}


def _gp_line_table(length_m: float, nu: float, nugget: float, spacing_m: float
                   ) -> tuple[FloatArray, FloatArray]:
    key = (round(length_m, 3), nu, nugget, spacing_m)
    if key not in _LINE_TABLES:
        hyper = MaternHyper(0.0, 1.0, length_m, nugget, nu)
        half = min(4.0 * length_m, 200.0)
        s = np.arange(-half, half + 1e-9, spacing_m)
        line = Kriging(hyper=hyper, cell_m=spacing_m / 2, max_global=10_000).fit(
            s, np.zeros_like(s), np.zeros_like(s))
        d = np.linspace(0.0, min(3.0 * length_m, 100.0), 200)
        v = line.unit_variance(np.zeros_like(d), d)
        _LINE_TABLES[key] = (d, np.maximum.accumulate(v))
    return _LINE_TABLES[key]


@dataclass
class UncertaintyMap:
    """Uncertainty of the estimate on the planning cells (``x_m``, ``y_m``, flattened).

    ``sigma = amplitude * sqrt(variance)`` is the expected error in field units.
    """

    x_m: FloatArray
    y_m: FloatArray
    variance: FloatArray
    amplitude: FloatArray
    mean: FloatArray
    model: str
    length_m: float
    hyper: MaternHyper | None = None
    grid: Grid | None = None
    """The planning grid the cells were flattened from (row-major, ``[row=y, col=x]``)."""
    noisy: bool = False
    """The samples are noisy and the variance is the GP's with the noise as its nugget:
    what paths observe adds up (:meth:`combine`)."""

    def combine(self, variance: FloatArray, line_var: FloatArray) -> FloatArray:
        """The unit variance of cells at ``variance`` after a path that alone would leave
        them at ``line_var``.

        Exact samples: the smaller of the two (a place sampled once is known; a second
        path over it adds nothing). Noisy ones: their information adds,
        ``1 / v = 1 / variance + 1 / line_var - 1`` (the prior's, 1, counted once): a
        second pass over a place averages its noise down as a GP with that nugget says,
        so places where noise hides the field stay worth flying again, by as much as
        they are.

        >>> u = UncertaintyMap(np.zeros(1), np.zeros(1), np.ones(1), np.ones(1),
        ...                    np.zeros(1), "gp", 5.0)
        >>> float(u.combine(np.array([0.2]), np.array([0.2]))[0])
        0.2
        >>> u.noisy = True
        >>> round(float(u.combine(np.array([0.2]), np.array([0.2]))[0]), 4)
        0.1111
        """
        if not self.noisy:
            return np.minimum(variance, line_var)
        v = np.maximum(variance, 1e-12)
        w = np.maximum(line_var, 1e-12)
        return np.asarray(1.0 / np.maximum(1.0 / v + 1.0 / w - 1.0, 1.0), dtype=float)

    def sigma(self, variance: FloatArray | None = None) -> FloatArray:
        v = self.variance if variance is None else variance
        return self.amplitude * np.sqrt(v)

    def line_variance(self, d_m: FloatArray) -> FloatArray:
        return line_variance(d_m, self.model, self.length_m, self.hyper)

    def footprint_radius_m(self) -> float:
        """Beyond this distance a new line changes the variance by less than 3 %."""
        d = np.linspace(0.0, 6.0 * self.length_m, 600)
        v = self.line_variance(d)
        far = np.nonzero(v >= 0.97 * float(np.max(v)))[0]
        return float(min(d[far[0]] if far.size else d[-1], 25.0))


def uncertainty_map(
    x_m: FloatArray,
    y_m: FloatArray,
    values: FloatArray,
    estimate: FloatArray,
    grid: Grid,
    plan_grid: Grid,
    model: str = "gp",
    length_m: float = 5.0,
    floor: float | None = None,
    gradient_gain_m: float = 5.0,
    gradient_window_m: float = 7.0,
    hyper: MaternHyper | None = None,
    noise_std: float = 0.0,
) -> UncertaintyMap:
    """The uncertainty of ``estimate`` (on ``grid``) given the samples, on ``plan_grid``.

    Parameters
    ----------
    x_m, y_m, values : ndarray
        Every sample so far.
    estimate : ndarray
        The current reconstruction on ``grid``.
    plan_grid : Grid
        The coarse grid the planner scores on.
    model : {"gp", "proxy"}
        Variance model (module docstring).
    length_m : float
        Length of the ``proxy`` model.
    floor : float or None
        ``s0``; ``None``: the fitted GP amplitude ``sigma_f`` (``gp``) or a fifth of the
        sampled value range (``proxy``).
    gradient_gain_m, gradient_window_m : float
        ``l_g`` and the width ``w`` of the maximum filter of the gradient (module docstring).
    hyper : MaternHyper or None
        Hyperparameters for ``gp`` (fitted elsewhere, e.g. once per iteration).
    noise_std : float
        The samples' noise as the station estimated it (0: exact). With ``gp`` the
        samples are then averaged per cell, each mean's noise the hyperparameters' nugget
        over its count, and paths add information (:meth:`UncertaintyMap.combine`); the
        ``proxy`` ignores it.
    """
    if model not in ("gp", "proxy"):
        raise ValueError(f"model: must be 'gp' or 'proxy', got {model!r}")
    xx, yy = plan_grid.mesh
    cx, cy = xx.ravel(), yy.ravel()
    interp = RegularGridInterpolator((grid.y, grid.x), estimate, bounds_error=False,
                                     fill_value=None)
    mean = interp(np.column_stack([cy, cx]))
    gy, gx = np.gradient(estimate, grid.dy, grid.dx)
    size = max(1, int(round(gradient_window_m / min(grid.dx, grid.dy)))) | 1
    steep = maximum_filter(np.hypot(gx, gy), size=size, mode="nearest")
    steep_c = RegularGridInterpolator((grid.y, grid.x), steep, bounds_error=False,
                                      fill_value=None)(np.column_stack([cy, cx]))
    if model == "gp":
        if hyper is None:
            raise ValueError("model 'gp' needs fitted hyperparameters")
        variance = Kriging(hyper=hyper, cell_m=1.5, noise_std=noise_std or None).fit(
            x_m, y_m, values).unit_variance(cx, cy)
        s0 = hyper.amplitude if floor is None else floor
        length = hyper.length_m
    else:
        dist, _ = cKDTree(np.column_stack([x_m, y_m])).query(np.column_stack([cx, cy]))
        variance = 1.0 - np.exp(-(dist * dist) / (length_m * length_m))
        s0 = 0.2 * float(np.ptp(values)) if floor is None else floor
        length = length_m
    amplitude = s0 + gradient_gain_m * np.maximum(steep_c, 0.0)
    return UncertaintyMap(cx, cy, np.asarray(variance, dtype=float), amplitude, mean, model,
                          length, hyper if model == "gp" else None, plan_grid,
                          noisy=model == "gp" and noise_std > 0)


class Footprints:
    """Which planning cells each candidate path reaches, and how far they are from it.

    Stored flat (CSR-like): the cells of candidate ``c`` are
    ``cells[start[c]:start[c + 1]]`` with distances ``dist_m[...]`` to the path. A cell is
    near within the model's footprint radius, or ``min_radius_m`` if that is more.
    """

    def __init__(self, umap: UncertaintyMap, paths: list[FloatArray], step_m: float = 1.0,
                 min_radius_m: float = 0.0) -> None:
        if umap.grid is None:
            raise ValueError("umap: footprints need the planning grid")
        self.umap = umap
        self.grid = umap.grid
        # ``min_radius_m``: what a path changes that the model does not see (a planner's
        # distance floor) reaches that far whatever the model's own radius
        self.radius_m = max(umap.footprint_radius_m(), min_radius_m)
        cells: list[NDArray[np.intp]] = []
        dists: list[FloatArray] = []
        for path in paths:
            c, d = self.cells_near(path, step_m)
            cells.append(c)
            dists.append(d)
        sizes = np.array([len(c) for c in cells], dtype=np.intp)
        self.start = np.r_[0, np.cumsum(sizes)].astype(np.intp)
        self.cells = np.concatenate(cells) if cells else np.zeros(0, dtype=np.intp)
        self.dist_m = np.concatenate(dists) if dists else np.zeros(0)
        self.line_var = umap.line_variance(self.dist_m)
        self.owner = np.repeat(np.arange(len(paths)), sizes)

    def cells_near(self, path: FloatArray, step_m: float = 1.0
                   ) -> tuple[NDArray[np.intp], FloatArray]:
        """Planning cells within the footprint radius of a polyline, and their distances."""
        g, r = self.grid, self.radius_m
        pts = resample_polyline(path, step_m)
        c0 = max(0, int(np.floor((pts[:, 0].min() - r - g.region.xmin) / g.dx)))
        c1 = min(g.nx - 1, int(np.ceil((pts[:, 0].max() + r - g.region.xmin) / g.dx)))
        r0 = max(0, int(np.floor((pts[:, 1].min() - r - g.region.ymin) / g.dy)))
        r1 = min(g.ny - 1, int(np.ceil((pts[:, 1].max() + r - g.region.ymin) / g.dy)))
        if c1 < c0 or r1 < r0:
            return np.zeros(0, dtype=np.intp), np.zeros(0)
        rows, cols = np.mgrid[r0:r1 + 1, c0:c1 + 1]
        idx = (rows * g.nx + cols).ravel()
        d, _ = cKDTree(pts).query(np.column_stack([self.umap.x_m[idx], self.umap.y_m[idx]]),
                                  distance_upper_bound=r)
        near = np.isfinite(d)
        return idx[near], d[near]


def expected_error(amplitude: FloatArray, variance: FloatArray, power: float) -> FloatArray:
    """Per-cell expected error measure ``a^p v^(p/2)`` (``p = 2``: variance, 1: std)."""
    return amplitude**power * variance ** (power / 2.0)


def straddle(amplitude: FloatArray, variance: FloatArray, gap: FloatArray,
             open_cells: NDArray[np.bool_]) -> FloatArray:
    """Per-cell straddle score ``max(1.96 sigma - |mu - L|, 0)`` where still open.

    ``gap`` is ``min_L |mu - L|``; ``sigma = a sqrt(v)``.

    Examples
    --------
    >>> import numpy as np
    >>> s = straddle(np.array([10.0, 10.0]), np.array([1.0, 1.0]), np.array([5.0, 30.0]),
    ...              np.array([True, True]))
    >>> np.round(s, 6).tolist()
    [14.6, 0.0]
    """
    return np.where(open_cells, np.maximum(STRADDLE_Z * amplitude * np.sqrt(variance) - gap, 0.0),
                    0.0)
