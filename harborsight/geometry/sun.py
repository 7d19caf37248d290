"""The sun: its direction in a frame's local ENU, and the shadow a body casts on the water.

A frame gives the sun either in its ``sun`` block (elevation above the horizon and azimuth
clockwise from north, degrees: the simulator writes it) or through its ``timestamp`` and the
vessel's position, from which astral computes both (the timestamp must carry its UTC offset:
a time without one could be any zone's). Sunlight travels along

    s = (-sin(az) cos(el), -cos(az) cos(el), -sin(el))       (east, north, up)

and a point ``p`` above the water (``p_z > 0``) casts its shadow on the plane ``z = 0`` at
``p - (p_z / s_z) s``. A convex body's shadow is the convex hull of its corners' shadows and
its footprint; for the vessel, whose ``hull_points`` hull contains everything above the
waterline, that hull's shadow contains the vessel's.
"""

from __future__ import annotations

import math
from datetime import datetime

import cv2
import numpy as np

#: below this elevation no shadow is predicted: it would stretch over tens of hull lengths
MIN_SHADOW_ELEVATION_DEG = 5.0


def sun_ray_enu(elevation_deg: float, azimuth_deg: float) -> np.ndarray | None:
    """The unit direction sunlight travels (ENU, downward); None when the sun is below
    :data:`MIN_SHADOW_ELEVATION_DEG`."""
    if not elevation_deg >= MIN_SHADOW_ELEVATION_DEG:
        return None
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([-math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), -math.sin(el)])


def sun_position_deg(lat_deg: float, lon_deg: float, when: datetime) -> tuple[float, float]:
    """``(elevation, azimuth)`` of the sun in degrees (azimuth clockwise from north; the
    elevation as seen, atmospheric refraction included) at a place and a time that carries
    its UTC offset, by astral (NOAA's algorithm)."""
    if when.tzinfo is None:
        raise ValueError("a time without a UTC offset")
    from astral import Observer
    from astral.sun import azimuth, elevation

    observer = Observer(lat_deg, lon_deg)
    return float(elevation(observer, when)), float(azimuth(observer, when))


def shadow_on_water(points_enu: np.ndarray, ray_enu: np.ndarray) -> np.ndarray:
    """The convex outline ``(M, 2)`` (east, north) of the shadow that the convex hull of
    ``points_enu (N, 3)`` casts on the water along ``ray_enu``, its footprint included."""
    points = np.asarray(points_enu, float)
    above = points[points[:, 2] > 0.0]
    cast = above[:, :2] - (above[:, 2] / ray_enu[2])[:, None] * ray_enu[:2]
    everything = np.vstack((points[:, :2], cast)).astype(np.float32)
    return cv2.convexHull(everything).reshape(-1, 2).astype(float)
