"""Contour pieces of an estimated field (scikit-image marching squares)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from skimage import measure

from .geometry import FloatArray, Grid, path_length


@dataclass(frozen=True)
class ContourPiece:
    """One connected iso-line of the estimate at ``level`` (metres, polyline)."""

    level: float
    points_m: FloatArray  # shape (k, 2): x, y
    closed: bool

    @property
    def length_m(self) -> float:
        return path_length(self.points_m[:, 0], self.points_m[:, 1])

    def nearest_point(self, x_m: float, y_m: float) -> tuple[float, float]:
        d = np.hypot(self.points_m[:, 0] - x_m, self.points_m[:, 1] - y_m)
        i = int(np.argmin(d))
        return float(self.points_m[i, 0]), float(self.points_m[i, 1])

    def midpoint(self) -> tuple[float, float]:
        """The point halfway along the piece (a robust default start point)."""
        seg = np.hypot(*np.diff(self.points_m, axis=0).T)
        cum = np.r_[0.0, np.cumsum(seg)]
        i = int(np.searchsorted(cum, cum[-1] / 2))
        i = min(i, len(self.points_m) - 1)
        return float(self.points_m[i, 0]), float(self.points_m[i, 1])


def contour_pieces(
    estimate: FloatArray, grid: Grid, levels: FloatArray, min_length_m: float = 0.0
) -> list[ContourPiece]:
    """All iso-line pieces of ``estimate`` at ``levels``, shortest ones (< min_length_m) dropped."""
    out: list[ContourPiece] = []
    for level in np.asarray(levels, dtype=float):
        for rc in measure.find_contours(estimate, float(level)):
            x, y = grid.index_to_xy(rc[:, 0], rc[:, 1])
            pts = np.column_stack([x, y])
            closed = bool(len(pts) > 2 and np.allclose(pts[0], pts[-1]))
            piece = ContourPiece(float(level), pts, closed)
            if piece.length_m >= min_length_m:
                out.append(piece)
    return out
