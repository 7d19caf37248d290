"""What a simulated scene's camera and vessel poses say as frame metadata."""

from __future__ import annotations

import numpy as np

from harborsight.frame import FrameGeometry, FrameMetadata
from harborsight.geometry.geodesy import enu_to_geodetic


class PosedScene:
    """Mixin for scenes with ``intrinsics``, ``uav_enu`` (camera centre in ENU metres, origin at
    the vessel's antenna on the water), ``yaw_deg``/``pitch_deg``/``roll_deg``,
    ``vessel_heading_deg``, ``origin`` (a GeoOrigin at the antenna) and ``timestamp``; a
    rendered scene's ``environment`` gives the frame its ``sun`` block, and a flight's frame
    (``sequence``) the vessel's ground velocity and rate of turn."""

    def metadata(self, image: str) -> FrameMetadata:
        """``harborsight.frame/1`` metadata of the true poses (drone GPS from ENU by pymap3d)."""
        lat, lon, alt = enu_to_geodetic(np.asarray(self.uav_enu, float), self.origin)
        env = getattr(self, "environment", None)        # a rendered scene's sun
        # a flight's frame: the vessel's ground velocity, as its receiver would give it
        sequence = getattr(self, "sequence", None) or {}
        velocity = (None if "speed_mps" not in sequence else
                    tuple(float(sequence["speed_mps"]) * float(c) for c in sequence["direction_enu"]))
        return FrameMetadata(
            image=image, camera=self.intrinsics,
            uav_lat_deg=float(lat), uav_lon_deg=float(lon), uav_alt_m=float(alt),
            yaw_deg=self.yaw_deg, pitch_deg=self.pitch_deg, roll_deg=self.roll_deg,
            vessel_lat_deg=self.origin.lat_deg, vessel_lon_deg=self.origin.lon_deg,
            vessel_heading_deg=self.vessel_heading_deg, water_level_m=self.origin.alt_m,
            timestamp=self.timestamp,
            sun_elevation_deg=None if env is None else float(env.sun_elevation_deg),
            sun_azimuth_deg=None if env is None else float(env.sun_azimuth_deg),
            vessel_velocity_en_mps=velocity,
            # a flight's vessel does not turn: its rate gyro reads 0
            vessel_yaw_rate_deg_s=None if velocity is None else 0.0,
        )

    def geometry(self) -> FrameGeometry:
        return FrameGeometry.from_metadata(self.metadata("frame.png"))
