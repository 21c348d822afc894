"""Biharmonic spline interpolation of scattered samples (Sandwell, 1987).

This is the reconstruction used by the data fusion center: the same surface as
MATLAB's ``griddata(x, y, v, xq, yq, 'v4')``. Given ``N`` samples ``v_i`` at
distinct positions ``x_i`` the interpolant is

.. math::

    f(\\mathbf{x}) = \\sum_{i=1}^{N} w_i \\, g(|\\mathbf{x} - \\mathbf{x}_i|),
    \\qquad g(r) = r^2 (\\ln r - 1), \\quad g(0) = 0,

with the weights solving the dense ``N x N`` system ``G w = v``,
``G_ij = g(|x_i - x_j|)``. There is no polynomial term. Positions are in metres.

Two estimators share a verde-like API (``fit(x, y, v) -> self``,
``predict(x, y) -> values``; constructor arguments stored unchanged, fitted
state in attributes ending in ``_``):

* :class:`BiharmonicSpline` -- the exact dense solve, the reference.
  ``O(N^2)`` memory and ``O(N^3)`` time: fine up to a few thousand samples.
* :class:`FastBiharmonicSpline` -- thinned samples, a coarse global exact
  spline, and partition-of-unity levels of overlapping tiles (an exact spline
  per tile, split where samples are dense) for the residual: a mid level on
  samples 1.5 m apart that fills the gaps between contour lines, a fine level
  on all kept samples. About linear in ``N``; on samples recorded from real
  runs its error against the true field stays within a few percent of the
  exact solve's wherever that is feasible (``bench/reconstruction.py``).
  With ``warm_start=True`` a refit keeps the factorisations (and, when their
  data did not change, the weights) of tiles whose samples did not change.

:func:`fit_field` (and :func:`reconstruct`, its values alone) is the entry point the rest
of econdor calls. Samples with sensor noise are not interpolated as they are: the noise is
estimated from the samples (:mod:`.noise`) and they are smoothed first by local smoothing
splines (:mod:`.smoothing`); exact samples are interpolated. The pieces live in their own
modules: the Green's function and dense kernels (:mod:`.greens`), sample
checks and thinning (:mod:`.samples`), the exact solve (:mod:`.exact_spline`) and the
fast method (:mod:`.fast_spline`); this module holds the choice between them.

References
----------
Sandwell, D. T. (1987). Biharmonic spline interpolation of GEOS-3 and SEASAT
altimeter data. *Geophysical Research Letters*, 14(2), 139-142.
https://doi.org/10.1029/GL014i002p00139
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import RectBivariateSpline

from econdor_gcs.core.exact_spline import BiharmonicSpline
from econdor_gcs.core.fast_spline import DEFAULT_LEVELS, FastBiharmonicSpline, Tile, TileLevel
from econdor_gcs.core.geometry import Grid
from econdor_gcs.core.gp import Kriging
from econdor_gcs.core.greens import FloatArray, greens_function
from econdor_gcs.core.noise import NoiseEstimate
from econdor_gcs.core.samples import _check_samples, _merge_duplicates, _thin_pick
from econdor_gcs.core.smoothing import denoise

__all__ = [
    "AUTO_EXACT_MAX_SAMPLES",
    "AUTO_THIN_CELL_M",
    "DEFAULT_LEVELS",
    "FAST_EVAL_SPACING_M",
    "METHODS",
    "SMOOTHED_CELL_M",
    "BiharmonicSpline",
    "FastBiharmonicSpline",
    "Reconstruction",
    "Tile",
    "TileLevel",
    "fit_field",
    "greens_function",
    "reconstruct",
]

#: ``reconstruct(method="auto")`` uses the exact solve up to this many distinct positions,
#: and beyond that on the samples thinned to one per :data:`AUTO_THIN_CELL_M` square as
#: long as no more than this many are left.
AUTO_EXACT_MAX_SAMPLES = 2000

#: The thinning of the exact solve beyond :data:`AUTO_EXACT_MAX_SAMPLES` distinct positions
#: (the fast method's own ``cell_size``).
AUTO_THIN_CELL_M = 0.5

#: ``reconstruct`` evaluates the fast method on grids no finer than this and
#: upsamples bicubically (no measurable loss: the field varies over metres).
FAST_EVAL_SPACING_M = 1.0


#: Thinning of smoothed samples for the fast method: their values vary no faster than the
#: smoothing lets them, over a metre or more.
SMOOTHED_CELL_M = 1.0

METHODS = ("auto", "exact", "fast", "kriging")
"""The reconstruction methods (``algorithm.reconstruction``)."""


@dataclass(frozen=True)
class Reconstruction:
    """A field reconstructed on a grid, and what the reconstruction found out on the way.

    Attributes
    ----------
    values : ndarray
        The estimate on the grid, ``[row=y, col=x]``.
    noise : NoiseEstimate
        The samples' noise (estimated, or the one given); ``noise.noise_std`` is 0 when the
        samples were taken as exact and interpolated.
    method : str
        The method used: ``"exact"``, ``"fast"`` or ``"kriging"``.
    std : ndarray or None
        Kriging only, when asked for: the posterior standard deviation of the field on the
        grid under the fitted noise.
    """

    values: FloatArray
    noise: NoiseEstimate
    method: str
    std: FloatArray | None = None

    @property
    def noise_std(self) -> float:
        return self.noise.noise_std


# --------------------------------------------------------------------------- #
# Convenience entry points
# --------------------------------------------------------------------------- #
def reconstruct(
    x: ArrayLike, y: ArrayLike, v: ArrayLike, grid: Grid, method: str = "auto",
    estimator: FastBiharmonicSpline | None = None, noise_std: float | None = None,
) -> FloatArray:
    """Reconstruct the field on ``grid`` from scattered samples: :func:`fit_field`'s values."""
    return fit_field(x, y, v, grid, method, estimator, noise_std).values


def fit_field(
    x: ArrayLike, y: ArrayLike, v: ArrayLike, grid: Grid, method: str = "auto",
    estimator: FastBiharmonicSpline | None = None, noise_std: float | None = None,
    return_std: bool = False,
) -> Reconstruction:
    """Reconstruct the field on ``grid`` from scattered samples.

    The samples' noise is estimated first (unless given):
    :func:`~econdor_gcs.core.noise.estimate_noise` on the samples in the order they were
    taken. Exact samples are interpolated; noisy ones are smoothed by local smoothing
    splines (:func:`~econdor_gcs.core.smoothing.denoise`) and the spline interpolates the
    smoothed values. Kriging fits its model with the noise fixed to the estimate.

    Parameters
    ----------
    x, y : array_like
        Sample positions in metres, in the order they were taken.
    v : array_like
        Sample values.
    grid : Grid
        Evaluation grid.
    method : {"auto", "exact", "fast", "kriging"}
        ``"exact"``: :class:`BiharmonicSpline`; ``"fast"``:
        :class:`FastBiharmonicSpline`; ``"auto"``: exact when there are at most
        :data:`AUTO_EXACT_MAX_SAMPLES` distinct positions; else exact on the samples
        thinned to one per :data:`AUTO_THIN_CELL_M` square when that leaves at most
        as many (the fast method's tiles extrapolate across the wide gaps such sparse
        sets have); fast otherwise. The
        fast method is evaluated at :data:`FAST_EVAL_SPACING_M` spacing and
        upsampled bicubically when ``grid`` is finer. ``"kriging"``:
        :class:`~econdor_gcs.core.gp.Kriging` (Matérn, hyperparameters by likelihood).
    estimator : FastBiharmonicSpline, optional
        The fast estimator to fit when the fast method is chosen: for example
        one with ``warm_start=True`` kept between calls on a growing sample set,
        which then reuses the tiles whose samples did not change (its own
        ``noise_std`` is not used: this function's is). Default: a
        new :class:`FastBiharmonicSpline` (thinning smoothed samples to
        :data:`SMOOTHED_CELL_M`).
    noise_std : float or None
        The samples' noise: ``None`` estimates it, ``0`` takes them as exact.
    return_std : bool
        Kriging only: also the posterior standard deviation on the grid.

    Returns
    -------
    Reconstruction
        ``values`` of shape ``grid.shape`` = ``(ny, nx)``, indexed ``[row=y, col=x]``.

    Raises
    ------
    ReconstructionError
        Bad samples (see :meth:`BiharmonicSpline.fit`).
    ValueError
        Unknown ``method``, or a negative ``noise_std``.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, "
                         f"got {method!r}")
    xa, ya, va = _check_samples(x, y, v)
    if method == "kriging":
        return _krige(xa, ya, va, grid, noise_std, return_std)
    n_samples = xa.size
    d = denoise(xa, ya, va, noise_std)
    xa, ya, va = d.x, d.y, d.v
    exact = method == "exact"
    if method == "auto":
        exact = xa.size <= AUTO_EXACT_MAX_SAMPLES
        if not exact and not d.smoothed:  # smoothed samples are one per cell already
            # one sample per AUTO_THIN_CELL_M square, as the fast method thins them (no
            # more than the distinct positions)
            xt, yt, vt = _thin_pick(xa, ya, va, AUTO_THIN_CELL_M)
            exact = xt.size <= AUTO_EXACT_MAX_SAMPLES
            if exact:
                xm, ym, vm = _merge_duplicates(xa, ya, va)
                xa, ya, va = (xm, ym, vm) if xm.size <= AUTO_EXACT_MAX_SAMPLES else (xt, yt, vt)
    if exact:
        est: BiharmonicSpline | FastBiharmonicSpline = BiharmonicSpline()
        xa, ya, va = _merge_duplicates(xa, ya, va)
    elif estimator is not None:
        est = estimator
    else:
        est = FastBiharmonicSpline(cell_size=SMOOTHED_CELL_M) if d.smoothed else \
            FastBiharmonicSpline()
    est._fit_checked(xa, ya, va, merged=False)  # (merging twice returns the input)
    est._record_noise(d, n_samples)
    used = "exact" if exact else "fast"
    if isinstance(est, FastBiharmonicSpline) and min(grid.dx, grid.dy) < FAST_EVAL_SPACING_M:
        # The field varies on scales of metres: evaluate on a grid of about
        # FAST_EVAL_SPACING_M spacing and upsample with a bicubic spline.
        coarse = Grid(
            grid.region,
            max(4, min(grid.nx, int(np.ceil(grid.region.width_m / FAST_EVAL_SPACING_M)) + 1)),
            max(4, min(grid.ny, int(np.ceil(grid.region.height_m / FAST_EVAL_SPACING_M)) + 1)),
        )
        xx, yy = coarse.mesh
        zc = est.predict(xx, yy)
        values = RectBivariateSpline(coarse.y, coarse.x, zc, kx=3, ky=3)(grid.y, grid.x)
        return Reconstruction(values, d.noise, used)
    xx, yy = grid.mesh
    return Reconstruction(est.predict(xx, yy), d.noise, used)


def _krige(x: FloatArray, y: FloatArray, v: FloatArray, grid: Grid, noise_std: float | None,
           return_std: bool) -> Reconstruction:
    model = Kriging(noise_std=noise_std).fit(x, y, v)
    xx, yy = grid.mesh
    std = None
    if return_std:
        values, std = model.predict(xx, yy, return_std=True)
    else:
        values = model.predict(xx, yy)
    assert isinstance(values, np.ndarray)
    noise = model.noise_ if model.noise_ is not None else NoiseEstimate(
        model.noise_std_, model.noise_std_, 0, float(np.ptp(v)))
    return Reconstruction(values, noise, "kriging", std)
