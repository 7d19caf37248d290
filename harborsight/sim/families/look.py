"""How the families' frames look (:func:`sample_realistic_environment`): real harbours'
water and a consumer drone's camera."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from harborsight.sim.families._parts import _pick
from harborsight.sim.layout import _jitter, sample_environment
from harborsight.sim.scene import Environment

# water from clear blue over green to brown lake water (linear RGB, as the classic palette)
_REAL_WATER_RGB = [(0.01, 0.035, 0.07), (0.02, 0.06, 0.08), (0.03, 0.07, 0.04), (0.04, 0.06, 0.03),
                   (0.06, 0.05, 0.025), (0.045, 0.045, 0.03), (0.02, 0.04, 0.035),
                   (0.05, 0.07, 0.06)]
# turbid lake and river water, tan to olive (the lake-shore photos' water is about sRGB
# (150, 125, 90): linear (0.30, 0.20, 0.10)); drawn for most lake shores
_TURBID_WATER_RGB = [(0.26, 0.18, 0.09), (0.2, 0.16, 0.08), (0.16, 0.15, 0.08), (0.12, 0.12, 0.07),
                     (0.22, 0.2, 0.12), (0.09, 0.1, 0.06)]


def sample_realistic_environment(rng: np.random.Generator, family: str) -> Environment:
    """The classic draw (sun, sky, waves, haze) with real harbours' water and a consumer
    drone's camera: water from clear blue to brown (turbid tan or olive on 70 % of lake
    shores), calmer and with fewer whitecaps; vignetting, white balance off by a few percent,
    JPEG at quality 60-95, motion blur in a third of frames."""
    env = sample_environment(rng)
    return replace(
        env,
        water_rgb=_jitter(_pick(_TURBID_WATER_RGB if family == "lakeshore" and rng.random() < 0.7
                                else _REAL_WATER_RGB, rng), rng, 0.3),
        wave_scale=float(rng.uniform(0.02, 0.35)),
        foam_coverage=float(rng.uniform(0.0, 0.15)),       # sheltered water: few whitecaps
        vignetting=float(rng.uniform(0.0, 0.35)),
        white_balance=tuple(float(v) for v in rng.uniform(0.9, 1.1, 3)),
        jpeg_quality=int(rng.integers(60, 96)),
        motion_blur_px=float(rng.uniform(0.5, 2.5)) if rng.random() < 0.33 else 0.0,
        motion_blur_deg=float(rng.uniform(0.0, 180.0)),
    )
