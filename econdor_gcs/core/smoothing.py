"""Noisy samples smoothed before they are interpolated: local smoothing splines.

With noise of standard deviation ``sigma`` on the samples, the biharmonic (thin-plate)
smoothing spline minimises

.. math::

    \\sum_i (v_i - f(\\mathbf{x}_i))^2 + \\lambda \\, J(f), \\qquad
    f(\\mathbf{x}) = \\sum_i w_i \\, g(|\\mathbf{x} - \\mathbf{x}_i|) + a_0 + a_1 x + a_2 y,

with ``(G + lambda I) w + T a = v`` and ``T^T w = 0`` (``G`` the Green's matrix of
:mod:`.greens`, ``T`` the rows ``(1, x_i, y_i)``; Wahba 1990, §2.4). Its values at the
samples, ``f_i = v_i - lambda w_i``, are what the interpolating spline is then fitted to:
a smoothing spline is the interpolating spline of its own values at the samples, so the
exact and the fast interpolation of :mod:`.spline` reproduce it (the fast one to its
usual accuracy).

The damping ``lambda`` (m^2) is chosen per tile, not once for the area: a plume on a flat
background wants almost no smoothing over its peak and a plane fitted to the background
around it, and one global ``lambda`` has to give up one for the other. Each square tile
of a lattice takes the samples within a margin around it, picks ``lambda`` by minimising
the unbiased estimate of the risk with the noise known (Mallows' C_L; Craven & Wahba 1979
for its cross-validated cousin), on up to ``select_samples`` of them, then solves the
smoothing spline of the whole window with it. The values of overlapping windows are
blended with the same C^1 partition of unity as the fast spline's tiles.

On the window's samples projected off the plane, ``Q_2^T G Q_2 = U diag(mu) U^T``
(``Q_2`` an orthonormal basis of the complement of ``T``'s columns), and with
``c = U^T Q_2^T v`` the residual and the trace of ``I - A(lambda)`` are

.. math::

    \\|v - f\\|^2 = \\sum_k \\Big(\\frac{\\lambda c_k}{\\mu_k + \\lambda}\\Big)^2, \\qquad
    \\operatorname{tr}(I - A) = \\sum_k \\frac{\\lambda}{\\mu_k + \\lambda},

so the risk estimate ``|v - f|^2 - 2 gamma sigma^2 tr(I - A)`` (plus constants) costs
nothing per candidate once the eigendecomposition is made. With ``gamma = 1`` it is unbiased
but variable: now and then a tile in flat background finds its least risk at a small
damping and keeps its noise. Counting each degree of freedom ``gamma = 1.4`` times trades a
little bias for a steadier choice, as the "robust" GCV of Kim & Gu (2004) does.

References
----------
Craven, P. & Wahba, G. (1979). Smoothing noisy data with spline functions. *Numerische
Mathematik* 31, 377-403.
Kim, Y.-J. & Gu, C. (2004). Smoothing spline Gaussian regression: more scalable
computation via efficient approximation. *J. R. Stat. Soc. B* 66(2), 337-356.
Mallows, C. L. (1973). Some comments on C_p. *Technometrics* 15(4), 661-675.
Wahba, G. (1990). *Spline Models for Observational Data*. SIAM.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from econdor_gcs.core.greens import _G_PER_H, FloatArray, _Blocks, _one_blas_thread
from econdor_gcs.core.local_scale import ScaleParams, widen_on_plateaus
from econdor_gcs.core.noise import NoiseEstimate, estimate_noise
from econdor_gcs.core.samples import _block_mean_counts, _bump, _RectIndex

__all__ = ["Denoised", "SmoothedSamples", "SmoothingParams", "denoise", "smooth_samples"]


@dataclass(frozen=True)
class SmoothingParams:
    """How :func:`denoise` thins and :func:`smooth_samples` cuts the area and searches the
    damping.

    :func:`denoise` first averages the samples in each ``thin_cell_m`` square (a mean of
    ``n`` samples has ``1/n`` of their noise variance, and a cell of half a metre is small
    beside the scales the field varies on).
    Square tiles of side ``tile_m`` (a lattice anchored at the origin) each smooth the
    samples within ``margin_m`` of them; a window holding fewer than ``min_samples`` is
    widened (x1.5) until it holds them, a tile whose window holds more than
    ``max_samples`` is split in four (margin and overlap halved, the margin not below
    ``min_margin_m``). The damping is searched over ``n_damping`` values spaced
    logarithmically over ``damping_range_m2`` on ``select_samples`` of the window's
    samples, spread over them, each degree of freedom counted ``df_penalty`` times in the
    risk estimate (module docstring). Windows blend over ``overlap_m`` beyond their tile
    (``overlap_m <= margin_m``).
    """

    thin_cell_m: float = 0.5
    tile_m: float = 10.0
    margin_m: float = 5.0
    overlap_m: float = 2.5
    min_samples: int = 20
    max_samples: int = 300
    min_margin_m: float = 2.0
    select_samples: int = 80
    damping_range_m2: tuple[float, float] = (1e-2, 1e6)
    n_damping: int = 65
    df_penalty: float = 1.4
    local_scale: ScaleParams | None = ScaleParams()

    def __post_init__(self) -> None:
        if not (self.tile_m > 0 and 0 < self.overlap_m <= self.margin_m):
            raise ValueError(f"SmoothingParams needs tile_m > 0, 0 < overlap_m <= margin_m: "
                             f"{self}")
        if not 8 <= self.min_samples <= self.max_samples:
            raise ValueError(f"SmoothingParams needs 8 <= min_samples <= max_samples: {self}")
        if self.select_samples < 8:
            raise ValueError(f"SmoothingParams needs select_samples >= 8: {self}")
        lo, hi = self.damping_range_m2
        if not (0 < lo < hi and self.n_damping >= 2):
            raise ValueError(f"SmoothingParams needs 0 < damping range and n_damping >= 2: "
                             f"{self}")
        if not self.df_penalty > 0:
            raise ValueError(f"SmoothingParams needs df_penalty > 0: {self}")


@dataclass(frozen=True)
class SmoothedSamples:
    """What :func:`smooth_samples` returns.

    Attributes
    ----------
    values : ndarray
        The smoothing splines' values at the samples (blended where windows overlap).
    damping_m2 : ndarray
        The damping ``lambda`` each tile chose (m^2), in the order the tiles were solved.
    """

    values: FloatArray
    damping_m2: FloatArray


@dataclass(frozen=True)
class Denoised:
    """Samples ready to be interpolated: what :func:`denoise` returns.

    Attributes
    ----------
    x, y, v : ndarray
        Positions (m) and values to interpolate: the input as it was when no noise was
        found, else the cell means and their smoothed values.
    noise : NoiseEstimate
        The noise (estimated, or the one given).
    damping_m2 : ndarray
        Each tile's damping (m^2); empty when nothing was smoothed.
    """

    x: FloatArray
    y: FloatArray
    v: FloatArray
    noise: NoiseEstimate
    damping_m2: FloatArray

    @property
    def smoothed(self) -> bool:
        return self.damping_m2.size > 0


def denoise(x: FloatArray, y: FloatArray, v: FloatArray, noise_std: float | None = None,
            params: SmoothingParams | None = None) -> Denoised:
    """Estimate the noise of checked samples (unless given) and smooth them if there is any.

    Parameters
    ----------
    x, y, v : ndarray
        Checked samples (:func:`~econdor_gcs.core.samples._check_samples`), in the order
        they were taken.
    noise_std : float or None
        ``None``: estimated (:func:`~econdor_gcs.core.noise.estimate_noise`); ``0``: the
        samples are exact and returned as they are; ``> 0``: the sensor's known noise.
    params : SmoothingParams, optional

    Returns
    -------
    Denoised
    """
    if noise_std is None:
        noise = estimate_noise(x, y, v)
    elif noise_std >= 0 and np.isfinite(noise_std):
        noise = NoiseEstimate(float(noise_std), float(noise_std), 0, float(np.ptp(v)))
    else:
        raise ValueError(f"noise_std must be None or a finite number >= 0, got {noise_std}")
    if not noise.detected:
        return Denoised(x, y, v, noise, np.zeros(0))
    p = params or SmoothingParams()
    xm, ym, vm, counts = _block_mean_counts(x, y, v, p.thin_cell_m)
    smoothed = smooth_samples(xm, ym, vm, noise.noise_std, p, counts)
    values = smoothed.values
    if p.local_scale is not None:
        values = widen_on_plateaus(xm, ym, vm, counts, values, noise.noise_std,
                                  p.local_scale).values
    return Denoised(xm, ym, values, noise, smoothed.damping_m2)


def smooth_samples(x: FloatArray, y: FloatArray, v: FloatArray, noise_std: float,
                   params: SmoothingParams | None = None, counts: FloatArray | None = None
                   ) -> SmoothedSamples:
    """Smooth samples with noise ``noise_std`` by local smoothing splines (module docstring).

    Parameters
    ----------
    x, y : ndarray
        Distinct sample positions in metres (checked and merged by the caller).
    v : ndarray
        Sample values.
    noise_std : float
        Standard deviation of the noise on one sample (> 0), e.g. from
        :func:`~econdor_gcs.core.noise.estimate_noise`.
    params : SmoothingParams, optional
    counts : ndarray, optional
        How many samples each value is the mean of (its noise variance is
        ``noise_std**2 / count``); default one each.

    Returns
    -------
    SmoothedSamples

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> x, y = rng.uniform(0, 30, 900), rng.uniform(0, 30, 900)
    >>> truth = 0.2 * x + 0.1 * y
    >>> s = smooth_samples(x, y, truth + rng.normal(0, 1, 900), 1.0)
    >>> bool(np.abs(s.values - truth).mean() < 0.3)   # the noise's own is 0.8
    True
    """
    if not noise_std > 0:
        raise ValueError(f"noise_std must be > 0, got {noise_std}")
    p = params or SmoothingParams()
    grid = np.geomspace(*p.damping_range_m2, p.n_damping)
    pts = np.column_stack((x, y))
    weight = np.ones(v.size) if counts is None else np.asarray(counts, dtype=np.float64)
    blocks = _Blocks()
    num = np.zeros(v.size)
    den = np.zeros(v.size)
    with _one_blas_thread():
        windows, selections = _windows(x, y, _RectIndex(x, y), p)
        problems = [_Selection(blocks, pts[k], v[k], weight[k]) for k in selections]
        damping = _choose_damping(problems, noise_std, grid, p.df_penalty)
        for w in windows:
            lam = float(damping[w.group])
            if selections[w.group] is w.sel:  # the selection saw the whole window
                fitted = problems[w.group].fitted(lam)
            else:
                fitted = _solve_smoothing(blocks, pts[w.sel], v[w.sel], weight[w.sel], lam)
            phi = _bump(x[w.sel], w.x0 - w.overlap, w.x1 + w.overlap)
            phi *= _bump(y[w.sel], w.y0 - w.overlap, w.y1 + w.overlap)
            num[w.sel] += phi * fitted
            den[w.sel] += phi
    # every sample lies in its own tile, where that tile's weight is positive
    out = np.divide(num, den, out=v.copy(), where=den > 0)
    return SmoothedSamples(out, damping)


@dataclass(frozen=True)
class _Window:
    """A tile ``[x0, x1] x [y0, y1]``, its blending overlap, the samples it smooths and the
    damping selection it takes its damping from."""

    x0: float
    x1: float
    y0: float
    y1: float
    overlap: float
    sel: NDArray[np.intp]
    group: int


def _spread(sel: NDArray[np.intp], k: int) -> NDArray[np.intp]:
    """At most ``k`` of the indices ``sel`` (sorted), evenly spread over them."""
    if sel.size <= k:
        return sel
    return sel[np.unique(np.linspace(0, sel.size - 1, k).round().astype(np.intp))]


class _Selection:
    """One window's smoothing problem projected off the plane (module docstring).

    With weights ``n_i`` (noise variance ``sigma^2 / n_i``) it is the unweighted problem of
    ``W^(1/2) v``, ``W^(1/2) G W^(1/2)`` and ``W^(1/2) T`` (``W = diag(n_i)``).
    """

    def __init__(self, blocks: _Blocks, pts: FloatArray, v: FloatArray,
                 weight: FloatArray) -> None:
        self.v = v
        self.root = np.sqrt(weight)
        basis = _plane_basis(pts, self.root)
        q, _ = np.linalg.qr(basis, mode="complete")
        self.q2 = q[:, basis.shape[1]:]
        gmat = _G_PER_H * blocks.matrix(pts, pts)
        gmat *= self.root[:, None]
        gmat *= self.root[None, :]
        self.matrix = self.q2.T @ gmat @ self.q2
        self.z = self.q2.T @ (self.root * v)
        self.mu = np.zeros(0)  # eigenvalues, eigenvectors and coordinates of z in them,
        self.u = np.zeros((0, 0))  # set by _choose_damping
        self.c = np.zeros(0)

    def fitted(self, lam: float) -> FloatArray:
        k = self.z.size
        shrink = lam / (self.mu + lam)
        return self.v - (self.q2 @ (self.u[:k] @ (shrink * self.c))) / self.root


def _choose_damping(problems: list[_Selection], noise_std: float, grid: FloatArray,
                    df_penalty: float) -> FloatArray:
    """Each problem's damping of ``grid`` with the least estimated risk.

    The projected matrices are decomposed in one batched call, padded to one size with
    a diagonal far beyond the damping searched (a padded direction has ``c = 0`` and
    shrinks by nothing, so it changes neither the residual nor the trace).
    """
    size = max((pr.z.size for pr in problems), default=0)
    if size == 0:
        return np.full(len(problems), grid[-1])
    pad = 1e3 * float(grid[-1])
    stack = np.zeros((len(problems), size, size))
    z = np.zeros((len(problems), size))
    for i, pr in enumerate(problems):
        k = pr.z.size
        stack[i, :k, :k] = pr.matrix
        stack[i, np.arange(k, size), np.arange(k, size)] = pad
        z[i, :k] = pr.z
    mu, u = np.linalg.eigh(stack)
    np.maximum(mu, 0.0, out=mu)  # positive definite; rounding may dip below
    c = np.einsum("wkj,wk->wj", u, z)
    out = np.empty(len(problems))
    for i, pr in enumerate(problems):
        shrink = grid[:, None] / (mu[i][None, :] + grid[:, None])  # lambda / (mu + lambda)
        risk = (np.square(shrink * c[i]).sum(axis=1)
                - 2.0 * df_penalty * noise_std**2 * shrink.sum(axis=1))
        out[i] = grid[int(np.argmin(risk))]
        pr.mu, pr.u, pr.c = mu[i], u[i], c[i]
    return out


def _windows(x: FloatArray, y: FloatArray, index: _RectIndex, p: SmoothingParams
             ) -> tuple[list[_Window], list[NDArray[np.intp]]]:
    """The tiles with samples of their own and the samples each smooths; and the samples
    each damping selection is made on.

    The damping is selected once per tile of the lattice, on ``select_samples`` of its
    window; the quarters a crowded tile is split into take its damping (the field's
    roughness does not change at the scale of a split, only the density of samples).
    """
    tile = float(p.tile_m)
    i0, i1 = int(np.floor(x.min() / tile)), int(np.floor(x.max() / tile))
    j0, j1 = int(np.floor(y.min() / tile)), int(np.floor(y.max() / tile))
    stack = [(i * tile, (i + 1) * tile, j * tile, (j + 1) * tile, 1.0, -1)
             for j in range(j1, j0 - 1, -1) for i in range(i1, i0 - 1, -1)]
    n_min = min(p.min_samples, x.size)
    windows: list[_Window] = []
    selections: list[NDArray[np.intp]] = []
    while stack:
        tx0, tx1, ty0, ty1, scale, group = stack.pop()
        if index.inside(tx0, tx1, ty0, ty1).size == 0:
            continue  # no sample of its own to smooth
        margin = max(p.margin_m * scale, min(p.min_margin_m, p.margin_m))
        widened = False
        while True:
            sel = index.inside(tx0 - margin, tx1 + margin, ty0 - margin, ty1 + margin)
            if sel.size >= n_min:
                break
            margin *= 1.5
            widened = True
        sel = np.sort(sel)
        if group < 0:
            group = len(selections)
            selections.append(_spread(sel, p.select_samples))
        if sel.size > p.max_samples and not widened and scale > 1.0 / 16:
            xm, ym, half = 0.5 * (tx0 + tx1), 0.5 * (ty0 + ty1), 0.5 * scale
            stack += [(xm, tx1, ym, ty1, half, group), (tx0, xm, ym, ty1, half, group),
                      (xm, tx1, ty0, ym, half, group), (tx0, xm, ty0, ym, half, group)]
            continue
        if selections[group].size == sel.size and scale == 1.0:
            sel = selections[group]  # the same indices: the selection saw the whole window
        windows.append(_Window(tx0, tx1, ty0, ty1, min(p.overlap_m * scale, margin), sel,
                               group))
    return windows, selections


def _plane_basis(pts: FloatArray, root: FloatArray | None = None) -> FloatArray:
    """Orthonormal basis of the linear polynomials ``(1, x, y)`` at the points (columns;
    rows scaled by ``root`` if given); two columns when the points lie on a line, one when
    they coincide."""
    t = np.column_stack((np.ones(pts.shape[0]), pts - pts.mean(axis=0)))
    if root is not None:
        t *= root[:, None]
    u, s, _ = np.linalg.svd(t, full_matrices=False)
    return u[:, : int(np.count_nonzero(s > 1e-9 * s[0]))]


def _solve_smoothing(blocks: _Blocks, pts: FloatArray, v: FloatArray, weight: FloatArray,
                     lam: float) -> FloatArray:
    """Values at the samples of the smoothing spline with damping ``lam`` (bordered solve:
    ``(G + lam W^-1) w + T a = v``, ``T^T w = 0``)."""
    n = v.size
    basis = _plane_basis(pts)
    m = basis.shape[1]
    a = np.zeros((n + m, n + m))
    a[:n, :n] = _G_PER_H * blocks.matrix(pts, pts)
    a[np.arange(n), np.arange(n)] += lam / weight
    a[:n, n:] = basis
    a[n:, :n] = basis.T
    rhs = np.zeros(n + m)
    rhs[:n] = v
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
        try:
            sol = scipy.linalg.solve(a, rhs, assume_a="sym", overwrite_a=True,
                                     check_finite=False)
        except (scipy.linalg.LinAlgError, ValueError):
            return v.copy()
    if not np.all(np.isfinite(sol)):
        return v.copy()
    return v - (lam / weight) * sol[:n]
