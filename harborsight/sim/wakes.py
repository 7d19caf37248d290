"""Wakes behind boats under way: white water painted on the rendered water, labels untouched.

A boat under way leaves three kinds of white water on the surface (seen from above):

* the **turbulent wake** astern, as wide as the beam at the stern and widening slowly, its
  foam fading over several boat lengths: intensity
  ``exp(-a / (k_c L)) · exp(-2 (c / (w(a)/2))²)``, ``w(a) = B (1 + a / (2 L))``, with ``a``
  metres astern of the stern along the track, ``c`` across it, ``L`` the length and ``B``
  the beam;
* the two arms of the **Kelvin wedge** from the bow, at ``±19.47°`` to the track (the angle of
  a deep-water ship wave pattern, ``asin(1/3)``, whatever the speed): intensity
  ``exp(-a_b / (k_k L)) · exp(-((|c| - a_b tan 19.47°) / w_k)²)``, ``a_b`` metres astern of
  the bow, ``w_k = 0.25 + 0.02 a_b`` m;
* a short **bow wave** along both sides of the hull's forward half.

A wake ends where the boat's track astern (a corridor as wide as its beam) first meets
another object: it did not come through a pier or the shore.

The faster the boat, the longer its wake (``k_c``, ``k_k`` grow with the speed drawn). The
foam is broken by a noise field fixed on the water (a sum of random plane waves), so it stays
put as the camera moves: ``foam = I · clip(noise + 0.6 I, 0, 1)``, solid where the wake is
strong and patchy where it fades. It is painted only on pixels whose instance id is water, after the
render and before the camera effects: white water is water (class 0), and what stands on
the water hides its foam as it hid the water. Its brightness follows the water's own shading
(foam in a shadow is grey): ``out = pixel (1 - α) + foam_rgb · shade · α``, ``shade`` the
local water brightness over the frame's median water brightness, clipped to 0.35-1.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from shapely.geometry import LineString, Point

from harborsight.sim.scene import HarbourScene, SceneObject

#: half-angle of the Kelvin wedge: asin(1/3)
KELVIN_DEG = math.degrees(math.asin(1.0 / 3.0))
_WATER_ID = 0
_FOAM_BGR = np.array([232.0, 236.0, 238.0])
#: the white water is computed on every n-th pixel and resized (its finest detail, a Kelvin
#: arm 0.25 m wide, is 1-8 px across at 30-150 m)
_GRID_PX = 2


def _hull_extent(obj: SceneObject, course_deg: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The boat's stern and bow points on the water (e, n) along ``course_deg`` through its
    centre, its length and beam (m), from its vertices."""
    vertices = np.vstack([np.asarray(part.mesh.vertices)[:, :2] for part in obj.parts])
    bearing = math.radians(course_deg)
    ahead = np.array([math.sin(bearing), math.cos(bearing)])
    across = np.array([ahead[1], -ahead[0]])
    along, side = vertices @ ahead, vertices @ across
    centre_side = 0.5 * (side.min() + side.max())
    stern = along.min() * ahead + centre_side * across
    bow = along.max() * ahead + centre_side * across
    return stern, bow, float(np.ptp(along)), float(np.ptp(side))


def _foam_noise(xy: np.ndarray, rng: np.random.Generator, n_waves: int = 12) -> np.ndarray:
    """A broken-foam field in [0, 1] on the water: ``0.5 + Σ cos(k_i · x + φ_i) / (2 sqrt n)``
    with wavelengths 0.8-6 m in random directions, sharpened."""
    field = np.zeros(len(xy))
    for _ in range(n_waves):
        wavelength = rng.uniform(0.8, 6.0)
        angle = rng.uniform(0.0, 2 * math.pi)
        k = 2 * math.pi / wavelength * np.array([math.cos(angle), math.sin(angle)])
        field += np.cos(xy @ k + rng.uniform(0.0, 2 * math.pi))
    field = 0.5 + field / (2.0 * math.sqrt(n_waves))
    return np.clip((field - 0.35) / 0.4, 0.0, 1.0)


def clear_track_m(stern: np.ndarray, bow: np.ndarray, beam_m: float, others: list,
                  reach_m: float = 2_000.0) -> float:
    """How far astern of the stern the boat's track (a corridor as wide as its beam) runs
    before it meets another object's footprint: the boat cannot have come through it."""
    ahead = (bow - stern) / max(np.linalg.norm(bow - stern), 1e-9)
    corridor = LineString([tuple(stern - 0.01 * ahead), tuple(stern - reach_m * ahead)]).buffer(
        beam_m / 2, cap_style="flat")
    hits = [f for f in others if f.intersects(corridor)]
    if not hits:
        return reach_m
    return float(min(Point(*stern).distance(f.intersection(corridor)) for f in hits))


def wake_intensity(xy: np.ndarray, stern: np.ndarray, bow: np.ndarray, length_m: float,
                   beam_m: float, speed_mps: float, clear_m: float = np.inf) -> np.ndarray:
    """White-water intensity in [0, 1] at water points ``xy (N, 2)`` (module docstring);
    none farther astern than ``clear_m`` (:func:`clear_track_m`)."""
    ahead = (bow - stern) / max(np.linalg.norm(bow - stern), 1e-9)
    across = np.array([ahead[1], -ahead[0]])
    length_m, beam_m = max(length_m, 1.0), max(beam_m, 0.5)
    speed_factor = float(np.clip(speed_mps / 5.0, 0.3, 2.0))
    rel = xy - stern
    a = -(rel @ ahead)                               # metres astern of the stern
    c = rel @ across
    astern = a > 0
    width = beam_m * (1.0 + np.maximum(a, 0.0) / (2.0 * length_m))
    turbulent = np.where(astern, np.exp(-np.maximum(a, 0.0) / (3.0 * length_m * speed_factor))
                         * np.exp(-2.0 * (c / (width / 2)) ** 2), 0.0)
    a_bow = a + length_m                             # metres astern of the bow
    arm_width = 0.25 + 0.02 * np.maximum(a_bow, 0.0)
    kelvin = np.where(a_bow > 0, np.exp(-np.maximum(a_bow, 0.0) / (5.0 * length_m * speed_factor))
                      * np.exp(-((np.abs(c) - a_bow * math.tan(math.radians(KELVIN_DEG)))
                                 / arm_width) ** 2), 0.0)
    along_hull = (a_bow > 0) & (a_bow < 0.5 * length_m)
    bow_wave = np.where(along_hull, np.exp(-((np.abs(c) - beam_m / 2) / 0.3) ** 2), 0.0)
    intensity = np.maximum.reduce([0.9 * turbulent, 0.6 * kelvin, 0.7 * bow_wave])
    return np.clip(np.where(a <= clear_m, intensity, 0.0), 0.0, 1.0)


def paint_wakes(image_bgr: np.ndarray, instances: np.ndarray, scene: HarbourScene,
                rng: np.random.Generator) -> np.ndarray:
    """The rendered image with the wakes of the scene's boats under way (objects with a
    ``course_deg``) painted on its water pixels; unchanged when there are none.

    The white water is computed on a grid of every :data:`_GRID_PX`-th pixel (the centres of
    the blocks, so that a bilinear resize puts it back exactly) and painted at full size."""
    boats = [o for o in scene.objects if o.course_deg is not None]
    water = instances == _WATER_ID
    if not boats or not water.any():
        return image_bgr
    h, w = instances.shape
    grid_v, grid_u = np.mgrid[0:h:_GRID_PX, 0:w:_GRID_PX].astype(float) + (_GRID_PX - 1) / 2
    ground, valid = scene.geometry().camera.back_project_to_plane(
        np.column_stack((grid_u.ravel(), grid_v.ravel())))
    xy = ground[valid, :2]
    foam_valid = np.zeros(len(xy))
    for boat in boats:
        stern, bow, length_m, beam_m = _hull_extent(boat, boat.course_deg)
        speed_mps = float(rng.uniform(2.0, 10.0))
        others = [o.footprint() for o in scene.objects if o is not boat]
        clear_m = clear_track_m(stern, bow, beam_m, others)
        foam_valid = np.maximum(foam_valid, wake_intensity(xy, stern, bow, length_m, beam_m,
                                                           speed_mps, clear_m))
    # dense white water where the wake is strong, broken where it fades
    foam_valid *= np.clip(_foam_noise(xy, rng) + 0.6 * foam_valid, 0.0, 1.0)
    if not (foam_valid > 1e-3).any():
        return image_bgr
    foam_grid = np.zeros(valid.shape, np.float32)
    foam_grid[valid] = foam_valid
    foam = cv2.resize(foam_grid.reshape(grid_u.shape), (w, h), interpolation=cv2.INTER_LINEAR)
    v, u = np.nonzero(water & (foam > 1e-3))
    image = image_bgr.astype(np.float32)
    luminance = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY).astype(np.float32)
    water_luminance = np.where(water, luminance, 0.0).astype(np.float32)
    weight = cv2.GaussianBlur(water.astype(np.float32), (0, 0), 3.0)
    local = cv2.GaussianBlur(water_luminance, (0, 0), 3.0) / np.maximum(weight, 1e-6)
    shade = np.clip(local[v, u] / max(float(np.median(luminance[water])), 1.0), 0.35, 1.0)
    alpha = (0.85 * foam[v, u])[:, None]
    image[v, u] = image[v, u] * (1.0 - alpha) + _FOAM_BGR * shade[:, None] * alpha
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)
