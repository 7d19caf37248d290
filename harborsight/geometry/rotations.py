"""Rotations between the world (ENU), gimbal (FRD), camera (OpenCV) and vessel frames.

Conventions (``docs/geometry.md``):

* gimbal frame G is FRD: x along the optical axis at zero pitch, y right, z down;
* attitude is NED Euler ZYX: ``R_NED<-G = Rz(yaw) · Ry(pitch) · Rx(roll)``, yaw clockwise
  from true north, pitch -90 deg = straight down (DJI gimbal convention);
* camera frame C is OpenCV's: ``z_C = x_G``, ``x_C = y_G``, ``y_C = z_G``;
* vessel frame V: x bow, y starboard, z down; heading clockwise from true north.

So ``R_W<-C = R_ENU<-NED · R_NED<-G · R_G<-C``.
"""

from __future__ import annotations

import numpy as np

#: Maps NED vectors to ENU: (n, e, d) -> (e, n, -d).
ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: Maps OpenCV camera vectors to gimbal FRD: x_G = z_C, y_G = x_C, z_G = y_C.
GIMBAL_FROM_CAMERA = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def rot_x(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ned_from_gimbal_rotation(yaw_rad: float, pitch_rad: float, roll_rad: float) -> np.ndarray:
    """``R_NED<-G = Rz(yaw) · Ry(pitch) · Rx(roll)`` (intrinsic ZYX Euler angles)."""
    return rot_z(yaw_rad) @ rot_y(pitch_rad) @ rot_x(roll_rad)


def world_from_camera_rotation(yaw_rad: float, pitch_rad: float, roll_rad: float) -> np.ndarray:
    """``R_W<-C``: rotates OpenCV camera-frame vectors into the ENU world frame.

    At pitch = -90 deg the optical axis points down and the image top (-y_C) points
    toward ``yaw``.
    """
    return ENU_FROM_NED @ ned_from_gimbal_rotation(yaw_rad, pitch_rad, roll_rad) @ GIMBAL_FROM_CAMERA


def enu_from_vessel_rotation(heading_rad: float) -> np.ndarray:
    """``R_W<-V`` for a level vessel: columns are bow, starboard and down in ENU.

    bow = (sin h, cos h, 0), starboard = (cos h, -sin h, 0), down = (0, 0, -1).
    """
    s, c = np.sin(heading_rad), np.cos(heading_rad)
    return np.array([[s, c, 0.0], [c, -s, 0.0], [0.0, 0.0, -1.0]])
