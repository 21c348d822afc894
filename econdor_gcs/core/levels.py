"""Contour levels: the Lloyd-Max quantiser of the estimate's value distribution.

The paper's eqs. (4)-(5): given the PDF ``f_g`` of the field values, the ``M`` levels
are the centroids of their decision intervals and the decision thresholds are the
midpoints between neighbouring levels::

    l_i = int_{y_i}^{y_{i+1}} x f_g(x) dx / int_{y_i}^{y_{i+1}} f_g(x) dx        (4)
    y_i = (l_i + l_{i-1}) / 2                                                   (5)

As in the authors' code the PDF is a histogram of the estimate (``bins`` bins) and the
iteration starts from evenly spaced thresholds. Reference: K. Sayood, *Introduction
to Data Compression*, ch. 9 (Lloyd 1982, Max 1960).

Two variants of the outer thresholds ``y_0`` and ``y_M``:

* ``"textbook"`` (eqs. 4-5, our default): they stay at the minimum and maximum of the
  values, so the outer levels are the centroids of the whole tails;
* ``"authors"``: the authors' ``Lloyd_Max_2.m`` recomputes them in every iteration as
  ``y_0 = (x_0 + l_1) / 2`` and ``y_M = (l_M + x_end) / 2`` (``x_0``, ``x_end`` the
  ends of the histogram), which drops the outer halves of the tails; on a uniform
  distribution the levels then tend to ``k / (M + 1)`` instead of ``(k - 1/2) / M``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .geometry import FloatArray


def lloyd_max(
    values: ArrayLike,
    m: int,
    bins: int | None = 200,
    iterations: int = 100,
    tol: float = 1e-9,
    variant: str = "textbook",
) -> FloatArray:
    """Lloyd-Max reconstruction levels (sorted) for the distribution of ``values``.

    Parameters
    ----------
    values : array_like
        Samples of the distribution (e.g. an estimated field on its grid; NaNs ignored).
    m : int
        Number of levels, ``m >= 1``.
    bins : int or None
        Histogram bins for the PDF (the authors use 500 first, then 200). ``None`` uses the
        empirical distribution of ``values`` itself.
    iterations : int
        Maximum number of Lloyd iterations.
    tol : float
        Stop when no level moves more than ``tol`` times the value range.
    variant : {"textbook", "authors"}
        Outer thresholds fixed at the value range, or recomputed as in the authors'
        ``Lloyd_Max_2.m`` (module docstring).

    Returns
    -------
    levels : ndarray of shape (m,)

    Examples
    --------
    >>> import numpy as np
    >>> np.round(lloyd_max(np.linspace(0, 1, 100001), 4, bins=None), 3)
    array([0.125, 0.375, 0.625, 0.875])
    >>> np.round(lloyd_max(np.linspace(0, 1, 100001), 4, bins=None, variant="authors",
    ...                    iterations=2000), 2)
    array([0.2, 0.4, 0.6, 0.8])
    """
    if m < 1:
        raise ValueError(f"m: need at least one level, got {m}")
    if variant not in ("textbook", "authors"):
        raise ValueError(f"variant: must be 'textbook' or 'authors', got {variant!r}")
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        raise ValueError("values: no finite values")
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        return np.full(m, lo)
    if bins is None:
        x = np.sort(v)
        w = np.ones_like(x)
    else:
        counts, edges = np.histogram(v, bins=bins, range=(lo, hi))
        x = 0.5 * (edges[:-1] + edges[1:])
        w = counts.astype(float)
    cw = np.concatenate([[0.0], np.cumsum(w)])
    cxw = np.concatenate([[0.0], np.cumsum(x * w)])
    # Start from evenly spaced thresholds: levels at the centres of m equal cells.
    x0, x_end = float(x[0]), float(x[-1])
    # Start from evenly spaced thresholds: levels at the centres of m equal cells.
    edges = np.linspace(lo, hi, m + 1)
    levels = 0.5 * (edges[:-1] + edges[1:])
    if variant == "textbook":  # the outer cells always reach the ends of the data
        edges[0], edges[-1] = -np.inf, np.inf
    for _ in range(iterations):
        bounds = np.searchsorted(x, edges, side="right")
        mass = cw[bounds[1:]] - cw[bounds[:-1]]
        moment = cxw[bounds[1:]] - cxw[bounds[:-1]]
        # An empty cell keeps its previous level (eq. 4 is undefined there).
        new = np.where(mass > 0, moment / np.where(mass > 0, mass, 1.0), levels)
        new.sort()
        moved = float(np.max(np.abs(new - levels)))
        levels = new
        edges[1:-1] = 0.5 * (levels[1:] + levels[:-1])  # eq. (5)
        if variant == "authors":  # Lloyd_Max_2.m: the outer thresholds move too
            edges[0], edges[-1] = 0.5 * (x0 + levels[0]), 0.5 * (levels[-1] + x_end)
        if moved <= tol * (hi - lo):
            break
    return levels
