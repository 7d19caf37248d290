"""From a label mask to obstacle contour points: solid = not water, minus the own vessel.

**Own vessel.** The paper drops the blob the projected hull overlaps. When a moored
neighbour (or a quay) touches the hull, that blob is the vessel *and* the neighbour, and
dropping or keeping it whole both go wrong (every section reads zero, or the neighbour
vanishes). We instead remove only the vessel's own *region*: the vessel (mesh, or outline
plus air draft) projected into the image with the frame's pose, as the union of the convex
hulls of its layers (:attr:`VesselSpec.silhouette_layers`, :mod:`harborsight.vessel.layers`:
one hull over a tall deckhouse and a long low deck, or over a deckhouse aft and a mast
forward, would also cover water beside the deck in an oblique view),
grown by ``pose_margin_px`` for pose and mask error. Solid pixels outside that region are
obstacles whatever blob they belong to, so a touching neighbour is cut at the region's edge
and only the sections facing it read a small distance. Contour points on such a cut are
flagged ``contact``: the solid continues into the vessel's region there, so the true gap
is at most the reported distance.

**Own-vessel rim.** A learned segmenter draws the vessel a few pixels wider than it is,
mostly onto its own shadow; that sliver lies just outside the region and would read as an
obstacle touching the hull. With ``rim_px = r > 0``, *ship*-class pixels outside the region
that are within ``r`` px of it and do not survive a morphological opening of the ship-class
pixels outside the region with a disk of diameter ``2⌈r/2⌉ + 1`` (slivers at most ``r`` px
thick, for even r) are counted as the own vessel. A neighbour thicker than that keeps every
pixel, its edge at the hull included, so a touching ship still reads zero; obstacle-class
solids (quays, piles) are never touched.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

WATER, SHIP, OBSTACLE, IGNORE = 0, 1, 2, 255
LABEL_VALUES = (WATER, SHIP, OBSTACLE, IGNORE)

_SUBPIXEL_BITS = 4
#: OpenCV's morphology takes 16 columns of a row at a time and the rest one by one (a 9 x 9
#: disk dilates 335 columns in twice the time of 336): windows are widened to a multiple of
#: this where the image allows, and only the pixels wanted are kept (:func:`_simd_wide`)
_SIMD_COLUMNS = 16


_SQUARE_3X3 = np.ones((3, 3), np.uint8)


@dataclass(frozen=True)
class OwnRegion:
    """uint8 mask (255 = own vessel) and the slices of its bounding box (None if empty)."""

    mask: np.ndarray
    bbox: tuple[slice, slice] | None


def own_vessel_region(
    hull_px: np.ndarray | list[np.ndarray], shape: tuple[int, int], pose_margin_px: float
) -> OwnRegion:
    """The union of the convex hulls of projected vessel points (one set, or one per layer
    of the vessel: :attr:`VesselSpec.silhouette_layers`), grown by ``pose_margin_px``
    (elliptical dilation)."""
    region = np.zeros(shape, np.uint8)
    corners = []
    for layer_px in [hull_px] if isinstance(hull_px, np.ndarray) else hull_px:
        pts = layer_px[np.isfinite(layer_px).all(axis=1)]
        if len(pts) < 3:
            continue
        hull = cv2.convexHull(np.round(pts * (1 << _SUBPIXEL_BITS)).astype(np.int32))
        cv2.fillConvexPoly(region, hull, 255, lineType=cv2.LINE_8, shift=_SUBPIXEL_BITS)
        corners.append(hull.reshape(-1, 2))
    if not corners:
        return OwnRegion(region, None)
    radius = int(np.ceil(pose_margin_px))
    roi = _grown_bbox(np.vstack(corners) / (1 << _SUBPIXEL_BITS), radius + 1, shape)
    if radius > 0 and roi is not None:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        # the same as dilating region[roi] alone: the polygon lies inside roi, zeros around it
        wide = _simd_wide(roi, shape)
        region[roi] = cv2.dilate(region[wide], kernel)[_shifted(roi, wide)]
    return OwnRegion(region, roi)


def hidden_water_edge(layers_px: list[np.ndarray], waterline_px: np.ndarray,
                      shape: tuple[int, int], margin_px: float) -> np.ndarray:
    """Pixels ``(N, 2)`` on the edge of the water the vessel itself hides: its image (the
    layers' hulls, not grown) less its waterline outline grown by ``margin_px``. Seen
    obliquely a deckhouse hides the water beyond the deck on the far side, and at nadir a
    flared deck hides the water under its edge; an obstacle wholly there cannot be seen. The
    outer edge is the farthest such water from the hull (empty when none)."""
    region = own_vessel_region(layers_px, shape, 0.0)
    pts = waterline_px[np.isfinite(waterline_px).all(axis=1)]
    if region.bbox is None or len(pts) < 3:
        return np.zeros((0, 2))
    box = region.bbox
    offset = np.array([box[1].start, box[0].start])
    waterline = np.zeros((box[0].stop - box[0].start, box[1].stop - box[1].start), np.uint8)
    corners = cv2.convexHull(np.round((pts - offset) * (1 << _SUBPIXEL_BITS)).astype(np.int32))
    cv2.fillConvexPoly(waterline, corners, 255, lineType=cv2.LINE_8, shift=_SUBPIXEL_BITS)
    radius = int(np.ceil(margin_px))
    if radius > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        waterline = cv2.dilate(waterline, kernel)
    hidden = cv2.bitwise_and(region.mask[box], cv2.bitwise_not(waterline))
    edges, _ = cv2.findContours(hidden, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not edges:
        return np.zeros((0, 2))
    points = np.vstack([e.reshape(-1, 2) for e in edges])
    # the edge along the waterline is no reach: only the outer edge, every second pixel (the
    # image border is sampled so too)
    beside = cv2.dilate(waterline, _SQUARE_3X3)[points[:, 1], points[:, 0]] > 0
    return points[~beside][::2].astype(float) + offset


def _grown_slices(box: tuple[slice, slice], grow: int, shape: tuple[int, int]):
    """``box`` (row and column slices) grown by ``grow`` px, clipped to the image."""
    corners = np.array([[box[1].start, box[0].start], [box[1].stop - 1, box[0].stop - 1]])
    return _grown_bbox(corners, grow, shape)


def _grown_bbox(points: np.ndarray, grow: int, shape: tuple[int, int]):
    """Slices of the bounding box of ``points`` grown by ``grow`` px, clipped to the image."""
    x0, y0 = np.floor(points.min(axis=0)).astype(int) - grow
    x1, y1 = np.ceil(points.max(axis=0)).astype(int) + grow + 1
    h, w = shape
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if x0 >= x1 or y0 >= y1:
        return None
    return slice(y0, y1), slice(x0, x1)


@dataclass(frozen=True)
class ObstacleContours:
    """Contour pixels (u, v) of obstacles in contour order, with per-point flags.

    ``next_index[i]`` is the index of the point that follows i along its (closed) contour;
    ``contact`` marks points where the solid continues into the own-vessel region;
    ``on_border`` marks points on the image's outermost rows/columns, where the obstacle
    is cut by the frame and may reach closer out of view.
    """

    points_px: np.ndarray
    next_index: np.ndarray
    contact: np.ndarray
    on_border: np.ndarray

    @functools.cached_property
    def previous_index(self) -> np.ndarray:
        """``previous_index[i]``: the point before i along its contour."""
        previous = np.empty_like(self.next_index)
        previous[self.next_index] = np.arange(len(previous))
        return previous


def own_rim(labels: np.ndarray, own: OwnRegion, rim_px: int) -> np.ndarray:
    """uint8 mask (255) of the thin ship-class rim hugging the own region (see module doc).

    rim = S ∩ D_r(own) ∖ open(S, disk(2⌈r/2⌉ + 1)),  S = ship-class pixels outside ``own``,
    D_r = dilation by a disk of radius r. Only the region's box grown by 2r + 1 is searched.
    """
    rim = np.zeros(labels.shape, np.uint8)
    if rim_px <= 0 or own.bbox is None:
        return rim
    roi = _grown_slices(own.bbox, 2 * rim_px + 1, labels.shape)
    # 255 where ship-class and outside the region (OpenCV's compare: 255 where true)
    ship_outside = cv2.bitwise_and(cv2.compare(labels[roi], SHIP, cv2.CMP_EQ),
                                   cv2.compare(own.mask[roi], 0, cv2.CMP_EQ))
    # the rim's candidates, narrowed step by step to the box that holds them: the ship pixels
    # within r of the region's box; then within a (2r + 1) square of the region (a cheap
    # dilation that holds the disk's); outside the opening; within the disk's dilation. Each
    # step computes its mask over the last box grown by the mask's reach, which gives the box
    # the values it has over all of roi; no candidate left: no rim (a quay, a neighbour a few
    # metres off, a thick neighbour against the hull)
    diameter = 2 * int(np.ceil(rim_px / 2)) + 1
    opening = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (diameter, diameter))
    square = np.ones((2 * rim_px + 1, 2 * rim_px + 1), np.uint8)
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rim_px + 1, 2 * rim_px + 1))
    steps = ((own.mask[roi], rim_px, lambda window: cv2.dilate(window, square)),
             (ship_outside, 2 * (diameter // 2),
              lambda window: cv2.bitwise_not(cv2.morphologyEx(window, cv2.MORPH_OPEN, opening))),
             (own.mask[roi], rim_px, lambda window: cv2.dilate(window, disk)))
    box = _shifted(_grown_slices(own.bbox, rim_px, labels.shape), roi)
    candidates = ship_outside[box]
    for source, reach, mask_of in ((None, 0, None), *steps):
        if source is not None:
            window = _simd_wide(_grown_slices(box, reach, ship_outside.shape), ship_outside.shape)
            candidates = cv2.bitwise_and(candidates, mask_of(source[window])[_shifted(box, window)])
        x, y, w, h = cv2.boundingRect(candidates)
        if w == 0 or h == 0:
            return rim
        candidates = candidates[y:y + h, x:x + w]
        box = (slice(box[0].start + y, box[0].start + y + h),
               slice(box[1].start + x, box[1].start + x + w))
    rim[roi][box] = candidates
    return rim


def _simd_wide(box: tuple[slice, slice], shape: tuple[int, ...]) -> tuple[slice, slice]:
    """``box`` with its columns widened to a multiple of :data:`_SIMD_COLUMNS`, to the right
    and then to the left as far as ``shape`` allows (a morphology over more pixels gives the
    pixels it had the same values)."""
    extra = -(box[1].stop - box[1].start) % _SIMD_COLUMNS
    stop = min(box[1].stop + extra, shape[1])
    start = max(box[1].start - (extra - (stop - box[1].stop)), 0)
    return box[0], slice(start, stop)


def _shifted(box: tuple[slice, slice], within: tuple[slice, slice]) -> tuple[slice, slice]:
    """``box`` relative to the top-left corner of ``within`` (both row and column slices)."""
    return (slice(box[0].start - within[0].start, box[0].stop - within[0].start),
            slice(box[1].start - within[1].start, box[1].stop - within[1].start))


def obstacle_contours(labels: np.ndarray, own: OwnRegion, rim_px: int = 0) -> ObstacleContours:
    """Suzuki–Abe contours (``cv2.findContours``) of solid pixels outside ``own_region``.

    Solid is everything but water; ``ignore`` (255) counts as solid, the safe side. All
    contours are kept (``RETR_LIST``): the inner border of a basin that encloses the vessel
    is as much an obstacle as the outer border of a moored ship. The frame edge itself is
    never an obstacle: only solid pixels yield contour points, and those on the outermost
    rows/columns are flagged ``on_border``.
    """
    own_mask = own.mask
    if rim_px > 0:
        own_mask = cv2.bitwise_or(own_mask, own_rim(labels, own, rim_px))
    obstacle = cv2.subtract(labels, own_mask)  # saturating: 0 wherever the own mask is 255
    contours, _ = cv2.findContours(obstacle, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    if not contours:
        empty = np.zeros(0, bool)
        return ObstacleContours(np.zeros((0, 2), np.int32), np.zeros(0, int), empty, empty)
    lengths = np.array([len(c) for c in contours])
    points = np.concatenate(contours).reshape(-1, 2)
    next_index = np.arange(1, len(points) + 1)
    ends = np.cumsum(lengths)
    next_index[ends - 1] = ends - lengths  # close each contour
    h, w = labels.shape
    on_border = ((points[:, 0] == 0) | (points[:, 0] == w - 1)
                 | (points[:, 1] == 0) | (points[:, 1] == h - 1))
    # contact: the obstacle pixel touches solid pixels inside the own-vessel region (and rim)
    contact = np.zeros(len(points), bool)
    if own.bbox is not None:
        roi = _grown_slices(own.bbox, rim_px + 1, labels.shape)
        solid_inside = cv2.bitwise_and(labels[roi], own_mask[roi])
        touching = cv2.dilate(solid_inside, np.ones((3, 3), np.uint8))
        u, v = points[:, 0] - roi[1].start, points[:, 1] - roi[0].start
        near = (u >= 0) & (v >= 0) & (u < touching.shape[1]) & (v < touching.shape[0])
        contact[near] = touching[v[near], u[near]] > 0
    return ObstacleContours(points, next_index, contact, on_border)
