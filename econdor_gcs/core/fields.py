"""Synthetic and raster field models g(x, y).

A field is a callable ``field(x_m, y_m) -> values`` (numpy-vectorised; scalars in give
a 0-d result) with a ``region`` attribute. The models:

* :class:`GaussianSumField` — the paper's eq. (8)-(9): two groups of isotropic 2-D
  Gaussians (``sigma1_m`` = 10 and ``sigma2_m`` = 15 m) with random centres in the area and
  positive random weights, scaled so that the field lies in (0, peak).
* :func:`authors_field` — the generator of the authors' MATLAB code: 150 Gaussians with
  sigma 10 and weights ``2 peak (U - 0.5) / sqrt(2 pi) / sigma`` plus 150 with sigma 15
  and weights ``5 (U - 0.5) / sqrt(2 pi) / sigma``, normalised on the 101 x 101 grid as
  ``peak/2 * Z / range(Z) + 50``.
* :func:`plume_field` — a few narrow sources on a flat background (sharp features that
  the two diagonals can miss entirely).
* :class:`FrontField` — a sharp front: a meandering ``tanh`` step across the area and a
  few round islands with the same steep edge, on a gentle slope (a boundary that a
  survey between lines can only interpolate).
* :class:`RasterField` — a grid loaded from ``.npy``, ``.npz``, ``.mat`` or ``.csv``,
  spanning the region node-to-node, interpolated between nodes.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numba import njit
from numpy.typing import ArrayLike
from scipy.interpolate import RegularGridInterpolator

from ..errors import FieldError
from .geometry import FloatArray, Grid, Region


class Field(Protocol):
    region: Region

    def __call__(self, x_m: ArrayLike, y_m: ArrayLike) -> FloatArray: ...


@njit(cache=True)
def gaussian_sum_at(x_m: float, y_m: float, cx_m: FloatArray, cy_m: FloatArray,
                    inv2s2: FloatArray, weights: FloatArray) -> float:
    """``sum_p w_p exp(-((x - cx_p)^2 + (y - cy_p)^2) inv2s2_p)`` at one point, compiled.

    The one evaluation of a Gaussian sum: :meth:`GaussianSumField.raw` calls it for every
    point of a grid and the simulated sensor for every sample, so a value sensed at a
    point is bit for bit the true field there.
    """
    acc = 0.0
    for p in range(weights.shape[0]):
        dx = x_m - cx_m[p]
        dy = y_m - cy_m[p]
        acc += math.exp(-(dx * dx + dy * dy) * inv2s2[p]) * weights[p]
    return acc


@njit(cache=True)
def _gaussian_sum_many(xf: FloatArray, yf: FloatArray, cx_m: FloatArray, cy_m: FloatArray,
                       inv2s2: FloatArray, weights: FloatArray, out: FloatArray) -> None:
    for i in range(xf.shape[0]):
        out[i] = gaussian_sum_at(xf[i], yf[i], cx_m, cy_m, inv2s2, weights)


class GaussianSumField:
    """``g(x, y) = offset + scale * sum_p w_p exp(-((x - mx_p)^2 + (y - my_p)^2) / (2 s_p^2))``.

    Evaluated exactly (no interpolation) by the compiled :func:`gaussian_sum_at`.

    Examples
    --------
    >>> f = GaussianSumField(Region(0.0, 10.0, 0.0, 10.0), [[5.0, 5.0]], [2.0], [1.0],
    ...                      scale=3.0, offset=1.0)
    >>> float(f(5.0, 5.0)), float(f(7.0, 5.0)) == 1.0 + 3.0 * math.exp(-0.5)
    (4.0, True)
    """

    def __init__(
        self,
        region: Region,
        centres_m: FloatArray,
        sigmas_m: FloatArray,
        weights: FloatArray,
        scale: float = 1.0,
        offset: float = 0.0,
    ) -> None:
        self.region = region
        self.centres_m = np.asarray(centres_m, dtype=float).reshape(-1, 2)
        self.sigmas_m = np.asarray(sigmas_m, dtype=float).ravel()
        self.weights = np.asarray(weights, dtype=float).ravel()
        if not (len(self.centres_m) == len(self.sigmas_m) == len(self.weights)):
            raise FieldError("centres, sigmas and weights must have the same length")
        self.scale = float(scale)
        self.offset = float(offset)
        self.inv2s2 = 1.0 / (2.0 * self.sigmas_m**2)
        self.cx_m = np.ascontiguousarray(self.centres_m[:, 0])
        self.cy_m = np.ascontiguousarray(self.centres_m[:, 1])

    def raw(self, x_m: ArrayLike, y_m: ArrayLike) -> FloatArray:
        """The unscaled Gaussian sum."""
        x = np.asarray(x_m, dtype=float)
        y = np.asarray(y_m, dtype=float)
        shape = np.broadcast(x, y).shape
        xf = np.ascontiguousarray(np.broadcast_to(x, shape).ravel())
        yf = np.ascontiguousarray(np.broadcast_to(y, shape).ravel())
        out = np.empty(xf.size)
        _gaussian_sum_many(xf, yf, self.cx_m, self.cy_m, self.inv2s2, self.weights, out)
        return out.reshape(shape)

    def __call__(self, x_m: ArrayLike, y_m: ArrayLike) -> FloatArray:
        return self.offset + self.scale * self.raw(x_m, y_m)


def _uniform_points(rng: np.random.Generator, region: Region, n: int,
                    margin: float = 0.0) -> FloatArray:
    """``n`` points uniform in the region shrunk by ``margin`` (a fraction of its size)."""
    mx, my = margin * region.width_m, margin * region.height_m
    return np.column_stack([rng.uniform(region.xmin + mx, region.xmax - mx, n),
                            rng.uniform(region.ymin + my, region.ymax - my, n)])


def _norm_grid(region: Region) -> Grid:
    """The grid the generators normalise on: 101 x 101 nodes, as in the authors' code."""
    return Grid(region, 101, 101)


def paper_field(
    region: Region,
    seed: int,
    n1: int = 20,
    n2: int = 20,
    sigma1_m: float = 10.0,
    sigma2_m: float = 15.0,
    peak: float = 100.0,
) -> GaussianSumField:
    """The paper's eq. (8)-(9) with positive random weights, scaled into (0, peak).

    The weights ``a_p, b_p ~ U(0, 1)``; the sum is then scaled so its maximum over the
    101 x 101 grid is ``0.95 * peak`` (all values stay positive).
    """
    rng = np.random.default_rng(seed)
    n = n1 + n2
    centres = _uniform_points(rng, region, n)
    sigmas = np.r_[np.full(n1, sigma1_m), np.full(n2, sigma2_m)]
    weights = rng.uniform(0.0, 1.0, n)
    f = GaussianSumField(region, centres, sigmas, weights)
    xx, yy = _norm_grid(region).mesh
    f.scale = 0.95 * peak / float(np.max(f.raw(xx, yy)))
    return f


def authors_field(
    region: Region,
    seed: int,
    n1: int = 150,
    n2: int = 150,
    sigma1_m: float = 10.0,
    sigma2_m: float = 15.0,
    peak: float = 100.0,
) -> GaussianSumField:
    """The field generator of the authors' MATLAB code (see module docstring)."""
    rng = np.random.default_rng(seed)
    c1 = _uniform_points(rng, region, n1)
    w1 = 2 * peak * (rng.uniform(size=n1) - 0.5) / np.sqrt(2 * np.pi) / sigma1_m
    c2 = _uniform_points(rng, region, n2)
    w2 = 5 * (rng.uniform(size=n2) - 0.5) / np.sqrt(2 * np.pi) / sigma2_m
    f = GaussianSumField(
        region,
        np.vstack([c1, c2]),
        np.r_[np.full(n1, sigma1_m), np.full(n2, sigma2_m)],
        np.r_[w1, w2],
    )
    xx, yy = _norm_grid(region).mesh
    z = f.raw(xx, yy)
    span = float(np.ptp(z))
    if span <= 0:
        raise FieldError("authors field: degenerate (zero range)")
    f.scale = peak / 2 / span
    f.offset = 50.0 * peak / 100.0
    return f


def plume_field(
    region: Region,
    seed: int,
    sources: int = 3,
    sigma_min_m: float = 2.0,
    sigma_max_m: float = 5.0,
    background: float = 10.0,
    peak: float = 100.0,
) -> GaussianSumField:
    """A few narrow Gaussian sources on a flat background, peak value ``peak``."""
    rng = np.random.default_rng(seed)
    centres = _uniform_points(rng, region, sources, margin=0.1)
    sigmas = rng.uniform(sigma_min_m, sigma_max_m, sources)
    weights = rng.uniform(0.4, 1.0, sources)
    f = GaussianSumField(region, centres, sigmas, weights, offset=background)
    # Normalise on a grid fine enough to see the narrowest source.
    fine = Grid.with_spacing(region, min(0.5, sigma_min_m / 4))
    xx, yy = fine.mesh
    f.scale = (peak - background) / float(np.max(f.raw(xx, yy)))
    return f


class FrontField:
    """Sharp fronts: ``g = b + (p - b) max(H(s_front), H(s_island_1), ...) + slope``.

    ``H(s) = (1 + tanh(s / w)) / 2`` is a smooth step of width ``w``. The front's signed
    distance is ``s = (x - c) . n - A sin(2 pi (x - c) . t / lambda + phi)`` (a line through
    ``c`` with normal ``n`` and tangent ``t``, meandering with amplitude ``A``); an island's
    is ``R - |x - c_k|``. ``slope`` is a plane adding at most ``+-5 %`` of the step across
    the area, so neither side is exactly flat.
    """

    def __init__(self, region: Region, centre_m: FloatArray, normal: FloatArray,
                 amplitude_m: float, wavelength_m: float, phase_rad: float, width_m: float,
                 islands_m: FloatArray, background: float, peak: float,
                 slope: FloatArray) -> None:
        self.region = region
        self.centre_m = np.asarray(centre_m, dtype=float)
        self.normal = np.asarray(normal, dtype=float) / float(np.hypot(*normal))
        self.amplitude_m = amplitude_m
        self.wavelength_m = wavelength_m
        self.phase_rad = phase_rad
        self.width_m = width_m
        self.islands_m = np.asarray(islands_m, dtype=float).reshape(-1, 3)  # x, y, radius
        self.background = background
        self.peak = peak
        self.slope = np.asarray(slope, dtype=float)

    def __call__(self, x_m: ArrayLike, y_m: ArrayLike) -> FloatArray:
        x = np.asarray(x_m, dtype=float)
        y = np.asarray(y_m, dtype=float)
        dx, dy = x - self.centre_m[0], y - self.centre_m[1]
        nx, ny = self.normal
        along = -dx * ny + dy * nx
        s = dx * nx + dy * ny - self.amplitude_m * np.sin(
            2 * np.pi * along / self.wavelength_m + self.phase_rad)
        step = 0.5 * (1.0 + np.tanh(s / self.width_m))
        for cx, cy, r in self.islands_m:
            island = 0.5 * (1.0 + np.tanh((r - np.hypot(x - cx, y - cy)) / self.width_m))
            step = np.maximum(step, island)
        plane = self.slope[0] * (x - self.region.xmin) / self.region.width_m + self.slope[1] * (
            y - self.region.ymin) / self.region.height_m
        return self.background + (self.peak - self.background) * (step + plane)


def front_field(
    region: Region,
    seed: int,
    width_min_m: float = 1.0,
    width_max_m: float = 3.0,
    amplitude_m: float = 10.0,
    wavelength_m: float = 60.0,
    islands: int = 2,
    background: float = 10.0,
    peak: float = 100.0,
) -> FrontField:
    """A random :class:`FrontField`: the front through the middle third of the area at a
    random angle, ``islands`` islands of radius 6-12 m on the low side."""
    rng = np.random.default_rng(seed)
    centre = _uniform_points(rng, region, 1, margin=1 / 3)[0]
    ang = rng.uniform(0.0, 2 * np.pi)
    normal = np.array([np.cos(ang), np.sin(ang)])
    width = rng.uniform(width_min_m, width_max_m)
    phase = rng.uniform(0.0, 2 * np.pi)
    slope = rng.uniform(-0.05, 0.05, 2)
    f = FrontField(region, centre, normal, amplitude_m, wavelength_m, phase, width,
                   np.zeros((0, 3)), background, peak, slope)
    found: list[tuple[float, float, float]] = []
    for _ in range(200 * max(islands, 1)):
        if len(found) >= islands:
            break
        c = _uniform_points(rng, region, 1, margin=0.12)[0]
        r = rng.uniform(6.0, 12.0)
        # on the low side, clear of the front and of the other islands
        ring = c[None, :] + (r + 3 * width) * np.column_stack(
            [np.cos(np.linspace(0, 2 * np.pi, 24)), np.sin(np.linspace(0, 2 * np.pi, 24))])
        clear = all(np.hypot(c[0] - q[0], c[1] - q[1]) > r + q[2] + 6 for q in found)
        if clear and float(np.max(f(ring[:, 0], ring[:, 1]))) < background + 0.2 * (peak - background):
            found.append((float(c[0]), float(c[1]), float(r)))
    f.islands_m = np.array(found, dtype=float).reshape(-1, 3)
    return f


class RasterField:
    """A field given as a grid of values spanning ``region`` node to node.

    ``values[row, col]`` with row 0 at ``ymin`` (see :mod:`.geometry`). Points outside the
    region take the nearest edge value.
    """

    def __init__(self, region: Region, values: ArrayLike, method: str = "cubic") -> None:
        v = np.asarray(values, dtype=float)
        if v.ndim != 2 or min(v.shape) < 2:
            raise FieldError(f"raster must be a 2-D grid of at least 2 x 2, got shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise FieldError("raster contains NaN or infinite values")
        if method == "cubic" and min(v.shape) < 4:
            method = "linear"
        self.region = region
        self.values = v
        ny, nx = v.shape
        self._x = np.linspace(region.xmin, region.xmax, nx)
        self._y = np.linspace(region.ymin, region.ymax, ny)
        self._interp = RegularGridInterpolator((self._y, self._x), v, method=method)

    def __call__(self, x_m: ArrayLike, y_m: ArrayLike) -> FloatArray:
        x = np.clip(np.asarray(x_m, dtype=float), self.region.xmin, self.region.xmax)
        y = np.clip(np.asarray(y_m, dtype=float), self.region.ymin, self.region.ymax)
        shape = np.broadcast(x, y).shape
        pts = np.column_stack([np.broadcast_to(y, shape).ravel(),
                               np.broadcast_to(x, shape).ravel()])
        return self._interp(pts).reshape(shape)


def load_raster(path: str | Path, variable: str = "") -> FloatArray:
    """Load a 2-D grid from ``.npy``, ``.npz``, ``.mat`` (scipy.io) or ``.csv``."""
    p = Path(path)
    if not p.exists():
        raise FieldError(f"raster file not found: {p}")
    suffix = p.suffix.lower()
    try:
        if suffix == ".npy":
            return np.load(p, allow_pickle=False)
        if suffix == ".npz":
            with np.load(p, allow_pickle=False) as data:
                return _pick(dict(data), variable, p)
        if suffix == ".mat":
            import scipy.io

            data = {k: v for k, v in scipy.io.loadmat(p).items() if not k.startswith("__")}
            return _pick(data, variable, p)
        if suffix == ".csv":
            return np.loadtxt(p, delimiter=",", ndmin=2)
    except FieldError:
        raise
    except (OSError, ValueError) as exc:
        raise FieldError(f"cannot read raster {p}: {exc}") from exc
    raise FieldError(f"raster {p}: unsupported format {suffix!r} (use .npy, .npz, .mat or .csv)")


def _pick(data: dict[str, Any], variable: str, p: Path) -> FloatArray:
    if variable:
        if variable not in data:
            raise FieldError(f"raster {p}: no variable {variable!r} (has {', '.join(data)})")
        return np.asarray(data[variable])
    grids = [k for k, v in data.items() if np.ndim(v) == 2]
    if not grids:
        raise FieldError(f"raster {p}: no 2-D array inside")
    return np.asarray(data[grids[0]])


def make_field(model: str, params: dict[str, Any], region: Region, seed: int) -> Field:
    """Build a field model by name (the ``field:`` section of a mission)."""
    if model == "paper":
        return paper_field(region, seed, **params)
    if model == "authors":
        return authors_field(region, seed, **params)
    if model == "plume":
        return plume_field(region, seed, **params)
    if model == "front":
        return front_field(region, seed, **params)
    if model == "raster":
        values = load_raster(params["path"], params.get("variable", ""))
        return RasterField(region, values, params.get("method", "cubic"))
    raise FieldError(f"unknown field model {model!r}")
