"""The machinery of aligning a vessel's projected outline to the mask's ship pixels.

Shared by the pose refinement (:mod:`harborsight.clearance.pose_refinement`, a correction
within the sensors' prior) and the whole-image search (:mod:`harborsight.clearance.pose_search`,
the image's own placement of the hull, to tell a gross sensor error): the signed distance to
the ship pixels' boundary, the outline's samples, the projection of a pose correction
``p = (de, dn, dpsi, dh)`` with its Jacobian, robust Gauss-Newton and the measures of fit.
"""

from __future__ import annotations

import copy
import math
from dataclasses import replace

import cv2
import numpy as np

from harborsight.frame import FrameGeometry
from harborsight.perception.classes import SHIP

#: an outline point within this many pixels of a ship boundary is an inlier
INLIER_PX = 2.0
#: an outline point deeper than this inside ship pixels neither confirms nor denies a pose
#: (the vessel touches a neighbour there, or its own deck hides the edge)
DEEP_PX = 4.0
#: at least this many outline points must be in view to align
MIN_EDGE_POINTS = 24
#: spacing of the outline samples, pixels
SAMPLE_STEP_PX = 4.0
#: outline points nearer the image border than this are left out
BORDER_PX = 1.5
#: robust loss schedules (loss, scale px, iterations), each run from the sensors' pose; the
#: one with the lowest final cost wins. Huber has the wide basin a 2 m start needs but is
#: pulled by a touching neighbour; Tukey from a wide scale down is not, but needs a closer
#: start. Both end with Tukey at 3 px, which counts inliers.
SCHEDULES = (
    (("huber", 6.0, 10), ("tukey", 6.0, 3), ("tukey", 3.0, 5)),
    (("tukey", 16.0, 6), ("tukey", 8.0, 4), ("tukey", 3.0, 5)),
)
FINAL_TUKEY_PX = 3.0


def corrected_geometry(geometry: FrameGeometry, params: np.ndarray) -> FrameGeometry:
    """The frame's geometry with the vessel moved by ``(de, dn)`` m and turned by ``dpsi``
    rad, and (a fourth parameter) the camera raised by ``dh`` m."""
    moved = replace(geometry, vessel_position_enu=geometry.vessel_position_enu + params[:2],
                    vessel_heading_rad=geometry.vessel_heading_rad + float(params[2]))
    if len(params) > 3 and params[3] != 0.0:
        camera = geometry.camera
        moved = replace(moved, camera=replace(
            camera, position_enu=camera.position_enu + np.array([0.0, 0.0, float(params[3])])))
    return moved


class SignedDistance:
    """Signed distance (px) to the boundary of the ship pixels in a window of the mask,
    positive outside them; the boundary lies on pixel edges, so neighbours across it read
    +0.5 and -0.5. One distance transform (5x5 mask, within 2 % of Euclidean) from the
    pixels on either side of the boundary, signed by the mask, computed once per frame and
    kept in the transform's float32 (samples are read as float64). Sampled bilinearly with
    its gradient, at positions ``(x, y) = (u - u0, v - v0)`` relative to the window."""

    def __init__(self, ship: np.ndarray, top_left: tuple[int, int]) -> None:
        inside = ship.view(np.uint8)
        kernel = np.ones((3, 3), np.uint8)
        # 255 where the 3x3 neighbourhood is all ship or all not: away from the boundary
        off_edge = cv2.compare(cv2.dilate(inside, kernel), cv2.erode(inside, kernel), cv2.CMP_EQ)
        field = cv2.distanceTransform(off_edge, cv2.DIST_L2, cv2.DIST_MASK_5)
        field += np.float32(0.5)
        np.negative(field, out=field, where=ship)
        self.field = field
        self.u0, self.v0 = int(top_left[0]), int(top_left[1])
        self._flat = field.ravel()
        self._strides = np.array([1.0, field.shape[1]])
        #: flat offsets of a pixel and its right, lower and lower-right neighbours
        self._neighbours = np.array([[0], [1], [field.shape[1]], [field.shape[1] + 1]])

    def bounds(self, width: int, height: int) -> tuple[float, float, float, float]:
        """``(x_lo, x_hi, y_lo, y_hi)``, inclusive, relative to the window: the positions in
        view (at least :data:`BORDER_PX` inside the ``width`` x ``height`` image) whose four
        bilinear neighbours are in the window, ``0 <= x < w - 1`` (``x < a`` is
        ``x <= nextafter(a, -inf)``)."""
        h, w = self.field.shape
        return (max(0.0, BORDER_PX - self.u0),
                min(math.nextafter(w - 1, -math.inf), width - 1 - BORDER_PX - self.u0),
                max(0.0, BORDER_PX - self.v0),
                min(math.nextafter(h - 1, -math.inf), height - 1 - BORDER_PX - self.v0))

    def sample(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(value (n,), gradient (2, n))`` at window positions ``xy (2, n)`` within
        :meth:`bounds`. With the four neighbours ``f00, f10, f01, f11`` of a position and its
        fractions ``(a, b)``: ``top = f00 + (f10 - f00) a``, ``bottom = f01 + (f11 - f01) a``,
        ``value = top + (bottom - top) b``, ``d/du = f10 - f00 + ((f11 - f01) - (f10 - f00)) b``
        and ``d/dv = bottom - top``."""
        cell = np.floor(xy)
        fraction = xy - cell
        a, b = fraction[0], fraction[1]
        index = (self._strides @ cell).astype(np.intp)          # y w + x
        f = self._flat.take(index + self._neighbours).astype(np.float64)
        step = f[1::2] - f[::2]                     # f10 - f00, f11 - f01
        rows = step * a
        rows += f[::2]                              # top, bottom
        gradient = np.empty_like(step)
        np.subtract(rows[1], rows[0], out=gradient[1])
        np.subtract(step[1], step[0], out=gradient[0])
        gradient[0] *= b
        gradient[0] += step[0]
        return rows[0] + gradient[1] * b, gradient


def homogeneous(points: np.ndarray) -> np.ndarray:
    """Vessel-frame points ``(N, 2 or 3)`` as rows ``x, y, z, 1`` ``(4, N)`` (``z = 0`` when
    not given)."""
    out = np.zeros((4, len(points)))
    out[:points.shape[1]] = points.T
    out[3] = 1.0
    return out


def _hull_corners(uv: np.ndarray) -> np.ndarray | None:
    """Indices of the points whose pixels ``(N, 2)`` (NaN where they do not project) are the
    corners of their convex hull, in order; None when fewer than 3 project."""
    keep = np.isfinite(uv).all(axis=1).nonzero()[0]
    if len(keep) < 3:
        return None
    return keep[cv2.convexHull(uv[keep].astype(np.float32), returnPoints=False).reshape(-1)]


def _blend(points_h: np.ndarray, uv: np.ndarray, corner: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """Samples every :data:`SAMPLE_STEP_PX` along the polygon of the points ``corner`` (in
    order), ``(4, M)`` homogeneous blends of two points each, and their pixels blended
    alike (on a straight edge of the image; off it by a fraction of a pixel under
    perspective)."""
    following = np.concatenate((corner[1:], corner[:1]))
    lengths = np.hypot(*(uv[following] - uv[corner]).T)
    steps = np.minimum(np.maximum(np.ceil(lengths / SAMPLE_STEP_PX), 1), 2000).astype(int)
    first = np.repeat(np.cumsum(steps) - steps, steps)
    t = (np.arange(len(first)) - first) / np.repeat(steps, steps)      # k / n along an edge
    at, to = np.repeat(corner, steps), np.repeat(following, steps)
    points = points_h.take(at, axis=1) * (1 - t)
    points += points_h.take(to, axis=1) * t
    points[3] = 1.0
    return points, uv[at] * (1 - t)[:, None] + uv[to] * t[:, None]


def outline_points(hull_h: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Points along the silhouette outline, ``(4, M)`` homogeneous in the vessel frame,
    given the hull points ``(4, N)`` and their pixels ``(N, 2)`` (NaN where they do not
    project): every :data:`SAMPLE_STEP_PX` along the convex hull of the pixels, as fixed
    blends of two hull points each, so that they can be projected again under a changed
    pose. Empty when fewer than 3 hull points project."""
    corner = _hull_corners(uv)
    return np.zeros((4, 0)) if corner is None else _blend(hull_h, uv, corner)[0]


#: an outline sample of one layer this far (px) inside another layer's image is inside the
#: vessel's image, not on its outline
COVERED_PX = 0.5


def _half_planes(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """A convex polygon ``corners`` ``(V, 2)`` (in order, either way round) as half-planes
    ``n_i . p <= c_i`` with unit outward normals ``n_i``; None when it has no area."""
    edges = np.concatenate((corners[1:], corners[:1])) - corners
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    usable = lengths > 1e-9
    if usable.sum() < 3:
        return None
    edges, corners = edges[usable] / lengths[usable, None], corners[usable]
    following = np.concatenate((edges[1:], edges[:1]))
    turn = float(np.sum(edges[:, 0] * following[:, 1] - edges[:, 1] * following[:, 0]))
    normals = np.column_stack((edges[:, 1], -edges[:, 0])) * math.copysign(1.0, turn)
    return normals, (normals * corners).sum(axis=1)


def _inside_convex(corners: np.ndarray, points: np.ndarray, margin_px: float) -> np.ndarray:
    """Which of ``points`` ``(M, 2)`` lie more than ``margin_px`` inside the convex polygon
    ``corners`` ``(V, 2)`` (in order): inside every edge's half-plane by the margin (only
    the points inside its box are tested)."""
    inside = np.zeros(len(points), bool)
    low, high = corners.min(axis=0) + margin_px, corners.max(axis=0) - margin_px
    near = ((points > low) & (points < high)).all(axis=1).nonzero()[0]
    planes = _half_planes(corners) if len(near) else None
    if planes is not None:
        normals, offsets = planes
        inside[near] = (points[near] @ normals.T < offsets - margin_px).all(axis=1)
    return inside


def _corners_inside(corners: np.ndarray, points: np.ndarray) -> bool:
    """Whether all of a few ``points`` lie more than :data:`COVERED_PX` inside the convex
    polygon ``corners`` (OpenCV's signed distance, point by point)."""
    contour = corners.astype(np.float32).reshape(-1, 1, 2)
    return all(cv2.pointPolygonTest(contour, (float(u), float(v)), True) > COVERED_PX
               for u, v in points)


class Silhouette:
    """The vessel's image: the union of its layers' projected convex hulls
    (:attr:`VesselSpec.own_layers`: one hull for a prism drawn from dimensions; a hull and a
    deckhouse, a mast, for a mesh). ``points_h`` ``(4, N)`` holds every layer's points,
    homogeneous in the vessel frame, one layer after another; a single hull over them all
    would hold the slanted skirt from a deckhouse's roof to the deck's ends, which an
    oblique view shows as water beside the vessel, and the alignment pulled the hull off
    the vessel to fill it (docs/geometry.md)."""

    def __init__(self, layers) -> None:
        layers = [np.asarray(layer, float) for layer in layers]
        self.points_h = homogeneous(np.vstack(layers))
        self.ends = np.cumsum([len(layer) for layer in layers])[:-1]

    @property
    def layered(self) -> bool:
        return len(self.ends) > 0

    def layers_uv(self, uv: np.ndarray) -> list[np.ndarray]:
        """The pixels of ``points_h`` ``(N, 2)`` split by layer."""
        return np.split(uv, self.ends)

    def outline(self, uv: np.ndarray) -> np.ndarray:
        """Samples along the outline of the union of the layers' images, ``(4, M)``, given
        the pixels of ``points_h`` (NaN where they do not project): each layer's outline
        (:func:`outline_points`) less the samples more than :data:`COVERED_PX` inside
        another layer's image."""
        if not self.layered:
            return outline_points(self.points_h, uv)
        starts = np.concatenate(([0], self.ends))
        corners = []
        for start, layer_uv in zip(starts, self.layers_uv(uv), strict=True):
            corner = _hull_corners(layer_uv)
            corners.append(None if corner is None else corner + start)
        shown = [k for k, corner in enumerate(corners) if corner is not None]
        # a layer all inside another's image (a deckhouse seen from above) adds no outline,
        # and no other layer's outline enters it (its images are convex)
        shown = [k for k in shown if not any(
            j != k and _corners_inside(uv[corners[j]], uv[corners[k]]) for j in shown)]
        kept = []
        for k in shown:
            points, pixels = _blend(self.points_h, uv, corners[k])
            covered = np.zeros(points.shape[1], bool)
            for j in shown:
                if j != k:
                    covered |= _inside_convex(uv[corners[j]], pixels, COVERED_PX)
            kept.append(points[:, ~covered])
        return np.hstack(kept) if kept else np.zeros((4, 0))


class Alignment:
    """Signed distances of vessel-frame points under a pose correction
    ``p = (de, dn, dpsi, dh)`` and their Jacobian, with small-matrix operations per pose
    instead of a new geometry.

    With ``R = R_C<-W``, the camera centre ``c`` and the sensors' pose ``(e, n, h)``, a point
    ``X_V`` is in the camera frame at

        X_C = R (R_V(h + dpsi) X_V + (e + de, n + dn, 0) - c - (0, 0, dh)),

    ``R_V(h) = [[sin h, cos h, 0], [cos h, -sin h, 0], [0, 0, -1]]`` (bow, starboard and down
    in ENU), so ``dX_C/d(de, dn) = R[:, :2]``, ``dX_C/d(dpsi) = R R_V'(h + dpsi) X_V`` and
    ``dX_C/d(dh) = -R[:, 2]``. A
    pinhole gives ``(x z, y z, z) = K' X_C`` with ``K`` shifted to the signed distance's
    window (``cx - u0``, ``cy - v0``): one ``(6, 4)`` matrix per pose takes homogeneous vessel
    points to ``K' X_C`` and ``d(K' X_C)/d(dpsi)`` together, and with the signed distance's
    gradient ``(s_x, s_y)``, ``ds/d(K' X_C) = (s_x, s_y, -(s_x x + s_y y)) / z``. With lens
    distortion ``K'`` is left out and OpenCV gives the pixels and ``d(u, v)/dX_C`` (its
    Jacobian for the translation). Points behind the camera, out of view (within
    :data:`BORDER_PX` of the image border) or off the window are left out. Points are
    columns: ``(4, N)`` homogeneous in, ``(k, N)`` out.
    """

    def __init__(self, geometry: FrameGeometry, sdf: SignedDistance) -> None:
        camera = geometry.camera
        self.geometry, self.camera, self.sdf = geometry, camera, sdf
        self.intrinsics = intr = camera.intrinsics
        self.distorted = intr.has_distortion
        self.origin = np.array([[sdf.u0], [sdf.v0]], float)
        lens = np.eye(3) if self.distorted else np.array(
            [[intr.fx, 0.0, intr.cx - sdf.u0], [0.0, intr.fy, intr.cy - sdf.v0], [0.0, 0.0, 1.0]])
        lens_rotation = lens @ camera.camera_from_world
        self.lens_rotation_en_t = np.ascontiguousarray(lens_rotation[:, :2].T)
        self.lens_rotation_down = -lens_rotation[:, 2]
        #: blockdiag(L R, L R): world offsets and their derivative to lens coordinates
        self.to_lens = np.zeros((6, 6))
        self.to_lens[:3, :3] = self.to_lens[3:, 3:] = lens_rotation
        self.antenna_from_camera = (np.array([*geometry.vessel_position_enu, 0.0])
                                    - camera.position_enu).tolist()
        self.heading_rad = geometry.vessel_heading_rad
        x_lo, x_hi, y_lo, y_hi = sdf.bounds(intr.width, intr.height)
        # (x, y, z) within [lo, hi]: in view, in the window and in front (z > 1e-9)
        self.lo = (float(x_lo), float(y_lo), math.nextafter(1e-9, math.inf))
        self.hi = (float(x_hi), float(y_hi), math.inf)
        #: fewer points in view than this and a pose is not linearised
        self.min_points = MIN_EDGE_POINTS

    def with_min_points(self, count: int) -> Alignment:
        """This alignment, linearising a pose from ``count`` points in view."""
        relaxed = copy.copy(self)
        relaxed.min_points = count
        return relaxed

    def _project(self, points_h: np.ndarray, params: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """``(6, N)``: window position ``x, y``, depth ``z`` and ``d(K' X_C)/d(dpsi)``
        (``dX_C/d(dpsi)`` with distortion) of homogeneous vessel points; with distortion
        also OpenCV's Jacobian."""
        de, dn, dpsi, dh = params.tolist()
        h = self.heading_rad + dpsi
        s, c = math.sin(h), math.cos(h)
        e, n, u = self.antenna_from_camera
        world = np.array([s, c, 0.0, e + de,          # X_W - c, by x, y, z, 1
                          c, -s, 0.0, n + dn,
                          0.0, 0.0, -1.0, u - dh,
                          c, -s, 0.0, 0.0,            # dX_W/dh
                          -s, -c, 0.0, 0.0,
                          0.0, 0.0, 0.0, 0.0]).reshape(6, 4)
        lens = (self.to_lens @ world) @ points_h
        if not self.distorted:
            np.divide(lens[:2], lens[2], out=lens[:2], where=lens[2] > 1e-9)
            return lens, None
        intr = self.intrinsics
        uv, jac = cv2.projectPoints(np.ascontiguousarray(lens[:3].T).reshape(-1, 1, 3), np.zeros(3),
                                    np.zeros(3), intr.K, intr.dist_coeffs)
        lens[:2] = uv.reshape(-1, 2).T - self.origin
        return lens, jac

    def _seen(self, xyz: np.ndarray) -> np.ndarray:
        """Indices of the points ``(x, y, z)`` in view, in the window and in front."""
        if xyz.shape[1] == 0:
            return np.empty(0, np.intp)         # (OpenCV refuses an empty array)
        inside = cv2.inRange(np.ascontiguousarray(xyz[:3].T).reshape(-1, 1, 3), self.lo, self.hi)
        return inside.ravel().nonzero()[0]

    def pixels(self, points_h: np.ndarray, params: np.ndarray) -> np.ndarray:
        """Pixels ``(N, 2)`` of homogeneous vessel points, NaN where they do not project."""
        if self.distorted:      # Camera.project also refuses points past the lens model's fold
            moved = corrected_geometry(self.geometry, params)
            return moved.camera.project(moved.vessel_to_enu(points_h[:3].T))[0]
        xyz = self._project(points_h, params)[0]
        uv = (xyz[:2] + self.origin).T
        uv[xyz[2] <= 1e-9] = np.nan
        return uv

    def residuals(self, points_h: np.ndarray, params: np.ndarray) -> np.ndarray:
        """Signed distances (px) of the points in view (none of no points: an end of a hull
        outline with no sample near it)."""
        if points_h.shape[1] == 0:
            return np.empty(0)
        if self.distorted:
            xy = self.pixels(points_h, params).T - self.origin
            xyz = np.vstack((xy, np.ones((1, xy.shape[1]))))
        else:
            xyz = self._project(points_h, params)[0]
        return self.sdf.sample(xyz[:2].take(self._seen(xyz), axis=1))[0]

    def linearised(self, points_h: np.ndarray, params: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray] | None:
        """``(s (n,), ds/dp (4, n))`` of the points in view, or None when fewer than
        :attr:`min_points` (:data:`MIN_EDGE_POINTS`) are."""
        if points_h.shape[1] < self.min_points:
            return None
        projected, jac = self._project(points_h, params)
        seen = self._seen(projected)
        if len(seen) < self.min_points:
            return None
        projected = projected.take(seen, axis=1)
        xy = projected[:2]
        value, gradient = self.sdf.sample(xy)
        if self.distorted:      # ds/dX_C = s_u du/dX_C + s_v dv/dX_C
            duv_dc = jac[:, 3:6].reshape(-1, 2, 3)[seen]
            ds_dlens = (gradient[0][:, None] * duv_dc[:, 0] + gradient[1][:, None] * duv_dc[:, 1]).T
        else:                   # ds/d(x z, y z, z)
            ds_dlens = np.empty((3, len(seen)))
            ds_dlens[:2] = gradient
            np.einsum("ij,ij->j", gradient, xy, out=ds_dlens[2])
            np.negative(ds_dlens[2], out=ds_dlens[2])
            ds_dlens /= projected[2]
        ds_dp = np.empty((4, len(seen)))
        np.matmul(self.lens_rotation_en_t, ds_dlens, out=ds_dp[:2])
        np.einsum("ij,ij->j", ds_dlens, projected[3:], out=ds_dp[2])
        np.matmul(self.lens_rotation_down, ds_dlens, out=ds_dp[3])
        return value, ds_dp


#: a region of other pixels that a ship blob encloses, of at most this share of the blob's
#: area, is ship to the alignment's fill (:func:`ship_holes_filled`)
SHIP_HOLE_MAX_SHARE = 0.1


def ship_holes_filled(labels: np.ndarray) -> np.ndarray:
    """The mask with the holes of each ship blob (regions of water, solid or ignore that it
    encloses, each at most :data:`SHIP_HOLE_MAX_SHARE` of the blob's area) set to ship;
    ``labels`` itself when there are none. The alignment's ship fill (:func:`ship_fill`, a
    placement's gate) reads the mask so: a model calls patches of a deck water or solid,
    and 20 such holes of 2-5 px in a tug moored against a neighbour took the true
    placement under the gate, and the hull was laid 6-7 m over on the neighbour's blob and
    applied, unflagged. The signed distance keeps the holes' edges: the half-metre water
    between sister hulls pixelates into a chain of such holes, and filled, it made one blob
    of a row of sisters, on which a yacht between two of them was placed and applied where
    the sensors could not tell it from its sisters. The
    distances read the mask as given (the holes lie in the vessel's own region)."""
    contours, hierarchy = cv2.findContours(cv2.compare(labels, SHIP, cv2.CMP_EQ), cv2.RETR_CCOMP,
                                           cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return labels
    parents = hierarchy[0][:, 3]
    holes = [contours[i] for i in np.flatnonzero(parents >= 0)
             if cv2.contourArea(contours[i]) <= SHIP_HOLE_MAX_SHARE * cv2.contourArea(contours[parents[i]])]
    if not holes:
        return labels
    inside = np.zeros(labels.shape, np.uint8)
    cv2.drawContours(inside, holes, -1, 1, thickness=cv2.FILLED)
    filled = labels.copy()
    filled[inside.view(bool)] = SHIP
    return filled


_SQUARE_3X3 = np.ones((3, 3), np.uint8)
#: the ship fill counts the silhouette's interior (one pixel in from its outline) when that
#: holds at least this many pixels, else the whole silhouette
FILL_INTERIOR_MIN_PX = 20


def ship_fill(layers_uv: list[np.ndarray], window: tuple[slice, slice], ship: np.ndarray,
              known: np.ndarray) -> float:
    """Share of the silhouette's labelled pixels inside ``window`` that are ship pixels,
    given the pixels of each layer's points (:meth:`Silhouette.layers_uv`; NaN where they
    do not project): the union of the layers' convex hulls.

    Only the silhouette's interior counts (its drawn pixels eroded by a 3x3 square; the
    window's edge does not erode it), unless that leaves fewer than
    :data:`FILL_INTERIOR_MIN_PX`: the outline's own ring of pixels is half water wherever the
    mask's edge falls a pixel inside the hull's, and at 110-150 m, where a hull is a few
    dozen pixels long, that ring alone took the fill under the gate and threw away good
    alignments (docs/results.md)."""
    offset = np.array([window[1].start, window[0].start])
    polygons = []
    for uv in layers_uv:
        uv = uv[np.isfinite(uv).all(axis=1)]      # the corners' hull: close enough for a share
        if len(uv) >= 3:
            polygons.append(cv2.convexHull(np.round((uv - offset) * 16).astype(np.int32)))
    if not polygons:
        return 0.0
    corners = np.vstack(polygons)
    # drawn only over its bounding box within the window, with a margin of empty pixels
    # (drawing rounds a corner up to a pixel out) for the erosion
    lo = np.maximum((corners.min(axis=(0, 1)) >> 4) - 2, 0)
    hi = np.minimum((corners.max(axis=(0, 1)) >> 4) + 3, (ship.shape[1], ship.shape[0]))
    if (hi <= lo).any():
        return 0.0
    box = slice(lo[1], hi[1]), slice(lo[0], hi[0])
    inside = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), np.uint8)
    for polygon in polygons:
        cv2.fillConvexPoly(inside, (polygon - lo * 16).astype(np.int32), 1, lineType=cv2.LINE_8,
                           shift=4)
    interior = cv2.erode(inside, _SQUARE_3X3, borderType=cv2.BORDER_REPLICATE)
    if np.count_nonzero(interior) >= FILL_INTERIOR_MIN_PX:
        inside = interior
    counted = inside.view(bool) & known[box]
    total = np.count_nonzero(counted)
    return np.count_nonzero(ship[box] & counted) / total if total else 0.0


def irls_weights(residual: np.ndarray, loss: str, scale_px: float) -> np.ndarray:
    """IRLS weights: Huber ``min(1, c/|r|)``, Tukey's biweight ``(1 - min(|r|/c, 1)²)²``."""
    a = np.abs(residual)
    if loss == "huber":
        return np.minimum(scale_px / np.maximum(a, 1e-12), 1.0)
    return np.square(1 - np.square(np.minimum(a / scale_px, 1.0)))


def tukey_cost(residual: np.ndarray, scale_px: float) -> np.ndarray:
    """Tukey's biweight: ``c²/6 (1 - (1 - (r/c)²)³)`` inside ``c``, ``c²/6`` beyond."""
    inside = np.minimum(np.abs(residual) / scale_px, 1.0)
    return scale_px ** 2 / 6 * (1 - (1 - inside ** 2) ** 3)


def outline_fit(value: np.ndarray) -> tuple[float, float | None, int]:
    """``(inlier fraction, RMS of the inliers px, points that can tell)`` of the signed
    distances of an outline's points in view: those not deep inside ship pixels
    (:data:`DEEP_PX`) can tell."""
    telling = value[value > -DEEP_PX]
    if not len(telling):
        return 0.0, None, 0
    inliers = telling[np.abs(telling) <= INLIER_PX]
    rms = math.sqrt(np.add.reduce(inliers ** 2) / len(inliers)) if len(inliers) else None
    return len(inliers) / len(telling), rms, len(telling)




#: one sigma (m) of the prior that holds a direction of the correction at the sensors' value
#: (:func:`gauss_newton`'s ``held``)
HELD_SIGMA = 0.01


def gauss_newton(align: Alignment, silhouette: Silhouette, outline: np.ndarray, schedule,
                 start: np.ndarray, prior_diagonal: np.ndarray, edge_weight: float,
                 held: np.ndarray | None = None,
                 ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Gauss-Newton IRLS through ``schedule`` (``(loss, scale px, iterations)`` stages) from
    ``start``, with a Gaussian prior ``diag(prior_diagonal)`` (inverse variances) about the
    sensors' pose: ``(params, information, final cost, the outline's signed distances in
    view)``. ``held``, a unit direction of the correction the image cannot observe (the
    shift along a hull with no edge across its length in view), adds
    ``held heldᵀ / HELD_SIGMA²`` to the prior: the solve keeps that component at the
    sensors' value (whose error the caller carries apart: the information holds it to a
    centimetre). ``outline`` is sampled at the
    sensors' pose; each later stage samples the outline afresh (its corners move with the
    pose). The final cost is Tukey's at :data:`FINAL_TUKEY_PX` over ``outline`` (points out
    of view count as outliers) plus the prior's; it is infinite when the solve failed."""
    prior_information = np.diag(prior_diagonal)
    if held is not None:
        prior_information += np.outer(held, held) / HELD_SIGMA ** 2
    params, information = start.astype(float), prior_information

    def failed() -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        return params, information, np.inf, align.residuals(outline, params)

    for stage, (loss, scale_px, iterations) in enumerate(schedule):
        tolerance_m = 1e-3 if stage == len(schedule) - 1 else 1e-2
        # at the sensors' pose that is the outline already sampled
        points = (silhouette.outline(align.pixels(silhouette.points_h, params)) if params.any()
                  else outline)
        if points.shape[1] == 0:
            return failed()
        for _ in range(iterations):
            linear = align.linearised(points, params)
            if linear is None:
                return failed()
            r, jac_t = linear
            weights = irls_weights(r, loss, scale_px)
            if edge_weight != 1.0:
                weights *= edge_weight
            weighted_jac_t = jac_t * weights
            information = weighted_jac_t @ jac_t.T + prior_information
            gradient = weighted_jac_t @ r + prior_information @ params
            try:
                delta = -np.linalg.solve(information, gradient)
            except np.linalg.LinAlgError:
                return failed()
            d_e, d_n, d_psi, d_h = delta.tolist()
            if not (math.isfinite(d_e) and math.isfinite(d_n) and math.isfinite(d_psi)
                    and math.isfinite(d_h)):
                return failed()
            params = params + delta
            if (math.hypot(d_e, d_n) < tolerance_m and abs(d_psi) < tolerance_m / 50
                    and abs(d_h) < tolerance_m):
                break
    value = align.residuals(outline, params)
    out_of_view = outline.shape[1] - len(value)
    cost = (tukey_cost(value, FINAL_TUKEY_PX).sum()
            + out_of_view * FINAL_TUKEY_PX ** 2 / 6) * edge_weight
    return params, information, float(cost + params @ prior_information @ params), value
