"""A Gaussian-process (kriging) model of a field from its samples.

The field is modelled as a Gaussian process with a constant mean ``m`` and a Matérn
covariance

.. math::

    k(\\mathbf{x}, \\mathbf{x}') = \\sigma_f^2 \\, \\rho_\\nu(|\\mathbf{x} - \\mathbf{x}'| / \\ell),
    \\qquad
    \\rho_{1/2}(r) = e^{-r}, \\quad
    \\rho_{3/2}(r) = (1 + \\sqrt{3} r) e^{-\\sqrt{3} r}, \\quad
    \\rho_{5/2}(r) = (1 + \\sqrt{5} r + \\tfrac{5}{3} r^2) e^{-\\sqrt{5} r},

plus a small nugget ``eta * sigma_f^2`` on the diagonal (sensor noise, and numerical
conditioning for the dense samples of a flown path). Given samples ``v`` at ``X`` the
posterior (kriging) mean and variance at ``x`` are

.. math::

    \\mu(\\mathbf{x}) = m + \\mathbf{k}_x^T K^{-1} (\\mathbf{v} - m), \\qquad
    \\sigma^2(\\mathbf{x}) = \\sigma_f^2 - \\mathbf{k}_x^T K^{-1} \\mathbf{k}_x .

The posterior variance depends only on where the samples are, not on their values: a
planner can add a path it has not flown yet as pseudo-observations (Rasmussen &
Williams 2006, §2.2; Krause, Singh & Guestrin 2008).

Hyperparameters are fitted by maximum likelihood on a subsample (:func:`fit_matern`). The
amplitude and the mean have closed forms for a given length scale (the profile
likelihood), which leaves a one-dimensional search over ``log l``: about ten times
faster than scikit-learn's ``GaussianProcessRegressor`` optimising all of them (measured
in ``bench/kriging.py``), at the same likelihood (tested against scikit-learn).

Prediction (:class:`LocalKriging`) solves a small kriging system per query point with its
``k`` nearest samples (local neighbourhood kriging; Cressie 1993, §3.2): the dense
system of a flown path (tens of thousands of samples) is never formed.

References
----------
Rasmussen, C. E. & Williams, C. K. I. (2006). *Gaussian Processes for Machine Learning*.
MIT Press (eqs. 2.19, 4.14-4.17; the profile likelihood: §5.4.1).
Cressie, N. (1993). *Statistics for Spatial Data*. Wiley.
Krause, A., Singh, A. & Guestrin, C. (2008). Near-optimal sensor placements in Gaussian
processes. *JMLR* 9, 235-284.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Self

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import OptimizeResult, minimize, minimize_scalar
from scipy.spatial import cKDTree

from ..errors import ReconstructionError
from .geometry import FloatArray, Grid
from .noise import NoiseEstimate, estimate_noise
from .samples import _block_mean_counts

__all__ = ["Kriging", "MaternHyper", "fit_matern", "kriging_reconstruct", "matern", "thin_samples"]

NU_CHOICES = (0.5, 1.5, 2.5)
FLAT_RTOL = 1e-9
"""Samples whose values differ by less than this fraction of their magnitude are alike
(:func:`fit_matern` learns no amplitude from them)."""


def matern(r: ArrayLike, nu: float) -> FloatArray:
    """Matérn correlation ``rho_nu(r)`` of the scaled distance ``r = d / l`` (module docstring).

    Examples
    --------
    >>> import numpy as np
    >>> np.round(matern([0.0, 1.0], 1.5), 4)
    array([1.    , 0.4834])
    """
    r = np.abs(np.asarray(r, dtype=np.float64))
    if nu == 0.5:
        return np.exp(-r)
    if nu == 1.5:
        s = math.sqrt(3.0) * r
        return (1.0 + s) * np.exp(-s)
    if nu == 2.5:
        s = math.sqrt(5.0) * r
        return (1.0 + s + s * s / 3.0) * np.exp(-s)
    raise ValueError(f"nu: must be one of {NU_CHOICES}, got {nu}")


@dataclass(frozen=True)
class MaternHyper:
    """Hyperparameters of the Matérn model: mean ``m``, amplitude ``sigma_f``, length
    scale ``l`` (m), relative nugget ``eta`` and smoothness ``nu``."""

    mean: float
    amplitude: float
    length_m: float
    nugget: float = 1e-6
    nu: float = 2.5

    def correlation(self, d_m: ArrayLike) -> FloatArray:
        """``rho_nu(d / l)`` for distances in metres."""
        return matern(np.asarray(d_m, dtype=np.float64) / self.length_m, self.nu)


def thin_samples(x: FloatArray, y: FloatArray, cell_m: float) -> NDArray[np.intp]:
    """Indices of one sample per ``cell_m`` square: the one nearest the square's centre.

    Samples along a flown path are a fraction of a metre apart; one per cell keeps the
    kriging systems small and well conditioned without moving any sample.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.array([0.1, 0.4, 0.45, 2.2]); y = np.zeros(4) + 0.5
    >>> sorted(thin_samples(x, y, 1.0).tolist())
    [2, 3]
    """
    if cell_m <= 0:
        raise ValueError(f"cell_m: must be > 0, got {cell_m}")
    if x.size == 0:
        return np.zeros(0, dtype=np.intp)
    gx = (x - x.min()) / cell_m
    gy = (y - y.min()) / cell_m
    ix = np.floor(gx).astype(np.int64)
    iy = np.floor(gy).astype(np.int64)
    cell = iy * (int(ix.max()) + 1) + ix
    off = np.hypot(gx - ix - 0.5, gy - iy - 0.5)
    order = np.lexsort((off, cell))
    keep = np.r_[True, cell[order][1:] != cell[order][:-1]]
    return np.sort(order[keep])


def _profile_nll(log_l: float, d: FloatArray, v: FloatArray, nu: float,
                 nugget: float) -> tuple[float, float, float]:
    """Negative profile log-likelihood at ``l = exp(log_l)`` and the optimal mean and
    amplitude (Rasmussen & Williams 2006, §5.4.1):

    ``m = 1^T C^-1 v / 1^T C^-1 1``, ``sigma_f^2 = (v - m)^T C^-1 (v - m) / n``,
    ``nll = n/2 log sigma_f^2 + 1/2 log|C| + n/2 (1 + log 2 pi)``, ``C = R(l) + eta I``.
    """
    n = v.size
    c = matern(d / math.exp(log_l), nu)
    c[np.diag_indices(n)] += nugget
    try:
        chol = scipy.linalg.cho_factor(c, lower=True, check_finite=False)
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        return math.inf, math.nan, math.nan
    ones = np.ones(n)
    ci_1 = scipy.linalg.cho_solve(chol, ones, check_finite=False)
    ci_v = scipy.linalg.cho_solve(chol, v, check_finite=False)
    mean = float(ci_v.sum() / ci_1.sum())
    resid = v - mean
    var = float(resid @ (ci_v - mean * ci_1)) / n
    if not var > 0:
        return math.inf, mean, math.nan
    logdet = 2.0 * float(np.sum(np.log(np.diag(chol[0]))))
    nll = 0.5 * n * math.log(var) + 0.5 * logdet + 0.5 * n * (1.0 + math.log(2.0 * math.pi))
    return nll, mean, math.sqrt(var)


def fit_matern(
    x: ArrayLike,
    y: ArrayLike,
    v: ArrayLike,
    nu: float = 2.5,
    nugget: float = 1e-6,
    max_points: int = 400,
    length_bounds_m: tuple[float, float] = (0.5, 200.0),
    cell_m: float = 1.0,
    seed: int = 0,
    noise_std: float = 0.0,
    start: MaternHyper | None = None,
) -> MaternHyper:
    """Maximum-likelihood Matérn hyperparameters from (a subsample of) the samples.

    The samples are first thinned to one per ``cell_m`` square, then at most
    ``max_points`` of them are drawn at random (reproducibly, from ``seed``). The mean
    and amplitude are profiled out (closed form, see :func:`_profile_nll`); ``log l`` is
    found by a bounded scalar search.

    With the noise known (``noise_std > 0``, e.g. from
    :func:`~econdor_gcs.core.noise.estimate_noise`) the nugget is ``(noise_std /
    sigma_f)^2``, so the amplitude no longer profiles out: ``(log l, log sigma_f)`` are
    found together (L-BFGS-B from three starting lengths; the mean still in closed
    form). A nugget fitted by likelihood alone on a few hundred points a few metres apart
    comes out low (the field's short-range variation and the noise look alike at that
    spacing); the noise seen between neighbouring samples along a track is the
    better-founded number. Given the fit of a sample set this one grew from (``start``),
    the search is one descent from its optimum instead: a planner refitting after every
    flight moves the optimum little, and three searches from afar cost it most of its
    time.

    Parameters
    ----------
    x, y, v : array_like
        Sample positions (m) and values.
    nu : {0.5, 1.5, 2.5}
        Matérn smoothness.
    nugget : float
        Relative nugget ``eta`` (noise variance over ``sigma_f^2``); with ``noise_std > 0``
        it is fitted instead.
    max_points : int
        Size of the subsample the likelihood is evaluated on.
    length_bounds_m : (float, float)
        Search interval of the length scale.
    cell_m : float
        Thinning cell before the subsample is drawn.
    seed : int
        Seed of the subsample.
    noise_std : float
        Standard deviation of the samples' noise in field units, when known (``0``: the
        relative ``nugget`` is used as given).
    start : MaternHyper, optional
        With ``noise_std > 0``: a previous fit (of fewer samples of the same field) to
        start the one search from; ``None`` searches from three lengths.

    Returns
    -------
    MaternHyper

    Raises
    ------
    ReconstructionError
        Fewer than 3 distinct samples, or all values equal.
    """
    xa, ya, va = _as_samples(x, y, v)
    if nu not in NU_CHOICES:
        raise ValueError(f"nu: must be one of {NU_CHOICES}, got {nu}")
    idx = thin_samples(xa, ya, cell_m)
    if idx.size > max_points:
        idx = np.sort(np.random.default_rng(seed).choice(idx, max_points, replace=False))
    if idx.size < 3:
        raise ReconstructionError(f"need at least 3 distinct samples to fit a GP, got {idx.size}")
    px, py, pv = xa[idx], ya[idx], va[idx]
    if np.ptp(pv) <= FLAT_RTOL * max(1.0, float(np.max(np.abs(pv)))):
        # every value alike, to rounding (a flat background sums to 10 +- 1e-15): no
        # amplitude to learn, and a likelihood of rounding noise is singular at some lengths
        return MaternHyper(float(np.mean(pv)), 0.0, length_bounds_m[1], nugget, nu)
    d = np.hypot(px[:, None] - px[None, :], py[:, None] - py[None, :])
    lo, hi = (math.log(b) for b in length_bounds_m)
    if noise_std > 0:
        return _fit_known_noise(d, pv, nu, noise_std, (lo, hi), start)
    res = minimize_scalar(lambda t: _profile_nll(t, d, pv, nu, nugget)[0], bounds=(lo, hi),
                          method="bounded", options={"xatol": 1e-3})
    _, mean, amp = _profile_nll(float(res.x), d, pv, nu, nugget)
    if not math.isfinite(amp):
        raise ReconstructionError("GP fit failed: the covariance is singular at every length scale")
    return MaternHyper(mean, amp, math.exp(float(res.x)), nugget, nu)


def _known_noise_nll(theta: FloatArray, d: FloatArray, v: FloatArray, nu: float,
                     noise_var: float) -> float:
    """Negative log-likelihood (constants dropped) at ``theta = (log l, log sigma_f)`` with
    the noise variance fixed and the mean in closed form (generalised least squares)."""
    n = v.size
    c = math.exp(2.0 * theta[1]) * matern(d / math.exp(theta[0]), nu)
    c[np.diag_indices(n)] += noise_var
    try:
        chol = scipy.linalg.cho_factor(c, lower=True, check_finite=False)
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        return math.inf
    ci_1 = scipy.linalg.cho_solve(chol, np.ones(n), check_finite=False)
    ci_v = scipy.linalg.cho_solve(chol, v, check_finite=False)
    mean = float(ci_v.sum() / ci_1.sum())
    quad = float((v - mean) @ (ci_v - mean * ci_1))
    return 0.5 * quad + float(np.sum(np.log(np.diag(chol[0]))))


def _fit_known_noise(d: FloatArray, v: FloatArray, nu: float, noise_std: float,
                     log_length_bounds: tuple[float, float],
                     warm: MaternHyper | None = None) -> MaternHyper:
    noise_var = noise_std * noise_std
    spread = max(float(np.std(v)), noise_std)
    amp_bounds = (math.log(1e-3 * spread), math.log(1e3 * spread))

    def search(starts: list[tuple[float, float]]) -> OptimizeResult | None:
        best = None
        for log_l, log_a in starts:
            start = np.array([min(max(log_l, log_length_bounds[0]), log_length_bounds[1]),
                              min(max(log_a, amp_bounds[0]), amp_bounds[1])])
            res = minimize(_known_noise_nll, start, args=(d, v, nu, noise_var),
                           method="L-BFGS-B", bounds=[log_length_bounds, amp_bounds])
            if math.isfinite(float(res.fun)) and (best is None or res.fun < best.fun):
                best = res
        return best

    best = None
    if warm is not None and warm.amplitude > 0.0:
        best = search([(math.log(warm.length_m), math.log(warm.amplitude))])
    if best is None:  # no previous fit, or its optimum is singular now: three searches
        best = search([(math.log(length), math.log(spread)) for length in (3.0, 10.0, 30.0)])
    if best is None:
        raise ReconstructionError("GP fit failed: the covariance is singular at every length scale")
    length, amp = math.exp(float(best.x[0])), math.exp(float(best.x[1]))
    c = matern(d / length, nu)
    c[np.diag_indices(v.size)] += noise_var / amp**2
    chol = scipy.linalg.cho_factor(c, lower=True, check_finite=False)
    ci_1 = scipy.linalg.cho_solve(chol, np.ones(v.size), check_finite=False)
    mean = float(scipy.linalg.cho_solve(chol, v, check_finite=False).sum() / ci_1.sum())
    return MaternHyper(mean, amp, length, noise_var / amp**2, nu)


def _as_samples(x: ArrayLike, y: ArrayLike, v: ArrayLike) -> tuple[FloatArray, ...]:
    xa = np.asarray(x, dtype=np.float64).ravel()
    ya = np.asarray(y, dtype=np.float64).ravel()
    va = np.asarray(v, dtype=np.float64).ravel()
    if not (xa.size == ya.size == va.size):
        raise ReconstructionError(
            f"sample arrays have mismatched lengths: x={xa.size}, y={ya.size}, v={va.size}")
    if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(ya)) and np.all(np.isfinite(va))):
        raise ReconstructionError("non-finite (NaN/inf) samples")
    if xa.size < 3:
        raise ReconstructionError(f"need at least 3 samples, got {xa.size}")
    return xa, ya, va


@dataclass
class _Tile:
    """One kriging system: its samples, the Cholesky factor and ``C^-1 (v - m)``."""

    x0: float
    x1: float
    y0: float
    y1: float
    overlap_m: float
    px: FloatArray
    py: FloatArray
    chol: tuple[FloatArray, bool]
    alpha: FloatArray


class Kriging:
    """Kriging (GP posterior mean and standard deviation) of scattered samples.

    Up to ``max_global`` samples (after thinning) are solved as one exact system. Beyond
    that the area is cut into square tiles, each solved exactly with the samples within
    ``margin_m`` of it (tiles with more than ``max_tile`` samples are split in four), and
    the tile predictions are blended with a partition of unity of C^1 bumps that overlap
    by ``overlap_m`` (as :class:`~econdor_gcs.core.spline.FastBiharmonicSpline` does for
    the spline). Dense samples screen the far ones off, so the tiles lose little.

    Parameters
    ----------
    hyper : MaternHyper or None
        Fixed hyperparameters; ``None`` fits them with :func:`fit_matern` in :meth:`fit`.
    nu : float
        Matérn smoothness when the hyperparameters are fitted.
    cell_m : float
        The samples are thinned to one per ``cell_m`` square (:func:`thin_samples`).
    max_global : int
        Largest sample count solved as one system.
    tile_m, margin_m, overlap_m : float
        Tile side, sample margin around a tile and blending width (metres).
    max_tile : int
        Largest sample count of one tile system.
    noise_std : float or None
        Standard deviation of the samples' noise when the hyperparameters are fitted:
        ``None`` estimates it from the samples in the order they were taken
        (:func:`~econdor_gcs.core.noise.estimate_noise`), ``0`` takes them as exact. With
        noise the samples are averaged per ``cell_m`` square instead of thinned (a mean
        of ``n`` has ``1/n`` of the noise variance, and the nugget of its row is divided
        by ``n``), and :func:`fit_matern` fits the length and amplitude with the noise
        fixed. With ``hyper`` given its nugget says what noise it assumes: ``None`` (or 0)
        thins the samples, any ``noise_std > 0`` averages them per cell with the nugget
        divided by each count as above.

    Attributes
    ----------
    hyper_ : MaternHyper
        The hyperparameters used.
    n_used_ : int
        Samples after thinning.
    tiles_ : list
        The kriging systems (one when global).
    noise_std_ : float
        The noise the model assumes: estimated or given, ``0`` when the samples are taken
        as exact (the default nugget is then numerical conditioning only); with ``hyper``
        given, ``sigma_f sqrt(eta)``. :meth:`predict`'s standard deviation is the field's
        under this noise (the noise of a new sample would add ``noise_std_^2``).
    noise_ : NoiseEstimate or None
        The estimate itself (``None`` when not estimated).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> x, y = rng.uniform(0, 20, 300), rng.uniform(0, 20, 300)
    >>> model = Kriging().fit(x, y, np.sin(x / 4) + y / 10)
    >>> mu, sd = model.predict(np.array([10.0]), np.array([10.0]), return_std=True)
    >>> bool(abs(mu[0] - (np.sin(2.5) + 1.0)) < 1e-3 and sd[0] < 1e-2)
    True
    """

    def __init__(self, hyper: MaternHyper | None = None, nu: float = 2.5, cell_m: float = 1.0,
                 max_global: int = 1500, tile_m: float = 25.0, margin_m: float = 15.0,
                 overlap_m: float = 4.0, max_tile: int = 1500,
                 noise_std: float | None = None) -> None:
        self.hyper = hyper
        self.nu = nu
        self.cell_m = cell_m
        self.max_global = max_global
        self.tile_m = tile_m
        self.margin_m = margin_m
        self.overlap_m = overlap_m
        self.max_tile = max_tile
        self.noise_std = noise_std

    def fit(self, x: ArrayLike, y: ArrayLike, v: ArrayLike) -> Self:
        """Thin the samples, fit the hyperparameters (unless given), factor the systems.

        Raises
        ------
        ReconstructionError
            Fewer than 3 samples, mismatched lengths or non-finite input.
        """
        xa, ya, va = _as_samples(x, y, v)
        self.noise_ = self._noise(xa, ya, va)
        noise = self.noise_.noise_std if self.noise_ is not None else 0.0
        if noise > 0:
            x, y, v, counts = _block_mean_counts(xa, ya, va, self.cell_m)
            self.counts_: FloatArray | None = counts
        else:
            idx = thin_samples(xa, ya, self.cell_m)
            x, y, v = xa[idx], ya[idx], va[idx]
            self.counts_ = None
        self.n_used_ = int(x.size)
        self.hyper_ = self.hyper or fit_matern(x, y, v, nu=self.nu, cell_m=max(self.cell_m, 1.0),
                                               noise_std=noise)
        hyp = self.hyper_
        self.noise_std_ = noise if self.hyper is None else hyp.amplitude * math.sqrt(hyp.nugget)
        x0, x1, y0, y1 = float(x.min()), float(x.max()), float(y.min()), float(y.max())
        if x.size <= self.max_global:
            self.tiles_ = [self._tile(x0, x1, y0, y1, 1.0, np.arange(x.size), x, y, v)]
            return self
        n = max(1, int(np.ceil(max(x1 - x0, y1 - y0) / self.tile_m - 1e-9)))
        xe, ye = np.linspace(x0, x1, n + 1), np.linspace(y0, y1, n + 1)
        stack = [(xe[i], xe[i + 1], ye[j], ye[j + 1], 1.0) for j in range(n) for i in range(n)]
        self.tiles_ = []
        while stack:
            tx0, tx1, ty0, ty1, scale = stack.pop()
            margin = self.margin_m * scale
            while True:
                sel = (x >= tx0 - margin) & (x <= tx1 + margin) & (y >= ty0 - margin) & (
                    y <= ty1 + margin)
                if np.count_nonzero(sel) >= min(50, x.size):
                    break
                margin *= 1.5
            if np.count_nonzero(sel) > self.max_tile and scale > 1.0 / 16:
                xm, ym, h = 0.5 * (tx0 + tx1), 0.5 * (ty0 + ty1), 0.5 * scale
                stack += [(tx0, xm, ty0, ym, h), (xm, tx1, ty0, ym, h), (tx0, xm, ym, ty1, h),
                          (xm, tx1, ym, ty1, h)]
                continue
            self.tiles_.append(self._tile(tx0, tx1, ty0, ty1, scale, np.flatnonzero(sel),
                                          x[sel], y[sel], v[sel]))
        return self

    def _noise(self, x: FloatArray, y: FloatArray, v: FloatArray) -> NoiseEstimate | None:
        if self.hyper is not None and not (self.noise_std or 0.0) > 0:
            return None
        if self.noise_std is None:
            return estimate_noise(x, y, v)
        if not (math.isfinite(self.noise_std) and self.noise_std >= 0):
            raise ValueError(f"noise_std: must be None or a finite number >= 0, "
                             f"got {self.noise_std}")
        return NoiseEstimate(float(self.noise_std), float(self.noise_std), 0, float(np.ptp(v)))

    def _tile(self, x0: float, x1: float, y0: float, y1: float, scale: float,
              rows: NDArray[np.intp], px: FloatArray, py: FloatArray, pv: FloatArray) -> _Tile:
        h = self.hyper_
        c = h.correlation(np.hypot(px[:, None] - px[None, :], py[:, None] - py[None, :]))
        # a cell mean of n samples has 1/n of their noise variance
        c[np.diag_indices(px.size)] += (h.nugget if self.counts_ is None
                                        else h.nugget / self.counts_[rows])
        chol = scipy.linalg.cho_factor(c, lower=True, overwrite_a=True, check_finite=False)
        alpha = scipy.linalg.cho_solve(chol, pv - h.mean, check_finite=False)
        return _Tile(x0, x1, y0, y1, self.overlap_m * scale, px, py, chol, alpha)

    def predict(self, x: ArrayLike, y: ArrayLike, return_std: bool = False
                ) -> FloatArray | tuple[FloatArray, FloatArray]:
        """Posterior mean (and standard deviation) at the query points (any shape)."""
        mean, var = self._predict(x, y, want_var=return_std)
        if return_std:
            return mean, self.hyper_.amplitude * np.sqrt(var)
        return mean

    def unit_variance(self, x: ArrayLike, y: ArrayLike) -> FloatArray:
        """Posterior variance over ``sigma_f^2`` (in [0, 1]) at the query points."""
        return self._predict(x, y, want_var=True)[1]

    def _predict(self, x: ArrayLike, y: ArrayLike, want_var: bool) -> tuple[FloatArray, FloatArray]:
        xq = np.asarray(x, dtype=np.float64)
        yq = np.asarray(y, dtype=np.float64)
        shape = xq.shape
        xf, yf = xq.ravel(), yq.ravel()
        h = self.hyper_
        if len(self.tiles_) == 1:
            mean, var = self._tile_predict(self.tiles_[0], xf, yf, want_var)
            return (h.mean + mean).reshape(shape), var.reshape(shape)
        num = np.zeros(xf.size)
        vnum = np.zeros(xf.size)
        den = np.zeros(xf.size)
        for t in self.tiles_:
            lo_x, hi_x = t.x0 - t.overlap_m, t.x1 + t.overlap_m
            lo_y, hi_y = t.y0 - t.overlap_m, t.y1 + t.overlap_m
            inside = np.nonzero((xf > lo_x) & (xf < hi_x) & (yf > lo_y) & (yf < hi_y))[0]
            if inside.size == 0:
                continue
            phi = _bump(xf[inside], lo_x, hi_x) * _bump(yf[inside], lo_y, hi_y)
            m, v = self._tile_predict(t, xf[inside], yf[inside], want_var)
            num[inside] += phi * m
            vnum[inside] += phi * v
            den[inside] += phi
        # Query points outside every tile's blending zone (beyond the samples' bounding box)
        # take the nearest tile.
        lost = np.nonzero(den <= 0)[0]
        if lost.size:
            centres = np.array([(0.5 * (t.x0 + t.x1), 0.5 * (t.y0 + t.y1)) for t in self.tiles_])
            owner = cKDTree(centres).query(np.column_stack([xf[lost], yf[lost]]))[1]
            for k in np.unique(owner):
                pts = lost[owner == k]
                m, v = self._tile_predict(self.tiles_[int(k)], xf[pts], yf[pts], want_var)
                num[pts], vnum[pts], den[pts] = m, v, 1.0
        return (h.mean + num / den).reshape(shape), (vnum / den).reshape(shape)

    def _tile_predict(self, t: _Tile, xq: FloatArray, yq: FloatArray, want_var: bool
                      ) -> tuple[FloatArray, FloatArray]:
        """Mean (minus the GP mean) and unit variance at query points from one system."""
        h = self.hyper_
        mean = np.empty(xq.size)
        var = np.zeros(xq.size)
        step = max(1, 4_000_000 // max(1, t.px.size))
        for s in range(0, xq.size, step):
            kq = h.correlation(np.hypot(xq[s:s + step, None] - t.px[None, :],
                                        yq[s:s + step, None] - t.py[None, :]))
            mean[s:s + step] = kq @ t.alpha
            if want_var:
                half = scipy.linalg.solve_triangular(t.chol[0], kq.T, lower=True,
                                                     check_finite=False)
                var[s:s + step] = np.clip(1.0 - np.einsum("ij,ij->j", half, half), 0.0, 1.0)
        return mean, var


def _bump(t: FloatArray, lo: float, hi: float) -> FloatArray:
    """C^1 bump ``(1 - s^2)^2`` on ``[lo, hi]`` (``s`` from -1 to 1), zero outside."""
    s = (t - 0.5 * (lo + hi)) / (0.5 * (hi - lo))
    out = np.clip(1.0 - s * s, 0.0, None)
    return out * out


def kriging_reconstruct(x: ArrayLike, y: ArrayLike, v: ArrayLike, grid: Grid,
                        nu: float = 2.5, noise_std: float | None = None) -> FloatArray:
    """Reconstruct the field on ``grid`` by kriging (``algorithm.reconstruction: kriging``),
    the noise estimated from the samples unless given (:class:`Kriging`).

    Returns
    -------
    ndarray
        Shape ``grid.shape``, indexed ``[row=y, col=x]``.
    """
    xx, yy = grid.mesh
    out = Kriging(nu=nu, noise_std=noise_std).fit(x, y, v).predict(xx, yy)
    assert isinstance(out, np.ndarray)
    return out
