"""What the mask says beyond a measured edge, for the error bars of
:mod:`harborsight.clearance.uncertainty`: how far past a section's obstacle point the model
is first sure of a solid (the model's doubt, :func:`edge_doubt_m`), and how far a contact's
ship blob runs on past the reading before the first sure solid (the vessel's own blob drawn
wide, or its shadow read as ship: :func:`own_spill_m`). Both walk rays through the image a
pixel at a time, every ray at once."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from harborsight.geometry.camera import Camera
from harborsight.perception.classes import IGNORE, SHIP, WATER

if TYPE_CHECKING:
    from harborsight.perception.confidence import SolidConfidence

#: the solid probability at which the model counts as sure of an obstacle (calibrated on
#: the seed-7 bench's frames 0-259, validated on 260-519: docs/results.md)
CONFIDENT_SOLID_P = 0.9
#: a ship run that ends this close outside the vessel's predicted shadow (pixels) may still
#: be that shadow: the model's edges and the pixel grid blur it by a pixel or two
SHADOW_TOLERANCE_PX = 3.0
#: step (px) of the look along the ray beyond the obstacle point, and the stretches (in
#: steps) it is read in; 0: to the image's edge
_RAY_STEP_PX = 1.0
_RAY_STRETCHES_PX = (8, 56, 0)


def _samples_to_edge(start: np.ndarray, unit: np.ndarray, width: int, height: int) -> np.ndarray:
    """How many :data:`_RAY_STEP_PX` samples each ray ``start + s·unit`` (``s ≥ 0``) has inside
    a ``width`` x ``height`` image (pixel centres 0 .. W-1, 0 .. H-1); at least 1."""
    with np.errstate(divide="ignore", invalid="ignore"):
        # per axis, the ray's length to the far edge it heads for (inf along the edge)
        to_edge = np.where(unit == 0, np.inf, np.where(
            unit > 0, np.array([width - 1, height - 1]) - start, start) / np.abs(unit))
    reach = np.fmin(to_edge[:, 0], to_edge[:, 1])
    return (np.clip(np.where(np.isfinite(reach), reach, 0.0), 0.0, None) // _RAY_STEP_PX).astype(int) + 1


def edge_doubt_m(hull_px: np.ndarray, obstacle_px: np.ndarray, hull_enu: np.ndarray,
                 distance_m: np.ndarray, camera: Camera, confidence: SolidConfidence) -> np.ndarray:
    """``s_c - d`` of each section (:mod:`~harborsight.clearance.uncertainty`'s docstring):
    how far beyond the measured edge, in metres on the water, the model is first sure of a
    solid along the ray from the hull point ``hull_px`` through the obstacle point
    ``obstacle_px``; 0 in contact (no ray).

    The rays are read in growing stretches (:data:`_RAY_STRETCHES_PX`): most are sure within
    a few pixels of the edge, and only the others are read on."""
    toward = obstacle_px - hull_px
    length = np.hypot(*toward.T)
    doubt = np.zeros(len(hull_px))
    rays = np.flatnonzero(np.isfinite(length) & (length >= _RAY_STEP_PX))
    if len(rays) == 0:
        return doubt
    unit = toward[rays] / length[rays, None]
    start = obstacle_px[rays]
    steps = _samples_to_edge(start, unit, camera.intrinsics.width, camera.intrinsics.height)
    first = steps - 1                       # the ray's last sample, unless a sure one is found
    open_rays = np.arange(len(rays))
    begin = 0
    for stretch in _RAY_STRETCHES_PX:
        open_rays = open_rays[steps[open_rays] > begin]
        if len(open_rays) == 0:
            break
        end = begin + stretch if stretch else int(steps[open_rays].max())
        along = np.arange(begin, end) * _RAY_STEP_PX
        inside = np.arange(begin, end)[None, :] < steps[open_rays, None]
        samples = start[open_rays, None, :] + along[None, :, None] * unit[open_rays, None, :]
        sure = np.zeros(inside.shape, bool)
        sure[inside] = confidence.solid_probability(samples[inside]) >= CONFIDENT_SOLID_P
        hit = sure.any(axis=1)
        first[open_rays[hit]] = begin + sure[hit].argmax(axis=1)
        open_rays = open_rays[~hit]
        begin = end
    far_px = start + (first * _RAY_STEP_PX)[:, None] * unit
    far_enu, valid = camera.back_project_to_plane(far_px)
    far_m = np.hypot(*(far_enu[:, :2] - hull_enu[rays]).T)
    doubt[rays] = np.where(valid, np.maximum(far_m - distance_m[rays], 0.0), 0.0)
    return doubt


def _first_per_walk(hits: np.ndarray, walk_of: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Per walk, the first of the sorted sample indices ``hits`` in it, else the walk's end
    (``ends``: one past each walk's last sample)."""
    first = ends.copy()
    if len(hits):
        lead = hits[np.r_[True, walk_of[hits][1:] != walk_of[hits][:-1]]]
        first[walk_of[lead]] = lead
    return first


def own_spill_m(hull_px: np.ndarray, obstacle_px: np.ndarray, hull_enu: np.ndarray,
                distance_m: np.ndarray, antenna_px: np.ndarray, camera: Camera,
                labels: np.ndarray, confidence: SolidConfidence | None = None,
                shadow_px: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``s_c - d`` of each contact reading against a ship
    (:mod:`~harborsight.clearance.uncertainty`'s docstring): walking from
    the hull point ``hull_px`` away from the antenna's pixel, through the first run of ship
    pixels it meets (the ship the reading touches), how far on the water the first pixel
    sure to be solid beyond that run lies beyond the reading; 0 for a reading whose
    obstacle pixel is not ship. With ``shadow_px``, the pixels of the vessel's shadow on
    the water and of its footprint (two convex polygons, the first containing the second),
    only runs that end inside the shadow, within :data:`SHADOW_TOLERANCE_PX`, and outside
    the footprint by more than that count: the blob may be that shadow (a run that ends at
    the hull's own edge is the vessel drawn a little wide, and a walk that meets no ship
    run is not explained by it). One pixel steps, every walk at once."""
    spill = np.zeros(len(hull_px))
    height, width = labels.shape
    at = np.rint(obstacle_px).astype(int) if len(obstacle_px) else np.zeros((0, 2), int)
    inside = ((at >= 0) & (at < [width, height])).all(axis=1) & np.isfinite(hull_px).all(axis=1)
    ship = np.zeros(len(hull_px), bool)
    ship[inside] = labels[at[inside, 1], at[inside, 0]] == SHIP
    outward = hull_px - antenna_px
    length = np.hypot(*outward.T) if len(outward) else np.zeros(0)
    todo = np.flatnonzero(ship & np.isfinite(length) & (length > 0))
    if len(todo) == 0:
        return spill
    # every walk at once: walk j of section todo[j] has steps[j] samples, to the image's edge
    unit = outward[todo] / length[todo, None]
    start = hull_px[todo]
    steps = _samples_to_edge(start, unit, width, height)
    ends = np.cumsum(steps)
    walk_of = np.repeat(np.arange(len(todo)), steps)
    along = (np.arange(ends[-1]) - np.repeat(ends - steps, steps)) * _RAY_STEP_PX
    walk = start[walk_of] + along[:, None] * unit[walk_of]
    pixel = np.clip(np.rint(walk).astype(int), 0, [width - 1, height - 1])
    label = labels[pixel[:, 1], pixel[:, 0]]
    ship = label == SHIP
    # the ship the reading touches: each walk's first run of ship samples
    run_start = _first_per_walk(np.flatnonzero(ship), walk_of, ends)
    after = np.arange(ends[-1]) >= run_start[walk_of]
    run_end = _first_per_walk(np.flatnonzero(after & ~ship), walk_of, ends)
    in_run = after & (np.arange(ends[-1]) < run_end[walk_of])
    if confidence is not None:
        solid = confidence.solid_probability(walk) >= CONFIDENT_SOLID_P
    else:
        solid = (label != WATER) & (label != IGNORE)
    # the first sure sample outside that run, else the walk's last
    first = np.minimum(_first_per_walk(np.flatnonzero(solid & ~in_run), walk_of, ends), ends - 1)
    far_enu, valid = camera.back_project_to_plane(walk[first])
    far_m = np.hypot(*(far_enu[:, :2] - hull_enu[todo]).T)
    spill[todo] = np.where(valid, np.maximum(far_m - distance_m[todo], 0.0), 0.0)
    if shadow_px is not None:
        has_run = run_start < ends
        last = walk[np.where(has_run, run_end - 1, ends - 1)]      # each run's last ship sample
        shadow, footprint = (np.asarray(p, np.float32).reshape(-1, 1, 2) for p in shadow_px)
        in_shadow = np.array([
            cv2.pointPolygonTest(shadow, point, True) >= -SHADOW_TOLERANCE_PX
            and cv2.pointPolygonTest(footprint, point, True) < -SHADOW_TOLERANCE_PX
            for point in map(tuple, last.astype(float))], bool) & has_run
        spill[todo[~in_shadow]] = 0.0
    return spill
