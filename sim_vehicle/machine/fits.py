"""Fits of the field's gradient from the vehicle's own samples.

:func:`fit_gradient` fits a plane to the last samples (the search's descent, the crossing's
gradient); :func:`fit_cross_gradient` the magnitude of the gradient across a curved track
(the trace leg's offset scale). Samples are kept in rings of ``x, y, value`` rows
(:func:`ring_push`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def ring_push(buf: np.ndarray, start: int, length: int, x: float, y: float, v: float
              ) -> tuple[int, int]:
    """Append the row ``x, y, v`` to the ring ``buf[start : start + length]`` (the oldest
    row goes when it is full); the ring's new ``start, length``."""
    cap = buf.shape[0]
    if length < cap:
        k = (start + length) % cap
        length += 1
    else:
        k = start
        start = (start + 1) % cap
    buf[k, 0] = x
    buf[k, 1] = y
    buf[k, 2] = v
    return start, length


@njit(cache=True)
def fit_gradient(buf: np.ndarray, start: int, length: int, count: int,
                 ridge: float = 1e-4, sigma: float = 0.0) -> tuple[float, float, float]:
    """Least-squares plane ``v = a + g . (p - mean p)`` through the last ``count`` samples.

    With readings of noise ``sigma`` the gradient's component along each principal axis
    of the positions (spread ``s`` there, ``n`` samples) has the standard error
    ``se = sigma / (s sqrt n)``, and each is shrunk to ``g^2 / (g^2 + se^2)`` of itself
    (``g`` the component as fitted). Along a straight track the component across it is
    the noise over the track's few centimetres of wander, and would hand a crossing a
    gradient several times too steep and pointing anywhere; a component the samples span
    well keeps nearly all of itself.

    Returns
    -------
    gx, gy, spread_m
        The gradient and the smallest standard deviation of the positions (how well
        the plane is determined across the track).
    """
    n = min(count, length)
    if n < 3:
        return 0.0, 0.0, 0.0
    cap = buf.shape[0]
    first = start + length - n
    mx = my = mv = 0.0
    for i in range(n):
        k = (first + i) % cap
        mx += buf[k, 0]
        my += buf[k, 1]
        mv += buf[k, 2]
    mx /= n
    my /= n
    mv /= n
    sxx = syy = sxy = sxv = syv = 0.0
    for i in range(n):
        k = (first + i) % cap
        dx = buf[k, 0] - mx
        dy = buf[k, 1] - my
        dv = buf[k, 2] - mv
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
        sxv += dx * dv
        syv += dy * dv
    sxx /= n
    syy /= n
    sxy /= n
    tr = sxx + syy
    det0 = sxx * syy - sxy * sxy
    lam_min = max(0.5 * tr - math.sqrt(max(0.25 * tr * tr - det0, 0.0)), 0.0)
    a = sxx + ridge
    d = syy + ridge
    det = a * d - sxy * sxy
    if det <= 0.0:
        return 0.0, 0.0, 0.0
    bx = sxv / n
    by = syv / n
    gx = (d * bx - sxy * by) / det
    gy = (a * by - sxy * bx) / det
    if sigma > 0.0:
        gx, gy = _shrunk(gx, gy, sxx, syy, sxy, lam_min, n, sigma)
    return gx, gy, math.sqrt(lam_min)


@njit(cache=True)
def _shrunk(gx: float, gy: float, sxx: float, syy: float, sxy: float, lam_min: float,
            n: int, sigma: float) -> tuple[float, float]:
    """The gradient's components along the positions' principal axes, each shrunk by its
    signal over signal plus variance (:func:`fit_gradient`)."""
    lam_max = sxx + syy - lam_min
    # the major axis: the eigenvector of the positions' covariance for lam_max
    if abs(sxy) > 1e-12:
        ax, ay = lam_max - syy, sxy
    elif sxx >= syy:
        ax, ay = 1.0, 0.0
    else:
        ax, ay = 0.0, 1.0
    norm = math.hypot(ax, ay)
    ax, ay = ax / norm, ay / norm
    g_major = gx * ax + gy * ay
    g_minor = -gx * ay + gy * ax
    g_major = _shrink(g_major, g_major * g_major, sigma * sigma / (n * lam_max)
                      if lam_max > 0.0 else math.inf)
    g_minor = _shrink(g_minor, g_minor * g_minor, sigma * sigma / (n * lam_min)
                      if lam_min > 0.0 else math.inf)
    return g_major * ax - g_minor * ay, g_major * ay + g_minor * ax


@njit(inline="always")
def _shrink(g: float, prior2: float, var: float) -> float:
    """``g`` times ``prior2 / (prior2 + var)``: the posterior mean of a component of
    variance ``prior2`` measured with the error variance ``var``."""
    return g * prior2 / (prior2 + var) if prior2 + var > 0.0 and var < math.inf else 0.0


@njit(cache=True)
def _dot(a: np.ndarray, b: np.ndarray, n: int) -> float:
    acc = 0.0
    for i in range(n):
        acc += a[i] * b[i]
    return acc


@njit(cache=True)
def _project_out(q: np.ndarray, rank: int, r: np.ndarray, n: int) -> None:
    """``r -= Q Q^T r`` twice (re-orthogonalised), ``Q`` the first ``rank`` rows of ``q``."""
    for _ in range(2):
        for c in range(rank):
            proj = _dot(q[c], r, n)
            for i in range(n):
                r[i] -= proj * q[c, i]


@njit(cache=True)
def fit_cross_gradient(buf: np.ndarray, start: int, length: int) -> tuple[float, float]:
    """Cross-track gradient magnitude from samples along a (curved) track.

    The samples are expressed in a local frame (``s`` along the chord of the window,
    ``n`` across it) and fitted with ``v = a + b s + c s^2 + g n``: the quadratic term
    absorbs the curvature of a contour that is being followed, so ``g`` is only
    determined by genuine excursions across the iso-line. ``g`` is computed by
    Frisch-Waugh-Lovell: with ``r_n`` and ``r_v`` the residuals of ``n`` and ``v`` after
    projecting out the trend ``(1, s, s^2)`` (an orthonormal basis by modified
    Gram-Schmidt, re-orthogonalised; a column below 1e-10 of its norm is dropped, as a
    least-squares solve with a rank cutoff would), ``g = <r_n, r_v> / <r_n, r_n>``.

    Returns
    -------
    g_abs, spread_m
        ``|g|`` and the standard deviation of ``n`` left after removing a quadratic
        trend in ``s`` (how well ``g`` is determined).
    """
    n = length
    if n < 6:
        return 0.0, 0.0
    cap = buf.shape[0]
    k0 = start % cap
    k1 = (start + n - 1) % cap
    mx = my = 0.0
    for i in range(n):
        k = (start + i) % cap
        mx += buf[k, 0]
        my += buf[k, 1]
    mx /= n
    my /= n
    chord_x, chord_y = buf[k1, 0] - buf[k0, 0], buf[k1, 1] - buf[k0, 1]
    chord = math.hypot(chord_x, chord_y)
    if chord < 1e-6:
        return 0.0, 0.0
    ux, uy = chord_x / chord, chord_y / chord
    work = np.empty((6, n))  # rows: q0, q1, q2, along, r_n, r_v
    q = work[:3]
    along, r_n, r_v = work[3], work[4], work[5]
    for i in range(n):
        k = (start + i) % cap
        cx = buf[k, 0] - mx
        cy = buf[k, 1] - my
        along[i] = cx * ux + cy * uy
        r_n[i] = -cx * uy + cy * ux
        r_v[i] = buf[k, 2]
    rank = 0
    for j in range(3):
        col = q[rank]
        for i in range(n):
            col[i] = 1.0 if j == 0 else (along[i] if j == 1 else along[i] * along[i])
        norm0 = math.sqrt(_dot(col, col, n))
        _project_out(q, rank, col, n)
        norm = math.sqrt(_dot(col, col, n))
        if norm > 1e-10 * norm0 and norm > 0.0:
            for i in range(n):
                col[i] /= norm
            rank += 1
    _project_out(q, rank, r_n, n)
    nn = _dot(r_n, r_n, n)
    spread = math.sqrt(nn / n)
    if spread <= 1e-9:
        return 0.0, spread
    _project_out(q, rank, r_v, n)
    return abs(_dot(r_n, r_v, n) / nn), spread
