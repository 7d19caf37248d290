"""Ground sample distance (GSD) of a nadir camera, the paper's pixel-to-metre factor.

The paper (Sec. III, "Image-based Distance Computation") converts a pixel distance
``d_v`` to metres with

    D_v = max(a·w_s / (f·w_i), a·h_s / (f·h_i)) · d_v

with ``a`` the camera height above the ground (here: above the water), ``w_s``/``h_s``
the sensor width/height, ``f`` the focal length and ``w_i``/``h_i`` the image size in
pixels. With focal lengths in pixels (``fx = f·w_i/w_s``) this is ``a · max(1/fx, 1/fy)``.
"""

from __future__ import annotations


def nadir_gsd_m_per_px(height_above_water_m: float, fx_px: float, fy_px: float) -> float:
    """``GSD = a · max(1/fx, 1/fy)`` in metres per pixel (nadir, flat ground)."""
    return height_above_water_m * max(1.0 / fx_px, 1.0 / fy_px)


def nadir_gsd_from_sensor(
    height_above_water_m: float,
    sensor_width_mm: float,
    sensor_height_mm: float,
    focal_length_mm: float,
    image_width_px: int,
    image_height_px: int,
) -> float:
    """The paper's formula literally: ``max(a·w_s/(f·w_i), a·h_s/(f·h_i))`` in m/px."""
    a = height_above_water_m
    return max(
        a * sensor_width_mm / (focal_length_mm * image_width_px),
        a * sensor_height_mm / (focal_length_mm * image_height_px),
    )
