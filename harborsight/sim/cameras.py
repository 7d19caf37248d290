"""Camera presets of real drone cameras.

A frame spans the sensor's width when it is at least as wide as the sensor (16:9 video from
a 4:3 or 3:2 sensor): ``fx = f / sensor_width · image_width``; a narrower one (a 4:3 photo
from a 3:2 sensor, a portrait crop) spans its height: ``fx = f / sensor_height ·
image_height``. The principal point is at the image centre; values are from the
manufacturers' published specifications (nominal: a unit's factory calibration, DJI's
``CalibratedFocalLength``, may differ by about 1 %, and video modes that crop the sensor
further are not modelled).
"""

from __future__ import annotations

from dataclasses import dataclass

from harborsight.geometry.camera import CameraIntrinsics, sensor_focal_px


@dataclass(frozen=True)
class CameraPreset:
    name: str
    focal_length_mm: float
    sensor_width_mm: float
    sensor_height_mm: float
    source: str
    #: the lens as a 35 mm equivalent (a DJI SRT's focal_len says when the camera zoomed)
    focal_35mm_mm: float = 24.0

    def intrinsics(self, width: int, height: int) -> CameraIntrinsics:
        f_px, _ = sensor_focal_px(self.focal_length_mm, self.sensor_width_mm,
                                  self.sensor_height_mm, width, height)
        return CameraIntrinsics(width, height, f_px, f_px, (width - 1) / 2, (height - 1) / 2)


CAMERA_PRESETS = {
    preset.name: preset for preset in (
        CameraPreset("dji-mavic3", 12.29, 17.3, 13.0,
                     "DJI Mavic 3 Hasselblad L2D-20c: 4/3\" CMOS 17.3 x 13.0 mm, 24 mm equivalent "
                     "(12.29 mm) lens; dji.com/mavic-3/specs"),
        CameraPreset("dji-p4rtk", 8.8, 13.2, 8.8,
                     "DJI Phantom 4 RTK: 1\" CMOS 13.2 x 8.8 mm, 8.8 mm (24 mm equivalent) lens; "
                     "dji.com/phantom-4-rtk/specs"),
        CameraPreset("dji-m30-wide", 4.5, 6.4, 4.8,
                     "DJI Matrice 30 wide camera: 1/2\" CMOS (6.4 x 4.8 mm), 4.5 mm (24 mm "
                     "equivalent) lens; dji.com/matrice-30/specs"),
    )
}
