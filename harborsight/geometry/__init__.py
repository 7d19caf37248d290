"""Frames, rotations, geodesy, the camera model, ground-plane projection and GSD."""

from harborsight.geometry.calibration_files import load_camera_calibration
from harborsight.geometry.camera import Camera, CameraIntrinsics
from harborsight.geometry.geodesy import GeoOrigin, enu_to_geodetic, geodetic_to_enu
from harborsight.geometry.gsd import nadir_gsd_from_sensor, nadir_gsd_m_per_px
from harborsight.geometry.rotations import (
    enu_from_vessel_rotation,
    world_from_camera_rotation,
)

__all__ = [
    "Camera",
    "CameraIntrinsics",
    "GeoOrigin",
    "enu_from_vessel_rotation",
    "enu_to_geodetic",
    "geodetic_to_enu",
    "load_camera_calibration",
    "nadir_gsd_from_sensor",
    "nadir_gsd_m_per_px",
    "world_from_camera_rotation",
]
