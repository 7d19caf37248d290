"""Pose refinement: move the projected vessel onto its own ship pixels.

Real sensors misplace the vessel in the image: standalone GPS on the drone and on the
vessel is off by 1-3 m each, a compass by 1-3 degrees. The vessel is visible, so its pose
can be corrected from the label mask.

**Model.** A correction ``p = (de, dn, dpsi)`` of the vessel's pose in the frame's local
ENU: the antenna moves by ``(de, dn)`` metres and the heading turns by ``dpsi`` about the
antenna. It absorbs the horizontal errors of both receivers and the yaw errors of both
compasses (a yaw error of a nadir camera turns the whole scene, which keeps the distances
between the hull and what surrounds it). The drone's height is not refined.

**Objective.** The vessel's image silhouette is the convex hull of its projected hull
points (as for the own-vessel region). ``N`` points are sampled along that outline, and
each should lie on the boundary of the mask's ship pixels. With the signed distance
``s(u, v)`` to that boundary (positive outside ship pixels) the MAP estimate is

    p* = argmin  sum_i rho(s(x_i(p))) / sigma_e^2  +  p^T diag(sigma_p)^-2 p

with a robust ``rho`` (Huber, then Tukey's biweight) so that a touching neighbour, a
partly wrong mask or a mooring line do not pull the outline, and a Gaussian prior from the
sensors' accuracy. Gauss-Newton on iteratively re-weighted least squares; the Jacobian
``ds/dp = grad s · dx/dp`` comes from the bilinear gradient of ``s`` and finite differences
of the projection (exact for any lens model). Outline points outside the image, or within
a pixel of its border, are left out: a hull partly out of view is aligned on what is seen.

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
silhouette short, graduated Tukey from the sensors' pose and from the prior's reach to
either side across the hull, and the lowest final Tukey cost among the filled candidates
wins.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from harborsight.clearance.obstacles import IGNORE, SHIP
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
    edge_sigma_px: float = 1.0
    #: a correction larger than this is refused (4 sigma of the default prior)
    max_shift_m: float = 12.0
    max_rotation_deg: float = 12.0
    min_inlier_fraction: float = 0.5
    #: share of the silhouette's pixels in view that must be ship pixels: a rigid outline can
    #: fit straight edges of the wrong blobs, but then it covers water or a quay
    min_ship_fill: float = 0.9
    max_residual_px: float = 1.5

    def __post_init__(self) -> None:
        for name in ("prior_shift_m", "prior_heading_deg", "edge_sigma_px", "max_shift_m",
                     "max_rotation_deg", "max_residual_px"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value}")
        for name in ("min_inlier_fraction", "min_ship_fill"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")


@dataclass(frozen=True)
class PoseRefinement:
    """What the alignment found. ``shift_m``/``rotation_deg`` are the correction it found
    (also when not applied); ``covariance`` is its 3x3 posterior covariance in (m, m, rad)."""

    applied: bool
    shift_m: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0
    residual_px: float | None = None
    inlier_fraction: float | None = None
    inlier_fraction_before: float | None = None
    edge_points: int = 0
    ship_fill: float | None = None
    reason: str | None = None
    covariance: np.ndarray | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        def rounded(value: float | None, digits: int) -> float | None:
            return None if value is None else round(float(value), digits)

        return {
            "applied": self.applied,
            "shift_m": [round(float(v), 3) for v in self.shift_m],
            "rotation_deg": round(float(self.rotation_deg), 3),
            "residual_px": rounded(self.residual_px, 3),
            "inlier_fraction": rounded(self.inlier_fraction, 3),
            "inlier_fraction_before": rounded(self.inlier_fraction_before, 3),
            "edge_points": self.edge_points,
            "ship_fill": rounded(self.ship_fill, 3),
            "reason": self.reason,
        }


OFF = PoseRefinement(applied=False, reason="off")


def corrected_geometry(geometry: FrameGeometry, params: np.ndarray) -> FrameGeometry:
    """The frame's geometry with the vessel moved by ``(de, dn)`` m and turned by ``dpsi`` rad."""
    return replace(geometry, vessel_position_enu=geometry.vessel_position_enu + params[:2],
                   vessel_heading_rad=geometry.vessel_heading_rad + float(params[2]))


class _SignedDistance:
    """Signed distance (px) to the boundary of the ship pixels in a window of the mask,
    positive outside them; the boundary lies on pixel edges, so neighbours across it read
    +0.5 and -0.5. One distance transform (5x5 mask, within 2 % of Euclidean) from the
    pixels on either side of the boundary, signed by the mask. Sampled bilinearly with its
    gradient."""

    def __init__(self, ship: np.ndarray, top_left: tuple[int, int]) -> None:
        inside = ship.astype(np.uint8)
        kernel = np.ones((3, 3), np.uint8)
        edge = cv2.dilate(inside, kernel) != cv2.erode(inside, kernel)
        to_edge = cv2.distanceTransform((~edge).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
        self.field = np.where(inside > 0, -0.5 - to_edge, 0.5 + to_edge).astype(np.float64)
        self.u0, self.v0 = top_left

    def sample(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(value, gradient (N, 2), valid)`` at pixel positions ``uv`` (image coordinates)."""
        h, w = self.field.shape
        x = uv[:, 0] - self.u0
        y = uv[:, 1] - self.v0
        valid = np.isfinite(x) & np.isfinite(y) & (x >= 0) & (y >= 0) & (x < w - 1) & (y < h - 1)
        x0 = np.where(valid, np.floor(np.where(valid, x, 0)), 0).astype(int)
        y0 = np.where(valid, np.floor(np.where(valid, y, 0)), 0).astype(int)
        fx = np.where(valid, x - x0, 0.0)
        fy = np.where(valid, y - y0, 0.0)
        f = self.field
        x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
        v00, v10, v01, v11 = f[y0, x0], f[y0, x1], f[y1, x0], f[y1, x1]
        value = (v00 * (1 - fx) * (1 - fy) + v10 * fx * (1 - fy) + v01 * (1 - fx) * fy
                 + v11 * fx * fy)
        grad = np.column_stack(((v10 - v00) * (1 - fy) + (v11 - v01) * fy,
                                (v01 - v00) * (1 - fx) + (v11 - v10) * fx))
        return value, grad, valid


class _Outline:
    """Points along the silhouette outline, as fixed blends of two hull points each, so
    that they can be projected again under a changed pose."""

    def __init__(self, vessel: VesselSpec, geometry: FrameGeometry) -> None:
        points = vessel.hull_points
        uv, front = geometry.camera.project(geometry.vessel_to_enu(points))
        keep = np.flatnonzero(front & np.isfinite(uv).all(axis=1))
        self.points_v = np.zeros((0, 3))
        if len(keep) < 3:
            return
        corner = keep[cv2.convexHull(uv[keep].astype(np.float32), returnPoints=False).reshape(-1)]
        following = np.roll(corner, -1)
        lengths = np.hypot(*(uv[following] - uv[corner]).T)
        steps = np.clip(np.ceil(lengths / SAMPLE_STEP_PX), 1, 2000).astype(int)
        t = np.concatenate([np.arange(n) / n for n in steps])
        a = np.repeat(corner, steps)
        b = np.repeat(following, steps)
        p3 = points if points.shape[1] == 3 else np.column_stack((points, np.zeros(len(points))))
        self.points_v = (1 - t)[:, None] * p3[a] + t[:, None] * p3[b]

    def project(self, geometry: FrameGeometry) -> np.ndarray:
        return geometry.camera.project(geometry.vessel_to_enu(self.points_v))[0]


def _project_with_jacobian(geometry: FrameGeometry, points_v: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of vessel-frame points and their derivatives ``d(u, v)/d(de, dn, dpsi)``
    ``(N, 2, 3)``. OpenCV gives ``d(u, v)/dX_C`` with the lens model (its Jacobian with
    respect to the translation), ``dX_C/dX_W = R_C<-W``, and for the pose
    ``X_W = R(h) X_V + (e, n, 0)``: ``dX_W/d(de, dn) = I``, ``dX_W/dh = R'(h) X_V`` with
    ``R'(h) X_V = (x cos h - y sin h, -x sin h - y cos h, 0)``."""
    camera = geometry.camera
    intr = camera.intrinsics
    points_c = camera.to_camera_frame(geometry.vessel_to_enu(points_v))
    if intr.has_distortion:
        uv, jac = cv2.projectPoints(points_c.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), intr.K,
                                    intr.dist_coeffs)
        uv = uv.reshape(-1, 2)
        duv_dc = jac[:, 3:6].reshape(-1, 2, 3)
    else:   # pinhole: u = fx x/z + cx, v = fy y/z + cy
        x, y, z = points_c.T
        inv_z = 1.0 / np.where(np.abs(z) > 1e-9, z, 1e-9)
        uv = np.column_stack((intr.fx * x * inv_z + intr.cx, intr.fy * y * inv_z + intr.cy))
        duv_dc = np.zeros((len(points_c), 2, 3))
        duv_dc[:, 0, 0] = intr.fx * inv_z
        duv_dc[:, 0, 2] = -intr.fx * x * inv_z ** 2
        duv_dc[:, 1, 1] = intr.fy * inv_z
        duv_dc[:, 1, 2] = -intr.fy * y * inv_z ** 2
    uv[points_c[:, 2] <= 1e-9] = np.nan
    duv_dw = duv_dc @ camera.camera_from_world
    h = geometry.vessel_heading_rad
    s, c = math.sin(h), math.cos(h)
    x, y = points_v[:, 0], points_v[:, 1]
    dw_dp = np.zeros((len(points_v), 3, 3))
    dw_dp[:, 0, 0] = dw_dp[:, 1, 1] = 1.0
    dw_dp[:, 0, 2] = x * c - y * s
    dw_dp[:, 1, 2] = -x * s - y * c
    return uv, duv_dw @ dw_dp


def _in_view(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    ok = np.isfinite(uv).all(axis=1)
    u, v = np.where(ok, uv[:, 0], -1.0), np.where(ok, uv[:, 1], -1.0)
    return ok & (u >= BORDER_PX) & (v >= BORDER_PX) & (u <= width - 1 - BORDER_PX) & (
        v <= height - 1 - BORDER_PX)


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


def _ship_fill(geometry: FrameGeometry, vessel: VesselSpec, window: tuple[slice, slice],
               ship: np.ndarray, known: np.ndarray) -> float:
    """Share of the silhouette's labelled pixels inside ``window`` that are ship pixels."""
    uv = geometry.camera.project(geometry.vessel_to_enu(vessel.hull_points))[0]
    uv = uv[np.isfinite(uv).all(axis=1)]      # the corners' hull: close enough for a share
    if len(uv) < 3:
        return 0.0
    offset = np.array([window[1].start, window[0].start])
    corners = cv2.convexHull(np.round((uv - offset) * 16).astype(np.int32))
    inside = np.zeros(ship.shape, np.uint8)
    cv2.fillConvexPoly(inside, corners, 1, lineType=cv2.LINE_8, shift=4)
    counted = (inside > 0) & known
    total = int(counted.sum())
    return float((ship & counted).sum()) / total if total else 0.0


def _weights(residual: np.ndarray, loss: str, scale_px: float) -> np.ndarray:
    """IRLS weights of the Huber or Tukey biweight loss."""
    a = np.abs(residual)
    if loss == "huber":
        return np.where(a <= scale_px, 1.0, scale_px / np.maximum(a, 1e-12))
    return np.where(a < scale_px, (1 - (a / scale_px) ** 2) ** 2, 0.0)


def _tukey_cost(residual: np.ndarray, scale_px: float) -> np.ndarray:
    """Tukey's biweight: ``c²/6 (1 - (1 - (r/c)²)³)`` inside ``c``, ``c²/6`` beyond."""
    inside = np.minimum(np.abs(residual) / scale_px, 1.0)
    return scale_px ** 2 / 6 * (1 - (1 - inside ** 2) ** 3)


def _fit(value: np.ndarray, valid: np.ndarray) -> tuple[float, float | None, int]:
    """``(inlier fraction, RMS of the inliers px, points that can tell)`` of an outline:
    points in view and not deep inside ship pixels (:data:`DEEP_PX`)."""
    telling = value[valid & (value > -DEEP_PX)]
    if not len(telling):
        return 0.0, None, 0
    inlier = np.abs(telling) <= INLIER_PX
    rms = float(np.sqrt(np.mean(telling[inlier] ** 2))) if inlier.any() else None
    return float(inlier.mean()), rms, len(telling)


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
    intr = geometry.camera.intrinsics
    outline = _Outline(vessel, geometry)
    if len(outline.points_v) == 0:
        return geometry, PoseRefinement(False, reason="the hull does not project into the image")
    uv0 = outline.project(geometry)
    window = _search_window(uv0, geometry, vessel, settings, labels.shape)
    if window is None:
        return geometry, PoseRefinement(False, reason="the hull is not in the image")
    ship = labels[window] == SHIP
    if not ship.any():
        return geometry, PoseRefinement(False, reason="no ship pixels near the projected hull")
    if ship.all():
        return geometry, PoseRefinement(False, reason="only ship pixels around the projected hull")
    sdf = _SignedDistance(ship, (window[1].start, window[0].start))

    def residuals(params: np.ndarray, points: _Outline) -> tuple[np.ndarray, np.ndarray]:
        uv = points.project(corrected_geometry(geometry, params))
        value, _, valid = sdf.sample(uv)
        return value, valid & _in_view(uv, intr.width, intr.height)

    before, before_rms_px, _ = _fit(*residuals(np.zeros(3), outline))

    prior_sigma = np.array([settings.prior_shift_m, settings.prior_shift_m,
                            math.radians(settings.prior_heading_deg)])
    prior_information = np.diag(prior_sigma ** -2.0)

    def solve(schedule, start: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Gauss-Newton IRLS through ``schedule`` from ``start``: ``(params, information,
        final cost)``."""
        params, information = start.astype(float), prior_information
        for stage, (loss, scale_px, iterations) in enumerate(schedule):
            tolerance_m = 1e-3 if stage == len(schedule) - 1 else 1e-2
            points = _Outline(vessel, corrected_geometry(geometry, params))  # corners move
            n = len(points.points_v)
            if n == 0:
                return params, information, np.inf
            for _ in range(iterations):
                current = corrected_geometry(geometry, params)
                uv, duv_dp = _project_with_jacobian(current, points.points_v)
                value, grad, valid = sdf.sample(uv)
                valid &= _in_view(uv, intr.width, intr.height)
                if valid.sum() < MIN_EDGE_POINTS:
                    return params, information, np.inf
                jac = np.einsum("ij,ijk->ik", grad, duv_dp)
                r, J = value[valid], jac[valid]
                w = _weights(r, loss, scale_px) / settings.edge_sigma_px ** 2
                information = J.T @ (w[:, None] * J) + prior_information
                gradient = J.T @ (w * r) + prior_information @ params
                try:
                    delta = -np.linalg.solve(information, gradient)
                except np.linalg.LinAlgError:
                    return params, information, np.inf
                if not np.isfinite(delta).all():
                    return params, information, np.inf
                params = params + delta
                if np.hypot(delta[0], delta[1]) < tolerance_m and abs(delta[2]) < tolerance_m / 50:
                    break
        # final cost: Tukey over the whole outline (points out of view count as outliers)
        value, valid = residuals(params, outline)
        cost = np.where(valid, _tukey_cost(np.where(valid, value, 0.0), _FINAL_TUKEY_PX),
                        _FINAL_TUKEY_PX ** 2 / 6).sum() / settings.edge_sigma_px ** 2
        return params, information, float(cost + params @ prior_information @ params)

    known = labels[window] != IGNORE

    def fill(params: np.ndarray) -> float:
        return _ship_fill(corrected_geometry(geometry, params), vessel, window, ship, known)

    # the first start; when it leaves the outline or the silhouette short of ship pixels,
    # the second schedule from the sensors' pose and from a beam's reach to either side
    first = solve(SCHEDULES[0], np.zeros(3))
    candidates = [(*first, fill(first[0]))]        # (params, information, cost, fill)
    if (_fit(*residuals(first[0], outline))[0] < SKIP_SECOND_START_FRACTION
            or candidates[0][3] < settings.min_ship_fill):
        h = geometry.vessel_heading_rad
        across = np.array([math.cos(h), -math.sin(h), 0.0]) * settings.prior_shift_m
        for start in (np.zeros(3), across, -across):
            found = solve(SCHEDULES[1], start)
            candidates.append((*found, fill(found[0])))
    full = [c for c in candidates if c[3] >= settings.min_ship_fill]
    params, information, _, ship_fill = min(full or candidates, key=lambda c: c[2])

    fraction, residual_px, n_edge = _fit(*residuals(params, outline))
    shift = (float(params[0]), float(params[1]))
    rotation_deg = math.degrees(float(params[2]))
    if n_edge < MIN_EDGE_POINTS:
        return geometry, PoseRefinement(
            False, shift, rotation_deg, edge_points=n_edge, inlier_fraction_before=before,
            reason=f"only {n_edge} outline points in view where the mask can tell "
                   f"(at least {MIN_EDGE_POINTS} needed)")
    try:
        covariance = np.linalg.inv(information)
    except np.linalg.LinAlgError:
        covariance = None
    found = PoseRefinement(False, shift, rotation_deg, residual_px, fraction, before, n_edge,
                           ship_fill=ship_fill, covariance=covariance)
    reason = None
    if not np.isfinite(params).all():
        reason = "the alignment diverged"
    elif math.hypot(*shift) > settings.max_shift_m:
        reason = f"shift {math.hypot(*shift):.1f} m beyond {settings.max_shift_m:g} m"
    elif abs(rotation_deg) > settings.max_rotation_deg:
        reason = f"rotation {rotation_deg:.1f} deg beyond {settings.max_rotation_deg:g} deg"
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
        return geometry, replace(found, reason=reason)
    return corrected_geometry(geometry, params), replace(found, applied=True)


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
