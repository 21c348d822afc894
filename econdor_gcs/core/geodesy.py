"""Local ENU metres <-> WGS-84 geodetic coordinates around the mission origin (pymap3d).

The scalar methods suit one point at a time (a few hundred microseconds per call, mostly
pymap3d's fixed overhead); the ``*_many`` methods convert whole arrays in one vectorised
pymap3d call, which is what per-sample paths (vehicle sample batches, GCS sample logs) use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pymap3d
from numpy.typing import ArrayLike


@dataclass(frozen=True)
class Origin:
    """Mission origin: the ENU frame's (0, 0, 0). ``alt_m`` is AMSL (WGS-84 height)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def to_global(self, x_m: float, y_m: float, up_m: float = 0.0) -> tuple[float, float, float]:
        """ENU metres -> ``(lat_deg, lon_deg, alt_m)``; ``alt_m`` is height above the origin's."""
        lat, lon, h = pymap3d.enu2geodetic(x_m, y_m, up_m, self.lat_deg, self.lon_deg, self.alt_m)
        return float(lat), float(lon), float(h) - self.alt_m

    def to_local(self, lat_deg: float, lon_deg: float, rel_alt_m: float = 0.0) -> tuple[float, float, float]:
        """``(lat_deg, lon_deg, alt above origin)`` -> ENU ``(x_m, y_m, up_m)``."""
        e, n, u = pymap3d.geodetic2enu(
            lat_deg, lon_deg, rel_alt_m + self.alt_m, self.lat_deg, self.lon_deg, self.alt_m
        )
        return float(e), float(n), float(u)

    def to_global_many(self, x_m: ArrayLike, y_m: ArrayLike, up_m: ArrayLike = 0.0
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised :meth:`to_global`: ENU arrays -> ``(lat_deg, lon_deg, alt_m)`` arrays
        (``alt_m`` above the origin's height); scalars broadcast."""
        x, y, u = np.broadcast_arrays(np.asarray(x_m, dtype=float),
                                      np.asarray(y_m, dtype=float),
                                      np.asarray(up_m, dtype=float))
        if x.size == 0:
            e = np.zeros(x.shape)
            return e, e.copy(), e.copy()
        lat, lon, h = pymap3d.enu2geodetic(x, y, u, self.lat_deg, self.lon_deg, self.alt_m)
        return (np.asarray(lat, dtype=float).reshape(x.shape),
                np.asarray(lon, dtype=float).reshape(x.shape),
                np.asarray(h, dtype=float).reshape(x.shape) - self.alt_m)

    def to_local_many(self, lat_deg: ArrayLike, lon_deg: ArrayLike, rel_alt_m: ArrayLike = 0.0
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised :meth:`to_local`: ``(lat, lon, alt above origin)`` arrays -> ENU
        ``(x_m, y_m, up_m)`` arrays; scalars broadcast."""
        la, lo, a = np.broadcast_arrays(np.asarray(lat_deg, dtype=float),
                                        np.asarray(lon_deg, dtype=float),
                                        np.asarray(rel_alt_m, dtype=float))
        if la.size == 0:
            e = np.zeros(la.shape)
            return e, e.copy(), e.copy()
        e, n, u = pymap3d.geodetic2enu(la, lo, a + self.alt_m, self.lat_deg, self.lon_deg,
                                       self.alt_m)
        return (np.asarray(e, dtype=float).reshape(la.shape),
                np.asarray(n, dtype=float).reshape(la.shape),
                np.asarray(u, dtype=float).reshape(la.shape))
