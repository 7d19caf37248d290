"""One standard deviation for every measured clearance, propagated from the sensors.

A section's clearance is ``d = |O - H|``: ``O`` the obstacle point, back-projected from its
pixel onto the water plane with the drone's pose, ``H`` the nearest hull point, placed by
the vessel's pose. To first order a small error moves ``O`` by ``δO`` and ``H`` by ``δH``
and changes the distance by ``u · (δO - δH)``, ``u = (O - H) / d`` (the nearest hull point
may slide along the hull, which changes ``d`` only to second order). Where ``O`` is the
crossing of an obstacle edge (direction ``t`` on the water) with the band's boundary ray
(from the section's end ``H`` along ``u``), the ray moves with the hull and the crossing
slides along the edge: a relative motion ``Δ`` of the scene moves it to where the moved edge
meets the ray, ``δd = u·Δ - c n·Δ``, ``n`` the ray's normal and ``c = (u·t) / (n·t)`` (a
motion along the edge moves nothing; one across it, ``1 / sin`` of the angle between edge
and ray). Every term below is then read along ``w = u - c n`` instead of ``u`` (``c = 0``
elsewhere); a hull end's section, whose band is a wedge, is where this matters most (a
2 degree turn slid one 0.9 m along a quay). The sources are independent, so

    sigma² = Σ_s (w · (δO_s - δH_s))²

with each ``δ`` the displacement caused by a one-sigma error of source ``s``
(:class:`~harborsight.geometry.sensor_sigmas.SensorSigmas`):

* drone horizontal position (per axis): ``δO`` is that shift, ``δH = 0``;
* drone height above the water, camera yaw, camera tilt about east and north: ``δO`` is
  where the same pixel lands with the perturbed camera (exact back-projection, lens
  included), minus where it lands now;
* vessel position (per axis) and heading: ``δH`` is the shift, or the turn ``δψ · (r_n, -r_e)``
  of ``r = H - V`` about the antenna ``V`` (heading is clockwise);
* the hull outline itself (``outline_sigma_m`` of the vessel spec; a hull drawn from AIS
  dimensions, whole metres and a guessed bow, is off the real one by about 0.6 m): ``δH``
  along the section's normal, that sigma in full;
* the clock between video and telemetry, when the frame gives both ground velocities:
  ``δO - δH = σ_t · (v_uav - v_vessel)``;
* the pixel grid: the edge lies anywhere in its pixel, whose extent along ``u`` on the
  water is ``w = |u·J_u| + |u·J_v|`` (``J`` the pixel-to-water Jacobian): ``w / sqrt 12``;
* the mask's edge: ``edge_px`` pixels across the edge, ``edge_px · |Jᵀu|``, and ``edge_m``
  metres that do not shrink with the pixel (a model's boundary errors), in quadrature;
* the model's doubt about the obstacle itself, when its probabilities are given
  (:class:`~harborsight.perception.confidence.SolidConfidence`). Read the model's solid
  probability ``p(s)`` along the ray from the hull point through the obstacle point, ``s``
  metres from the hull, as the chance that the obstacle's true edge lies nearer than ``s``:
  a normal edge at ``d`` with spread ``σ_c`` has ``p(d + z σ_c) = Φ(z)``. The first point
  beyond the measured edge where the model is sure, ``p ≥`` :data:`CONFIDENT_SOLID_P`, is
  at ``s_c``, so ``σ_c = (s_c - d) / Φ⁻¹(CONFIDENT_SOLID_P)``; where the model never gets
  sure before the image's edge, ``s_c`` is that edge. A doubtful blob of "solid" (glare,
  a wake, a shadow) in front of the real quay is the model's commonest gross error, and this
  is what widens its bar. Only the far side is read: a solid the model missed nearer to the
  hull need not lie on the ray, and reading the doubted water as solid made the lower
  bound far too cautious (docs/results.md);
* a contact the vessel's own pixels may cause: when the hull was placed by the sensors (the
  alignment neither applied nor confirming them) and a section reads contact with a *ship*
  blob, that blob may be the vessel itself, metres off its projected outline. Walk from the
  hull point outward, away from the antenna's pixel, through the first run of ship pixels
  on the way, to the first pixel beyond it sure to be solid (``p ≥``
  :data:`CONFIDENT_SOLID_P`; for a mask file, any solid label), at ``s_c`` metres on the
  water (the image's edge if none); the reading's spread is then
  ``σ_c = (s_c - d) / Φ⁻¹(CONFIDENT_SOLID_P)`` as for the doubt. The distance and its lower
  bound stay as read (a neighbour moored alongside looks the same, and the crew's alarm goes
  by the bound): only the bar, and the weight a filter over time gives the reading, change.
  When the image placed the hull, the same holds for a blob that ends inside the vessel's
  predicted shadow on the water, where the sun is known (:mod:`harborsight.geometry.sun`):
  a model paints that shadow ship, and the alignment leaves it outside the hull.

When the pose refinement was applied (or found the sensors' pose fitting the mask as well as
any correction, and that correction itself within its own 99 % ellipse of zero,
:func:`image_confirms_sensors`: a height error the alignment found but did not apply stays
in the distances, and the bar keeps the sensors' terms then), the hull is placed by the
image, not by the vessel's
sensors. Then each camera error moves the hull as well: by the rigid motion (shift and
turn) that best fits that error's displacement of the silhouette's points the alignment
fits, each at its own height (a tilt ``δ`` moves a deck edge ``z`` above the water by
``(h - z) δ``, the water by ``h δ``: the parallax stays in the distance), which is what the
alignment absorbs; only what no rigid motion absorbs is left (a height error scales the
scene about the nadir: ``(d + u·(H - c))·δh / h`` remains, ``c`` the outline's centre,
unless the alignment refined the height too: then it absorbs that scale, and the height's
posterior enters with the pose's, through ``∂d/∂h = u·(O - n) / h``, ``n`` the nadir). A
drone shift or a camera yaw is absorbed entirely, and the vessel's position and heading
errors are replaced by the alignment's own covariance, scaled by
:data:`REFINEMENT_COVARIANCE_SCALE` (calibrated on the bench: see docs/results.md).

A shift the sensors' stated accuracy does not explain (beyond the 99 % ellipse of the two
receivers and the camera errors' own shifts) is read as a camera tilted more than stated as
well: a gimbal given as straight down that looks 7 degrees off shows the hull 7 m from its
fix at 60 m, which the alignment takes for a vessel shift. The distances that tilt would
give differ (the parallax above, and the tilted view's scale), and the difference enters
the bar in full (:func:`_unexplained_shift`; the report's ``uncertainty.unexplained_shift``).

A contact (the obstacle touches the vessel's own region) reads long by up to the region's
margin: the own region is the projected hull grown by ``pose_margin_px``, and by
``own_rim_px`` more of ship pixels, and an obstacle's pixels under it are not seen. Where
the obstacle truly ends nearer (seen obliquely, a quay's face under the hull's skirt; a
neighbour moored against the hull), the reading lies up to ``m = k · (|u·J_u| + |u·J_v|)``
beyond it, ``k`` the pixels cut (the margin, and the rim where the contact is ship), one
sided. The bar takes it as ``sigma += m / 1.645`` (systematic), so that the lower bound
reaches ``m`` further in. So does a height the alignment changed (``dh``, from the hull's
size in the image, which a model's edges drawn a pixel or two thin all round fake as a
higher camera): ``m = max(0, dh u·(O - n)) / h``, the reading at the sensors' height where
that is nearer (:func:`_height_change_reach_m`; not when the scale test found the image's
scale beyond a mask's bias).

Parts: ``sigma_random_m`` holds what changes from frame to frame (pixel grid, mask edge,
the alignment); the rest (GPS, compasses, height, tilt, clock) drifts slowly and is not
averaged away over frames, which matters to a filter over time. ``distance_lower_m`` is
``max(0, d - 1.645 sigma)``: the one-sided 95 % bound of a normal error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist
from typing import TYPE_CHECKING

import cv2
import numpy as np

from harborsight.clearance.alignment import Silhouette
from harborsight.clearance.along_hull import along_direction, along_variance_m2
from harborsight.clearance.edge_evidence import CONFIDENT_SOLID_P, edge_doubt_m, own_spill_m
from harborsight.clearance.pose_refinement import SENSORS_FIT, PoseRefinement
from harborsight.clearance.report import STATUS_OK, SectionClearance
from harborsight.frame import FrameGeometry
from harborsight.geometry.camera import Camera
from harborsight.geometry.rotations import rot_x, rot_y, rot_z
from harborsight.geometry.sensor_sigmas import SensorSigmas
from harborsight.perception.classes import SHIP

if TYPE_CHECKING:
    from harborsight.perception.confidence import SolidConfidence

#: z of the one-sided lower bound (5 % of a normal distribution lies below mean - z sigma)
LOWER_BOUND_Z = 1.645
LOWER_BOUND_QUANTILE = 0.05
#: the alignment's Gauss-Newton covariance treats outline points as independent, which
#: they are not (a mask's edge errors run along the edge): inflate its variance by this
REFINEMENT_COVARIANCE_SCALE = 25.0
#: how far a band's crossing may slide along its obstacle edge per unit of the edge's
#: motion across the ray (the cotangent of the angle between edge and ray: edges within
#: 11 degrees of the ray are taken at 11 degrees)
MAX_SLIDE = 5.0
#: chi-square's 99th percentile with 3 and 4 degrees of freedom: a correction the alignment
#: found within this of zero (its covariance scaled as above) confirms the sensors' pose
_CHI2_99 = {3: 11.345, 4: 13.277}
_CONFIDENT_Z = NormalDist().inv_cdf(CONFIDENT_SOLID_P)
_PIXEL_STEP = 0.5
#: at most this many of the silhouette's points take part in the rigid fits
_SILHOUETTE_POINTS = 48
#: χ² with two degrees of freedom at 99 %: an alignment shift beyond this many squared
#: sigmas of the sensors' stated accuracy is not theirs to explain (:func:`_unexplained_shift`)
UNEXPLAINED_SHIFT_CHI2 = -2.0 * math.log(0.01)
_UNIFORM_SIGMA = 1.0 / math.sqrt(12.0)


@dataclass(frozen=True)
class FrameVelocities:
    """Ground velocities (east, north) in m/s of drone and vessel; None when unknown."""

    uav_en_mps: tuple[float, float] | None = None
    vessel_en_mps: tuple[float, float] | None = None
    #: the vessel's velocity sigma (m/s, per axis), rate of turn and its sigma (deg/s)
    vessel_sigma_mps: float | None = None
    vessel_yaw_rate_deg_s: float | None = None
    vessel_yaw_rate_sigma_deg_s: float | None = None


def _camera_errors(sigmas: SensorSigmas, height_m: float) -> list[str]:
    """The names of the camera errors :func:`_perturbed_cameras` moves the camera by, in its
    order: ``height`` (with the focal length's scale, at ``height_m``), ``yaw``,
    ``tilt_east``, ``tilt_north`` (those with a sigma above 0)."""
    named = (("height", sigmas.scale_height_m(height_m)), ("yaw", sigmas.camera_yaw_deg),
             ("tilt_east", sigmas.camera_tilt_deg), ("tilt_north", sigmas.camera_tilt_deg))
    return [name for name, sigma in named if sigma > 0]


def _perturbed_cameras(camera: Camera, sigmas: SensorSigmas) -> list[Camera]:
    """The camera moved by one sigma of each camera error (:func:`_camera_errors`): up by
    the scale's sigma (the height's and the focal length's), turned about the vertical by
    the yaw's, about east and north by the tilt's."""
    cameras = []
    height_m = sigmas.scale_height_m(float(camera.position_enu[2]))
    if height_m > 0:
        cameras.append(Camera(camera.intrinsics, camera.position_enu + np.array([0.0, 0.0, height_m]),
                              camera.world_from_camera))
    for about, sigma_deg in ((rot_z, sigmas.camera_yaw_deg), (rot_x, sigmas.camera_tilt_deg),
                             (rot_y, sigmas.camera_tilt_deg)):
        if sigma_deg > 0:
            turn = about(math.radians(sigma_deg))   # about the world's up, east or north
            cameras.append(Camera(camera.intrinsics, camera.position_enu,
                                  turn @ camera.world_from_camera))
    return cameras


def _points_at_heights(cameras: list[Camera], uv: np.ndarray, height_m: np.ndarray) -> np.ndarray:
    """Where pixels ``uv (N, 2)`` meet the horizontal planes ``z = height_m (N,)``, each
    pixel its own plane, for each of ``cameras`` (same intrinsics): ``(C, N, 2)``, NaN where
    a ray misses its plane. The ray ``c + λ R (x, y, 1)`` meets ``z`` at
    ``λ = (z - c_z) / (R (x, y, 1))_z``."""
    m = cameras[0].normalized_coordinates(uv)
    rays = np.einsum("cij,nj->cni", np.stack([c.world_from_camera for c in cameras]),
                     np.column_stack((m, np.ones(len(m)))))
    centre = np.stack([c.position_enu for c in cameras])
    with np.errstate(divide="ignore", invalid="ignore"):
        reach = (height_m[None, :] - centre[:, 2:]) / rays[..., 2]
        points = centre[:, None, :2] + reach[..., None] * rays[..., :2]
    points[~(np.isfinite(reach) & (reach > 0))] = np.nan
    return points


def _silhouette_enu(camera: Camera, layers_enu: list[np.ndarray]) -> np.ndarray | None:
    """What the alignment fits: points every :data:`~harborsight.clearance.alignment.SAMPLE_STEP_PX`
    along the outline of the vessel's image (its layers' hulls' union,
    :class:`~harborsight.clearance.alignment.Silhouette`; every k-th, at most
    :data:`_SILHOUETTE_POINTS`), in ENU with their heights (the deck's edge, not the
    waterline), those that project into the image; None when fewer than 3 do."""
    silhouette = Silhouette(layers_enu)
    uv, _ = camera.project(silhouette.points_h[:3].T)
    sampled = silhouette.outline(uv)[:3].T
    if len(sampled) < 3:
        return None
    sampled = sampled[::-(-len(sampled) // _SILHOUETTE_POINTS)]     # evenly, at most that many
    pixels, _ = camera.project(sampled)
    intr = camera.intrinsics
    inside = (np.isfinite(pixels).all(axis=1) & (pixels >= 0).all(axis=1)
              & (pixels[:, 0] <= intr.width - 1) & (pixels[:, 1] <= intr.height - 1))
    return sampled[inside] if inside.sum() >= 3 else None


def _rigid_fit(points: np.ndarray, moved_by: np.ndarray, with_scale: bool = False
               ) -> tuple[np.ndarray, np.ndarray | float, np.ndarray, np.ndarray | float]:
    """Least-squares 2-D rigid motion (shift ``t``, small turn ``ω`` anticlockwise about the
    centre ``c``; with ``with_scale`` also a small scale ``k``) of displacements ``moved_by``
    at ``points (M, 2)``: ``δ ≈ t + ω·perp(p - c) + k·(p - c)``. ``moved_by`` is ``(M, 2)``
    or ``(C, M, 2)``, one set per camera: then ``t`` is ``(C, 2)`` and ``ω``, ``k`` ``(C,)``.
    Returns ``(t, ω, c, k)``; ``k`` is 0 without ``with_scale``."""
    centre = points.mean(axis=0)
    shift = moved_by.mean(axis=-2)
    rel, rest = points - centre, moved_by - shift[..., None, :]
    spread = float((rel ** 2).sum())
    turn = (rel[:, 0] * rest[..., 1] - rel[:, 1] * rest[..., 0]).sum(axis=-1)
    scale = (rel[:, 0] * rest[..., 0] + rel[:, 1] * rest[..., 1]).sum(axis=-1)
    turn = turn / spread if spread else np.zeros_like(turn)
    scale = scale / spread if (spread and with_scale) else np.zeros_like(scale)
    if moved_by.ndim == 2:
        return shift, float(turn), centre, float(scale)
    return shift, turn, centre, scale


def _perp(vectors: np.ndarray) -> np.ndarray:
    """Each 2-vector turned 90 degrees anticlockwise."""
    return np.column_stack((-vectors[:, 1], vectors[:, 0]))


def _plane_points(cameras: list[Camera], uv: np.ndarray) -> np.ndarray:
    """Where pixels ``uv (N, 2)`` meet the water plane ``z = 0``, for each of ``cameras``
    (posed differently, with the same intrinsics): ``(C, N, 2)``, NaN where a ray misses it.

    The same arithmetic as :meth:`Camera.back_project_to_plane`, so the same numbers, but
    the pixels are undistorted once for all cameras and each camera is one homography
    applied to all pixels: the propagation back-projects one set of pixels (obstacle points,
    their Jacobian's neighbours, the outline) with five cameras."""
    m = cameras[0].normalized_coordinates(uv)
    x, y = m[:, 0], m[:, 1]
    # Camera.plane_homography(0) of each camera: rows c_x r_3 + dz r_1, c_y r_3 + dz r_2, r_3
    rows = np.stack([c.world_from_camera for c in cameras])
    centre = np.stack([c.position_enu for c in cameras])
    dz = 0.0 - centre[:, 2:]
    h = np.empty((len(cameras), 3, 3))
    h[:, 0] = centre[:, :1] * rows[:, 2] + dz * rows[:, 0]
    h[:, 1] = centre[:, 1:2] * rows[:, 2] + dz * rows[:, 1]
    h[:, 2] = rows[:, 2]
    h = h[..., None]                                                        # (C, 3, 3, 1)
    down = x * h[:, 2, 0] + y * h[:, 2, 1] + h[:, 2, 2]                    # (C, N)
    with np.errstate(divide="ignore", invalid="ignore"):
        valid = np.isfinite(down) & (dz / down > 0)
        points = np.stack((x * h[:, 0, 0] + y * h[:, 0, 1] + h[:, 0, 2],
                           x * h[:, 1, 0] + y * h[:, 1, 1] + h[:, 1, 2]), axis=-1) / down[..., None]
    points[~valid] = np.nan
    return points


def perturbed_plane_points(camera: Camera, sigmas: SensorSigmas, uv: np.ndarray) -> np.ndarray:
    """Where pixels ``uv (N, 2)`` meet the water plane with the camera, then with the camera
    moved by one sigma of each of its errors (:func:`_perturbed_cameras`): ``(1 + C, N, 2)``,
    NaN where a ray misses the water."""
    return _plane_points([camera, *_perturbed_cameras(camera, sigmas)], uv)


def _absorbed_motion(points: np.ndarray, moved_by: np.ndarray, at: np.ndarray,
                     with_scale: bool) -> np.ndarray:
    """Per camera, the rigid motion (:func:`_rigid_fit`) that best fits the displacements
    ``moved_by (C, M, 2)`` of ``points (M, 2)``, evaluated at ``at (T, 2)``: ``(C, T, 2)``;
    NaN for a camera that leaves fewer than 3 points on the water."""
    usable = np.isfinite(moved_by).all(axis=2)
    if usable.all():            # the usual case: all cameras' fits at once
        t, turn, centre, scale = _rigid_fit(points, moved_by, with_scale)
        return (t[:, None] + turn[:, None, None] * _perp(at - centre)
                + scale[:, None, None] * (at - centre))
    out = np.full((len(moved_by), len(at), 2), np.nan)
    for i in np.flatnonzero(usable.sum(axis=1) >= 3):
        t, turn, centre, scale = _rigid_fit(points[usable[i]], moved_by[i, usable[i]], with_scale)
        out[i] = t + turn * _perp(at - centre) + scale * (at - centre)
    return out


def _unexplained_shift(refinement: PoseRefinement, sigmas: SensorSigmas, errors: list[str],
                       at_antenna: np.ndarray, along: np.ndarray, height_m: float) -> dict | None:
    """The camera-tilt reading of a shift the sensors' stated accuracy does not explain.

    The alignment moved the hull by ``s``. Were the sensors as good as stated, ``s`` would
    be normal with covariance ``Σ = (σ_uav² + σ_vessel²) I + Σ_c a_c a_cᵀ + k C``: the two
    receivers per axis, each camera error's shift ``a_c`` of the hull at the antenna
    (``at_antenna``, one sigma) and the alignment's own covariance ``C`` (scaled by
    :data:`REFINEMENT_COVARIANCE_SCALE`). Beyond the 99 % ellipse of that
    (``sᵀ Σ⁻¹ s >`` :data:`UNEXPLAINED_SHIFT_CHI2`), a camera tilted by more than stated
    (a gimbal given as straight down that is not, a body pitch left out) explains it as
    well as the receivers do, and the distances read differently then: the tilt's one-sigma
    changes ``along`` (one row per camera error, as summed into the bar), scaled by the
    ``k = T⁻¹ (-s)`` sigmas that move the hull by ``s`` (``T`` the two tilts' ``a_c``; the
    alignment moves the hull against the error). The change enters the bar in full,
    ``change_m``. None when the shift is explained, or the tilts are not modelled."""
    if "tilt_east" not in errors or "tilt_north" not in errors:
        return None
    shift = np.asarray(refinement.shift_m, float)
    absorbed = np.nan_to_num(at_antenna)
    covariance = (sigmas.uav_axis_m ** 2 + sigmas.vessel_axis_m ** 2) * np.eye(2)
    covariance += absorbed.T @ absorbed
    if refinement.covariance is not None:
        covariance += REFINEMENT_COVARIANCE_SCALE * np.asarray(refinement.covariance)[:2, :2]
    try:
        spread = float(shift @ np.linalg.solve(covariance, shift))
    except np.linalg.LinAlgError:
        return None
    if not spread > UNEXPLAINED_SHIFT_CHI2:
        return None
    tilt = [errors.index("tilt_east"), errors.index("tilt_north")]
    per_sigma = at_antenna[tilt].T                          # columns: the two tilts' shifts
    if not np.isfinite(per_sigma).all() or abs(np.linalg.det(per_sigma)) < 1e-12:
        return None
    k = np.linalg.solve(per_sigma, -shift)
    change_m = k @ along[tilt]
    return {"change_m": change_m, "shift_sigmas": round(math.sqrt(spread), 2),
            "tilt_deg": round(float(np.hypot(*k)) * sigmas.camera_tilt_deg, 2),
            "height_m": round(height_m, 2)}


#: the shadow is cut this far in front of the camera's plane (metres along its axis)
_IN_FRONT_M = 0.5


def _clip_convex(polygon: np.ndarray, a: np.ndarray, b: float) -> np.ndarray:
    """The part of a convex polygon ``(M, 2)`` where ``a·p >= b`` (one Sutherland-Hodgman
    step: keep the corners inside, add where an edge crosses the line)."""
    side = polygon @ a - b
    following, side_following = np.roll(polygon, -1, axis=0), np.roll(side, -1)
    kept = []
    for p, q, sp, sq in zip(polygon, following, side, side_following, strict=True):
        if sp >= 0:
            kept.append(p)
        if (sp >= 0) != (sq >= 0):
            kept.append(p + (q - p) * sp / (sp - sq))
    return np.array(kept).reshape(-1, 2)


def _own_shadow_px(geometry: FrameGeometry, vessel_points_enu: np.ndarray | None
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """The pixels of the vessel's shadow on the water and of its footprint, two convex
    polygons ``(M, 2)``, each cut on the water to the part in front of the camera
    (:func:`_clip_convex`) and its edges bent by the lens (``Camera.project_convex_outline``);
    None without the vessel's points or the sun, or when either has nothing in front of the
    camera."""
    if vessel_points_enu is None:
        return None
    ray = geometry.sun_ray_enu()
    if ray is None:
        return None
    from harborsight.geometry.sun import shadow_on_water

    camera = geometry.camera
    axis = camera.world_from_camera[:, 2]              # the optical axis, in ENU
    # water points p in front: (p - c)·axis >= _IN_FRONT_M, a half-plane a·(e, n) >= b
    a, b = axis[:2], _IN_FRONT_M + float(camera.position_enu @ axis)
    points = np.asarray(vessel_points_enu, float)
    polygons = []
    for outline in (shadow_on_water(points, ray),
                    cv2.convexHull(points[:, :2].astype(np.float32)).reshape(-1, 2)):
        corners = _clip_convex(outline, a, b)
        if len(corners) < 3:
            return None
        pixels = camera.project_convex_outline(np.column_stack((corners, np.zeros(len(corners)))))
        if len(pixels) < 3:
            return None
        polygons.append(pixels)
    return polygons[0], polygons[1]


def _sliding_direction(u: np.ndarray, sections: list[SectionClearance], step_u: np.ndarray,
                       step_v: np.ndarray) -> np.ndarray:
    """The direction ``w`` each section's first-order terms are read along (module
    docstring): ``u``, but where the obstacle point is the crossing of an obstacle edge with
    the band's boundary ray, ``w = u - c n``, ``n`` the ray's normal and
    ``c = (u·t) / (n·t)`` for the edge's direction ``t`` on the water (its pixel direction
    through the Jacobian ``step_u``, ``step_v``), ``|c|`` at most :data:`MAX_SLIDE`."""
    w = u.copy()
    for k, section in enumerate(sections):
        edge = section.crossing_edge_px
        if edge is None or section.contact:
            continue
        t = edge[0] * step_u[k] + edge[1] * step_v[k]
        normal = np.array([-u[k, 1], u[k, 0]])
        across, along = float(normal @ t), float(u[k] @ t)
        if not (math.isfinite(across) and math.isfinite(along)) or across == along == 0.0:
            continue
        slide = along / across if abs(across) * MAX_SLIDE > abs(along) else math.copysign(
            MAX_SLIDE, along * (across or 1.0))
        w[k] = u[k] - slide * normal
    return w


def image_confirms_sensors(refinement: PoseRefinement) -> bool:
    """Whether an alignment that kept the sensors' pose (``SENSORS_FIT``) places the hull:
    the correction it found, ``p = (de, dn, dpsi[, dh])``, lies within the 99 % ellipse of
    zero under its covariance scaled by :data:`REFINEMENT_COVARIANCE_SCALE`,
    ``pᵀ C⁻¹ p <= chi²₉₉``. A correction beyond it (a height error found and not applied)
    stays in the distances."""
    covariance = refinement.covariance
    if refinement.reason != SENSORS_FIT or covariance is None:
        return False
    covariance = REFINEMENT_COVARIANCE_SCALE * np.asarray(covariance, float)
    found = [*refinement.shift_m, math.radians(refinement.rotation_deg), refinement.height_change_m]
    found = np.array(found[:len(covariance)], float)
    try:
        chi2 = float(found @ np.linalg.solve(covariance, found))
    except np.linalg.LinAlgError:
        return False
    return math.isfinite(chi2) and chi2 <= _CHI2_99.get(len(found), math.inf)


def add_section_uncertainty(
    sections: list[SectionClearance], geometry: FrameGeometry, outline_enu: np.ndarray,
    refinement: PoseRefinement, sigmas: SensorSigmas,
    velocities: FrameVelocities | None = None, *, outline_px: np.ndarray | None = None,
    confidence: SolidConfidence | None = None, labels: np.ndarray | None = None,
    vessel_points_enu: np.ndarray | None = None, outline_sigma_m: float = 0.0,
    vessel_layers_enu: list[np.ndarray] | None = None,
    own_margin_px: float = 0.0, own_rim_px: float = 0.0,
) -> dict | None:
    """Set ``sigma_m``, ``sigma_random_m`` and ``distance_lower_m`` of every ``ok`` section
    with a finite distance (module docstring). ``geometry`` is the one the distances were
    measured with (refined or not); ``outline_enu`` the hull outline's points on the water;
    ``outline_px`` their pixels with that geometry's camera (NaN where they do not project),
    when the caller has them already (else they are projected here); ``confidence`` the
    model's probabilities, when the mask came from a model; ``vessel_points_enu`` the
    vessel's hull points (above the waterline), for its shadow when the sun is known, and
    ``vessel_layers_enu`` its layers' points, for the silhouette the alignment fits (the
    hull points' hull when not given); ``outline_sigma_m`` the hull outline's own one
    sigma against the real hull (a hull drawn from AIS dimensions); ``own_margin_px`` and
    ``own_rim_px`` the own region's margin and ship rim (the contacts' cut). Returns what
    :func:`_unexplained_shift` found
    (``shift_sigmas``, ``tilt_deg``, ``height_m``) when it widened the bars, else None."""
    ok = [s for s in sections if s.status == STATUS_OK and s.distance_m is not None
          and math.isfinite(s.distance_m) and s.obstacle_point_enu is not None]
    if not ok:
        return None
    camera = geometry.camera
    obstacle = np.array([s.obstacle_point_enu for s in ok], float)
    hull = np.array([s.hull_point_enu for s in ok], float)
    obstacle_px = np.array([s.obstacle_point_px for s in ok], float)
    hull_px = np.array([s.hull_point_px for s in ok], float)
    distance_m = np.array([s.distance_m for s in ok])
    direction = obstacle - hull
    length = np.hypot(*direction.T)
    # in contact (d = 0) the direction is outward from the antenna through the hull point
    outward = hull - geometry.vessel_position_enu
    direction = np.where((length > 1e-6)[:, None], direction, outward)
    u = direction / np.maximum(np.hypot(*direction.T), 1e-12)[:, None]

    systematic = np.zeros(len(ok))
    random = np.zeros(len(ok))
    # the hull is placed by the image when the alignment moved it, and also when it found
    # the sensors' pose fitting as well as any correction would, that correction near zero
    refined = refinement.applied or image_confirms_sensors(refinement)
    if refined:
        if outline_px is None:
            outline = np.asarray(outline_enu, float)[:, :2]
            outline_px, _ = camera.project(np.column_stack((outline, np.zeros(len(outline)))))
        outline_px = outline_px[np.isfinite(outline_px).all(axis=1)]
    else:
        outline_px = np.zeros((0, 2))
    # the alignment fits the hull's silhouette at its own heights (the deck's edge): a camera
    # tilt moves it in the image by (H - z)·δ, not H·δ, and the difference is the parallax the
    # distances keep. Without the vessel's points the waterline outline stands in for it.
    layers = vessel_layers_enu or ([vessel_points_enu] if vessel_points_enu is not None else None)
    silhouette = _silhouette_enu(camera, layers) if refined and layers else None
    if silhouette is not None:
        outline_px = np.zeros((0, 2))
    # one back-projection of every pixel needed, with the camera and each perturbed camera:
    # the obstacle points, the outline (its rigid fit) and the obstacle points' neighbours
    # half a pixel away (the Jacobian, with the camera only)
    n_ok, n_outline = len(ok), len(outline_px)
    du, dv = np.array([_PIXEL_STEP, 0.0]), np.array([0.0, _PIXEL_STEP])
    cameras = [camera, *_perturbed_cameras(camera, sigmas)]
    planes = _plane_points(cameras, np.concatenate((
        obstacle_px, outline_px, obstacle_px + du, obstacle_px - du, obstacle_px + dv,
        obstacle_px - dv)))
    here, outline_here = planes[0, :n_ok], planes[0, n_ok:n_ok + n_outline]
    # the pixel-to-water Jacobian at each obstacle point, and the direction every first-order
    # term is read along (u, or for a band's crossing the slide it makes: module docstring)
    right, left, below, above = planes[0, n_ok + n_outline:].reshape(4, n_ok, 2)
    step_u = (right - left) / (2 * _PIXEL_STEP)
    step_v = (below - above) / (2 * _PIXEL_STEP)
    w = _sliding_direction(u, ok, step_u, step_v)
    shift_o = planes[1:, :n_ok] - here                      # (cameras, sections, 2)
    shift_h = np.zeros_like(shift_o)
    # each camera error's shift of the hull at the antenna, as the alignment absorbs it
    at_antenna = np.full((len(cameras) - 1, 2), np.nan)
    # the alignment also absorbs a scale when it refined the drone's height
    height_refined = bool(refined and np.shape(refinement.covariance) == (4, 4))
    if silhouette is not None:
        on_planes = _points_at_heights(cameras, camera.project(silhouette)[0], silhouette[:, 2])
        fit_points, fit_moved = on_planes[0], on_planes[1:] - on_planes[0]
    else:
        fit_points, fit_moved = outline_here, planes[1:, n_ok:n_ok + n_outline] - outline_here
    if refined and len(fit_points) >= 3 and len(shift_o):
        moved = _absorbed_motion(fit_points, fit_moved,
                                 np.vstack((hull, geometry.vessel_position_enu[None, :2])),
                                 height_refined)
        if refinement.along_hull_held:
            # the alignment held the shift along the hull: it absorbs none of a camera
            # error's motion of the hull along its length (at the antenna)
            axis = along_direction(geometry.vessel_heading_rad)[:2]
            moved = moved - (np.nan_to_num(moved[:, n_ok]) @ axis)[:, None, None] * axis
        shift_h, at_antenna = np.nan_to_num(moved[:, :n_ok]), moved[:, n_ok]
    # the scene turns about the antenna relative to the hull: at the obstacle point (for u the
    # same as at the hull point, O - H being along u)
    r = obstacle[:, :2] - geometry.vessel_position_enu[:2]
    relative = None
    if (velocities is not None and velocities.uav_en_mps is not None
            and velocities.vessel_en_mps is not None):
        relative = np.subtract(velocities.uav_en_mps, velocities.vessel_en_mps)
    covariance = (REFINEMENT_COVARIANCE_SCALE * np.asarray(refinement.covariance)
                  if refined and refinement.covariance is not None else None)

    def read_along(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The first-order terms read along the directions ``d`` (sections, 2): their
        systematic and random variances, and each camera error's change (cameras, sections)."""
        sys_part, rand_part = np.zeros(len(ok)), np.zeros(len(ok))
        # each camera error in turn (summed in order, as independent sources)
        cameras_along = np.nan_to_num(np.einsum("ij,cij->ci", d, shift_o - shift_h))
        for along in cameras_along:
            sys_part += along ** 2
        if not refined:
            # drone shift moves O, vessel shift moves H: along d in full (|d| = 1 off crossings)
            sys_part += ((sigmas.uav_axis_m ** 2 + sigmas.vessel_axis_m ** 2)
                         * np.einsum("ij,ij->i", d, d))
            turn = math.radians(sigmas.vessel_heading_deg) * np.column_stack((r[:, 1], -r[:, 0]))
            sys_part += np.einsum("ij,ij->i", d, turn) ** 2
            if relative is not None:
                sys_part += (sigmas.clock_s * (d @ relative)) ** 2
        elif refinement.along_hull_held:        # the sensors' place along the hull
            sys_part += along_variance_m2(d, geometry.vessel_heading_rad, sigmas)
        if covariance is not None:      # (refined only)
            columns = [d[:, 0], d[:, 1], d[:, 0] * r[:, 1] - d[:, 1] * r[:, 0]]
            if height_refined:
                # a height error dh moves each back-projected obstacle point away from the
                # nadir by (O - n) dh / h, the hull staying where the alignment put it (the
                # sign as the columns above: the change of the distance, negated)
                height_m = max(float(camera.position_enu[2]), 1e-6)
                columns.append(-np.einsum("ij,ij->i", d, obstacle[:, :2] - camera.position_enu[:2])
                               / height_m)
            gradient = np.column_stack(columns)
            rand_part += np.einsum("ij,jk,ik->i", gradient, covariance, gradient)
        # pixel grid and mask edge, through the local pixel-to-water Jacobian at the obstacle
        by_u = np.abs(np.einsum("ij,ij->i", d, step_u))
        by_v = np.abs(np.einsum("ij,ij->i", d, step_v))
        rand_part += np.nan_to_num(((by_u + by_v) * _UNIFORM_SIGMA) ** 2
                                   + sigmas.edge_px ** 2 * (by_u ** 2 + by_v ** 2))
        return sys_part, rand_part, cameras_along

    # read along u, and where a section's obstacle point may slide along its edge (w != u),
    # along w too: the larger is kept (a pixel staircase's nearest pixel may stay put under
    # a small turn, or slide with the edge under a larger one)
    sys_u, rand_u, cameras_along = read_along(u)
    sliding = np.flatnonzero((w != u).any(axis=1))
    if len(sliding):
        sys_w, rand_w, along_w = read_along(w)
        wider = sliding[(sys_w + rand_w)[sliding] > (sys_u + rand_u)[sliding]]
        sys_u[wider], rand_u[wider] = sys_w[wider], rand_w[wider]
        cameras_along[:, wider] = along_w[:, wider]
    systematic += sys_u
    random += rand_u + sigmas.edge_m ** 2
    unexplained = None
    if refinement.applied:
        height_m = float(camera.position_enu[2])
        unexplained = _unexplained_shift(refinement, sigmas, _camera_errors(sigmas, height_m),
                                         at_antenna, cameras_along, height_m)
        if unexplained is not None:
            systematic += unexplained.pop("change_m") ** 2
    # the outline itself off the real hull moves the hull point along the section's normal
    systematic += outline_sigma_m ** 2
    # a pixel's extent along u (the contact's cut is along the ray)
    along_u = np.abs(np.einsum("ij,ij->i", u, step_u))
    along_v = np.abs(np.einsum("ij,ij->i", u, step_v))
    if confidence is not None:
        doubt = edge_doubt_m(hull_px, obstacle_px, hull[:, :2], distance_m, camera, confidence)
        random += (doubt / _CONFIDENT_Z) ** 2
    contact = np.array([bool(s.contact) for s in ok])
    shadow_px = None
    if labels is not None and refined and contact.any():
        shadow_px = _own_shadow_px(geometry, vessel_points_enu)
    if labels is not None and contact.any() and (not refined or shadow_px is not None):
        antenna_px, _ = camera.project(np.array([[*geometry.vessel_position_enu[:2], 0.0]]))
        spill = np.zeros(len(ok))
        spill[contact] = own_spill_m(hull_px[contact], obstacle_px[contact], hull[contact, :2],
                                     distance_m[contact], antenna_px[0], camera, labels,
                                     confidence, shadow_px)
        random += (spill / _CONFIDENT_Z) ** 2

    total = np.sqrt(systematic + random)
    if refinement.applied and height_refined and refinement.scale_prior_m is None:
        # the height the alignment changed, from the hull's size in the image, is what a
        # model's edges drawn a pixel or two off all round fake: the bound reaches the
        # reading at the sensors' height too, where that is nearer (one sided, as the
        # contact's cut; not when the scale test found the image's scale beyond such a bias)
        reach_m = _height_change_reach_m(refinement.height_change_m, u, obstacle, camera)
        total = total + reach_m / LOWER_BOUND_Z
    if contact.any() and own_margin_px + own_rim_px > 0:
        # the own region's margin (and, for a ship, its rim) may hide the contact's nearer
        # edge: the bound reaches that far further in (module docstring)
        cut_px = np.full(len(ok), float(own_margin_px))
        if labels is not None and own_rim_px > 0:
            u_px = np.clip(np.rint(obstacle_px[:, 0]).astype(int), 0, labels.shape[1] - 1)
            v_px = np.clip(np.rint(obstacle_px[:, 1]).astype(int), 0, labels.shape[0] - 1)
            cut_px += np.where(labels[v_px, u_px] == SHIP, float(own_rim_px), 0.0)
        total = total + np.where(contact, np.nan_to_num(cut_px * (along_u + along_v)), 0.0) / LOWER_BOUND_Z
    for section, sigma, sigma_random in zip(ok, total, np.sqrt(random), strict=True):
        if not math.isfinite(sigma):
            continue
        section.sigma_m = float(sigma)
        section.sigma_random_m = float(sigma_random)
        section.distance_lower_m = lower_bound_m(section.distance_m, float(sigma))
    return unexplained


def _height_change_reach_m(height_change_m: float, u: np.ndarray, obstacle: np.ndarray,
                           camera: Camera) -> np.ndarray:
    """How much longer each distance reads (along ``u``, sections x 2) for a camera raised
    by ``height_change_m`` over the truth, 0 where it reads shorter: every back-projected
    point moves away from the nadir ``n`` by ``(O - n) dh / h``, the hull staying where the
    alignment put it, so ``max(0, dh u·(O - n)) / h``. A model that drew the whole scene 3 px
    thin raised the camera 4 m at 80 m, and 9 % of the sections of such frames read beyond
    their bound, up to 13 % long (docs/results.md)."""
    height_m = max(float(camera.position_enu[2]), 1e-6)
    along = np.einsum("ij,ij->i", u, obstacle[:, :2] - camera.position_enu[:2])
    return np.nan_to_num(np.maximum(0.0, float(height_change_m) * along) / height_m)


def bounded_where_band_left(section: SectionClearance) -> bool:
    """Whether an ``ok`` section's lower bound is where its band leaves the picture
    (``clear_to_m``, nearer than its obstacle: something nearer may lie out of view), not
    the propagated bound of the obstacle seen."""
    return (section.status == STATUS_OK and section.clear_to_m is not None
            and section.distance_lower_m is not None and section.sigma_m is not None
            and section.distance_m is not None and section.distance_lower_m >= section.clear_to_m)


def seen_lower_bound_m(section: SectionClearance) -> float:
    """The propagated lower bound of the obstacle a section saw, ``max(0, d - z sigma)``,
    whatever may lie out of view."""
    return lower_bound_m(section.distance_m, section.sigma_m)


def lower_bound_m(distance_m: float, sigma_m: float) -> float:
    """The one-sided 95 % lower bound of a normal reading, ``max(0, d - z sigma)``."""
    return max(0.0, distance_m - LOWER_BOUND_Z * sigma_m)


def add_nadir_approximation(sections: list[SectionClearance]) -> None:
    """Widen the sigmas of the paper's ``gsd`` method by its own error: it reads a distance
    as pixels times the nadir GSD, which holds only straight below a level camera. The same
    two pixels back-projected onto the water (the ``hull_point_enu`` and
    ``obstacle_point_enu`` of the section) are ``|O - H|`` apart; the difference
    ``b = |d_gsd - |O - H||`` is the approximation's error for this pair of pixels (8 % of
    the distance at 8 degrees of tilt). It is systematic, and added in quadrature:
    ``sigma² += b²``; the lower bound is taken again."""
    for section in sections:
        if (section.status != STATUS_OK or section.sigma_m is None
                or section.hull_point_enu is None or section.obstacle_point_enu is None):
            continue
        plane_m = math.dist(section.hull_point_enu[:2], section.obstacle_point_enu[:2])
        bias_m = abs(section.distance_m - plane_m)
        if not math.isfinite(bias_m):
            continue
        section.sigma_m = math.hypot(section.sigma_m, bias_m)
        section.distance_lower_m = lower_bound_m(section.distance_m, section.sigma_m)

