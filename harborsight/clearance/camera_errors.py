"""Whether one error of the camera's attitude explains where the image puts the hull.

The whole-image search (:mod:`harborsight.clearance.pose_search`) finds the hull somewhere
the sensors did not put it, as a correction ``(de, dn, dpsi, dh)`` of the vessel's position
and heading and of the camera's height. One sensor error moves several of those at once
when it is the camera's: a yaw turns the whole scene about the camera's vertical, a tilt
slides it and changes its scale. Counted component by component, such a placement looks
like two gross errors at once, which the refinement takes for a bad mask; these tests say
when it is one.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from harborsight.clearance.alignment import (
    SCHEDULES,
    Alignment,
    SignedDistance,
    Silhouette,
    corrected_geometry,
    gauss_newton,
    outline_fit,
)
from harborsight.clearance.pose_search import edge_share
from harborsight.frame import FrameGeometry
from harborsight.geometry.camera import Camera
from harborsight.geometry.rotations import rot_x, rot_y

#: a tilt (deg) this small is no gross error: the refinement's prior takes it as a shift
MIN_TILT_DEG = 2.0
#: Gauss-Newton iterations of the tilt's fit, and the step (rad, m) of its numeric Jacobian
_TILT_ITERATIONS = 12
_STEP = 1e-5


def camera_yaw_explains(params: np.ndarray, geometry: FrameGeometry, tolerance_m: float) -> bool:
    """Whether a correction's shift and turn are one error of the camera's yaw: that turns
    the whole scene about the vertical through the camera, so the vessel's antenna ``A``
    moves about the camera's ground point ``C`` by the turn, ``phi = -dpsi`` counter-clockwise
    in ENU (a compass heading turns the other way), to ``C + R(phi) (A - C)``. True when the
    shift is that motion within ``tolerance_m`` (the GPS errors' reach). On the sample frames
    a camera yaw 30-180 degrees off gave placements within 0.04 m of it."""
    phi = -float(params[2])
    offset = (np.asarray(geometry.vessel_position_enu[:2], float)
              - np.asarray(geometry.camera.position_enu[:2], float))
    turned = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]]) @ offset
    return bool(np.hypot(*(np.asarray(params[:2], float) - (turned - offset))) <= tolerance_m)


def _tilted(camera: Camera, east_rad: float, north_rad: float) -> Camera:
    """The camera turned about the world's east, then north axis through its centre."""
    return Camera(camera.intrinsics, camera.position_enu,
                  rot_y(north_rad) @ rot_x(east_rad) @ camera.world_from_camera)


def _tilt_start(params: np.ndarray, geometry: FrameGeometry, hull_points_v: np.ndarray,
                prior_sigma: np.ndarray) -> np.ndarray | None:
    """``(δ_east, δ_north, dpsi, dh)``: the tilt (rad), with a turn and a height held to their
    priors (``prior_sigma[2:]``), that puts the hull at the sensors' position (no shift)
    where the correction ``params`` puts it with the camera as given: a damped
    Gauss-Newton on the pixels of the hull's points in view, numeric Jacobian. Without a
    shift to trade against, the tilt is well determined. None when under 3 points are in
    view or a projection fails."""
    placed = corrected_geometry(geometry, np.asarray(params, float))
    target, _ = placed.camera.project(placed.vessel_to_enu(hull_points_v))
    intr = geometry.camera.intrinsics
    seen = (np.isfinite(target).all(axis=1) & (target[:, 0] >= 0) & (target[:, 1] >= 0)
            & (target[:, 0] <= intr.width - 1) & (target[:, 1] <= intr.height - 1))
    if seen.sum() < 3:
        return None
    target, points_v = target[seen], hull_points_v[seen]

    def pixels(x: np.ndarray) -> np.ndarray:
        moved = corrected_geometry(geometry, np.array([0.0, 0.0, x[2], x[3]]))
        return _tilted(moved.camera, x[0], x[1]).project(moved.vessel_to_enu(points_v))[0]

    damping = np.concatenate(([0.0, 0.0], np.asarray(prior_sigma, float)[2:] ** -2.0))
    x = np.zeros(4)
    for _ in range(_TILT_ITERATIONS):
        here = pixels(x)
        residual = (here - target).ravel()
        jacobian = np.empty((len(residual), 4))
        for k in range(4):
            nudged = x.copy()
            nudged[k] += _STEP
            jacobian[:, k] = (pixels(nudged) - here).ravel() / _STEP
        if not (np.isfinite(residual).all() and np.isfinite(jacobian).all()):
            return None
        step = np.linalg.solve(jacobian.T @ jacobian + np.diag(damping),
                               -(jacobian.T @ residual + damping * x))
        x += step
        if np.abs(step[:2]).max() < 1e-7:
            break
    return x


def camera_tilt_explaining(params: np.ndarray, geometry: FrameGeometry, silhouette: Silhouette,
                           ship: np.ndarray, prior_sigma: np.ndarray, reach: np.ndarray,
                           edge_weight: float, max_residual_px: float, min_edge_share: float
                           ) -> float | None:
    """The camera tilt (deg) that puts the hull where the image does (the whole-image
    search's correction ``params``), when one does; None otherwise.

    A camera believed to look straight down that looks ``δ`` off it sees the vessel ``H tan δ``
    away from where the sensors put it, at a range ``H / cos δ`` and foreshortened: a shift
    and a change of scale (a height) at once. First the tilt that moves the hull from the
    sensors' position to ``params`` (:func:`_tilt_start`); then, with the camera so tilted,
    the refinement's own alignment to the mask's ship pixels ``ship`` (the whole image),
    the sensors' errors held to their priors (``prior_sigma``, one sigma of ``de, dn, dpsi,
    dh``). The tilt explains the placement when that alignment leaves every sensor error
    within its ``reach`` (shift m, turn rad, height m), fits (RMS residual within
    ``max_residual_px``, at least ``min_edge_share`` of the outline's points in view on a
    ship edge) and the tilt is at least :data:`MIN_TILT_DEG`. ``silhouette`` is the vessel's
    (its layers' points in the vessel frame)."""
    start = _tilt_start(params, geometry, silhouette.points_h[:3].T, prior_sigma)
    if start is None:
        return None
    tilt_deg = math.degrees(math.hypot(start[0], start[1]))
    if tilt_deg < MIN_TILT_DEG:
        return None
    tilted = replace(geometry, camera=_tilted(geometry.camera, start[0], start[1]))
    align = Alignment(tilted, SignedDistance(ship, (0, 0)))
    outline = silhouette.outline(align.pixels(silhouette.points_h, np.zeros(4)))
    if outline.shape[1] == 0:
        return None
    fitted, _, cost, _ = gauss_newton(align, silhouette, outline, SCHEDULES[1],
                                      np.array([0.0, 0.0, start[2], start[3]]),
                                      np.asarray(prior_sigma, float) ** -2.0, edge_weight)
    if not (math.isfinite(cost) and np.isfinite(fitted).all()):
        return None
    final = silhouette.outline(align.pixels(silhouette.points_h, fitted))
    if final.shape[1] == 0:
        return None
    value = align.residuals(final, fitted)
    _, residual_px, _ = outline_fit(value)
    errors = np.array([math.hypot(fitted[0], fitted[1]), abs(fitted[2]), abs(fitted[3])])
    explained = ((errors <= np.asarray(reach, float)).all() and residual_px is not None
                 and residual_px <= max_residual_px and edge_share(value) >= min_edge_share)
    return tilt_deg if explained else None
