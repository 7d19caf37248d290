"""A drone camera's auto-exposure, for the realistic families' frames.

A render's exposure is fixed per frame (``Environment.exposure_ev``, a draw of -0.3..0.7 EV
through Blender's AgX view), while a real camera meters every frame toward mid-grey. Measured
on the 42 real lake-shore drone photos against the 49 lake-shore frames of a family render
(mean CIE L* of each image, 0-100): photos 50.1 ± 2.2, renders 37.2 ± 12.6 (its 44 marina
frames 32.1 ± 8.7). The renders were darker by a median 1.0 EV (marinas 1.3 EV) and six times
as variable.

The metering here: a gain ``2^ev`` in linear light (the 8-bit render decoded from sRGB) such
that the image's mean L* meets a target drawn per frame from the photos' spread; what the
gain lifts past white clips, as a camera's highlights do. The mean L* rises monotonically with
the gain, so ``ev`` is found by bisection on a copy at most 160 pixels wide.
"""

from __future__ import annotations

import cv2
import numpy as np

#: the target mean L* (0-100) of a metered frame: mean and spread of the real lake-shore photos
TARGET_LIGHTNESS_MEAN = 50.0
TARGET_LIGHTNESS_SD = 2.5
#: the camera's range of correction, EV either way
EV_LIMIT = 3.0


def srgb_to_linear(srgb_8bit: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 decoding: 8-bit sRGB values -> linear light in [0, 1]."""
    v = np.asarray(srgb_8bit, np.float32) / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """Linear light (clipped to [0, 1]) -> sRGB on the 8-bit scale (float, 0-255)."""
    v = np.clip(linear, 0.0, 1.0)
    return (255.0 * np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)).astype(np.float32)


def mean_lightness(linear_bgr: np.ndarray) -> float:
    """Mean CIE L* (D65, 0-100) of a linear-light BGR image, values clipped to [0, 1]."""
    clipped = np.clip(linear_bgr, 0.0, 1.0).astype(np.float32)
    return float(cv2.cvtColor(clipped, cv2.COLOR_LBGR2Lab)[..., 0].mean())


#: the metering reads a copy at most this many pixels wide (every k-th pixel)
METERING_WIDTH_PX = 160


def metered_ev(image_bgr: np.ndarray, target_lightness: float, ev_limit: float = EV_LIMIT,
               iterations: int = 16) -> float:
    """The gain (EV) that brings ``image_bgr`` (8-bit scale sRGB) to a mean L* of
    ``target_lightness``, within ``±ev_limit``."""
    step = max(1, image_bgr.shape[1] // METERING_WIDTH_PX)
    small = srgb_to_linear(image_bgr[::step, ::step])
    low, high = -ev_limit, ev_limit
    for _ in range(iterations):
        mid = (low + high) / 2
        if mean_lightness(small * 2.0 ** mid) < target_lightness:
            low = mid
        else:
            high = mid
    return (low + high) / 2


def auto_expose(image_bgr: np.ndarray, target_lightness: float) -> tuple[np.ndarray, float]:
    """``image_bgr`` (sRGB, 8-bit scale, any float or integer type) metered to
    ``target_lightness``: the image (float32, 0-255) and the gain applied (EV)."""
    ev = metered_ev(image_bgr, target_lightness)
    return linear_to_srgb(srgb_to_linear(image_bgr) * 2.0 ** ev), ev


def draw_target_lightness(rng: np.random.Generator) -> float:
    """A frame's metering target: the real photos' spread, kept within 3 sigma."""
    return float(np.clip(rng.normal(TARGET_LIGHTNESS_MEAN, TARGET_LIGHTNESS_SD),
                         TARGET_LIGHTNESS_MEAN - 3 * TARGET_LIGHTNESS_SD,
                         TARGET_LIGHTNESS_MEAN + 3 * TARGET_LIGHTNESS_SD))
