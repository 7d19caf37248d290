"""Where an obstacle's edge lies near its nearest contour pixel: the pixel-boundary correction.

A label mask says, per pixel, what its centre (or most of its square) shows; the obstacle's
true edge lies somewhere between its outermost solid pixel centres and the first water ones.
The distance to the nearest contour pixel centre ``c`` along the unit ray ``u`` from ``c``
toward the hull is therefore too long by the depth of ``c`` inside the edge, and the
correction moves ``c`` by that depth toward the hull.

*The square rule* (the conservative bound): the solid pixel covers its whole square, so the
edge is where the ray leaves the square, ``0.5 / max(|u_x|, |u_y|)`` px out (0.5 to 0.71).
Right for an edge along a pixel row or column (whose boundary pixels all lie at one depth,
uniform in [0, 1), mean 0.5), it is half a pixel short on a slanted straight edge: the
boundary pixels of a digital half-plane with unit normal ``n`` lie at depths spread over
``[0, m)``, ``m = max(|n_x|, |n_y|)``, and the nearest of many is the least deep, about 0.

*The line rule* (used where the edge is straight): fit a line to the contour pixels
``EDGE_FIT_HALF_POINTS`` either side of ``c`` (centroid ``q̄``, normal ``n`` the covariance's
minor eigenvector, turned toward the hull). Their depths average ``m / 2``, so ``c``'s depth
is estimated as

    δ = clip(m / 2 - n·(c - q̄), 0, m)

and ``c`` moves by ``δ / (n·u)`` along the ray, never farther than the square rule allows
(the solid pixel's own square is solid). Where the fit is not a straight edge (a pixel of
the window farther than ``EDGE_FIT_MAX_RESIDUAL_PX`` from the line: a corner, a tip), where
the ray grazes the line (a ray along a one-pixel spar)
(``n·u`` under ``EDGE_FIT_MIN_COSINE``), where the window reaches the image border or the
contour is shorter than the window, the square rule stays.

Measured on half-planes rasterised at pixel centres, at random angles and offsets, the
nearest point 8-60 px away (``docs/geometry.md``, "Pixel-boundary correction"): the square
rule reads -0.31 to -0.41 px on average (MAE 0.33-0.42 px), the line rule +0.03 to +0.06 px
(MAE 0.07-0.10 px, the largest 0.45-0.87 px of 600); on a 90-degree corner pointing at the
hull both read +0.15 px. On gently convex outlines the line rule reads long, the unsafe
side, because the nearest pixel stands out of the line through its neighbours: on average
+0.09 px at a 160-degree corner and +0.22 px at a 170-degree one, +0.06 and +0.13 px on discs
of 20 and 40 px radius. The square rule reads -0.21 to -0.32 px there.
"""

from __future__ import annotations

import numpy as np

from harborsight.clearance.obstacles import ObstacleContours

#: contour pixels either side of the nearest one that the local edge line is fitted to
EDGE_FIT_HALF_POINTS = 4
#: the farthest of those pixels from their line, above which the edge is not straight there
#: (a digital straight edge's boundary pixels lie within a band of width m <= 1 px, so
#: within about half a pixel of its least-squares line; a corner in the window bends it)
EDGE_FIT_MAX_RESIDUAL_PX = 0.6
#: the ray toward the hull must leave the line at least this steeply (cosine with its normal)
EDGE_FIT_MIN_COSINE = 0.25
_HALF_PIXEL = 0.5


def square_exit_px(unit: np.ndarray) -> np.ndarray:
    """The square rule: how far rays ``unit (N, 2)`` from pixel centres leave their square."""
    return _HALF_PIXEL / np.maximum(np.abs(unit).max(axis=1), _HALF_PIXEL * 2 ** 0.5)


def _windows(contours: ObstacleContours, index: np.ndarray) -> np.ndarray:
    """``(N, 2k + 1)`` contour indices: each of ``index``, then the ``k``
    (:data:`EDGE_FIT_HALF_POINTS`) before and after it, alternately."""
    columns = [index]
    before = after = index
    for _ in range(EDGE_FIT_HALF_POINTS):
        before, after = contours.previous_index[before], contours.next_index[after]
        columns += [before, after]
    return np.stack(columns, axis=1)


def edge_shift_px(contours: ObstacleContours, index: np.ndarray, unit: np.ndarray) -> np.ndarray:
    """How far to move each chosen contour pixel ``contours.points_px[index]`` along its ray
    ``unit (N, 2)`` toward the hull to reach the obstacle's edge (module docstring). An
    ``index`` of -1 (a point that is not a contour pixel) gets the square rule.

    The fitted line's normal is the minor axis of the window's 2x2 scatter matrix
    ``[[a, b], [b, c]]``: the major axis is at ``θ = atan2(2b, a - c) / 2``, the normal at
    ``θ + 90°``."""
    unit = np.asarray(unit, float).reshape(-1, 2)
    index = np.asarray(index, int).reshape(-1)
    shift = square_exit_px(unit)
    chosen = np.flatnonzero(index >= 0)
    if not len(chosen):
        return shift
    window = _windows(contours, index[chosen])
    ordered = np.sort(window, axis=1)
    fits = ((np.diff(ordered, axis=1) != 0).all(axis=1)         # the window is not a whole contour
            & ~contours.on_border[window].any(axis=1))
    points = contours.points_px[window].astype(float)            # (M, 2k + 1, 2)
    centroid = points.mean(axis=1, keepdims=True)
    spread = points - centroid
    a = (spread[..., 0] ** 2).mean(axis=1)
    b = (spread[..., 0] * spread[..., 1]).mean(axis=1)
    c = (spread[..., 1] ** 2).mean(axis=1)
    theta = 0.5 * np.arctan2(2.0 * b, a - c)
    normal = np.stack([-np.sin(theta), np.cos(theta)], axis=1)
    fits &= np.abs(np.einsum("mkd,md->mk", spread, normal)).max(axis=1) <= EDGE_FIT_MAX_RESIDUAL_PX
    cosine = np.einsum("md,md->m", normal, unit[chosen])
    normal *= np.where(cosine < 0, -1.0, 1.0)[:, None]           # toward the hull
    cosine = np.abs(cosine)
    fits &= cosine >= EDGE_FIT_MIN_COSINE
    step = np.abs(normal).max(axis=1)
    offset = np.einsum("md,md->m", normal, points[:, 0] - centroid[:, 0])
    depth = np.clip(step / 2 - offset, 0.0, step)
    line = np.minimum(depth / np.maximum(cosine, EDGE_FIT_MIN_COSINE), shift[chosen])
    shift[chosen[fits]] = line[fits]
    return shift
