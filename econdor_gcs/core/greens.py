"""The biharmonic Green's function and the dense kernels built on it.

``g(r) = r^2 (ln r - 1)``, ``g(0) = 0`` (Sandwell 1987): the Green's matrix of a set of
points, its dense solve, evaluation at query points in memory-bounded chunks, and the
blocks of the fast method computed in reusable scratch memory. Positions are in metres.

References
----------
Sandwell, D. T. (1987). Biharmonic spline interpolation of GEOS-3 and SEASAT altimeter
data. *Geophysical Research Letters*, 14(2), 139-142. https://doi.org/10.1029/GL014i002p00139
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import lapack
from scipy.spatial.distance import cdist
from threadpoolctl import threadpool_limits

__all__ = ["greens_function"]

FloatArray = NDArray[np.float64]

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

