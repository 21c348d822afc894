"""Local ENU metres <-> WGS-84 geodetic coordinates around the mission origin (pymap3d)."""

from __future__ import annotations

from dataclasses import dataclass

import pymap3d


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
