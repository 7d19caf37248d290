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
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

WATER, SHIP, OBSTACLE, IGNORE = 0, 1, 2, 255
LABEL_VALUES = (WATER, SHIP, OBSTACLE, IGNORE)

_SUBPIXEL_BITS = 4


def own_vessel_region(
    hull_px: np.ndarray, shape: tuple[int, int], pose_margin_px: float
) -> np.ndarray:
    """uint8 mask (1 = own vessel) of the convex hull of projected vessel points."""
    region = np.zeros(shape, np.uint8)
    pts = hull_px[np.isfinite(hull_px).all(axis=1)]
    if len(pts) < 3:
        return region
    hull = cv2.convexHull(np.round(pts * (1 << _SUBPIXEL_BITS)).astype(np.int32))
    cv2.fillConvexPoly(region, hull, 1, lineType=cv2.LINE_8, shift=_SUBPIXEL_BITS)
    radius = int(np.ceil(pose_margin_px))
    if radius > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        region = cv2.dilate(region, kernel)
    return region


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


def obstacle_contours(labels: np.ndarray, own_region: np.ndarray) -> ObstacleContours:
    """Suzuki–Abe contours (``cv2.findContours``) of solid pixels outside ``own_region``.

    Solid is everything but water; ``ignore`` (255) counts as solid, the safe side. All
    contours are kept (``RETR_LIST``): the inner border of a basin that encloses the vessel
    is as much an obstacle as the outer border of a moored ship. The frame edge itself is
    never an obstacle: only solid pixels yield contour points, and those on the outermost
    rows/columns are flagged ``on_border``.
    """
    solid = labels != WATER
    obstacle = (solid & (own_region == 0)).astype(np.uint8)
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
    # contact: the obstacle pixel touches solid pixels inside the own-vessel region
    solid_inside = (solid & (own_region > 0)).astype(np.uint8)
    touching = cv2.dilate(solid_inside, np.ones((3, 3), np.uint8))
    contact = touching[points[:, 1], points[:, 0]] > 0
    return ObstacleContours(points, next_index, contact, on_border)
