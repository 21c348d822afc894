"""The fast biharmonic spline: thinned samples, a coarse exact spline and tile levels.

See :class:`FastBiharmonicSpline`.

References
----------
Sandwell, D. T. (1987). Biharmonic spline interpolation of GEOS-3 and SEASAT altimeter
data. *Geophysical Research Letters*, 14(2), 139-142. https://doi.org/10.1029/GL014i002p00139
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from econdor_gcs.core.exact_spline import BiharmonicSpline, _Spline
from econdor_gcs.core.greens import (
    FloatArray,
    _Blocks,
    _one_blas_thread,
    _resolve,
    _Solution,
)
from econdor_gcs.core.samples import (
    _block_mean,
    _block_pick,
    _bump,
    _check_query,
    _merge_duplicates,
    _RectIndex,
    _thin_pick,
)
from econdor_gcs.errors import ReconstructionError

__all__ = ["DEFAULT_LEVELS", "FastBiharmonicSpline", "Tile", "TileLevel"]

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
    noise_std : float or None
        Standard deviation of the samples' noise: ``None`` estimates it, ``0`` interpolates
        every sample exactly (see :meth:`fit`: noisy samples are smoothed before they are
        thinned and interpolated).

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
    noise_std_, noise_, damping_m2_
        The noise the fit assumed and the smoothing's damping per tile, as
        :class:`~econdor_gcs.core.exact_spline.BiharmonicSpline` has them.

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
        noise_std: float | None = None,
    ) -> None:
        self.cell_size = cell_size
        self.thinning = thinning
        self.coarse_cell = coarse_cell
        self.coarse_max_samples = coarse_max_samples
        self.levels = levels
        self.warm_start = warm_start
        self.noise_std = noise_std

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
