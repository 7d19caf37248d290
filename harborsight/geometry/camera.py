"""Pinhole camera with OpenCV distortion: intrinsics, projection, back-projection (the
calibration files that give the intrinsics: :mod:`harborsight.geometry.calibration_files`).

A world point ``X_W`` (ENU, metres) maps to pixels by

    X_C = R_C<-W · (X_W - c_W)          (c_W: camera centre in W)
    (u, v) = K · distort(X_C / z_C)     (OpenCV model, cv2.projectPoints)

and a pixel back-projects to the ray ``c_W + t · R_W<-C · [x, y, 1]`` with ``(x, y)`` the
undistorted normalised coordinates; the ray meets the plane ``z = z_p`` at
``t = (z_p - c_z) / d_z`` when ``t > 0``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from harborsight.errors import InputError, brief
from harborsight.geometry.polygons import clip_to_box

VALID_DISTORTION_LENGTHS = (0, 4, 5, 8, 12, 14)
#: the longest image side a calibration or a frame may state (a 100 000 px side is already
#: beyond any camera; the limit keeps a typo of 400 digits from becoming a width of 1e308)
MAX_IMAGE_SIDE_PX = 100_000
# a hull edge reaching far past the image (a point just in front of the camera plane) is cut
# into at most this many steps; its distorted part beyond the fold is refused anyway
_MAX_STEPS_PER_EDGE = 4096
# a step of an outline that crosses a barrel fold is bisected this often (to 1/32 of a step)
_FOLD_BISECTIONS = 5
_NEWTON_STEPS = 6
_NEWTON_SKIP_PX = 1e-7  # pixels that OpenCV's iteration already brought this close are left


#: a convex set reaching behind the camera is cut at this depth (m, or this share of its
#: farthest point's depth if more): what lies nearer projects beyond any image
_NEAR_DEPTH_M = 1e-3
_NEAR_DEPTH_SHARE = 1e-4


def _ahead_of_camera(points_c: np.ndarray) -> np.ndarray:
    """The part of a convex set (points in the camera frame, ``z`` along the optical axis) in
    front of the near plane ``z = n``: its points beyond it and the crossings of the plane by
    every segment from one of those to a point nearer, ``p + (n - z_p)/(z_q - z_p) (q - p)``
    (the convex hull of the set cut by the plane has its new corners on such segments).
    Dropping the points behind (as before) shrank the hull's image: a review's low, close
    view of a yacht's 20 m mast left 615 of its 5,014 pixels outside the vessel's region."""
    depth = points_c[:, 2]
    if len(points_c) == 0 or depth.max() <= 0:
        return points_c[depth > 1e-9]
    near = max(_NEAR_DEPTH_M, _NEAR_DEPTH_SHARE * float(depth.max()))
    ahead, behind = points_c[depth > near], points_c[depth <= near]
    if len(behind) == 0 or len(ahead) == 0:
        return ahead if len(ahead) else points_c[depth > 1e-9]
    if len(ahead) * len(behind) <= _MAX_NEAR_PAIRS:
        p, q = np.repeat(ahead, len(behind), axis=0), np.tile(behind, (len(ahead), 1))
    else:
        p, q = _hull_edges_across(points_c, depth > near)
    t = (near - p[:, 2]) / (q[:, 2] - p[:, 2])
    return np.vstack((ahead, p + t[:, None] * (q - p)))


#: beyond this many pairs of points either side of the near plane, only the pairs joined by
#: an edge of the set's convex hull are cut: the plane's polygon has its corners on such
#: edges. Every pair of a scanned hull's 20,737 points, 10,000 of them behind a low drone,
#: asked for 18 GB
_MAX_NEAR_PAIRS = 200_000


def _hull_edges_across(points_c: np.ndarray, ahead: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ends ``(p ahead, q behind)`` of the edges of the points' 3-D convex hull that
    cross the near plane (``ahead``: which points lie beyond it). Qhull joggles a flat set
    (``QJ``); a set it cannot hull at all is paired on every k-th point of either side, so
    that the pairs stay within :data:`_MAX_NEAR_PAIRS`."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        try:
            simplices = ConvexHull(points_c).simplices
        except QhullError:
            simplices = ConvexHull(points_c, qhull_options="QJ").simplices
    except (QhullError, ValueError):
        front, back = points_c[ahead], points_c[~ahead]
        k = math.ceil(math.sqrt(len(front) * len(back) / _MAX_NEAR_PAIRS))
        front, back = front[::k], back[::k]
        return np.repeat(front, len(back), axis=0), np.tile(back, (len(front), 1))
    edges = np.concatenate((simplices[:, [0, 1]], simplices[:, [1, 2]], simplices[:, [2, 0]]))
    edges = edges[ahead[edges[:, 0]] != ahead[edges[:, 1]]]
    first_ahead = ahead[edges[:, 0]]
    p = np.where(first_ahead, edges[:, 0], edges[:, 1])
    q = np.where(first_ahead, edges[:, 1], edges[:, 0])
    return points_c[p], points_c[q]


@functools.lru_cache(maxsize=64)
def fold_radius(distortion: tuple[float, ...]) -> float:
    """The undistorted radius ``r`` (normalised) at which an OpenCV model's distorted
    radius ``r (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)`` stops growing
    (a barrel fold): a point there or beyond projects back inside, onto a point nearer the
    centre. Found on a grid of 1e-4 out to r = 20 (inf when the model grows that far).
    Projecting a point a little past the fold, the undistortion found it again (it converged
    to that root): a tug's hull 2.7-3.1 past a fold at 1.13 was drawn 200 px above the image
    and its outline reached there."""
    k = (list(distortion) + [0.0] * 8)[:8]
    k1, k2, _p1, _p2, k3, k4, k5, k6 = k
    r = np.linspace(0.0, 20.0, 200_001)
    r2 = r * r
    with np.errstate(divide="ignore", invalid="ignore"):
        grown = r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    stops = np.flatnonzero(~(np.diff(grown) > 0))
    return float(r[stops[0]]) if len(stops) else math.inf


def sensor_focal_px(focal_mm: float, sensor_width_mm: float, sensor_height_mm: float,
                    width: int, height: int) -> tuple[float, str]:
    """A lens's focal length in pixels of a ``width`` x ``height`` frame of its sensor, and
    the side (``"width"`` or ``"height"``) the frame spans: the width when the frame is at
    least as wide as the sensor (16:9 video from a 4:3 or 3:2 sensor), else the height (a
    4:3 photo from a 3:2 sensor, a portrait crop): ``f / side_mm · side_px``."""
    if width * sensor_height_mm >= height * sensor_width_mm:
        return focal_mm / sensor_width_mm * width, "width"
    return focal_mm / sensor_height_mm * height, "height"


@dataclass(frozen=True)
class CameraIntrinsics:
    """Image size (px), focal lengths and principal point (px), OpenCV distortion."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = ()

    @classmethod
    def from_sensor(
        cls,
        width: int,
        height: int,
        sensor_width_mm: float,
        sensor_height_mm: float,
        focal_length_mm: float,
        distortion: tuple[float, ...] = (),
    ) -> CameraIntrinsics:
        """``fx = f·width/sensor_width``, ``cx = (width-1)/2``, likewise for y."""
        return cls(
            width=int(width),
            height=int(height),
            fx=focal_length_mm * width / sensor_width_mm,
            fy=focal_length_mm * height / sensor_height_mm,
            cx=(width - 1) / 2.0,
            cy=(height - 1) / 2.0,
            distortion=tuple(distortion),
        )

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(abs(k) > 0.0 for k in self.distortion)

    @property
    def dist_coeffs(self) -> np.ndarray:
        return np.asarray(self.distortion if self.distortion else (0.0,) * 5, dtype=float)

    def to_dict(self) -> dict:
        return {
            "width": self.width, "height": self.height,
            "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
            "distortion": list(self.distortion) if self.distortion else [0.0] * 5,
        }

    def validate(self, source: str | Path | None, prefix: str = "camera") -> None:
        """Raise :class:`InputError` on non-finite or out-of-range values."""
        for name in ("width", "height"):
            value = getattr(self, name)
            if not (isinstance(value, int) and 0 < value <= MAX_IMAGE_SIDE_PX):
                raise InputError(source, f"{prefix}.{name}", "must be a whole number of pixels "
                                 f"from 1 to {MAX_IMAGE_SIDE_PX}, got {brief(value)}")
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(source, f"{prefix}.{name}", f"must be a positive number, got {value!r}")
        for name in ("cx", "cy"):
            value = getattr(self, name)
            if not np.isfinite(value):
                raise InputError(source, f"{prefix}.{name}", f"must be finite, got {value!r}")
        if len(self.distortion) not in VALID_DISTORTION_LENGTHS:
            raise InputError(
                source, f"{prefix}.distortion",
                f"OpenCV takes 4, 5, 8, 12 or 14 coefficients, got {len(self.distortion)}",
            )
        if not all(np.isfinite(self.distortion)):
            raise InputError(source, f"{prefix}.distortion", "coefficients must be finite")


@dataclass(frozen=True)
class Camera:
    """A posed camera: intrinsics plus centre ``position_enu`` and ``R_W<-C``."""

    intrinsics: CameraIntrinsics
    position_enu: np.ndarray
    world_from_camera: np.ndarray = field(repr=False)

    @property
    def camera_from_world(self) -> np.ndarray:
        return self.world_from_camera.T

    def to_camera_frame(self, points_enu: np.ndarray) -> np.ndarray:
        """``X_C = R_C<-W · (X_W - c_W)`` for points of shape ``(N, 3)``."""
        return (np.asarray(points_enu, float) - self.position_enu) @ self.world_from_camera

    def project(self, points_enu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project ENU points ``(N, 3)`` to pixels ``(N, 2)``.

        Returns ``(uv, in_front)``; points at or behind the camera plane get NaN pixels.
        So do points beyond the radius where a strongly barrel-distorted model stops growing
        (``r·(1 + k1·r² + ...)`` turns back): ``cv2.projectPoints`` folds them back into the
        image, so a projection whose undistortion does not return the point is refused.
        """
        pts_c = self.to_camera_frame(np.atleast_2d(points_enu))
        in_front = pts_c[:, 2] > 1e-9
        uv = np.full((len(pts_c), 2), np.nan)
        if not np.any(in_front):
            return uv, in_front
        front = pts_c[in_front]
        intr = self.intrinsics
        if intr.has_distortion:
            projected, _ = cv2.projectPoints(
                front.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), intr.K, intr.dist_coeffs
            )
            projected = projected.reshape(-1, 2)
            ideal = front[:, :2] / front[:, 2:3]
            recovered = self._undistorted(projected)
            with np.errstate(invalid="ignore"):
                folded = ~(np.hypot(*(recovered - ideal).T)
                           <= 1e-6 * (1.0 + np.hypot(*ideal.T)))
            # the undistortion can land back on a point past the fold (another root of
            # the model): that the model still grows there is checked on its own
            folded |= np.hypot(*ideal.T) >= fold_radius(intr.distortion)
            projected[folded] = np.nan
            uv[in_front] = projected
            in_front[np.flatnonzero(in_front)[folded]] = False
        else:
            uv[in_front, 0] = intr.fx * front[:, 0] / front[:, 2] + intr.cx
            uv[in_front, 1] = intr.fy * front[:, 1] / front[:, 2] + intr.cy
        return uv, in_front

    def project_convex_outline(self, points_enu: np.ndarray, max_step_px: float = 4.0) -> np.ndarray:
        """Pixels ``(M, 2)`` along the image outline of the convex hull of ``points_enu``.

        A pinhole maps the solid's convex hull to the 2-D convex hull of its projected
        vertices, so without distortion that polygon's corners are returned. Lens distortion
        then bends each straight edge (barrel: outward, by up to several px near the image
        corners for ``k1 ≈ -0.25``), so the hull of the projected corners alone would cut
        the curve. The edges are therefore cut, in undistorted normalised coordinates
        ``(x/z, y/z)``, into steps of at most ``max_step_px`` before distorting, and the
        convex hull of the result follows a barrel-bent edge: the chord of a step ``s`` on a
        curve of radius ``R`` falls ``s^2 / 8R`` short, 0.004 px for 4 px steps on a box
        near the corner of a 90-degree lens with ``k1 = -0.2`` (0.0002 px for 1 px steps, at
        four times the cost; 0.055 px for 16 px).
        Points at or behind the camera plane, and points past a fold, are left out.
        """
        return self.project_convex_outlines([points_enu], max_step_px)[0]

    def project_convex_outlines(self, point_sets: list[np.ndarray], max_step_px: float = 4.0
                                ) -> list[np.ndarray]:
        """:meth:`project_convex_outline` of several point sets (a vessel's layers) at once:
        one projection for all of them, the edges of every set's hull cut into steps
        together."""
        # each set's part in front of the camera (a mast above a low drone reaches behind it)
        sets_c = [_ahead_of_camera(self.to_camera_frame(np.atleast_2d(points)))
                  for points in point_sets]
        if not self.intrinsics.has_distortion:
            sizes = [len(pts_c) for pts_c in sets_c]
            every_c = np.vstack(sets_c) if sets_c else np.zeros((0, 3))
            uv, front = self.project(every_c @ self.world_from_camera.T + self.position_enu)
            return [self._within_reach(u[f]) for u, f in zip(
                np.split(uv, np.cumsum(sizes)[:-1]), np.split(front, np.cumsum(sizes)[:-1]),
                strict=True)]
        step = max_step_px / max(self.intrinsics.fx, self.intrinsics.fy)
        corners, following, owner = [], [], []
        for k, pts_c in enumerate(sets_c):
            pts_c = pts_c[pts_c[:, 2] > 1e-9]
            if len(pts_c) == 0:
                continue
            ideal = pts_c[:, :2] / pts_c[:, 2:3]
            if len(ideal) >= 3:
                ideal = ideal[cv2.convexHull(ideal.astype(np.float32), returnPoints=False).reshape(-1)]
            corners.append(ideal)
            following.append(np.concatenate((ideal[1:], ideal[:1])))
            owner.append(np.full(len(ideal), k))
        out = [np.zeros((0, 2)) for _ in point_sets]
        if not corners:
            return out
        corners, following, owner = np.vstack(corners), np.vstack(following), np.concatenate(owner)
        n_steps = np.clip(np.ceil(np.hypot(*(following - corners).T) / step), 1,
                          _MAX_STEPS_PER_EDGE).astype(int)
        edge = np.repeat(np.arange(len(corners)), n_steps)
        t = np.arange(len(edge)) - np.repeat(np.cumsum(n_steps) - n_steps, n_steps)
        t = (t / n_steps[edge])[:, None]
        dense = corners[edge] * (1.0 - t) + following[edge] * t
        uv, front = self._project_ideal(dense)
        dense_owner = owner[edge]
        # where an outline leaves the lens model (past a barrel fold), the steps would stop up
        # to a step short of the edge of what projects: bisect each such step to its end
        following_sample = np.concatenate((np.arange(1, len(dense)), [0]))
        first_of_set = np.r_[0, np.flatnonzero(np.diff(dense_owner)) + 1]
        last_of_set = np.r_[first_of_set[1:], len(dense)] - 1
        following_sample[last_of_set] = first_of_set           # each set's outline is closed
        change = np.flatnonzero(front != front[following_sample])
        if len(change):
            inside = np.where(front[change, None], dense[change], dense[following_sample[change]])
            outside = np.where(front[change, None], dense[following_sample[change]], dense[change])
            for _ in range(_FOLD_BISECTIONS):
                middle = 0.5 * (inside + outside)
                _, ok = self._project_ideal(middle)
                inside[ok], outside[~ok] = middle[ok], middle[~ok]
            end_uv, end_ok = self._project_ideal(inside)
            uv = np.vstack((uv, end_uv))
            front = np.concatenate((front, end_ok))
            dense_owner = np.concatenate((dense_owner, dense_owner[change]))
        for k in np.unique(dense_owner):
            mine = (dense_owner == k) & front
            out[k] = self._within_reach(uv[mine])
        return out

    def _within_reach(self, uv: np.ndarray) -> np.ndarray:
        """Pixels of a convex outline, its hull clipped to the image grown by four times its
        size on every side where it reaches farther (a part just in front of the camera
        projects millions of pixels out): the image's part of it is the same."""
        intr = self.intrinsics
        w, h = intr.width, intr.height
        if len(uv) < 3 or ((uv > [-4 * w, -4 * h]) & (uv < [5 * w, 5 * h])).all():
            return uv
        hull = uv[cv2.convexHull(uv.astype(np.float32), returnPoints=False).reshape(-1)]
        return clip_to_box(hull, -4.0 * w, -4.0 * h, 5.0 * w, 5.0 * h)

    def _project_ideal(self, ideal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`project` of the rays through undistorted normalised coordinates ``(N, 2)``."""
        rays_c = np.column_stack((ideal, np.ones(len(ideal))))
        return self.project(rays_c @ self.world_from_camera.T + self.position_enu)

    def _undistorted(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates of pixels ``(N, 2)``: OpenCV's fixed-point
        iteration, then Newton steps on ``K · distort(x, y) = uv``.

        The fixed-point iteration contracts by roughly ``1 - r_d'(r)`` per step, so near a
        barrel model's fold (``r_d' → 0``) it crawls: with ``k1 = -0.2`` a point 3 % inside
        the fold is still 1e-3 (0.4 px) off after 40 steps. Newton's step
        ``δ = J⁻¹ (uv - K · distort(x, y))`` uses the 2x2 Jacobian that ``cv2.projectPoints``
        gives for the translation (a shift of the point ``(x, y, 1)`` is a shift of ``(x, y)``);
        a step that does not reduce the residual is not taken.
        """
        intr = self.intrinsics
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
        xy = cv2.undistortPointsIter(
            uv.reshape(-1, 1, 2), intr.K, intr.dist_coeffs, None, None, criteria
        ).reshape(-1, 2).astype(float)
        projected, _ = cv2.projectPoints(np.column_stack((xy, np.ones(len(xy)))).reshape(-1, 1, 3),
                                         np.zeros(3), np.zeros(3), intr.K, intr.dist_coeffs)
        with np.errstate(invalid="ignore"):
            slow = np.isfinite(xy).all(axis=1) & ~(
                np.abs(projected.reshape(-1, 2) - uv).max(axis=1) <= _NEWTON_SKIP_PX)
        if slow.any():
            xy[slow] = self._newton_polished(xy[slow], uv[slow])
        return xy

    def _newton_polished(self, xy: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Newton steps on ``K · distort(x, y) = uv`` from ``xy``; see :meth:`_undistorted`."""
        residual_px, jacobian = self._distortion_residual(xy, uv)
        for _ in range(_NEWTON_STEPS):
            a, b, c, d = jacobian[:, 0, 0], jacobian[:, 0, 1], jacobian[:, 1, 0], jacobian[:, 1, 1]
            with np.errstate(divide="ignore", invalid="ignore"):
                det = a * d - b * c
                step = np.column_stack((d * residual_px[:, 0] - b * residual_px[:, 1],
                                        a * residual_px[:, 1] - c * residual_px[:, 0])) / det[:, None]
            trial = xy - np.where(np.isfinite(step), step, 0.0)
            trial_residual, trial_jacobian = self._distortion_residual(trial, uv)
            with np.errstate(invalid="ignore"):
                better = (np.hypot(*trial_residual.T) < np.hypot(*residual_px.T))
            if not better.any():
                break
            xy[better] = trial[better]
            residual_px[better] = trial_residual[better]
            jacobian[better] = trial_jacobian[better]
        return xy

    def _distortion_residual(self, xy: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``K · distort(x, y) - uv`` ``(N, 2)`` and its Jacobian by ``(x, y)`` ``(N, 2, 2)``."""
        intr = self.intrinsics
        rays = np.column_stack((xy, np.ones(len(xy)))).reshape(-1, 1, 3)
        projected, jacobian = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), intr.K,
                                                intr.dist_coeffs)
        residual = projected.reshape(-1, 2) - uv
        # columns 3:6 of OpenCV's Jacobian are d(u, v)/d(tvec); rows alternate u, v
        return residual, jacobian[:, 3:5].reshape(-1, 2, 2)

    def normalized_coordinates(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalised image coordinates ``(x, y)`` of pixels ``(N, 2)``; NaN for
        a pixel the distortion model cannot invert (beyond a strongly barrel-distorted
        model's fold, the iteration stops at a point that does not project back to it)."""
        uv = np.atleast_2d(np.asarray(uv, float))
        intr = self.intrinsics
        if len(uv) == 0:
            return np.zeros((0, 2))
        if intr.has_distortion:
            xy = self._undistorted(uv)
            back, _ = cv2.projectPoints(np.column_stack((xy, np.ones(len(xy)))).reshape(-1, 1, 3),
                                        np.zeros(3), np.zeros(3), intr.K, intr.dist_coeffs)
            with np.errstate(invalid="ignore"):
                xy[~(np.hypot(*(back.reshape(-1, 2) - uv).T) <= 0.01)] = np.nan
            return xy
        return np.column_stack(((uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy))

    def plane_homography(self, plane_z_m: float = 0.0) -> np.ndarray:
        """3x3 ``H`` mapping undistorted normalised coordinates ``m = (x, y, 1)`` to the
        homogeneous point where the ray meets the plane ``z = z_p``.

        With ``r_i`` the rows of ``R_W<-C`` and ``c`` the camera centre, the ray
        ``c + t · R m`` meets the plane at ``t = (z_p - c_z) / (r_3 · m)``, so

            (X, Y) = (c_x·(r_3·m) + (z_p - c_z)·(r_1·m),  c_y·(r_3·m) + (z_p - c_z)·(r_2·m)) / (r_3·m)

        i.e. ``H = [c_x r_3 + (z_p - c_z) r_1; c_y r_3 + (z_p - c_z) r_2; r_3]``. The hit is
        in front of the camera when ``(z_p - c_z) / (r_3 · m) > 0``.
        """
        R = self.world_from_camera
        c = self.position_enu
        dz = plane_z_m - c[2]
        return np.vstack((c[0] * R[2] + dz * R[0], c[1] * R[2] + dz * R[1], R[2]))

    def pixels_to_plane_xy(
        self, uv: np.ndarray, plane_z_m: float = 0.0, post: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Plane coordinates ``(N, 2)`` of pixels, optionally mapped by a 3x3 ``post``
        (e.g. world -> vessel frame); returns ``(xy, valid)``, NaN where invalid."""
        m = self.normalized_coordinates(uv)
        H = self.plane_homography(plane_z_m)
        # the unmapped homography's last row is the ray's vertical component r_3 · m
        down = m[:, 0] * H[2, 0] + m[:, 1] * H[2, 1] + H[2, 2]
        if post is not None:
            H = post @ H
        dz = plane_z_m - self.position_enu[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            valid = np.isfinite(down) & (dz / down > 0)
            w = m[:, 0] * H[2, 0] + m[:, 1] * H[2, 1] + H[2, 2]
            xy = np.column_stack((m[:, 0] * H[0, 0] + m[:, 1] * H[0, 1] + H[0, 2],
                                  m[:, 0] * H[1, 0] + m[:, 1] * H[1, 1] + H[1, 2])) / w[:, None]
        xy[~valid] = np.nan
        return xy, valid

    def back_project_to_plane(
        self, uv: np.ndarray, plane_z_m: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Intersect pixel rays with the horizontal plane ``z = plane_z_m``.

        Returns ``(points_enu (N, 3), valid (N,))``; rays that point at or above the
        horizon (no intersection in front of the camera) are invalid and NaN.
        """
        xy, valid = self.pixels_to_plane_xy(uv, plane_z_m)
        points = np.column_stack((xy, np.full(len(xy), float(plane_z_m))))
        points[~valid] = np.nan
        return points, valid

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """True where a pixel lies inside the image (pixel centres at integers)."""
        uv = np.atleast_2d(uv)
        w, h = self.intrinsics.width, self.intrinsics.height
        with np.errstate(invalid="ignore"):
            return (
                np.isfinite(uv).all(axis=1)
                & (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5)
                & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5)
            )


def image_border_px(width: int, height: int, per_side: int) -> np.ndarray:
    """``4 · per_side`` pixel centres evenly along the image's border, in order round it
    from the top-left corner (clockwise on screen), ``(N, 2)``."""
    w, h = width - 1.0, height - 1.0
    t = np.linspace(0.0, 1.0, per_side, endpoint=False)
    return np.vstack((
        np.column_stack((t * w, np.zeros_like(t))),
        np.column_stack((np.full_like(t, w), t * h)),
        np.column_stack((w - t * w, np.full_like(t, h))),
        np.column_stack((np.zeros_like(t), h - t * h)),
    ))


#: pixels on the image's border tested for a ray before the whole image is (the fold's edge
#: is looked for only where some of them have none)
_FOLD_BORDER_SAMPLES = 256
#: the image is tested for rays on a grid of about this many columns (its longer side's)
_FOLD_GRID_COLUMNS = 320


@functools.lru_cache(maxsize=16)
def ray_edge_px(intrinsics: CameraIntrinsics) -> np.ndarray | None:
    """The edge of the image's pixels that have a ray, as a closed loop of pixels
    ``(N, 2)`` in order (read-only), or None when every pixel on the image's border has one
    (the border is then that edge, as without distortion).

    A barrel model's fold (:func:`fold_radius`) inside the image leaves the pixels past it
    without a ray (:meth:`Camera.normalized_coordinates` gives NaN): what the frame shows of
    the water ends at the fold's edge there, not at the image's border. With tangential
    coefficients that edge is not the image of one circle (up to 27 and 124 px from it on two
    such lenses), so it is found from the pixels themselves: a grid every ``s`` pixels
    (:data:`_FOLD_GRID_COLUMNS` across the longer side; 2 px at 640 wide) is tested, and the
    outer contour of its largest region with rays, in pixels, is the loop. Its points are
    pixels with a ray, within ``s`` of the edge on its inside: what was seen is taken short
    by at most that, never long. Made once per set of intrinsics (0.1 s at 640x360)."""
    if not intrinsics.has_distortion or not math.isfinite(fold_radius(intrinsics.distortion)):
        return None
    w, h = intrinsics.width, intrinsics.height
    camera = Camera(intrinsics, np.zeros(3), np.eye(3))
    border = image_border_px(w, h, _FOLD_BORDER_SAMPLES // 4)
    if np.isfinite(camera.normalized_coordinates(border)).all():
        return None
    step = max(2.0, math.ceil(max(w, h) / _FOLD_GRID_COLUMNS))
    us = np.unique(np.append(np.arange(0.0, w, step), w - 1.0))
    vs = np.unique(np.append(np.arange(0.0, h, step), h - 1.0))
    grid = np.column_stack((np.tile(us, len(vs)), np.repeat(vs, len(us))))
    has_ray = np.isfinite(camera.normalized_coordinates(grid)).all(axis=1).reshape(len(vs), len(us))
    # padded, so that a region reaching the border is closed along it
    contours, _ = cv2.findContours(np.pad(has_ray.astype(np.uint8), 1), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    if not contours:
        loop = np.zeros((0, 2))
    else:
        cells = max(contours, key=cv2.contourArea).reshape(-1, 2) - 1
        loop = np.column_stack((us[cells[:, 0]], vs[cells[:, 1]]))
    loop.flags.writeable = False
    return loop

