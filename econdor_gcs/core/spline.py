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

:func:`reconstruct` is the entry point the rest of econdor calls.

References
----------
Sandwell, D. T. (1987). Biharmonic spline interpolation of GEOS-3 and SEASAT
altimeter data. *Geophysical Research Letters*, 14(2), 139-142.
https://doi.org/10.1029/GL014i002p00139
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Self

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import RectBivariateSpline
from scipy.linalg import lapack
from scipy.spatial.distance import cdist
from threadpoolctl import threadpool_limits

from econdor_gcs.core.geometry import Grid
from econdor_gcs.errors import ReconstructionError

__all__ = [
    "AUTO_EXACT_MAX_SAMPLES",
    "AUTO_THIN_CELL_M",
    "DEFAULT_LEVELS",
    "FAST_EVAL_SPACING_M",
    "BiharmonicSpline",
    "FastBiharmonicSpline",
    "Tile",
    "TileLevel",
    "greens_function",
    "reconstruct",
]

FloatArray = NDArray[np.float64]
IndexArray = NDArray[np.intp]

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

# Upper bound on the number of (query, sample) pairs held in memory at once
# while evaluating: 1 MB per temporary, so they are reused from the heap instead
# of mapped fresh (page faults cost more than the arithmetic on small VMs).
_CHUNK_PAIRS = 131_072


# --------------------------------------------------------------------------- #
# Green's function and the dense solve
# --------------------------------------------------------------------------- #
def greens_function(r: ArrayLike) -> FloatArray:
    """Biharmonic Green's function ``g(r) = r^2 (ln r - 1)`` with ``g(0) = 0``.

    Parameters
    ----------
    r : array_like
        Non-negative distances in metres.

    Returns
    -------
    g : ndarray
        Same shape as ``r``.

    Examples
    --------
    >>> greens_function([1.0, 2.0, 10.0]).round(4).tolist()
    [-1.0, -1.2274, 130.2585]
    """
    r = np.asarray(r, dtype=np.float64)
    return _green_from_sq(r * r)


def _green_from_sq(r2: FloatArray) -> FloatArray:
    """``g`` from squared distances: ``r^2 (ln r - 1) = r2 (ln(r2)/2 - 1)``, in place-ish."""
    out = np.zeros_like(r2)
    np.log(r2, out=out, where=r2 > 0.0)
    out *= 0.5
    out -= 1.0
    out *= r2  # r2 == 0 gives (0 - 1) * 0 = 0
    return out


def _sq_dist(xa: FloatArray, ya: FloatArray, xb: FloatArray, yb: FloatArray) -> FloatArray:
    dx = xa[:, None] - xb[None, :]
    dy = ya[:, None] - yb[None, :]
    dx *= dx
    dy *= dy
    dx += dy
    return dx


def _green_matrix(x: FloatArray, y: FloatArray) -> FloatArray:
    """``G_ij = g(|x_i - x_j|)``, built in row blocks (peak memory ~ one ``N x N`` array)."""
    gmat = np.empty((x.size, x.size))
    step = max(1, _CHUNK_PAIRS // max(1, x.size))
    for start in range(0, x.size, step):
        stop = min(start + step, x.size)
        gmat[start:stop] = _green_from_sq(_sq_dist(x[start:stop], y[start:stop], x, y))
    return gmat


def _solve_weights(x: FloatArray, y: FloatArray, v: FloatArray) -> FloatArray:
    """Solve ``G w = v`` for distinct positions (already validated and merged)."""
    gmat = _green_matrix(x, y)
    with warnings.catch_warnings():
        # Closely spaced samples make G badly conditioned; the solution is
        # still what MATLAB's backslash would return, so do not warn.
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
        try:
            w = scipy.linalg.solve(
                gmat, v, assume_a="sym", overwrite_a=True, check_finite=False
            )
        except (scipy.linalg.LinAlgError, ValueError):
            w = None
    if w is None or not np.all(np.isfinite(w)):
        gmat = _green_matrix(x, y)
        w = scipy.linalg.lstsq(gmat, v, check_finite=False)[0]
    return np.asarray(w, dtype=np.float64)


def _evaluate(
    xs: FloatArray, ys: FloatArray, w: FloatArray, xq: FloatArray, yq: FloatArray
) -> FloatArray:
    """``sum_i w_i g(|q - s_i|)`` for 1-D query arrays, in memory-bounded chunks."""
    out = np.empty(xq.size, dtype=np.float64)
    step = max(1, _CHUNK_PAIRS // max(1, xs.size))
    for start in range(0, xq.size, step):
        stop = min(start + step, xq.size)
        out[start:stop] = _green_from_sq(_sq_dist(xq[start:stop], yq[start:stop], xs, ys)) @ w
    return out


# --------------------------------------------------------------------------- #
# The fast method's kernels: small blocks of point pairs, in scratch memory
# --------------------------------------------------------------------------- #
# Pairs per block when evaluating at many points: a block and its scratch stay
# in a core's cache (1 MB each) while numpy makes its passes over them.
_BLOCK_PAIRS = 131_072
_INV_E = float(np.exp(-1.0))
_G_PER_H = 0.5 * float(np.exp(2.0))  # g = _G_PER_H * h (see _Blocks)
# Where a level's blending weights add up to less than this, its correction fades to zero.
_PHI_FLOOR = 0.1

# A tile spline that reaches this many times the range of its data on the edge of its
# blending area is ill-conditioned (samples nearly on one line, the spline bending away
# from it); such a tile is left out and its area left to the levels above.
_WILD_RATIO = 100.0
# The corners and edge midpoints of a rectangle, in units of its half sides.
_EDGE_PROBES = np.array([[-1.0, -1.0], [0.0, -1.0], [1.0, -1.0], [-1.0, 0.0],
                         [1.0, 0.0], [-1.0, 1.0], [0.0, 1.0], [1.0, 1.0]])


def _is_wild(blocks: _Blocks, pts: FloatArray, force: FloatArray, values: FloatArray,
             blend: tuple[float, float, float, float]) -> bool:
    """Whether the tile spline exceeds ``_WILD_RATIO`` x its data range at the corners
    or edge midpoints of its blending area."""
    x0, x1, y0, y1 = blend
    probe = _EDGE_PROBES * (0.5 * (x1 - x0), 0.5 * (y1 - y0)) + (0.5 * (x0 + x1),
                                                                  0.5 * (y0 + y1))
    return bool(np.abs(blocks.evaluate(pts, force, probe)).max()
                > _WILD_RATIO * max(float(np.ptp(values)), 1e-300))


@dataclass(frozen=True)
class Tile:
    """One partition-of-unity tile of a fitted :class:`FastBiharmonicSpline`.

    The tile proper is ``[x0_m, x1_m] x [y0_m, y1_m]`` (its place in the level's
    lattice); its blending weight is positive on ``blend_m = (xmin, xmax, ymin,
    ymax)``, the tile plus its overlap. Its spline interpolates
    ``values`` (the residuals its level fits) at the samples ``xy_m`` (an ``(n, 2)``
    array of positions) within its margin: ``r(x) = sum_i force_i g(|x - x_i|)``.
    ``lu`` and ``piv`` are the LU factors of its matrix, kept only by a
    warm-starting estimator.
    """

    x0_m: float
    x1_m: float
    y0_m: float
    y1_m: float
    blend_m: tuple[float, float, float, float]
    xy_m: FloatArray
    values: FloatArray
    force: FloatArray
    lu: FloatArray | None = None
    piv: NDArray[np.int32] | None = None


@dataclass(frozen=True)
class _Solution:
    force: FloatArray
    lu: FloatArray | None
    piv: NDArray[np.int32] | None


class _Blocks:
    """Green's matrices of point blocks, computed in reusable scratch memory.

    The blocks use ``h(r) = s ln s`` with ``s = (r / e)^2``: since
    ``g = r^2 (ln r - 1) = (r^2 / 2) ln(r^2 / e^2)``, ``g = c h`` with
    ``c = e^2 / 2``. Weights stay those of ``g`` (``G w = v`` is ``H (c w) = v``),
    and ``h`` takes four passes over a block: squared distances of the points
    scaled by ``1/e`` (:func:`scipy.spatial.distance.cdist`), a floor at a tiny
    value (``h(0) = 0``), the log, and the product.

    A fresh multi-megabyte temporary per block costs page faults that, on small
    virtual machines, take several times longer than the arithmetic; the two
    scratch buffers here are allocated once and grow when needed.
    """

    def __init__(self) -> None:
        self._a = np.empty(0)
        self._b = np.empty(0)

    def _scratch(self, m: int, n: int) -> tuple[FloatArray, FloatArray]:
        if self._a.size < m * n:
            self._a = np.empty(m * n)
            self._b = np.empty(m * n)
        return self._a[: m * n].reshape(m, n), self._b[: m * n].reshape(m, n)

    def matrix(self, pa: FloatArray, pb: FloatArray) -> FloatArray:
        """``h(|a_i - b_j|)`` for ``(n, 2)`` point arrays, as an ``(na, nb)`` view of
        scratch memory (valid until the next call)."""
        out, tmp = self._scratch(pa.shape[0], pb.shape[0])
        cdist(pa * _INV_E, pb * _INV_E, "sqeuclidean", out=out)
        np.maximum(out, 1e-300, out=tmp)
        np.log(tmp, out=tmp)
        out *= tmp
        return out

    def solve(self, pts: FloatArray, v: FloatArray, keep_factors: bool) -> _Solution:
        """Weights of the spline through ``v`` at ``pts`` (LU; least squares if singular)."""
        hmat = self.matrix(pts, pts)
        # h is symmetric, so its Fortran-ordered view is the same matrix: factorised in place.
        lu, piv, info = lapack.dgetrf(hmat.T, overwrite_a=True)
        if info == 0:
            u, info = lapack.dgetrs(lu, piv, v)
            if info == 0 and np.all(np.isfinite(u)):
                if keep_factors:
                    return _Solution(u / _G_PER_H, lu.copy(order="F"), piv.copy())
                return _Solution(u / _G_PER_H, None, None)
        hmat = self.matrix(pts, pts)
        u = scipy.linalg.lstsq(hmat, v, check_finite=False)[0]
        return _Solution(np.asarray(u, dtype=np.float64) / _G_PER_H, None, None)

    def evaluate(self, pts: FloatArray, w: FloatArray, query: FloatArray) -> FloatArray:
        """``sum_i w_i g(|q - p_i|)`` at the ``(m, 2)`` query points, in cache-sized blocks."""
        wh = _G_PER_H * w
        out = np.empty(query.shape[0], dtype=np.float64)
        step = max(1, _BLOCK_PAIRS // max(1, pts.shape[0]))
        for start in range(0, query.shape[0], step):
            stop = min(start + step, query.shape[0])
            np.dot(self.matrix(query[start:stop], pts), wh, out=out[start:stop])
        return out


def _resolve(prev: _Solution, v: FloatArray) -> _Solution | None:
    """New weights from kept LU factors, or None if there are none or they fail."""
    if prev.lu is None or prev.piv is None:
        return None
    u, info = lapack.dgetrs(prev.lu, prev.piv, v)
    if info != 0 or not np.all(np.isfinite(u)):
        return None
    return _Solution(u / _G_PER_H, prev.lu, prev.piv)


@contextmanager
def _one_blas_thread() -> Iterator[None]:
    """Small dense blocks only lose from BLAS threads (spin-waits, oversubscription)."""
    with threadpool_limits(limits=1, user_api="blas"):
        yield


# --------------------------------------------------------------------------- #
# Input handling (done once, at the public entry points)
# --------------------------------------------------------------------------- #
def _check_samples(x: ArrayLike, y: ArrayLike, v: ArrayLike) -> tuple[FloatArray, ...]:
    try:
        xa = np.asarray(x, dtype=np.float64).ravel()
        ya = np.asarray(y, dtype=np.float64).ravel()
        va = np.asarray(v, dtype=np.float64).ravel()
    except (TypeError, ValueError) as exc:
        raise ReconstructionError(f"samples must be numeric arrays: {exc}") from exc
    if not (xa.size == ya.size == va.size):
        raise ReconstructionError(
            f"sample arrays have mismatched lengths: x={xa.size}, y={ya.size}, v={va.size}"
        )
    for name, arr in (("x", xa), ("y", ya), ("v", va)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        if bad:
            raise ReconstructionError(f"{bad} non-finite value(s) (NaN/inf) in sample {name}")
    if xa.size < 3:
        raise ReconstructionError(f"need at least 3 samples to reconstruct, got {xa.size}")
    return xa, ya, va


def _merge_duplicates(
    x: FloatArray, y: FloatArray, v: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Average the values of samples at identical positions (else ``G`` is singular).

    Without duplicates the input is returned as it is; with them, the distinct
    positions sorted by ``(x, y)`` and the mean value at each.
    """
    order = np.lexsort((y, x))
    xs, ys = x[order], y[order]
    new = np.ones(x.size, dtype=bool)
    new[1:] = (xs[1:] != xs[:-1]) | (ys[1:] != ys[:-1])
    n_distinct = int(np.count_nonzero(new))
    if n_distinct == x.size:
        return x, y, v
    if n_distinct < 3:
        raise ReconstructionError(f"need at least 3 distinct sample positions, got {n_distinct}")
    group = np.cumsum(new) - 1
    vm = np.bincount(group, weights=v[order]) / np.bincount(group)
    return xs[new], ys[new], vm


def _check_query(x: ArrayLike, y: ArrayLike) -> tuple[FloatArray, FloatArray, tuple[int, ...]]:
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    if xa.shape != ya.shape:
        raise ReconstructionError(f"query x and y shapes differ: {xa.shape} vs {ya.shape}")
    if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(ya))):
        raise ReconstructionError("non-finite (NaN/inf) query coordinates")
    return xa.ravel(), ya.ravel(), xa.shape


# --------------------------------------------------------------------------- #
# Thinning on a lattice anchored at the coordinate origin (cell i covers
# [i c, (i + 1) c)): a new sample only ever changes the pick of its own cell,
# which is what lets a warm-started fit keep untouched tiles.
# --------------------------------------------------------------------------- #
def _cell_keys(x: FloatArray, y: FloatArray, cell: float
               ) -> tuple[NDArray[np.int64], FloatArray]:
    """Cell number of each point and its squared distance to the cell centre (in cells,
    so below 0.5)."""
    fx = x / cell
    fy = y / cell
    ix = np.floor(fx)
    iy = np.floor(fy)
    d2 = (fx - ix - 0.5) ** 2 + (fy - iy - 0.5) ** 2
    ixi = ix.astype(np.int64)
    iyi = iy.astype(np.int64)
    ixi -= ixi.min()
    iyi -= iyi.min()
    return iyi * (int(ixi.max()) + 1) + ixi, d2


def _by_cell(key: NDArray[np.int64], d2: FloatArray) -> tuple[IndexArray, NDArray[np.bool_]]:
    """Order by cell, nearest the centre first (``key + d2`` sorts both at once, d2 < 1),
    and the mask of each cell's first entry in that order."""
    order = np.argsort(key + d2)
    ks = key[order]
    first = np.ones(order.size, dtype=bool)
    np.not_equal(ks[1:], ks[:-1], out=first[1:])
    return order, first


def _block_pick(x: FloatArray, y: FloatArray, cell: float) -> IndexArray:
    """Indices of one sample per occupied ``cell`` x ``cell`` square (the one nearest its
    centre), in cell order."""
    order, first = _by_cell(*_cell_keys(x, y, cell))
    return order[first]


def _thin_pick(x: FloatArray, y: FloatArray, v: FloatArray, cell: float
               ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`_block_pick`, with the values of samples at the picked position averaged
    (as :func:`_merge_duplicates` does; duplicates share the cell and the distance)."""
    order, first = _by_cell(*_cell_keys(x, y, cell))
    head = np.flatnonzero(first)
    group = np.cumsum(first) - 1
    xo, yo = x[order], y[order]
    same = (xo == xo[head][group]) & (yo == yo[head][group])
    counts = np.bincount(group[same], minlength=head.size)
    sums = np.bincount(group[same], weights=v[order][same], minlength=head.size)
    pick = order[head]
    return x[pick], y[pick], sums / counts


def _block_mean(
    x: FloatArray, y: FloatArray, v: FloatArray, cell: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Average position and value of the samples in each ``cell`` x ``cell`` square."""
    key, _ = _cell_keys(x, y, cell)
    _, inverse = np.unique(key, return_inverse=True)
    inverse = inverse.ravel()
    counts = np.bincount(inverse).astype(np.float64)
    return (
        np.bincount(inverse, weights=x) / counts,
        np.bincount(inverse, weights=y) / counts,
        np.bincount(inverse, weights=v) / counts,
    )


class _RectIndex:
    """Points sorted by x, for the points inside axis-aligned rectangles."""

    def __init__(self, x: FloatArray, y: FloatArray, order: IndexArray | None = None) -> None:
        self.order = np.argsort(x) if order is None else order
        self.xs = x[self.order]
        self.ys = y[self.order]

    def clamped(self, x0: float, x1: float, y0: float, y1: float) -> _RectIndex:
        """The same points clamped to a rectangle (clamping keeps the x order)."""
        out = _RectIndex.__new__(_RectIndex)
        out.order = self.order
        out.xs = np.clip(self.xs, x0, x1)
        out.ys = np.clip(self.ys, y0, y1)
        return out

    def inside(self, x0: float, x1: float, y0: float, y1: float) -> IndexArray:
        lo = int(np.searchsorted(self.xs, x0, side="left"))
        hi = int(np.searchsorted(self.xs, x1, side="right"))
        yc = self.ys[lo:hi]
        return self.order[lo:hi][(yc >= y0) & (yc <= y1)]


def _bump(t: FloatArray, lo: float, hi: float) -> FloatArray:
    """C^1 bump ``(1 - s^2)^2`` on ``[lo, hi]`` (``s`` = -1..1), zero outside."""
    c = 0.5 * (lo + hi)
    h = 0.5 * (hi - lo)
    s = (t - c) / h
    out = 1.0 - s * s
    np.clip(out, 0.0, None, out=out)
    out *= out
    return out


# --------------------------------------------------------------------------- #
# Estimators
# --------------------------------------------------------------------------- #
class _Spline:
    """Shared public entry: validate once, then the private fit that trusts its input."""

    def fit(self, x: ArrayLike, y: ArrayLike, v: ArrayLike) -> Self:
        """Fit the spline to samples ``v`` at ``(x, y)``.

        Parameters
        ----------
        x, y : array_like
            Sample positions in metres (any shape, flattened).
        v : array_like
            Sample values, same size as ``x``.

        Returns
        -------
        self

        Raises
        ------
        ReconstructionError
            Fewer than 3 (distinct) samples, mismatched lengths or non-finite input.
        """
        xa, ya, va = _check_samples(x, y, v)
        return self._fit_checked(xa, ya, va, merged=False)

    def _fit_checked(self, x: FloatArray, y: FloatArray, v: FloatArray, *,
                     merged: bool) -> Self:
        raise NotImplementedError


class BiharmonicSpline(_Spline):
    """Exact biharmonic spline (Sandwell 1987; MATLAB ``griddata`` ``'v4'``).

    .. math::

        f(\\mathbf{x}) = \\sum_{i=1}^{N} w_i \\, g(|\\mathbf{x} - \\mathbf{x}_i|),
        \\quad g(r) = r^2 (\\ln r - 1),\\ g(0) = 0, \\quad G\\,w = v,

    solved densely with :func:`scipy.linalg.solve` (least squares if singular).
    Samples at identical positions are merged (mean value) first. Cost is
    ``O(N^2)`` memory and ``O(N^3)`` time -- use :class:`FastBiharmonicSpline`
    beyond a few thousand samples.

    Attributes
    ----------
    coords_ : tuple of ndarray
        ``(x, y)`` of the distinct sample positions actually used.
    force_ : ndarray
        The weights ``w``.
    n_samples_ : int
        Number of samples given to :meth:`fit` (before merging).

    References
    ----------
    Sandwell, D. T. (1987). Biharmonic spline interpolation of GEOS-3 and
    SEASAT altimeter data. *Geophys. Res. Lett.*, 14(2), 139-142.

    Examples
    --------
    >>> spl = BiharmonicSpline().fit([0, 10, 0, 10], [0, 0, 10, 10], [1, 2, 3, 4])
    >>> spl.predict([0, 10], [0, 10]).round(6)
    array([1., 4.])
    """

    def _fit_checked(
        self, x: FloatArray, y: FloatArray, v: FloatArray, *, merged: bool
    ) -> BiharmonicSpline:
        self.n_samples_ = int(x.size)
        if not merged:
            x, y, v = _merge_duplicates(x, y, v)
        self.coords_ = (x, y)
        self.force_ = _solve_weights(x, y, v)
        return self

    def predict(self, x: ArrayLike, y: ArrayLike) -> FloatArray:
        """Evaluate the spline at ``(x, y)``; returns an array of the shape of ``x``."""
        if not hasattr(self, "force_"):
            raise ReconstructionError("BiharmonicSpline is not fitted; call fit() first")
        xq, yq, shape = _check_query(x, y)
        return _evaluate(self.coords_[0], self.coords_[1], self.force_, xq, yq).reshape(shape)


@dataclass(frozen=True)
class TileLevel:
    """One partition-of-unity level of :class:`FastBiharmonicSpline`.

    The level interpolates the residual left by the levels before it, at the
    samples thinned to one per ``cell_m`` square (``None``: all the estimator's
    thinned samples), with an exact spline per square tile of side ``tile_m``
    (a lattice anchored at the coordinate origin) through the samples within
    ``margin_m`` of the tile. A window holding fewer than ``min_samples`` is
    widened (x1.5) until it holds them; a tile whose window holds more than
    ``max_samples`` is split in four, margin and overlap halved but the margin
    not below ``min_margin_m``. Tile splines are blended with weights positive up
    to ``overlap_m`` beyond the tile (``overlap_m <= margin_m``).
    """

    tile_m: float
    margin_m: float
    overlap_m: float
    cell_m: float | None = None
    min_samples: int = 40
    max_samples: int = 300
    min_margin_m: float = 2.0

    def __post_init__(self) -> None:
        if not (self.tile_m > 0 and 0 < self.overlap_m <= self.margin_m):
            raise ValueError(f"TileLevel needs tile_m > 0 and 0 < overlap_m <= margin_m: {self}")
        if self.cell_m is not None and self.cell_m <= 0:
            raise ValueError(f"TileLevel.cell_m must be > 0 or None: {self}")
        if not 1 <= self.min_samples <= self.max_samples:
            raise ValueError(f"TileLevel needs 1 <= min_samples <= max_samples: {self}")


#: A mid level on samples 1.5 m apart fills the gaps between contour lines as the
#: exact solve does; a fine level adds the detail along the lines.
DEFAULT_LEVELS = (
    TileLevel(tile_m=20.0, margin_m=10.0, overlap_m=5.0, cell_m=1.5, max_samples=400),
    TileLevel(tile_m=10.0, margin_m=4.0, overlap_m=2.5, max_samples=120, min_margin_m=1.0),
)

_TileKey = tuple[float, float, float, float]


class FastBiharmonicSpline(_Spline):
    """Approximate biharmonic spline for large ``N`` (multilevel partition of unity).

    Approximates the exact surface of :class:`BiharmonicSpline`,

    .. math::

        f(\\mathbf{x}) = \\sum_{i} w_i \\, g(|\\mathbf{x} - \\mathbf{x}_i|),
        \\quad g(r) = r^2 (\\ln r - 1),

    in time roughly linear in ``N``:

    1. Thin: one sample per square cell of side ``cell_size`` is kept (the one
       nearest the cell centre; ``thinning="mean"`` averages position and
       value instead). Cells are anchored at the coordinate origin, so a new
       sample only ever changes its own cell. Along densely sampled contour
       lines this keeps about one sample per ``cell_size`` metres -- closer
       samples add almost nothing to the reconstruction. Picking keeps real
       samples, so the surface still interpolates data as the exact spline
       does; averaging biases curved fields by about ``g'' cell^2 / 24`` but
       smooths sensor noise.
    2. Coarse global level: one sample per ``coarse_cell`` square (the one
       nearest the cell centre; the cell grows until at most
       ``coarse_max_samples`` remain) is interpolated by an exact spline
       ``f_0``. It carries the long-range behaviour of the exact solution into
       unsampled areas.
    3. Tile levels (``levels``, coarse to fine; see :class:`TileLevel`): level
       ``l`` interpolates the residual ``v_i - sum_{m<l} f_m(x_i)`` by exact
       splines ``r_k`` on overlapping square tiles, blended by a partition of
       unity:

       .. math:: f_l = \\frac{\\sum_k \\phi_k r_k}{\\sum_k \\phi_k}, \\qquad
                 f = f_0 + \\sum_l f_l,

       ``phi_k`` a product of C^1 bumps ``(1 - s^2)^2`` over the tile plus its
       overlap. A tile whose spline reaches 100x the range of its data on the
       edge of its blending area is left out: its samples lie nearly on one
       line (typically a window widened into a sparse area), and it would
       extrapolate wildly across a gap. Where the weights add up to less than 0.1 (around
       such a tile, beyond a level's tiles) the denominator is held at 0.1, so
       the level's correction fades out there. Every ``r_k`` interpolates all samples of its level where
       its weight is positive, so the finest level (on all thinned samples)
       makes ``f`` interpolate every kept sample. A mid level on sparser
       samples with wide windows fills the gaps between contour lines as the
       global solve does; the fine level's small windows stay cheap.

    With ``warm_start=True``, :meth:`fit` reuses the previous fit: a tile whose
    samples are the same as before keeps the LU factors of its matrix and is
    only re-solved for its new residuals (``O(n^2)`` instead of ``O(n^3)``); if
    its residuals are the same too it keeps its weights. The result is the same,
    to the last bit, as a fit from scratch.

    Parameters
    ----------
    cell_size : float
        Thinning cell side in metres (``0`` disables thinning).
    thinning : {"pick", "mean"}
        Keep the sample nearest each cell centre, or the cell average.
    coarse_cell : float or None
        Initial cell side of the coarse level in metres (``None`` or ``0``:
        no coarse level).
    coarse_max_samples : int
        Upper bound on the coarse level's sample count.
    levels : sequence of TileLevel
        The partition-of-unity levels, coarse to fine (default
        :data:`DEFAULT_LEVELS`).
    warm_start : bool
        Reuse the tiles of the previous :meth:`fit` whose samples did not change.

    Attributes
    ----------
    coarse_ : BiharmonicSpline or None
        The coarse global level.
    tiles_ : list of list of Tile
        The tiles of each level.
    bounds_ : list of tuple of float
        ``(xmin, xmax, ymin, ymax)`` covered by each level's tiles.
    n_samples_ : int
        Number of samples given to :meth:`fit`.
    n_used_ : int
        Number of samples after thinning (duplicates merged).
    n_factored_ : int
        Tiles whose matrix was factorised in the last :meth:`fit`.
    n_resolved_ : int
        Tiles re-solved from kept factors (warm start).
    n_kept_ : int
        Tiles whose weights were kept as they were (warm start).
    n_dropped_ : int
        Ill-conditioned tiles left out (see above).

    References
    ----------
    Sandwell, D. T. (1987). Biharmonic spline interpolation of GEOS-3 and
    SEASAT altimeter data. *Geophys. Res. Lett.*, 14(2), 139-142.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> x, y = rng.uniform(0, 40, 3000), rng.uniform(0, 40, 3000)
    >>> spl = FastBiharmonicSpline().fit(x, y, np.sin(x / 8) * np.cos(y / 8))
    >>> xq, yq = np.meshgrid(np.linspace(5, 35, 31), np.linspace(5, 35, 31))
    >>> bool(np.abs(spl.predict(xq, yq) - np.sin(xq / 8) * np.cos(yq / 8)).max() < 1e-4)
    True
    """

    def __init__(
        self,
        cell_size: float = 0.5,
        thinning: str = "pick",
        coarse_cell: float | None = 6.0,
        coarse_max_samples: int = 300,
        levels: tuple[TileLevel, ...] = DEFAULT_LEVELS,
        warm_start: bool = False,
    ) -> None:
        self.cell_size = cell_size
        self.thinning = thinning
        self.coarse_cell = coarse_cell
        self.coarse_max_samples = coarse_max_samples
        self.levels = levels
        self.warm_start = warm_start

    # -- fitting --------------------------------------------------------------------------
    def _fit_checked(
        self, x: FloatArray, y: FloatArray, v: FloatArray, *, merged: bool
    ) -> FastBiharmonicSpline:
        if self.thinning not in ("pick", "mean"):
            raise ValueError(f"thinning must be 'pick' or 'mean', got {self.thinning!r}")
        if not self.levels or not all(isinstance(lv, TileLevel) for lv in self.levels):
            raise ValueError("levels must be a non-empty sequence of TileLevel")
        previous = self._previous_tiles()
        self.n_samples_ = int(x.size)
        blocks = _Blocks()
        with _one_blas_thread():
            x, y, v = self._thin(x, y, v, merged)
            self.n_used_ = int(x.size)
            r = self._fit_coarse(x, y, v, blocks)
            self.tiles_: list[list[Tile]] = []
            self.bounds_: list[tuple[float, float, float, float]] = []
            self.n_factored_ = self.n_resolved_ = self.n_kept_ = self.n_dropped_ = 0
            last = len(self.levels) - 1
            pts = np.column_stack((x, y))
            index = _RectIndex(x, y)
            for k, level in enumerate(self.levels):
                if level.cell_m is not None and level.cell_m > float(self.cell_size):
                    sel = _block_pick(x, y, level.cell_m)
                    lpts, rs, lindex = pts[sel], r[sel], _RectIndex(x[sel], y[sel])
                else:
                    lpts, rs, lindex = pts, r, index
                prev = previous[k] if k < len(previous) else {}
                tiles, bounds = self._fit_level(level, lpts, rs, lindex, prev, blocks)
                self.tiles_.append(tiles)
                self.bounds_.append(bounds)
                if k < last:
                    r = r - _evaluate_level(tiles, bounds, pts, index, blocks)
        return self

    def _previous_tiles(self) -> list[dict[_TileKey, Tile]]:
        if not self.warm_start or not hasattr(self, "tiles_"):
            return []
        return [{(t.x0_m, t.x1_m, t.y0_m, t.y1_m): t for t in level} for level in self.tiles_]

    def _thin(self, x: FloatArray, y: FloatArray, v: FloatArray, merged: bool
              ) -> tuple[FloatArray, FloatArray, FloatArray]:
        cell = float(self.cell_size)
        if cell > 0 and self.thinning == "pick":
            xb, yb, vb = _thin_pick(x, y, v, cell)  # duplicates merged on the way
        else:
            if not merged:
                x, y, v = _merge_duplicates(x, y, v)
            if cell <= 0:
                return x, y, v
            xb, yb, vb = _block_mean(x, y, v, cell)
        if xb.size < 3:
            return _merge_duplicates(x, y, v) if not merged else (x, y, v)
        return xb, yb, vb

    def _fit_coarse(self, x: FloatArray, y: FloatArray, v: FloatArray, blocks: _Blocks
                    ) -> FloatArray:
        """Fit the coarse level; return the residuals the tiles interpolate."""
        self.coarse_: BiharmonicSpline | None = None
        if not self.coarse_cell:
            return v
        # Picking, not averaging: the residual is then zero at the coarse nodes
        # (averaging cost ~10 % MAE on dense data).
        cell = float(self.coarse_cell)
        pick = _block_pick(x, y, cell)
        while pick.size > int(self.coarse_max_samples):
            cell *= 1.25
            pick = _block_pick(x, y, cell)
        if pick.size < 3:
            return v
        self.coarse_ = BiharmonicSpline()._fit_checked(x[pick], y[pick], v[pick], merged=True)
        return v - blocks.evaluate(np.column_stack(self.coarse_.coords_), self.coarse_.force_,
                                   np.column_stack((x, y)))

    def _fit_level(self, level: TileLevel, pts: FloatArray, r: FloatArray, index: _RectIndex,
                   previous: dict[_TileKey, Tile], blocks: _Blocks
                   ) -> tuple[list[Tile], tuple[float, float, float, float]]:
        x, y = pts[:, 0], pts[:, 1]
        tile = float(level.tile_m)
        i0, i1 = int(np.floor(x.min() / tile)), int(np.floor(x.max() / tile))
        j0, j1 = int(np.floor(y.min() / tile)), int(np.floor(y.max() / tile))
        # Initial tiles: the lattice cells over the samples' bounding box; crowded
        # tiles are split in four (margin and overlap scale with the tile).
        stack = [(i * tile, (i + 1) * tile, j * tile, (j + 1) * tile, 1.0)
                 for j in range(j1, j0 - 1, -1) for i in range(i1, i0 - 1, -1)]
        n_min = min(level.min_samples, x.size)
        tiles: list[Tile] = []
        while stack:
            tx0, tx1, ty0, ty1, scale = stack.pop()
            margin = max(level.margin_m * scale, min(level.min_margin_m, level.margin_m))
            widened = False
            while True:
                sel = index.inside(tx0 - margin, tx1 + margin, ty0 - margin, ty1 + margin)
                if sel.size >= n_min:
                    break
                margin *= 1.5
                widened = True
            # A window widened in a sparse area may overshoot max_samples; splitting
            # it would only widen the children's windows again.
            if sel.size > level.max_samples and not widened and scale > 1.0 / 16:
                xm, ym = 0.5 * (tx0 + tx1), 0.5 * (ty0 + ty1)
                half = 0.5 * scale
                stack += [(xm, tx1, ym, ty1, half), (tx0, xm, ym, ty1, half),
                          (xm, tx1, ty0, ym, half), (tx0, xm, ty0, ym, half)]
                continue
            tpts, rs = pts[sel], r[sel]
            overlap = min(level.overlap_m * scale, margin)
            blend = (tx0 - overlap, tx1 + overlap, ty0 - overlap, ty1 + overlap)
            sol = self._tile_solution(previous.get((tx0, tx1, ty0, ty1)), tpts, rs, blocks)
            if _is_wild(blocks, tpts, sol.force, rs, blend):
                self.n_dropped_ += 1
                continue
            tiles.append(Tile(tx0, tx1, ty0, ty1, blend, tpts, rs, sol.force, sol.lu, sol.piv))
        return tiles, (i0 * tile, (i1 + 1) * tile, j0 * tile, (j1 + 1) * tile)

    def _tile_solution(self, prev: Tile | None, pts: FloatArray, rs: FloatArray,
                       blocks: _Blocks) -> _Solution:
        if prev is not None and np.array_equal(prev.xy_m, pts):
            kept = _Solution(prev.force, prev.lu, prev.piv)
            if np.array_equal(prev.values, rs):
                self.n_kept_ += 1
                return kept
            again = _resolve(kept, rs)
            if again is not None:
                self.n_resolved_ += 1
                return again
        self.n_factored_ += 1
        return blocks.solve(pts, rs, keep_factors=bool(self.warm_start))

    # -- evaluation -----------------------------------------------------------------------
    def predict(self, x: ArrayLike, y: ArrayLike) -> FloatArray:
        """Evaluate the spline at ``(x, y)``; returns an array of the shape of ``x``."""
        if not hasattr(self, "tiles_"):
            raise ReconstructionError("FastBiharmonicSpline is not fitted; call fit() first")
        xq, yq, shape = _check_query(x, y)
        blocks = _Blocks()
        query = np.column_stack((xq, yq))
        index = _RectIndex(xq, yq)
        with _one_blas_thread():
            out = np.zeros(xq.size)
            if self.coarse_ is not None:
                out += blocks.evaluate(np.column_stack(self.coarse_.coords_),
                                       self.coarse_.force_, query)
            for tiles, bounds in zip(self.tiles_, self.bounds_, strict=True):
                out += _evaluate_level(tiles, bounds, query, index, blocks)
        return out.reshape(shape)


def _evaluate_level(tiles: list[Tile], bounds: tuple[float, float, float, float],
                    query: FloatArray, index: _RectIndex, blocks: _Blocks) -> FloatArray:
    """One level's blend ``sum_k phi_k r_k / sum_k phi_k`` at ``(m, 2)`` query points."""
    x0, x1, y0, y1 = bounds
    # Outside the tiles the blending weights of the edge tiles are extended
    # (clamped coordinates) so every point gets a value.
    xw = np.clip(query[:, 0], x0, x1)
    yw = np.clip(query[:, 1], y0, y1)
    index = index.clamped(x0, x1, y0, y1)
    num = np.zeros(query.shape[0])
    den = np.zeros(query.shape[0])
    for t in tiles:
        lo_x, hi_x, lo_y, hi_y = t.blend_m
        idx = index.inside(lo_x, hi_x, lo_y, hi_y)
        if idx.size == 0:
            continue
        phi = _bump(xw[idx], lo_x, hi_x)
        phi *= _bump(yw[idx], lo_y, hi_y)
        den[idx] += phi
        num[idx] += phi * blocks.evaluate(t.xy_m, t.force, query[idx])
    # A plain partition of unity where the weights add up to more than the floor
    # (inside a level's cover they add up to at least ~0.38); beyond the tiles'
    # blending areas the correction fades out instead of jumping to zero.
    np.maximum(den, _PHI_FLOOR, out=den)
    return num / den


# --------------------------------------------------------------------------- #
# Convenience entry point
# --------------------------------------------------------------------------- #
def reconstruct(
    x: ArrayLike, y: ArrayLike, v: ArrayLike, grid: Grid, method: str = "auto",
    estimator: FastBiharmonicSpline | None = None,
) -> FloatArray:
    """Reconstruct the field on ``grid`` from scattered samples.

    Parameters
    ----------
    x, y : array_like
        Sample positions in metres.
    v : array_like
        Sample values.
    grid : Grid
        Evaluation grid.
    method : {"auto", "exact", "fast"}
        ``"exact"``: :class:`BiharmonicSpline`; ``"fast"``:
        :class:`FastBiharmonicSpline`; ``"auto"``: exact when there are at most
        :data:`AUTO_EXACT_MAX_SAMPLES` distinct positions; else exact on the samples
        thinned to one per :data:`AUTO_THIN_CELL_M` square when that leaves at most
        as many (the fast method's tiles extrapolate across the wide gaps such sparse
        sets have); fast otherwise. The
        fast method is evaluated at :data:`FAST_EVAL_SPACING_M` spacing and
        upsampled bicubically when ``grid`` is finer.
    estimator : FastBiharmonicSpline, optional
        The fast estimator to fit when the fast method is chosen: for example
        one with ``warm_start=True`` kept between calls on a growing sample set,
        which then reuses the tiles whose samples did not change. Default: a
        new :class:`FastBiharmonicSpline`.

    Returns
    -------
    ndarray
        Shape ``grid.shape`` = ``(ny, nx)``, indexed ``[row=y, col=x]``.

    Raises
    ------
    ReconstructionError
        Bad samples (see :meth:`BiharmonicSpline.fit`).
    ValueError
        Unknown ``method``.
    """
    if method not in ("auto", "exact", "fast"):
        raise ValueError(f"method must be 'auto', 'exact' or 'fast', got {method!r}")
    xa, ya, va = _check_samples(x, y, v)
    n_samples = xa.size
    exact = method == "exact"
    if method == "auto":
        exact = n_samples <= AUTO_EXACT_MAX_SAMPLES
        if not exact:
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
    else:
        est = FastBiharmonicSpline() if estimator is None else estimator
    est._fit_checked(xa, ya, va, merged=False)  # (merging twice returns the input)
    est.n_samples_ = int(n_samples)
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
        return RectBivariateSpline(coarse.y, coarse.x, zc, kx=3, ky=3)(grid.y, grid.x)
    xx, yy = grid.mesh
    return est.predict(xx, yy)
