"""Error metrics of the paper and a few more.

* learning error (eq. 3): ``E_n = mean |g~_n - g~_{n-1}|`` over the P x Q grid;
* MAE (eq. 10): ``mean |g - g~_n|``; in dB (eq. 11): ``20 log10(MAE)``;
* span ratio: ``(max - min of g~_n) / (max - min of g)``;
* iso-line error: mean distance between the estimate's and the true contour at a level;
* iso-line components missed: pieces of the true iso-line the estimate's is nowhere near.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree
from skimage import measure

from .geometry import FloatArray, Grid


def learning_error(estimate: ArrayLike, previous: ArrayLike) -> float:
    """Eq. (3)."""
    return float(np.mean(np.abs(np.asarray(estimate) - np.asarray(previous))))


def mae(truth: ArrayLike, estimate: ArrayLike) -> float:
    """Eq. (10)."""
    return float(np.mean(np.abs(np.asarray(truth) - np.asarray(estimate))))


def to_db(value: float) -> float:
    """Eq. (11): ``20 log10(value)``; ``-inf`` for 0."""
    return 20.0 * math.log10(value) if value > 0 else -math.inf


def span(values: ArrayLike) -> float:
    v = np.asarray(values)
    return float(np.max(v) - np.min(v))


def span_ratio(estimate: ArrayLike, truth: ArrayLike) -> float:
    s = span(truth)
    return span(estimate) / s if s > 0 else math.nan


def contour_points(values: FloatArray, grid: Grid, level: float) -> FloatArray:
    """All points (metres, shape (k, 2)) of the ``level`` iso-lines of a gridded field."""
    pieces = measure.find_contours(values, level)
    if not pieces:
        return np.zeros((0, 2))
    rc = np.vstack(pieces)
    x, y = grid.index_to_xy(rc[:, 0], rc[:, 1])
    return np.column_stack([x, y])


def isoline_error(truth: FloatArray, estimate: FloatArray, grid: Grid, level: float) -> float:
    """Mean symmetric distance (m) between the true and the estimated iso-line at ``level``.

    The average of (mean distance from true-contour points to the estimated contour) and
    (mean distance from estimated points to the true contour). ``nan`` when the level
    does not occur in the truth; when it occurs in only one of the two, the distance
    is taken to the far side of the area (the boundary was missed entirely).
    """
    a = contour_points(truth, grid, level)
    b = contour_points(estimate, grid, level)
    if len(a) == 0:
        return math.nan
    if len(b) == 0:
        return float(math.hypot(grid.region.width_m, grid.region.height_m))
    da, _ = cKDTree(b).query(a)
    db, _ = cKDTree(a).query(b)
    return float(0.5 * (np.mean(da) + np.mean(db)))


def isoline_components_missed(truth: FloatArray, estimate: FloatArray, grid: Grid, level: float,
                              tol_m: float = 3.0, min_length_m: float = 1.0) -> tuple[int, int]:
    """How many connected pieces of the true iso-line at ``level`` the estimate missed.

    A piece (at least ``min_length_m`` long) is missed when the median distance from its
    points to the estimate's iso-line at the same level exceeds ``tol_m``: the estimate
    has no contour where this one is (an unfound source, a boundary never crossed).

    Returns
    -------
    missed, total : int
    """
    pieces = [p for p in measure.find_contours(truth, level)
              if len(p) > 1 and float(np.sum(np.hypot(*np.diff(p, axis=0).T))) * min(
                  grid.dx, grid.dy) >= min_length_m]
    if not pieces:
        return 0, 0
    est = contour_points(estimate, grid, level)
    if len(est) == 0:
        return len(pieces), len(pieces)
    tree = cKDTree(est)
    missed = 0
    for rc in pieces:
        x, y = grid.index_to_xy(rc[:, 0], rc[:, 1])
        d, _ = tree.query(np.column_stack([x, y]))
        missed += int(np.median(d) > tol_m)
    return missed, len(pieces)
