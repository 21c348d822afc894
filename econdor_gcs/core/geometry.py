"""Coordinates and grids.

Conventions (after verde): positions are local ENU metres, ``x_m`` = easting and
``y_m`` = northing, measured from the mission origin. A region is
``(xmin, xmax, ymin, ymax)`` in that order. Gridded arrays are indexed
``[row, col] = [y, x]`` (``shape = (ny, nx)``), row 0 at ``ymin``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Region:
    """An axis-aligned rectangle ``(xmin, xmax, ymin, ymax)`` in metres."""

    xmin: float
    xmax: float
    ymin: float
    ymax: float

    def __post_init__(self) -> None:
        if not (self.xmax > self.xmin and self.ymax > self.ymin):
            raise ValueError(f"region must have xmax > xmin and ymax > ymin, got {self}")

    @property
    def width_m(self) -> float:
        return self.xmax - self.xmin

    @property
    def height_m(self) -> float:
        return self.ymax - self.ymin

    def contains(self, x: float, y: float, margin_m: float = 0.0) -> bool:
        return (
            self.xmin - margin_m <= x <= self.xmax + margin_m
            and self.ymin - margin_m <= y <= self.ymax + margin_m
        )

    def clip(self, x: float, y: float) -> tuple[float, float]:
        return (min(max(x, self.xmin), self.xmax), min(max(y, self.ymin), self.ymax))


@dataclass(frozen=True)
class Grid:
    """A regular P x Q evaluation grid over a region (nodes on the boundary included)."""

    region: Region
    nx: int
    ny: int

    def __post_init__(self) -> None:
        if self.nx < 2 or self.ny < 2:
            raise ValueError(f"grid needs at least 2 x 2 nodes, got {self.nx} x {self.ny}")

    @classmethod
    def with_spacing(cls, region: Region, spacing_m: float) -> Grid:
        nx = int(round(region.width_m / spacing_m)) + 1
        ny = int(round(region.height_m / spacing_m)) + 1
        return cls(region, nx, ny)

    @cached_property
    def x(self) -> FloatArray:
        return np.linspace(self.region.xmin, self.region.xmax, self.nx)

    @cached_property
    def y(self) -> FloatArray:
        return np.linspace(self.region.ymin, self.region.ymax, self.ny)

    @cached_property
    def mesh(self) -> tuple[FloatArray, FloatArray]:
        """``(X, Y)`` arrays of shape ``(ny, nx)``."""
        xx, yy = np.meshgrid(self.x, self.y)
        return xx, yy

    @property
    def shape(self) -> tuple[int, int]:
        return (self.ny, self.nx)

    @property
    def dx(self) -> float:
        return self.region.width_m / (self.nx - 1)

    @property
    def dy(self) -> float:
        return self.region.height_m / (self.ny - 1)

    def index_to_xy(self, rows: FloatArray, cols: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Map fractional (row, col) indices, e.g. from scikit-image contours, to metres."""
        return (self.region.xmin + cols * self.dx, self.region.ymin + rows * self.dy)


def path_length(x: FloatArray, y: FloatArray) -> float:
    """Length of the polyline through ``(x, y)`` in metres."""
    if len(x) < 2:
        return 0.0
    return float(np.sum(np.hypot(np.diff(x), np.diff(y))))
