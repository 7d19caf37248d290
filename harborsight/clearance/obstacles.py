"""From a label mask to obstacle contour points: solid = not water, minus the own vessel.

**Own vessel.** The paper drops the blob the projected hull overlaps. When a moored
neighbour (or a quay) touches the hull, that blob is the vessel *and* the neighbour, and
dropping or keeping it whole both go wrong (every section reads zero, or the neighbour
vanishes). We instead remove only the vessel's own *region*: the convex hull of the whole
vessel (mesh, or outline plus air draft) projected into the image with the frame's pose,
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

from dataclasses import dataclass

import cv2
import numpy as np

WATER, SHIP, OBSTACLE, IGNORE = 0, 1, 2, 255
LABEL_VALUES = (WATER, SHIP, OBSTACLE, IGNORE)

_SUBPIXEL_BITS = 4


@dataclass(frozen=True)
class OwnRegion:
    """uint8 mask (255 = own vessel) and the slices of its bounding box (None if empty)."""

    mask: np.ndarray
    bbox: tuple[slice, slice] | None


def own_vessel_region(
    hull_px: np.ndarray, shape: tuple[int, int], pose_margin_px: float
) -> OwnRegion:
    """The convex hull of projected vessel points, grown by ``pose_margin_px`` (elliptical
    dilation)."""
    region = np.zeros(shape, np.uint8)
    pts = hull_px[np.isfinite(hull_px).all(axis=1)]
    if len(pts) < 3:
        return OwnRegion(region, None)
    hull = cv2.convexHull(np.round(pts * (1 << _SUBPIXEL_BITS)).astype(np.int32))
    cv2.fillConvexPoly(region, hull, 255, lineType=cv2.LINE_8, shift=_SUBPIXEL_BITS)
    radius = int(np.ceil(pose_margin_px))
    roi = _grown_bbox(hull.reshape(-1, 2) / (1 << _SUBPIXEL_BITS), radius + 1, shape)
    if radius > 0 and roi is not None:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        region[roi] = cv2.dilate(region[roi], kernel)
    return OwnRegion(region, roi)


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


def own_rim(labels: np.ndarray, own: OwnRegion, rim_px: int) -> np.ndarray:
    """uint8 mask (255) of the thin ship-class rim hugging the own region (see module doc).

    rim = S ∩ D_r(own) ∖ open(S, disk(2⌈r/2⌉ + 1)),  S = ship-class pixels outside ``own``,
    D_r = dilation by a disk of radius r. Only the region's box grown by 2r + 1 is searched.
    """
    rim = np.zeros(labels.shape, np.uint8)
    if rim_px <= 0 or own.bbox is None:
        return rim
    roi = _grown_slices(own.bbox, 2 * rim_px + 1, labels.shape)
    ship_outside = np.where((labels[roi] == SHIP) & (own.mask[roi] == 0), 255, 0).astype(np.uint8)
    diameter = 2 * int(np.ceil(rim_px / 2)) + 1
    opening = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (diameter, diameter))
    thick = cv2.morphologyEx(ship_outside, cv2.MORPH_OPEN, opening)
    reach = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rim_px + 1, 2 * rim_px + 1))
    near_own = cv2.dilate(own.mask[roi], reach)
    rim[roi] = ship_outside & near_own & cv2.bitwise_not(thick)
    return rim


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
