"""Geodetic <-> local ENU (WGS84) through pymap3d.

The world frame W is a local east-north-up tangent plane whose origin is a reference
latitude/longitude at the water surface (``z = 0`` is the water plane).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pymap3d


@dataclass(frozen=True)
class GeoOrigin:
    """Origin of a local ENU frame: geodetic latitude/longitude (deg) and height (m)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def to_dict(self) -> dict[str, float]:
        return {"lat": self.lat_deg, "lon": self.lon_deg, "alt_m": self.alt_m}


def geodetic_to_enu(lat_deg, lon_deg, alt_m, origin: GeoOrigin) -> np.ndarray:
    """Geodetic WGS84 coordinates to ENU metres about ``origin``.

    Returns an array of shape ``(..., 3)`` holding (east, north, up).
    """
    e, n, u = pymap3d.geodetic2enu(
        lat_deg, lon_deg, alt_m, origin.lat_deg, origin.lon_deg, origin.alt_m, deg=True
    )
    return np.stack(np.broadcast_arrays(e, n, u), axis=-1).astype(float)


def enu_to_geodetic(enu_m: np.ndarray, origin: GeoOrigin) -> np.ndarray:
    """ENU metres about ``origin`` to (lat_deg, lon_deg, alt_m), shape ``(..., 3)``."""
    enu_m = np.asarray(enu_m, dtype=float)
    lat, lon, alt = pymap3d.enu2geodetic(
        enu_m[..., 0], enu_m[..., 1], enu_m[..., 2],
        origin.lat_deg, origin.lon_deg, origin.alt_m, deg=True,
    )
    return np.stack(np.broadcast_arrays(lat, lon, alt), axis=-1).astype(float)
