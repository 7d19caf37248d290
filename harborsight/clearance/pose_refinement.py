"""Pose refinement: move the projected vessel onto its own ship pixels.

Real sensors misplace the vessel in the image: standalone GPS on the drone and on the
vessel is off by 1-3 m each, a compass by 1-3 degrees. The vessel is visible, so its pose
can be corrected from the label mask.

**Model.** A correction ``p = (de, dn, dpsi, dh)``: the vessel's antenna moves by
``(de, dn)`` metres in the frame's local ENU, its heading turns by ``dpsi`` about the
antenna, and the drone's height above the water changes by ``dh``. The first three absorb
the horizontal errors of both receivers and the yaw errors of both compasses (a yaw error of
a nadir camera turns the whole scene, which keeps the distances between the hull and what
surrounds it). The height scales the whole scene about the nadir (a barometric metre at
60 m is 1.7 % of every distance); the hull's known size in pixels measures it, so it is
refined too, with its own prior (``prior_height_m``), and the corrected height is what the
distances are then measured with.

**Objective.** The vessel's image silhouette is the convex hull of its projected hull
points (as for the own-vessel region). ``N`` points are sampled along that outline, and
each should lie on the boundary of the mask's ship pixels. With the signed distance
``s(u, v)`` to that boundary (positive outside ship pixels) the MAP estimate is

    p* = argmin  sum_i rho(s(x_i(p))) / sigma_e^2  +  p^T diag(sigma_p)^-2 p

with a robust ``rho`` (Huber, then Tukey's biweight) so that a touching neighbour, a
partly wrong mask or a mooring line do not pull the outline, and a Gaussian prior from the
sensors' accuracy. Gauss-Newton on iteratively re-weighted least squares; the Jacobian
``ds/dp = grad s · dx/dp`` comes from the bilinear gradient of ``s`` and the analytic
derivative of the projection (OpenCV's with lens distortion). Outline points outside the
image, or within a pixel of its border, are left out: a hull partly out of view is aligned
on what is seen.

**Cost.** Per frame the signed distance is one distance transform of the window the
outline can reach; per Gauss-Newton step a pose is one ``(6, 4)`` matrix that takes the
outline's homogeneous vessel-frame points to their pixels and depth and to their derivative
in ``dpsi`` (:class:`_Alignment`), so a step is a few dozen array operations on about 200
points, not a new geometry.

**Quality.** ``residual_px`` is the RMS of the inliers' distances after the fit,
``inlier_fraction`` the share of visible outline points within :data:`INLIER_PX` of a ship
boundary (points deep inside ship pixels, :data:`DEEP_PX`, cannot tell and are left out),
and ``ship_fill`` the share of the silhouette's pixels in view that are ship pixels: a
rigid outline can fit the straight edges of the wrong blobs (a neighbour's side, a
deckhouse), but then it covers water or a quay. A correction is applied only when enough of
the outline is seen, most of it fits, the silhouette is filled, the fit is not worse than
the sensors' pose, and the correction is within the search bounds; otherwise the frame keeps
the sensors' pose and the report says why.

**Starts.** Huber from the sensors' pose first; when that leaves the outline or the
silhouette short, graduated Tukey from the sensors' pose, from the prior's reach to either
side across the hull and from the best cells of a coarse translation search
(:func:`_translation_search`), and the lowest final Tukey cost among the filled candidates
wins.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from harborsight.clearance.obstacles import IGNORE, SHIP
from harborsight.errors import require_positive
from harborsight.frame import FrameGeometry
from harborsight.vessel.spec import VesselSpec

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
_FINAL_TUKEY_PX = 3.0
#: the sensors' pose is kept when it fits within this much RMS of the refined one, with as
#: many inliers: a correction then follows the mask's rounding, not the sensors' error
SAME_FIT_RMS_PX = 0.25
#: the reason given when the sensors' pose fits the mask as well as the refined one
SENSORS_FIT = "the sensors' pose fits the mask as well"
#: the other schedules run only when the first leaves fewer inliers than this
SKIP_SECOND_START_FRACTION = 0.9


@dataclass(frozen=True)
class PoseRefinementSettings:
    """Priors (one sigma of the combined drone + vessel error, per axis) and acceptance."""

    enabled: bool = True
    prior_shift_m: float = 3.0
    prior_heading_deg: float = 3.0
    #: one sigma of the drone's height above the water (a barometer); refined with the rest
    prior_height_m: float = 1.0
    refine_height: bool = True
    edge_sigma_px: float = 1.0
    #: a correction larger than this is refused (4 sigma of the default prior)
    max_shift_m: float = 12.0
    max_rotation_deg: float = 12.0
    #: a height change larger than this is refused (4 sigma of the default prior)
    max_height_change_m: float = 4.0
    min_inlier_fraction: float = 0.5
    #: share of the silhouette's pixels in view that must be ship pixels: a rigid outline can
    #: fit straight edges of the wrong blobs, but then it covers water or a quay
    min_ship_fill: float = 0.9
    max_residual_px: float = 1.5

    def __post_init__(self) -> None:
        require_positive(self, ("prior_shift_m", "prior_heading_deg", "prior_height_m", "edge_sigma_px",
                                "max_shift_m", "max_rotation_deg", "max_height_change_m",
                                "max_residual_px"))
        for name in ("min_inlier_fraction", "min_ship_fill"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")


@dataclass(frozen=True)
class PoseRefinement:
    """What the alignment found. ``shift_m``/``rotation_deg``/``height_change_m`` are the
    correction it found (also when not applied); ``covariance`` is its 4x4 posterior
    covariance in (m, m, rad, m), or 3x3 without the height when that was not refined."""

    applied: bool
    shift_m: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0
    height_change_m: float = 0.0
    residual_px: float | None = None
    inlier_fraction: float | None = None
    inlier_fraction_before: float | None = None
    edge_points: int = 0
    ship_fill: float | None = None
    reason: str | None = None
    #: the sensors' pose fits the mask badly and a correction beyond the limits fits it well:
    #: the image says the sensors are off by more than the refinement may correct
    #: (:func:`contradicts_sensors`)
    sensors_contradicted: bool = False
    covariance: np.ndarray | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        def rounded(value: float | None, digits: int) -> float | None:
            return None if value is None else round(float(value), digits)

        return {
            "applied": self.applied,
            "shift_m": [round(float(v), 3) for v in self.shift_m],
            "rotation_deg": round(float(self.rotation_deg), 3),
            "height_change_m": round(float(self.height_change_m), 3),
            "residual_px": rounded(self.residual_px, 3),
            "inlier_fraction": rounded(self.inlier_fraction, 3),
            "inlier_fraction_before": rounded(self.inlier_fraction_before, 3),
            "edge_points": self.edge_points,
            "ship_fill": rounded(self.ship_fill, 3),
            "reason": self.reason,
            "sensors_contradicted": self.sensors_contradicted,
        }


OFF = PoseRefinement(applied=False, reason="off")


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


class _SignedDistance:
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


def _homogeneous(points: np.ndarray) -> np.ndarray:
    """Vessel-frame points ``(N, 2 or 3)`` as rows ``x, y, z, 1`` ``(4, N)`` (``z = 0`` when
    not given)."""
    out = np.zeros((4, len(points)))
    out[:points.shape[1]] = points.T
    out[3] = 1.0
    return out


def _outline_points(hull_h: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Points along the silhouette outline, ``(4, M)`` homogeneous in the vessel frame,
    given the hull points ``(4, N)`` and their pixels ``(N, 2)`` (NaN where they do not
    project): every :data:`SAMPLE_STEP_PX` along the convex hull of the pixels, as fixed
    blends of two hull points each, so that they can be projected again under a changed
    pose. Empty when fewer than 3 hull points project."""
    keep = np.isfinite(uv).all(axis=1).nonzero()[0]
    if len(keep) < 3:
        return np.zeros((4, 0))
    corner = keep[cv2.convexHull(uv[keep].astype(np.float32), returnPoints=False).reshape(-1)]
    following = np.concatenate((corner[1:], corner[:1]))
    lengths = np.hypot(*(uv[following] - uv[corner]).T)
    steps = np.minimum(np.maximum(np.ceil(lengths / SAMPLE_STEP_PX), 1), 2000).astype(int)
    first = np.repeat(np.cumsum(steps) - steps, steps)
    t = (np.arange(len(first)) - first) / np.repeat(steps, steps)      # k / n along an edge
    points = hull_h.take(np.repeat(corner, steps), axis=1) * (1 - t)
    points += hull_h.take(np.repeat(following, steps), axis=1) * t
    points[3] = 1.0
    return points


class _Alignment:
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

    def __init__(self, geometry: FrameGeometry, sdf: _SignedDistance) -> None:
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
        """Signed distances (px) of the points in view."""
        if self.distorted:
            xy = self.pixels(points_h, params).T - self.origin
            xyz = np.vstack((xy, np.ones((1, xy.shape[1]))))
        else:
            xyz = self._project(points_h, params)[0]
        return self.sdf.sample(xyz[:2].take(self._seen(xyz), axis=1))[0]

    def linearised(self, points_h: np.ndarray, params: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray] | None:
        """``(s (n,), ds/dp (4, n))`` of the points in view, or None when fewer than
        :data:`MIN_EDGE_POINTS` are."""
        projected, jac = self._project(points_h, params)
        seen = self._seen(projected)
        if len(seen) < MIN_EDGE_POINTS:
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


def _search_window(uv: np.ndarray, geometry: FrameGeometry, vessel: VesselSpec,
                   settings: PoseRefinementSettings, shape: tuple[int, int]
                   ) -> tuple[slice, slice] | None:
    """The part of the image the outline can reach within the search bounds."""
    finite = uv[np.isfinite(uv).all(axis=1)]
    if not len(finite):
        return None
    intr = geometry.camera.intrinsics
    height_m = max(float(geometry.camera.position_enu[2]), 1e-3)
    # 2.5 sigma of the prior: a correction beyond it needs edges the window still holds
    reach_m = min(settings.max_shift_m, 2.5 * settings.prior_shift_m) + 0.5 * vessel.length_m * (
        math.radians(min(settings.max_rotation_deg, 2.5 * settings.prior_heading_deg)))
    reach_px = min(reach_m * max(intr.fx, intr.fy) / height_m, max(shape)) + 4
    lo = np.floor(finite.min(axis=0) - reach_px).astype(int)
    hi = np.ceil(finite.max(axis=0) + reach_px).astype(int)
    u0, v0 = max(lo[0], 0), max(lo[1], 0)
    u1, v1 = min(hi[0] + 1, shape[1]), min(hi[1] + 1, shape[0])
    if u1 - u0 < 2 or v1 - v0 < 2:
        return None
    return slice(v0, v1), slice(u0, u1)


_SQUARE_3X3 = np.ones((3, 3), np.uint8)
#: the ship fill counts the silhouette's interior (one pixel in from its outline) when that
#: holds at least this many pixels, else the whole silhouette
FILL_INTERIOR_MIN_PX = 20


def _ship_fill(uv: np.ndarray, window: tuple[slice, slice], ship: np.ndarray,
               known: np.ndarray) -> float:
    """Share of the silhouette's labelled pixels inside ``window`` that are ship pixels,
    given the hull points' pixels ``uv`` (NaN where they do not project).

    Only the silhouette's interior counts (its drawn pixels eroded by a 3x3 square; the
    window's edge does not erode it), unless that leaves fewer than
    :data:`FILL_INTERIOR_MIN_PX`: the outline's own ring of pixels is half water wherever the
    mask's edge falls a pixel inside the hull's, and at 110-150 m, where a hull is a few
    dozen pixels long, that ring alone took the fill under the gate and threw away good
    alignments (docs/results.md)."""
    uv = uv[np.isfinite(uv).all(axis=1)]      # the corners' hull: close enough for a share
    if len(uv) < 3:
        return 0.0
    offset = np.array([window[1].start, window[0].start])
    corners = cv2.convexHull(np.round((uv - offset) * 16).astype(np.int32))
    # drawn only over its bounding box within the window, with a margin of empty pixels
    # (drawing rounds a corner up to a pixel out) for the erosion
    lo = np.maximum((corners.min(axis=(0, 1)) >> 4) - 2, 0)
    hi = np.minimum((corners.max(axis=(0, 1)) >> 4) + 3, (ship.shape[1], ship.shape[0]))
    if (hi <= lo).any():
        return 0.0
    box = slice(lo[1], hi[1]), slice(lo[0], hi[0])
    inside = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), np.uint8)
    cv2.fillConvexPoly(inside, (corners - lo * 16).astype(np.int32), 1, lineType=cv2.LINE_8, shift=4)
    interior = cv2.erode(inside, _SQUARE_3X3, borderType=cv2.BORDER_REPLICATE)
    if np.count_nonzero(interior) >= FILL_INTERIOR_MIN_PX:
        inside = interior
    counted = inside.view(bool) & known[box]
    total = np.count_nonzero(counted)
    return np.count_nonzero(ship[box] & counted) / total if total else 0.0


def _weights(residual: np.ndarray, loss: str, scale_px: float) -> np.ndarray:
    """IRLS weights: Huber ``min(1, c/|r|)``, Tukey's biweight ``(1 - min(|r|/c, 1)²)²``."""
    a = np.abs(residual)
    if loss == "huber":
        return np.minimum(scale_px / np.maximum(a, 1e-12), 1.0)
    return np.square(1 - np.square(np.minimum(a / scale_px, 1.0)))


def _tukey_cost(residual: np.ndarray, scale_px: float) -> np.ndarray:
    """Tukey's biweight: ``c²/6 (1 - (1 - (r/c)²)³)`` inside ``c``, ``c²/6`` beyond."""
    inside = np.minimum(np.abs(residual) / scale_px, 1.0)
    return scale_px ** 2 / 6 * (1 - (1 - inside ** 2) ** 3)


def _fit(value: np.ndarray) -> tuple[float, float | None, int]:
    """``(inlier fraction, RMS of the inliers px, points that can tell)`` of the signed
    distances of an outline's points in view: those not deep inside ship pixels
    (:data:`DEEP_PX`) can tell."""
    telling = value[value > -DEEP_PX]
    if not len(telling):
        return 0.0, None, 0
    inliers = telling[np.abs(telling) <= INLIER_PX]
    rms = math.sqrt(np.add.reduce(inliers ** 2) / len(inliers)) if len(inliers) else None
    return len(inliers) / len(telling), rms, len(telling)


#: the coarse translation search's grid step, as a share of the prior's sigma; how many of
#: its best cells start a Gauss-Newton run; at most this many outline points score a cell;
SEARCH_STEP_SIGMA = 1 / 3
SEARCH_STARTS = 2
SEARCH_POINTS = 120
#: the Tukey scale (px) a search cell is scored at: the second schedule's first
SEARCH_TUKEY_PX = SCHEDULES[1][0][1]


def _translation_search(align: _Alignment, outline: np.ndarray, settings: PoseRefinementSettings,
                        taken: list[np.ndarray]) -> list[tuple[float, float]]:
    """The best horizontal shifts ``(de, dn)`` (metres) of a grid over the prior's reach
    (within ``min(max_shift_m, 2.5 prior_shift_m)``, steps of :data:`SEARCH_STEP_SIGMA`
    sigma): starts for the Gauss-Newton runs when the sensors are so far off that their
    neighbourhood holds the wrong basin (a start 5 m off with a 3 m prior, docs/results.md).

    A cell is scored by the Tukey cost, at the second schedule's first scale
    (:data:`SEARCH_TUKEY_PX`, the basin its run starts with), of the signed distances of up
    to :data:`SEARCH_POINTS` outline points (every k-th); points that leave the view count as
    outliers. The outline's pixels under a shift are taken to first order,
    ``uv(t) = uv(0) + J t``, with ``J`` from the projections at 1 m east and 1 m north: one
    projection per axis instead of one per cell. At most :data:`SEARCH_STARTS` cells, each
    cheaper than the sensors' pose and more than 1.5 steps from the other starts (``taken``,
    the sensors' pose among them) and from each other; none when no cell beats the sensors'
    pose."""
    reach_m = min(settings.max_shift_m, 2.5 * settings.prior_shift_m)
    step_m = SEARCH_STEP_SIGMA * settings.prior_shift_m
    n = int(reach_m // step_m)
    if n < 1 or outline.shape[1] == 0:
        return []
    outline = outline[:, ::-(-outline.shape[1] // SEARCH_POINTS)]    # every k-th point
    base = align.pixels(outline, np.zeros(4))
    east = align.pixels(outline, np.array([1.0, 0.0, 0.0, 0.0])) - base
    north = align.pixels(outline, np.array([0.0, 1.0, 0.0, 0.0])) - base
    keep = np.isfinite(base).all(axis=1) & np.isfinite(east).all(axis=1) & np.isfinite(north).all(axis=1)
    if keep.sum() < MIN_EDGE_POINTS:
        return []
    base, east, north = base[keep], east[keep], north[keep]
    offsets = np.arange(-n, n + 1) * step_m
    de, dn = (g.ravel() for g in np.meshgrid(offsets, offsets))
    inside = np.hypot(de, dn) <= reach_m + 1e-9
    de, dn = de[inside], dn[inside]
    xy = (base[None] + de[:, None, None] * east[None] + dn[:, None, None] * north[None]
          - align.origin.T[None])                                    # (cells, points, 2)
    seen = ((xy[..., 0] >= align.lo[0]) & (xy[..., 0] <= align.hi[0])
            & (xy[..., 1] >= align.lo[1]) & (xy[..., 1] <= align.hi[1]))
    values = np.full(seen.shape, np.inf)
    values[seen] = align.sdf.sample(xy[seen].T)[0]
    cost = _tukey_cost(values, SEARCH_TUKEY_PX).sum(axis=1)    # |inf| -> the outlier cost
    centre = cost[np.flatnonzero((de == 0) & (dn == 0))[0]]
    found: list[tuple[float, float]] = []
    others = [(float(t[0]), float(t[1])) for t in taken]
    for cell in np.argsort(cost, kind="stable"):
        if cost[cell] >= centre:
            break
        shift = (float(de[cell]), float(dn[cell]))
        if all(math.hypot(shift[0] - e, shift[1] - n_) > 1.5 * step_m for e, n_ in others + found):
            found.append(shift)
            if len(found) == SEARCH_STARTS:
                break
    return found


def refine_vessel_pose(
    labels: np.ndarray, geometry: FrameGeometry, vessel: VesselSpec,
    settings: PoseRefinementSettings = PoseRefinementSettings(),
) -> tuple[FrameGeometry, PoseRefinement]:
    """Align the vessel's projected silhouette to the mask's ship pixels (module docstring).

    Returns the geometry to measure with (refined, or the given one when the alignment is
    not trustworthy) and what was found. Never raises for a failed alignment.
    """
    if not settings.enabled:
        return geometry, OFF
    hull_h = _homogeneous(vessel.hull_points)
    outline = _outline_points(hull_h, geometry.camera.project(geometry.vessel_to_enu(hull_h[:3].T))[0])
    if outline.shape[1] == 0:
        return geometry, PoseRefinement(False, reason="the hull does not project into the image")
    uv0 = geometry.camera.project(geometry.vessel_to_enu(outline[:3].T))[0]
    window = _search_window(uv0, geometry, vessel, settings, labels.shape)
    if window is None:
        return geometry, PoseRefinement(False, reason="the hull is not in the image")
    ship = labels[window] == SHIP
    if not ship.any():
        return geometry, PoseRefinement(False, reason="no ship pixels near the projected hull")
    if ship.all():
        return geometry, PoseRefinement(False, reason="only ship pixels around the projected hull")
    align = _Alignment(geometry, _SignedDistance(ship, (window[1].start, window[0].start)))

    before, before_rms_px, _ = _fit(align.residuals(outline, np.zeros(4)))

    # without height refinement a prior of a micrometre holds the height where it is
    prior_sigma = np.array([settings.prior_shift_m, settings.prior_shift_m,
                            math.radians(settings.prior_heading_deg),
                            settings.prior_height_m if settings.refine_height else 1e-6])
    prior_diagonal = prior_sigma ** -2.0
    prior_information = np.diag(prior_diagonal)
    edge_weight = settings.edge_sigma_px ** -2.0

    def solve(schedule, start: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """Gauss-Newton IRLS through ``schedule`` from ``start``: ``(params, information,
        final cost, the outline's signed distances in view)``. Each stage samples the
        outline afresh (its corners move with the pose)."""
        params, information = start.astype(float), prior_information

        def failed() -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
            return params, information, np.inf, align.residuals(outline, params)

        for stage, (loss, scale_px, iterations) in enumerate(schedule):
            tolerance_m = 1e-3 if stage == len(schedule) - 1 else 1e-2
            # at the sensors' pose that is the outline already sampled
            points = _outline_points(hull_h, align.pixels(hull_h, params)) if params.any() else outline
            if points.shape[1] == 0:
                return failed()
            for _ in range(iterations):
                linear = align.linearised(points, params)
                if linear is None:
                    return failed()
                r, jac_t = linear
                weights = _weights(r, loss, scale_px)
                if edge_weight != 1.0:
                    weights *= edge_weight
                weighted_jac_t = jac_t * weights
                information = weighted_jac_t @ jac_t.T + prior_information
                gradient = weighted_jac_t @ r + prior_diagonal * params
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
        # final cost: Tukey over the whole outline (points out of view count as outliers)
        value = align.residuals(outline, params)
        out_of_view = outline.shape[1] - len(value)
        cost = (_tukey_cost(value, _FINAL_TUKEY_PX).sum()
                + out_of_view * _FINAL_TUKEY_PX ** 2 / 6) * edge_weight
        return params, information, float(cost + params @ prior_information @ params), value

    known = labels[window] != IGNORE

    def fill(params: np.ndarray) -> float:
        return _ship_fill(align.pixels(hull_h, params), window, ship, known)

    # the first start; when it leaves the outline or the silhouette short of ship pixels,
    # the second schedule from the sensors' pose and from a beam's reach to either side
    first = solve(SCHEDULES[0], np.zeros(4))
    candidates = [(*first, fill(first[0]))]     # (params, information, cost, distances, fill)
    first_fit = _fit(first[3])
    if first_fit[0] < SKIP_SECOND_START_FRACTION or candidates[0][4] < settings.min_ship_fill:
        h = geometry.vessel_heading_rad
        across = np.array([math.cos(h), -math.sin(h), 0.0, 0.0]) * settings.prior_shift_m
        starts = [np.zeros(4), across, -across]
        starts += [np.array([de, dn, 0.0, 0.0])
                   for de, dn in _translation_search(align, outline, settings, starts)]
        for start in starts:
            found = solve(SCHEDULES[1], start)
            candidates.append((*found, fill(found[0])))
    full = [c for c in candidates if c[4] >= settings.min_ship_fill]
    params, information, _, value, ship_fill = best = min(full or candidates, key=lambda c: c[2])

    fraction, residual_px, n_edge = first_fit if best is candidates[0] else _fit(value)
    shift = (float(params[0]), float(params[1]))
    rotation_deg = math.degrees(float(params[2]))
    height_change_m = float(params[3]) if settings.refine_height else 0.0
    if not settings.refine_height:
        params = params.copy()
        params[3] = 0.0
    if n_edge < MIN_EDGE_POINTS:
        return geometry, PoseRefinement(
            False, shift, rotation_deg, edge_points=n_edge, inlier_fraction_before=before,
            reason=f"only {n_edge} outline points in view where the mask can tell "
                   f"(at least {MIN_EDGE_POINTS} needed)")
    try:
        covariance = np.linalg.inv(information)
        if not settings.refine_height:
            covariance = covariance[:3, :3]
    except np.linalg.LinAlgError:
        covariance = None
    found = PoseRefinement(False, shift, rotation_deg, height_change_m, residual_px, fraction, before,
                           n_edge, ship_fill=ship_fill, covariance=covariance)
    reason = None
    if not np.isfinite(params).all():
        reason = "the alignment diverged"
    elif math.hypot(*shift) > settings.max_shift_m:
        reason = f"shift {math.hypot(*shift):.1f} m beyond {settings.max_shift_m:g} m"
    elif abs(rotation_deg) > settings.max_rotation_deg:
        reason = f"rotation {rotation_deg:.1f} deg beyond {settings.max_rotation_deg:g} deg"
    elif abs(height_change_m) > settings.max_height_change_m:
        reason = f"height change {height_change_m:+.1f} m beyond {settings.max_height_change_m:g} m"
    elif fraction < settings.min_inlier_fraction:
        reason = (f"{100 * fraction:.0f} % of the outline fits a ship edge "
                  f"(at least {100 * settings.min_inlier_fraction:.0f} % needed)")
    elif ship_fill < settings.min_ship_fill:
        reason = (f"{100 * ship_fill:.0f} % of the silhouette is ship pixels "
                  f"(at least {100 * settings.min_ship_fill:.0f} % needed)")
    elif residual_px is None or residual_px > settings.max_residual_px:
        reason = f"residual {residual_px:.2f} px above {settings.max_residual_px:g} px"
    elif fraction < before - 0.02 or (
            fraction <= before + 0.02 and before_rms_px is not None
            and before_rms_px <= residual_px + SAME_FIT_RMS_PX):
        reason = SENSORS_FIT      # a correction would only follow the pixels' rounding
    if reason is not None:
        beyond = reason.startswith(BEYOND_LIMITS)
        in_view = len(value) / max(outline.shape[1], 1)
        return geometry, replace(found, reason=reason, sensors_contradicted=beyond and contradicts_sensors(
            before, fraction, ship_fill, residual_px, settings, in_view))
    return corrected_geometry(geometry, params), replace(found, applied=True)


#: a refused correction that puts this much more of the outline on ship edges than the
#: sensors' pose contradicts the sensors (:func:`contradicts_sensors`)
CONTRADICTION_GAIN = 0.25
#: the share of the outline that must be in view for a correction to contradict the sensors
CONTRADICTION_MIN_IN_VIEW = 0.7
#: the reasons that refuse a correction for its size alone
BEYOND_LIMITS = ("shift ", "rotation ", "height change ")


def contradicts_sensors(fraction_before: float, fraction: float, ship_fill: float,
                        residual_px: float | None, settings: PoseRefinementSettings,
                        in_view: float = 1.0) -> bool:
    """Whether a correction refused for its size alone shows the sensors' pose wrong: it
    passes every test of fit (inliers, ship fill, residual), and the sensors' pose leaves
    fewer than ``min_inlier_fraction`` of the outline on a ship edge or
    :data:`CONTRADICTION_GAIN` fewer than the correction. An altitude 5 m off (a water level
    left at 0 on a tide) or a magnetic heading taken for true 15 degrees off is such a case:
    the pose the distances are read with is then known to be wrong, by more than any sigma
    says (on the sample frames a quay 5.05 m away read 21.6 ± 2.3 m). Only a hull mostly in
    view (``in_view``, the share of the outline's samples in the image, at least
    :data:`CONTRADICTION_MIN_IN_VIEW`) can say so: of a bow alone, a wrong height and shift
    fit as well as the truth (a 30 m bench frame with 36 % of the hull in view "found" a
    height 10.7 m off)."""
    return (in_view >= CONTRADICTION_MIN_IN_VIEW
            and (fraction_before < settings.min_inlier_fraction
                 or fraction - fraction_before >= CONTRADICTION_GAIN)
            and fraction >= settings.min_inlier_fraction
            and ship_fill >= settings.min_ship_fill
            and residual_px is not None and residual_px <= settings.max_residual_px)


def refinement_counts(refinements: list[dict[str, Any] | None]) -> dict[str, int]:
    """How a batch's frames came out: ``applied``, ``sensors_pose_fitted`` (kept, fitting as
    well), ``kept_sensors_pose`` (kept, the alignment not trusted) and ``off``."""
    given = [r for r in refinements if r]
    off = sum(r.get("reason") == "off" for r in given)
    applied = sum(bool(r.get("applied")) for r in given)
    fitted = sum(r.get("reason") == SENSORS_FIT for r in given)
    return {"applied": applied, "sensors_pose_fitted": fitted,
            "kept_sensors_pose": len(given) - off - applied - fitted, "off": off}


def refinement_summary(refinements: list[dict[str, Any] | None]) -> str | None:
    """One line for a batch: on how many frames the pose was refined, on how many the
    sensors' pose fitted as well, and why the others kept it (reasons without their
    numbers, most common first; the line holds "kept" only then). None when it was off."""
    counts = refinement_counts(refinements)
    ran = counts["applied"] + counts["sensors_pose_fitted"] + counts["kept_sensors_pose"]
    if not ran:
        return None
    line = f"pose refined on {counts['applied']} of {ran} frame(s)"
    contradicted = sum(bool(r and r.get("sensors_contradicted")) for r in refinements)
    if contradicted:
        line = (f"the image contradicts the sensors' pose beyond the refinement's limits on "
                f"{contradicted} frame(s): their distances' lower bounds are 0; ") + line
    if counts["sensors_pose_fitted"]:
        line += f"; the sensors' pose fitted as well on {counts['sensors_pose_fitted']}"
    kept = [str(r.get("reason") or "") for r in refinements
            if r and not r.get("applied") and r.get("reason") not in ("off", SENSORS_FIT)]
    if kept:
        kinds: dict[str, int] = {}
        for reason in kept:
            kind = " ".join("".join(ch for ch in reason if not (ch.isdigit() or ch in ".-")).split())
            kinds[kind] = kinds.get(kind, 0) + 1
        top = sorted(kinds.items(), key=lambda kv: -kv[1])[:3]
        line += f"; the sensors' pose kept on {len(kept)} (" + "; ".join(
            f"{n}x {kind}" for kind, n in top) + ")"
    return line
