"""Sample handling shared by the reconstructions: input checks, merging, thinning, lookup.

Thinning uses a lattice anchored at the coordinate origin (cell ``i`` covers
``[i c, (i + 1) c)``): a new sample only ever changes the pick of its own cell, which is
what lets a warm-started fit keep untouched tiles.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from econdor_gcs.errors import ReconstructionError

FloatArray = NDArray[np.float64]
IndexArray = NDArray[np.intp]

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


def _block_mean_counts(
    x: FloatArray, y: FloatArray, v: FloatArray, cell: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """:func:`_block_mean`, and how many samples each mean is of."""
    key, _ = _cell_keys(x, y, cell)
    _, inverse = np.unique(key, return_inverse=True)
    inverse = inverse.ravel()
    counts = np.bincount(inverse).astype(np.float64)
    return (
        np.bincount(inverse, weights=x) / counts,
        np.bincount(inverse, weights=y) / counts,
        np.bincount(inverse, weights=v) / counts,
        counts,
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

