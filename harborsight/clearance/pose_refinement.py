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
in ``dpsi`` (:class:`Alignment`), so a step is a few dozen array operations on about 200
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
wins. When the pose kept or applied leaves its outline short of ship edges, the whole image
is searched for the hull (:mod:`harborsight.clearance.pose_search`): a placement it finds
within the limits is one more start, run whatever the first start left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from harborsight.clearance.alignment import (
    DEEP_PX,
    MIN_EDGE_POINTS,
    SCHEDULES,
    Alignment,
    SignedDistance,
    Silhouette,
    corrected_geometry,
    gauss_newton,
    homogeneous,
    outline_fit,
    ship_fill,
    tukey_cost,
)
from harborsight.clearance.camera_errors import camera_tilt_explaining, camera_yaw_explains
from harborsight.clearance.obstacles import IGNORE, SHIP
from harborsight.clearance.pose_search import (
    Placement,
    edge_share,
    place_hull,
    silhouette_overlap,
    whole_image_alignment,
)
from harborsight.errors import require_positive
from harborsight.frame import FrameGeometry
from harborsight.vessel.spec import VesselSpec

#: the sensors' pose is kept when it fits within this much RMS of the refined one, with as
#: many inliers: a correction then follows the mask's rounding, not the sensors' error
SAME_FIT_RMS_PX = 0.25
#: the reason given when the sensors' pose fits the mask as well as the refined one
SENSORS_FIT = "the sensors' pose fits the mask as well"
#: the other schedules run only when the first leaves fewer inliers than this
SKIP_SECOND_START_FRACTION = 0.9


@dataclass(frozen=True)
class PoseRefinementSettings:
    """Priors (one sigma of the combined drone + vessel error, per axis) and acceptance.
    The priors here are those of the default sensors; ``measure_clearance`` scales the
    shift's and the heading's to a frame's own (:func:`harborsight.clearance.measure.
    alignment_settings`)."""

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
    #: search the whole image for the hull when the outline fits badly (a gross sensor error)
    search_whole_image: bool = True
    #: how far a mask's ship edge may lie off the hull all round (pixels, one sigma), which
    #: scales the hull in the image whatever the sensors (:func:`_image_scale`): a pixel for
    #: a mask read from a file; a model's masks miss or add whole pieces of a hull
    scale_edge_px: float = 1.0

    def __post_init__(self) -> None:
        require_positive(self, ("prior_shift_m", "prior_heading_deg", "prior_height_m", "edge_sigma_px",
                                "max_shift_m", "max_rotation_deg", "max_height_change_m",
                                "max_residual_px", "scale_edge_px"))
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
    #: (:func:`contradicts_sensors`, or the whole-image search: :func:`_gross_error`); or the
    #: image shows no vessel where the sensors put it, and nowhere else (:func:`_unconfirmed`)
    sensors_contradicted: bool = False
    #: the share of the outline's points in view on a ship edge at the pose kept or applied
    #: (:func:`pose_search.edge_share`; None when nothing was aligned): what decides whether
    #: the whole image is searched
    edge_share: float | None = field(default=None, compare=False)
    #: where the image puts the hull when it contradicts the sensors: the silhouette's
    #: corners ``[[u, v], ...]`` (px) under the correction found, for the overlay
    image_hull_px: list[list[float]] | None = field(default=None, compare=False)
    #: the height prior (m) the alignment was re-solved with when the hull's size in the
    #: image disagreed with the frame's height and focal length; None when it agreed
    scale_prior_m: float | None = None
    #: the camera's height above the water at the sensors' pose (m), where the alignment ran:
    #: ``height_change_m`` over it is the scale the hull's size in the image puts on the frame
    height_m: float | None = field(default=None, compare=False)
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
            "image_hull_px": self.image_hull_px,
            "scale_prior_m": rounded(self.scale_prior_m, 3),
            "scale_change": (rounded(self.height_change_m / self.height_m, 4)
                             if self.height_m else None),
        }


OFF = PoseRefinement(applied=False, reason="off")


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
    shift_m, rotation_deg, _ = _reach(settings)
    reach_m = shift_m + 0.5 * vessel.length_m * math.radians(rotation_deg)
    reach_px = min(reach_m * max(intr.fx, intr.fy) / height_m, max(shape)) + 4
    lo = np.floor(finite.min(axis=0) - reach_px).astype(int)
    hi = np.ceil(finite.max(axis=0) + reach_px).astype(int)
    u0, v0 = max(lo[0], 0), max(lo[1], 0)
    u1, v1 = min(hi[0] + 1, shape[1]), min(hi[1] + 1, shape[0])
    if u1 - u0 < 2 or v1 - v0 < 2:
        return None
    return slice(v0, v1), slice(u0, u1)


#: the coarse translation search's grid step, as a share of the prior's sigma; how many of
#: its best cells start a Gauss-Newton run; at most this many outline points score a cell;
SEARCH_STEP_SIGMA = 1 / 3
SEARCH_STARTS = 2
SEARCH_POINTS = 120
#: the Tukey scale (px) a search cell is scored at: the second schedule's first
SEARCH_TUKEY_PX = SCHEDULES[1][0][1]


def _shift_costs(align: Alignment, outline: np.ndarray, params: np.ndarray, de: np.ndarray,
                 dn: np.ndarray, points: int = SEARCH_POINTS) -> np.ndarray | None:
    """The Tukey cost at :data:`SEARCH_TUKEY_PX` of up to ``points`` outline points
    (every k-th) under the correction ``params`` moved by each horizontal shift
    ``(de, dn)`` (metres; points that leave the view count as outliers), one per shift
    (:func:`_shifted_window_xy`). None when too few points project."""
    if outline.shape[1] == 0:
        return None
    outline = outline[:, ::-(-outline.shape[1] // points)]    # every k-th point
    shifted = _shifted_window_xy(align, outline, params, de, dn)
    if shifted is None or shifted[0].shape[1] < MIN_EDGE_POINTS:
        return None
    xy, seen = shifted
    values = np.full(seen.shape, np.inf)
    values[seen] = align.sdf.sample(xy[seen].T)[0]
    return tukey_cost(values, SEARCH_TUKEY_PX).sum(axis=1)    # |inf| -> the outlier cost


def _shifted_window_xy(align: Alignment, outline: np.ndarray, params: np.ndarray,
                       de: np.ndarray, dn: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Window positions ``(shifts, points, 2)`` of the outline's points that project under
    the correction ``params`` moved by each horizontal shift ``(de, dn)`` (metres), and
    which of them are in view and in the window. To first order, ``uv(t) = uv(0) + J t``,
    ``J`` from the projections at 1 m east and 1 m north: one projection per axis instead
    of one per shift. None when no point projects."""
    base = align.pixels(outline, params)
    east = align.pixels(outline, params + np.array([1.0, 0.0, 0.0, 0.0])) - base
    north = align.pixels(outline, params + np.array([0.0, 1.0, 0.0, 0.0])) - base
    keep = np.isfinite(base).all(axis=1) & np.isfinite(east).all(axis=1) & np.isfinite(north).all(axis=1)
    if not keep.any():
        return None
    base, east, north = base[keep], east[keep], north[keep]
    xy = (base[None] + de[:, None, None] * east[None] + dn[:, None, None] * north[None]
          - align.origin.T[None])
    seen = ((xy[..., 0] >= align.lo[0]) & (xy[..., 0] <= align.hi[0])
            & (xy[..., 1] >= align.lo[1]) & (xy[..., 1] <= align.hi[1]))
    return xy, seen


def _translation_search(align: Alignment, outline: np.ndarray, settings: PoseRefinementSettings,
                        taken: list[np.ndarray]) -> list[tuple[float, float]]:
    """The best horizontal shifts ``(de, dn)`` (metres) of a grid over the prior's reach
    (within ``min(max_shift_m, 2.5 prior_shift_m)``, steps of :data:`SEARCH_STEP_SIGMA`
    sigma): starts for the Gauss-Newton runs when the sensors are so far off that their
    neighbourhood holds the wrong basin (a start 5 m off with a 3 m prior, docs/results.md).

    A cell is scored by the Tukey cost, at the second schedule's first scale
    (:data:`SEARCH_TUKEY_PX`, the basin its run starts with), of the outline's points
    (:func:`_shift_costs`). At most :data:`SEARCH_STARTS` cells, each cheaper than the
    sensors' pose and more than 1.5 steps from the other starts (``taken``, the sensors'
    pose among them) and from each other; none when no cell beats the sensors' pose."""
    reach_m = _reach(settings)[0]
    step_m = SEARCH_STEP_SIGMA * settings.prior_shift_m
    n = int(reach_m // step_m)
    if n < 1:
        return []
    offsets = np.arange(-n, n + 1) * step_m
    de, dn = (g.ravel() for g in np.meshgrid(offsets, offsets))
    inside = np.hypot(de, dn) <= reach_m + 1e-9
    de, dn = de[inside], dn[inside]
    cost = _shift_costs(align, outline, np.zeros(4), de, dn)
    if cost is None:
        return []
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
    not trustworthy) and what was found. When the pose kept or applied leaves its outline
    short of ship edges, the whole image is searched for the hull (:func:`_gross_error`). A
    placement found there within the limits becomes one more start of the refinement (whose
    result replaces the first only when it applies a correction); one beyond them in exactly
    one of shift, rotation and height, with the other two within the refinement's reach
    (2.5 sigma of the prior for shift and rotation, the limit for height), contradicts the
    sensors; a shift and a turn that one camera yaw error explains count as one
    (:func:`~harborsight.clearance.camera_errors.camera_yaw_explains`), and so do a shift
    and a height change (with a turn) that one camera tilt explains
    (:func:`~harborsight.clearance.camera_errors.camera_tilt_explaining`). Beyond in two at
    once, it is more often a bad mask than two gross sensor errors (on the bench with the
    default model, 6 of 130 frames with 2 m and 2 degree sensors had such placements); a
    height counts as gross only beyond
    :data:`GROSS_HEIGHT_SHARE` of the camera's height. When the search changes nothing and the
    sensors' pose kept leaves its outline off the ship's edges, that contradicts the sensors
    too (:func:`_unconfirmed`). A pose kept because vessels alike fit the mask as well, or
    because the hull where the sensors put it is cut by the image's border and a placement
    elsewhere cannot be told from it (:func:`_twin_alongside`), is not searched: the search
    would find one of them. Never
    raises for a failed alignment.
    """
    if not settings.enabled:
        return geometry, OFF
    refined, found = _refine_within_prior(labels, geometry, vessel, settings)
    if (not settings.search_whole_image or found.sensors_contradicted or found.reason in NOT_IN_VIEW
            or (found.reason or "").startswith((TWIN_ALIKE, CUT_ALIKE))):
        return refined, found       # (the image holds vessels alike: it would find one of them)
    chosen, result = _search_whole_image(labels, geometry, refined, found, vessel, settings)
    if result is found:         # the search changed nothing: is the pose kept borne out?
        result = _unconfirmed(found, geometry, vessel)
    return chosen, result


def _unconfirmed(found: PoseRefinement, geometry: FrameGeometry, vessel: VesselSpec) -> PoseRefinement:
    """``found``, flagged ``sensors_contradicted`` when the sensors' pose is kept although
    under :data:`UNCONFIRMED_BELOW_SHARE` of its outline's points in view lie on a ship edge
    with the hull mostly in view (:data:`CONTRADICTION_MIN_IN_VIEW`) and the whole-image
    search placed it nowhere: the image does not show the vessel where the sensors put it.
    Either the pose is off by more than the search could tell (on the bench: a fix 14 m
    off, a heading reversed, a camera yaw 60 degrees off, with a model's mask) or the mask
    misses the vessel; the distances are untrustworthy either way."""
    if found.applied or found.reason == SENSORS_FIT or (found.reason or "").startswith(
            (TWIN_ALIKE, CUT_ALIKE)):
        return found
    share = found.edge_share or 0.0
    if share >= UNCONFIRMED_BELOW_SHARE:
        return found
    silhouette = Silhouette(vessel.alignment_layers)
    outline = silhouette.outline(_pixels(geometry, silhouette))
    if outline.shape[1] == 0:
        return found
    uv = geometry.camera.project(geometry.vessel_to_enu(outline[:3].T))[0]
    if geometry.camera.in_image(uv).mean() < CONTRADICTION_MIN_IN_VIEW:
        return found
    return replace(found, sensors_contradicted=True, reason=(
        f"only {100 * share:.0f} % of the hull's outline lies on a ship edge where the sensors "
        f"put it, and the image places it nowhere else ({found.reason})"))


def _search_whole_image(labels: np.ndarray, geometry: FrameGeometry, refined: FrameGeometry,
                        found: PoseRefinement, vessel: VesselSpec, settings: PoseRefinementSettings
                        ) -> tuple[FrameGeometry, PoseRefinement]:
    """What the whole-image search makes of the refinement's result (``refined``, ``found``):
    that result, unchanged, unless a placement corrects or contradicts it
    (:func:`refine_vessel_pose`)."""
    placement = _gross_error(labels, geometry, found, vessel, settings)
    if placement is None:
        return refined, found
    shift_m, rotation_deg, height_change_m = _sizes(placement.params)
    limits = _beyond(placement.params, settings.max_shift_m, settings.max_rotation_deg,
                     settings.max_height_change_m)
    if not any(limits):
        # within the limits, beyond the refinement's basin: refine again from there, and keep
        # the first result unless that applies a correction
        params = placement.params.copy()
        params[2] = math.radians(rotation_deg)
        again = _refine_within_prior(labels, geometry, vessel, settings, extra_start=params)
        return again if again[1].applied else (refined, found)
    gross = _gross(placement.params, geometry, settings)
    reach_shift_m, reach_rotation_deg, reach_height_m = _reach(settings)
    reach = _beyond(placement.params, reach_shift_m, reach_rotation_deg, reach_height_m)
    camera_yaw = (gross[0] or gross[1]) and camera_yaw_explains(placement.params, geometry, reach_shift_m)
    # the reason names the camera's yaw where the shift alone is beyond the reach (a turn with
    # a small shift is as well a heading's error)
    yaw_named = camera_yaw and reach[0]
    if camera_yaw:      # shift and turn together are one error: the camera's yaw
        gross, reach = [True, False, gross[2]], [True, False, reach[2]]
    tilt_deg = None
    # a gross shift with a height change the prior does not give (2.5 sigma) is looked at
    # as a tilt too, though one gross error flags the frame anyway: for the reason's sake
    scaled = abs(height_change_m) > 2.5 * settings.prior_height_m
    if gross[0] and (sum(gross) != 1 or sum(reach) > 1 or scaled):
        # shift and height (and the turn a tilt gives) may be one error: the camera's tilt
        tilt_deg = camera_tilt_explaining(
            placement.params, geometry, Silhouette(vessel.alignment_layers), labels == SHIP,
            np.array([settings.prior_shift_m, settings.prior_shift_m,
                      math.radians(settings.prior_heading_deg), settings.prior_height_m]),
            np.array([reach_shift_m, math.radians(reach_rotation_deg), reach_height_m]),
            settings.edge_sigma_px ** -2.0, settings.max_residual_px, SEARCH_BELOW_SHARE)
        if tilt_deg is not None:
            gross, reach = [True, False, False], [True, False, False]
    if sum(gross) != 1 or sum(reach) > 1:
        return refined, found       # not one gross error: two at once are more often a bad mask
    reason = (f"the image puts the hull {shift_m:.1f} m, {round(rotation_deg) + 0:+d} deg and "
              f"{round(height_change_m, 1) + 0.0:+.1f} m of height from the sensors' pose")
    if yaw_named:
        reason += f" (as a camera yaw {abs(round(rotation_deg))} deg off would)"
    elif tilt_deg is not None:
        reason += f" (as a camera tilted {tilt_deg:.0f} deg more than stated would)"
    return geometry, PoseRefinement(
        False, (float(placement.params[0]), float(placement.params[1])), rotation_deg, height_change_m,
        placement.residual_px, placement.inlier_fraction, found.inlier_fraction_before,
        placement.edge_points, ship_fill=placement.ship_fill, sensors_contradicted=True,
        edge_share=found.edge_share, image_hull_px=_silhouette_px(geometry, vessel, placement.params),
        reason=reason)


def _pixels(geometry: FrameGeometry, silhouette: Silhouette) -> np.ndarray:
    """The pixels of the silhouette's points at the frame's pose (NaN where they do not
    project)."""
    return geometry.camera.project(geometry.vessel_to_enu(silhouette.points_h[:3].T))[0]


def _silhouette_px(geometry: FrameGeometry, vessel: VesselSpec, params: np.ndarray
                   ) -> list[list[float]] | None:
    """The hull's silhouette (convex hull of its projected points, px, rounded to 0.1 px)
    under the correction ``params``; None when under 3 points project."""
    moved = corrected_geometry(geometry, params)
    uv = moved.camera.project(moved.vessel_to_enu(vessel.hull_points))[0]
    uv = uv[np.isfinite(uv).all(axis=1)]
    if len(uv) < 3:
        return None
    corners = cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2)
    return [[round(float(u), 1), round(float(v), 1)] for u, v in corners]


def _reach(settings: PoseRefinementSettings) -> tuple[float, float, float]:
    """The refinement's reach: 2.5 sigma of its prior for the shift (m) and the rotation (deg),
    within the limits, and the height's limit (m)."""
    return (min(settings.max_shift_m, 2.5 * settings.prior_shift_m),
            min(settings.max_rotation_deg, 2.5 * settings.prior_heading_deg),
            settings.max_height_change_m)


def _as_params(found: PoseRefinement) -> np.ndarray:
    """A refinement's correction as ``(de, dn, dpsi rad, dh)``."""
    return np.array([*found.shift_m, math.radians(found.rotation_deg), found.height_change_m])


def _gross(params: np.ndarray, geometry: FrameGeometry, settings: PoseRefinementSettings) -> list[bool]:
    """Which of shift, rotation and height of a correction are gross: beyond the limits, the
    height also beyond :data:`GROSS_HEIGHT_SHARE` of the camera's height."""
    return _beyond(params, settings.max_shift_m, settings.max_rotation_deg, max(
        settings.max_height_change_m, GROSS_HEIGHT_SHARE * float(geometry.camera.position_enu[2])))


def _sizes(params: np.ndarray) -> tuple[float, float, float]:
    """``(shift m, rotation deg in [-180, 180), height change m)`` of a correction."""
    turn = (float(params[2]) + math.pi) % (2 * math.pi) - math.pi
    return float(np.hypot(*params[:2])), math.degrees(turn), float(params[3])


def _beyond(params: np.ndarray, shift_m: float, rotation_deg: float, height_m: float) -> list[bool]:
    """Which of a correction's shift, rotation and height change exceed ``shift_m``,
    ``rotation_deg`` and ``height_m``."""
    shift, rotation, height = _sizes(params)
    return [shift > shift_m, abs(rotation) > rotation_deg, abs(height) > height_m]


#: a height change found by the whole-image search counts as a gross error only beyond this
#: share of the camera's height as well as the limit: a model's mask a pixel or two narrow
#: all round shrinks a hull 60 px long by several per cent (a 120 m bench frame "found" its
#: height 10 m off, 9 %; ellipsoidal heights read as heights above the water were 23 % and
#: more of the bench's altitudes)
GROSS_HEIGHT_SHARE = 0.15


#: the refinement's reasons when the hull is not in view at the sensors' pose: nothing to
#: search for (a ship in view is another)
NOT_IN_VIEW = ("the hull does not project into the image", "the hull is not in the image")
#: the whole image is searched when the pose kept or applied puts fewer of the outline's
#: points in view on a ship edge than this (:func:`pose_search.edge_share`)
SEARCH_BELOW_SHARE = 0.8
#: and slides the predicted silhouette over the whole image (a chamfer match of its outline,
#: :func:`pose_search._sliding_starts`) when the pose leaves under this share there: the
#: outline is then off its ship altogether, not pressed against a neighbour
SLIDE_BELOW_SHARE = 0.5
#: a sensors' pose kept with under this share of its outline's points in view on a ship
#: edge, and placed nowhere else by the search, is not borne out by the image (:func:`_unconfirmed`)
UNCONFIRMED_BELOW_SHARE = 0.2
#: a placement must put this much more of its outline on ship edges than the pose kept or
#: applied (a reversed heading applied at 100-140 m still put 75-79 % of its small outline
#: on edges; at 0.15, 0 of 390 bench frames with 2 m and 2 degree sensors were flagged)
SEARCH_GAIN = 0.15
#: when the pose kept or applied sits on ship pixels, a placement must overlap it by this
#: share of the smaller silhouette (the same ship, seen larger or turned): a hull laid on
#: another, smaller boat fits it as well (a bench frame "found" its hull 26 m away, turned
#: 177 degrees and 72 m higher, on a neighbour)
SAME_SHIP_OVERLAP = 0.5
#: ... but only a pose with at least this share of its outline's points in view on ship edges
#: (or both its ends) sits on a ship: one that fills ship pixels with most of its outline
#: inside the blob (the hull laid over part of a larger neighbour, 17-25 m from the own
#: vessel, by a camera tilt given wrong) does not hold the hull there (on the bench, with
#: the pitch given as -90, three frames so held read sections 8-25 m long; their poses put
#: 45-49 % of the outline on edges, the own vessel's placement 99-100 %)
HELD_FROM_SHARE = 0.5
#: ... or with both its ends on edges: the outline's points within this share of the hull's
#: length from the bow, and from the stern, at least :data:`ENDS_ON_EDGES_SHARE` of each end's
#: points in view on an edge (and :data:`ENDS_MIN_POINTS` of them): a vessel rafted between
#: two others shows its bow and stern though its sides lie against theirs (40-43 % of its
#: outline on edges; its ends 56-100 %), while a hull laid over part of a longer neighbour
#: has an end inside it (on the bench, one end at 0-35 %)
HULL_END_SHARE = 0.15
ENDS_ON_EDGES_SHARE = 0.5
ENDS_MIN_POINTS = 3


def _ends_on_edges(align: Alignment, silhouette: Silhouette, params: np.ndarray,
                   against_neighbours: bool = False, unseen_ok: bool = False) -> bool:
    """Whether the outline under the correction ``params`` has both its ends on ship edges
    (:data:`HULL_END_SHARE`, :data:`ENDS_ON_EDGES_SHARE`; an end with fewer than
    :data:`ENDS_MIN_POINTS` points in view is not on edges). ``against_neighbours``: an end's
    points deep inside ship pixels (:data:`~harborsight.clearance.alignment.DEEP_PX`) are
    left out of its share, as for a stern whose quarters lie against the sterns of vessels
    rafted alongside; an end all deep inside is still not on edges. ``unseen_ok``: an end
    mostly out of the picture (fewer than :data:`ENDS_MIN_POINTS` of its points, and under
    half, in view) neither confirms nor denies; the other end must be on edges."""
    outline = silhouette.outline(align.pixels(silhouette.points_h, params))
    if outline.shape[1] == 0:
        return False
    x = silhouette.points_h[0]
    reach = HULL_END_SHARE * float(x.max() - x.min())
    unseen = 0
    for end in (outline[:, outline[0] >= x.max() - reach], outline[:, outline[0] <= x.min() + reach]):
        values = align.residuals(end, params)
        if unseen_ok and len(values) < min(ENDS_MIN_POINTS, 0.5 * end.shape[1]):
            unseen += 1
            continue
        if against_neighbours:
            values = values[values > -DEEP_PX]
        if len(values) < ENDS_MIN_POINTS or edge_share(values) < ENDS_ON_EDGES_SHARE:
            return False
    return unseen < 2


def _gross_error(labels: np.ndarray, geometry: FrameGeometry, found: PoseRefinement,
                 vessel: VesselSpec, settings: PoseRefinementSettings) -> Placement | None:
    """The image's own placement of the hull (:func:`pose_search.place_hull`) when it shows
    the pose the refinement kept or applied wrong: that pose puts under
    :data:`SEARCH_BELOW_SHARE` of its outline's points in view on a ship edge, and the
    placement puts :data:`SEARCH_GAIN` more there (and at least that share), passes
    every test of fit, has at least :data:`CONTRADICTION_MIN_IN_VIEW` of its outline in view
    and, when the pose sits on a ship (fills ship pixels and has :data:`HELD_FROM_SHARE` of
    its outline on edges, or both its ends: :func:`_ends_on_edges`), overlaps it
    (:data:`SAME_SHIP_OVERLAP`). None otherwise."""
    share = found.edge_share or 0.0
    if share >= SEARCH_BELOW_SHARE:
        return None
    ship = labels == SHIP
    if not ship.any():
        return None
    align = whole_image_alignment(ship, geometry)
    silhouette = Silhouette(vessel.alignment_layers)
    chosen = _as_params(found) if found.applied else np.zeros(4)
    known = labels != IGNORE
    # the refinement's own correction, refused for its size, is a start too: the search's
    # blob starts may lay the hull on another ship (a 22 m shift at 150 m, exact labels)
    refused = (_as_params(found),) if (found.reason or "").startswith(BEYOND_LIMITS) else ()
    chosen_uv = align.pixels(silhouette.points_h, chosen)
    whole = (slice(0, labels.shape[0]), slice(0, labels.shape[1]))
    on_a_ship = ((share >= HELD_FROM_SHARE or _ends_on_edges(align, silhouette, chosen))
                 and ship_fill(silhouette.layers_uv(chosen_uv), whole, ship, known)
                 >= settings.min_ship_fill)

    def elsewhere(params: np.ndarray) -> bool:
        """The pose sits on a ship, and ``params`` lay the hull on another one."""
        return on_a_ship and silhouette_overlap(
            chosen_uv, align.pixels(silhouette.points_h, params)) < SAME_SHIP_OVERLAP

    reach_shift_m = _reach(settings)[0]

    def gross_errors(params: np.ndarray) -> int:
        gross = _gross(params, geometry, settings)
        if (gross[0] or gross[1]) and camera_yaw_explains(params, geometry, reach_shift_m):
            return 1 + gross[2]             # shift and turn are one error: the camera's yaw
        return sum(gross)

    placement = place_hull(align, silhouette, ship, known, settings.edge_sigma_px ** -2.0,
                           settings.min_ship_fill, against=chosen, extra_starts=refused,
                           slide=share < SLIDE_BELOW_SHARE, slide_beyond_m=reach_shift_m,
                           gross_errors=gross_errors,
                           count_share=SEARCH_BELOW_SHARE)
    if (placement is None or placement.edge_share < max(share + SEARCH_GAIN, SEARCH_BELOW_SHARE)
            or placement.in_view < CONTRADICTION_MIN_IN_VIEW
            or placement.inlier_fraction < settings.min_inlier_fraction
            or placement.ship_fill < settings.min_ship_fill
            or placement.residual_px is None or placement.residual_px > settings.max_residual_px):
        return None
    if elsewhere(placement.params):
        return None     # the pose sits on a ship, the placement on another one
    return placement


#: the hull's size in the image disagrees with the frame's scale (its height and focal
#: length, :meth:`SensorSigmas.scale_height_m`) when the image's own estimate of the height
#: lies beyond this many sigma of the prior's (:func:`_image_scale`); a linear look at the
#: fit held by the prior screens for it first, from :data:`SCALE_SCREEN_Z`
SCALE_CONFLICT_Z = 3.0
SCALE_SCREEN_Z = 1.5


def _image_scale(align: Alignment, silhouette: Silhouette, outline: np.ndarray, params: np.ndarray,
                 information: np.ndarray, value: np.ndarray, prior_diagonal: np.ndarray,
                 edge_weight: float, geometry: FrameGeometry, edge_px: float
                 ) -> tuple[tuple, float] | None:
    """The alignment re-solved with the height's prior widened, and that prior (m), when the
    hull's size in the image and the frame's scale disagree; else None.

    Held by a prior ``N(0, σp²)``, the MAP height change ``μ`` (posterior variance ``C``)
    stops short of what the image alone says, ``μ_d = μ σp² / (σp² - C)`` with variance
    ``C σp² / (σp² - C)`` to first order. When that lies :data:`SCALE_SCREEN_Z` sigma out
    (with ``σp²`` and ``b²``, ``b = 2 · edge_px · h / span`` the height a mask's edge
    ``edge_px`` off all round would fake, ``h`` the camera's height, ``span`` the hull's
    extent in pixels; ``PoseRefinementSettings.scale_edge_px``), the fit is re-solved from
    ``μ`` with the prior ``hypot(σp, 3 μ_d)``. The scales disagree when the new height change
    ``μ'`` (variance ``C'``) lies beyond :data:`SCALE_CONFLICT_Z` · ``sqrt(C' + b² + σp²)``
    and the outline fits at least as well (as many inliers, within :data:`SAME_FIT_RMS_PX`
    of the RMS; ``value``: the first fit's signed distances): freed, a height can also slide
    to a worse minimum (a bench frame's went 10 m down, 65 % of its outline on edges against
    98 %). A focal length 5-10 % off (a video mode or stabilisation that crops the sensor)
    or an altitude off by more than its sigma is such a case: held by the prior, the
    correction stopped part way and the rest of the scale error was in every distance,
    beyond its bar (docs/results.md, "A focal length given wrong")."""
    sigma_p2 = 1.0 / float(prior_diagonal[3])
    try:
        posterior = float(np.linalg.inv(information)[3, 3])
    except np.linalg.LinAlgError:
        return None
    uv = align.pixels(outline, params)          # the outline's samples span the hull
    finite = uv[np.isfinite(uv).all(axis=1)]
    gap = sigma_p2 - posterior
    if gap <= 0.01 * sigma_p2 or len(finite) < 2:
        return None                       # the image hardly measures the scale
    span_px = max(float(np.ptp(finite, axis=0).max()), 1.0)
    bias2 = (2.0 * edge_px * float(geometry.camera.position_enu[2]) / span_px) ** 2
    mean_d = float(params[3]) * sigma_p2 / gap
    if abs(mean_d) <= SCALE_SCREEN_Z * math.sqrt(posterior * sigma_p2 / gap + bias2 + sigma_p2):
        return None
    prior_m = math.hypot(math.sqrt(sigma_p2), 3.0 * mean_d)
    widened = prior_diagonal.copy()
    widened[3] = prior_m ** -2.0
    again = gauss_newton(align, silhouette, outline, SCHEDULES[0], params, widened, edge_weight)
    if not (np.isfinite(again[2]) and np.isfinite(again[0]).all()):
        return None
    try:
        variance = float(np.linalg.inv(again[1])[3, 3])
    except np.linalg.LinAlgError:
        return None
    if abs(float(again[0][3])) <= SCALE_CONFLICT_Z * math.sqrt(variance + bias2 + sigma_p2):
        return None
    (fraction, rms_px, _), (fraction_again, rms_again_px, _) = outline_fit(value), outline_fit(again[3])
    if fraction_again < fraction or rms_again_px is None or (
            rms_px is not None and rms_again_px > rms_px + SAME_FIT_RMS_PX):
        return None
    return again, prior_m


def _refine_within_prior(
    labels: np.ndarray, geometry: FrameGeometry, vessel: VesselSpec, settings: PoseRefinementSettings,
    extra_start: np.ndarray | None = None,
) -> tuple[FrameGeometry, PoseRefinement]:
    """The refinement proper, within the sensors' prior; ``extra_start`` (a correction the
    whole-image search found within the limits) joins the starts, and the window reaches it."""
    silhouette = Silhouette(vessel.alignment_layers)
    outline = silhouette.outline(_pixels(geometry, silhouette))
    if outline.shape[1] == 0:
        return geometry, PoseRefinement(False, reason=NOT_IN_VIEW[0])
    uv0 = geometry.camera.project(geometry.vessel_to_enu(outline[:3].T))[0]
    if extra_start is not None:
        moved = corrected_geometry(geometry, extra_start)
        uv0 = np.vstack((uv0, moved.camera.project(moved.vessel_to_enu(outline[:3].T))[0]))
    window = _search_window(uv0, geometry, vessel, settings, labels.shape)
    if window is None:
        return geometry, PoseRefinement(False, reason=NOT_IN_VIEW[1])
    ship = labels[window] == SHIP
    if not ship.any():
        return geometry, PoseRefinement(False, reason="no ship pixels near the projected hull")
    if ship.all():
        return geometry, PoseRefinement(False, reason="only ship pixels around the projected hull")
    align = Alignment(geometry, SignedDistance(ship, (window[1].start, window[0].start)))

    at_sensors = align.residuals(outline, np.zeros(4))
    before, before_rms_px, _ = outline_fit(at_sensors)

    # without height refinement a prior of a micrometre holds the height where it is
    prior_sigma = np.array([settings.prior_shift_m, settings.prior_shift_m,
                            math.radians(settings.prior_heading_deg),
                            settings.prior_height_m if settings.refine_height else 1e-6])
    prior_diagonal = prior_sigma ** -2.0
    edge_weight = settings.edge_sigma_px ** -2.0

    def solve(schedule, start: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        return gauss_newton(align, silhouette, outline, schedule, start, prior_diagonal, edge_weight)

    known = labels[window] != IGNORE

    def fill(params: np.ndarray) -> float:
        return ship_fill(silhouette.layers_uv(align.pixels(silhouette.points_h, params)), window,
                         ship, known)

    # the first start; when it leaves the outline or the silhouette short of ship pixels,
    # the second schedule from the sensors' pose and from a beam's reach to either side
    first = solve(SCHEDULES[0], np.zeros(4))
    candidates = [(*first, fill(first[0]))]     # (params, information, cost, distances, fill)
    first_fit = outline_fit(first[3])
    if first_fit[0] < SKIP_SECOND_START_FRACTION or candidates[0][4] < settings.min_ship_fill:
        h = geometry.vessel_heading_rad
        across = np.array([math.cos(h), -math.sin(h), 0.0, 0.0]) * settings.prior_shift_m
        starts = [np.zeros(4), across, -across]
        starts += [np.array([de, dn, 0.0, 0.0])
                   for de, dn in _translation_search(align, outline, settings, starts)]
        for start in starts:
            found = solve(SCHEDULES[1], start)
            candidates.append((*found, fill(found[0])))
    if extra_start is not None:     # whatever the first start left: the search found it
        found = solve(SCHEDULES[1], extra_start)
        candidates.append((*found, fill(found[0])))
    full = [c for c in candidates if c[4] >= settings.min_ship_fill]
    params, information, _, value, fill_share = best = min(full or candidates, key=lambda c: c[2])
    scale_prior_m = None
    rescaled = (_image_scale(align, silhouette, outline, params, information, value, prior_diagonal,
                             edge_weight, geometry, settings.scale_edge_px)
                if settings.refine_height and np.isfinite(params).all() else None)
    if rescaled is not None:
        # the hull's size in the image and the frame's scale disagree: the image's scale,
        # re-solved with the height's prior widened, replaces the compromise
        again, scale_prior_m = rescaled
        params, information, _, value, fill_share = best = (*again, fill(again[0]))

    twin_alike = None
    if np.isfinite(params).all():
        def solve_and_fill(start: np.ndarray) -> tuple:
            found = solve(SCHEDULES[1], start)
            return (*found, fill(found[0]))

        cut = _cut_hull(align, silhouette, outline, at_sensors, params, prior_diagonal,
                        edge_weight, fill, settings)
        best, twin_alike = _twin_alongside(best, align, silhouette, geometry, settings,
                                           prior_diagonal, solve_and_fill, fill, ship, cut,
                                           solved=candidates)
        params, information, _, value, fill_share = best

    fraction, residual_px, n_edge = first_fit if best is candidates[0] else outline_fit(value)
    shift = (float(params[0]), float(params[1]))
    rotation_deg = math.degrees(float(params[2]))
    height_change_m = float(params[3]) if settings.refine_height else 0.0
    if not settings.refine_height:
        params = params.copy()
        params[3] = 0.0
    # (a placement among sisters alike may have fewer: the twin's reason is the one to give)
    if n_edge < MIN_EDGE_POINTS and twin_alike is None:
        return geometry, PoseRefinement(
            False, shift, rotation_deg, edge_points=n_edge, inlier_fraction_before=before,
            edge_share=edge_share(at_sensors),
            reason=f"only {n_edge} outline points in view where the mask can tell "
                   f"(at least {MIN_EDGE_POINTS} needed)")
    try:
        covariance = np.linalg.inv(information)
        if not settings.refine_height:
            covariance = covariance[:3, :3]
    except np.linalg.LinAlgError:
        covariance = None
    found = PoseRefinement(False, shift, rotation_deg, height_change_m, residual_px, fraction, before,
                           n_edge, ship_fill=fill_share, covariance=covariance,
                           scale_prior_m=scale_prior_m,
                           height_m=(float(geometry.camera.position_enu[2])
                                     if settings.refine_height else None))
    reason = None
    if not np.isfinite(params).all():
        reason = "the alignment diverged"
    elif math.hypot(*shift) > settings.max_shift_m:
        reason = f"shift {math.hypot(*shift):.1f} m beyond {settings.max_shift_m:g} m"
    elif abs(rotation_deg) > settings.max_rotation_deg:
        reason = f"rotation {rotation_deg:.1f} deg beyond {settings.max_rotation_deg:g} deg"
    elif abs(height_change_m) > settings.max_height_change_m:
        reason = f"height change {height_change_m:+.1f} m beyond {settings.max_height_change_m:.3g} m"
    elif fraction < settings.min_inlier_fraction:
        reason = (f"{100 * fraction:.0f} % of the outline fits a ship edge "
                  f"(at least {100 * settings.min_inlier_fraction:.0f} % needed)")
    elif fill_share < settings.min_ship_fill:
        reason = (f"{100 * fill_share:.0f} % of the silhouette is ship pixels "
                  f"(at least {100 * settings.min_ship_fill:.0f} % needed)")
    elif residual_px is None or residual_px > settings.max_residual_px:
        reason = f"residual {residual_px:.2f} px above {settings.max_residual_px:g} px"
    elif twin_alike is not None:
        reason = twin_alike
    elif fraction < before - 0.02 or (
            fraction <= before + 0.02 and before_rms_px is not None
            and before_rms_px <= residual_px + SAME_FIT_RMS_PX):
        reason = SENSORS_FIT      # a correction would only follow the pixels' rounding
    if reason is not None:
        beyond = reason.startswith(BEYOND_LIMITS)
        in_view = len(value) / max(outline.shape[1], 1)
        # the hull's size in the image put the scale off, beyond the height's limit: the
        # sensors' pose leaves that scale error in every distance, however well it fits;
        # so does a height change beyond it that fits the mask cleanly (a height 10 % off
        # at 100 m was found to 0.6 m, inliers 1.0, and neither applied nor flagged)
        scale_beyond = reason.startswith("height change ") and (
            scale_prior_m is not None or clean_fit(fraction, residual_px, fill_share))
        contradicted = beyond and contradicts_sensors(before, fraction, fill_share, residual_px,
                                                      settings, in_view, scale_beyond)
        if contradicted and scale_beyond:
            reason += " (the hull's size in the image: the altitude or the focal length is off)"
        image_hull_px = _silhouette_px(geometry, vessel, params) if contradicted else None
        return geometry, replace(found, reason=reason, edge_share=edge_share(at_sensors),
                                 sensors_contradicted=contradicted, image_hull_px=image_hull_px)
    return corrected_geometry(geometry, params), replace(found, applied=True, edge_share=edge_share(value))


#: a pose is checked for a twin alongside when this share of its outline's points in view
#: lies deep inside ship pixels (:data:`~harborsight.clearance.alignment.DEEP_PX`): a side
#: pressed against a neighbour's
TWIN_DEEP_SHARE = 0.2
#: a twin is another placement this share of the hull's beam or more from the pose
TWIN_APART_BEAMS = 0.5
#: placements that fit the mask alike are told apart by the prior alone, and only when their
#: squared prior distances differ by this much (odds of 20 to 1)
TWIN_ODDS_D2 = 2.0 * math.log(20.0)
#: how the reason for a pose kept for want of telling twins apart begins
TWIN_ALIKE = "the hull fits the mask as well "
#: another ship blob may hold a twin when its area is within these shares of the hull's
#: silhouette's (both in the window, both eroded and halved alike): less is a buoy, a tender
#: or a twin mostly out of view; more, a larger vessel, inside which the hull would fit with
#: its sides and one end on nothing. Low, for a model's masks: a yacht's blob eroded 2 px
#: at 150 m keeps under half its area
TWIN_BLOB_AREA = (0.4, 1.6)
#: at most this many such blobs are fitted, the likeliest under the prior first
TWIN_BLOB_STARTS = 3
#: a placement on another blob is a sister's when its outline's inlier share is at most
#: this much under the chosen pose's (a 12 m yacht's outline on a 14 m yacht's blob, or on a
#: box's, fits alike by the acceptance tests alone)
TWIN_BLOB_FRACTION = 0.15
#: the same for a candidate the refinement solved before the twin check: one with 0.90 of
#: its outline on edges, 7 m along a hull whose placement had 1.0, was no sister (a bench
#: frame of a marina: the first pass had applied it, and the twin reason left it so)
TWIN_SOLVED_FRACTION = 0.05
#: ... or this many more of its telling points off an edge, where that is more (of 19
#: telling points one off is 0.05: a hull rafted at the border, partly out of view)
TWIN_SOLVED_MISSES = 2
#: a placement on another blob is a sister's only when the ring of pixels just outside its
#: silhouette (:data:`RING_PX`) holds at most this much more ship than the chosen pose's:
#: a 12 x 4 m box's corners lie outside a yacht's outline laid inside it
TWIN_BLOB_RING = 0.1
RING_PX = 1
#: outline points that score a cell on such a blob (every k-th of the outline, so half as
#: many at least: never under the :data:`MIN_EDGE_POINTS` a score needs; at 40, an outline
#: of 41-46 points kept 21-23, and no sister was tried at 80-92 m); a start need only be in
#: the basin of the alignment's first scale
TWIN_BLOB_POINTS = 2 * MIN_EDGE_POINTS


#: a placement fits alike with :data:`MIN_EDGE_POINTS` of its outline's points able to tell
#: (not deep in ship pixels), or this many, half that, when they are at least
#: :data:`ALIKE_MIN_TELLING_SHARE` of its points in view (and :data:`MIN_EDGE_POINTS` are in
#: view): a yacht rafted between two sisters has its sides deep in theirs, and with the 24
#: an alignment needs its true placement (23 telling of about 50 at 100 m) lost to an outer
#: sister, which has a free side (34 of 144 frames laid 4 m over, a reviewer's probe). A
#: tug laid a beam over inside a larger moored ship's blob on a bench frame (a model's
#: mask) kept 20 telling of 102: no sister, and the share tells it apart
ALIKE_MIN_TELLING = MIN_EDGE_POINTS // 2
ALIKE_MIN_TELLING_SHARE = 1.0 / 3.0


def _fits_alike(candidate: tuple, align: Alignment, silhouette: Silhouette,
                settings: PoseRefinementSettings) -> bool:
    """Whether a candidate ``(params, information, cost, signed distances, fill)`` fits the
    mask as a placement of the hull would be accepted: within the limits, the outline's
    points that can tell on edges (:data:`ALIKE_MIN_TELLING`), the silhouette filled, both
    ends on edges where they are not against a neighbour's or out of the picture (a
    sister's stern cut by the image's border, or the vessel's own, does not rule the
    placement out)."""
    params, _, _, value, fill_share = candidate
    if not np.isfinite(params).all() or fill_share < settings.min_ship_fill:
        return False
    if any(_beyond(params, settings.max_shift_m, settings.max_rotation_deg,
                   settings.max_height_change_m)):
        return False
    fraction, residual_px, n_edge = outline_fit(value)
    telling = n_edge >= MIN_EDGE_POINTS or (
        n_edge >= ALIKE_MIN_TELLING and n_edge >= ALIKE_MIN_TELLING_SHARE * len(value))
    return (len(value) >= MIN_EDGE_POINTS and telling and fraction >= settings.min_inlier_fraction
            and residual_px is not None and residual_px <= settings.max_residual_px
            and _ends_on_edges(align, silhouette, params, against_neighbours=True, unseen_ok=True))


def _drawn_in_window(params: np.ndarray, align: Alignment, silhouette: Silhouette,
                     shape: tuple[int, int]) -> np.ndarray | None:
    """The convex hull of the silhouette's pixels under ``params``, drawn (1) in an array
    of the signed distance's window ``shape``; None when fewer than three points project."""
    uv = align.pixels(silhouette.points_h, params)
    uv = uv[np.isfinite(uv).all(axis=1)]
    if len(uv) < 3:
        return None
    drawn = np.zeros(shape, np.uint8)
    hull = cv2.convexHull(np.round((uv - align.origin.ravel()) * 16).astype(np.int32))
    cv2.fillConvexPoly(drawn, hull, 1, lineType=cv2.LINE_8, shift=4)
    return drawn


def _ring_ship_share(params: np.ndarray, align: Alignment, silhouette: Silhouette,
                     ship: np.ndarray, row: tuple[np.ndarray, ...] = ()) -> float:
    """Share of ship pixels in the ring :data:`RING_PX` wide just outside the silhouette
    under ``params`` (in the signed distance's window ``ship``): water round a hull alone on
    the water, ship where the blob holds more than the hull. With ``row`` (corrections:
    sisters' placements), the lower of that share and the share with the ring pixels
    inside their silhouettes left out: the row can only admit a placement."""
    drawn = _drawn_in_window(params, align, silhouette, ship.shape)
    if drawn is None:
        return 1.0
    size = 2 * RING_PX + 1
    ring = (cv2.dilate(drawn, np.ones((size, size), np.uint8)) > drawn)

    def share() -> float:
        total = np.count_nonzero(ring)
        return float(np.count_nonzero(ring & ship) / total) if total else 1.0

    alone = share()
    if not row:
        return alone
    for other in row:
        sister = _drawn_in_window(other, align, silhouette, ship.shape)
        if sister is not None:
            ring &= sister == 0
    return min(alone, share())


def _row_rings(best: np.ndarray, found: np.ndarray, align: Alignment, silhouette: Silhouette,
               ship: np.ndarray) -> tuple[float, float]:
    """The ring ship shares (:func:`_ring_ship_share`) of the pose ``best`` and of a
    placement ``found`` on a sister's blob, the latter's the lower of its own and its less
    the pixels a row of sisters at their spacing ``d = found - best`` would cover (hulls at
    ``best - d``, ``best`` and ``found + d``): the row can only admit a placement (taken
    out of both rings, it moved the shares apart: 0.032 / 0.113 became 0.009 / 0.122, and a
    real sister 4.8 m abeam was turned away). Sisters moored half a metre apart touch the
    ring along their sides, the middle one's on both: without the row, the true pose
    between two sisters read 0.3 more ship in its ring than an outer sister's, and a 14 m
    yacht in a row was laid a berth over (21 of 108 frames at 95-105 m). A box's corners
    beyond the hull's outline lie under no sister's placement and still count."""
    spacing = found - best
    spacing[2:] = 0.0
    return (_ring_ship_share(best, align, silhouette, ship),
            _ring_ship_share(found, align, silhouette, ship, (best - spacing, best, found + spacing)))


def _shift_d2(params: np.ndarray, prior_diagonal: np.ndarray) -> float:
    """``p^T diag(prior) p`` of a correction's horizontal shift alone: what tells sister
    placements apart. Their turns and heights are one vessel's, fitted twice; a mask's edge
    bias moved the fitted height between them, and with it the odds (2 px of erosion: 25 of
    144 frames of a yacht in a row laid a berth over, 13 on the shift alone)."""
    return float(params[0] ** 2 * prior_diagonal[0] + params[1] ** 2 * prior_diagonal[1])


def _blob_starts(params: np.ndarray, align: Alignment, silhouette: Silhouette, ship: np.ndarray,
                 prior_diagonal: np.ndarray, step_m: float, apart_m: float,
                 max_shift_m: float = math.inf) -> tuple[list[np.ndarray], bool]:
    """Starts of the alignment on the mask's other ship blobs, for identical vessels
    moored apart (a marina's row of charter yachts).

    The blobs are the connected components of the window's ship pixels (``ship``) eroded
    by a 3x3 square and at half the resolution, a pixel ship where all four under it are
    (which parts blobs joined by a pixel or two: a metre of water at 150 m).
    Shifts of the pose ``params`` on a grid of ``step_m`` are kept where the prior cannot
    rule them out (:func:`_shift_d2`, the shift shortened by a step, within
    :data:`TWIN_ODDS_D2` of ``params``'; no farther from the sensors' pose than
    ``max_shift_m``, the most a correction may be: a prior of a kilometre, a receiver
    without a fix, would grid millions of cells at a step of half a beam), ``apart_m`` or
    more from it, and where the hull's centre falls on a blob other than its own whose
    area is within :data:`TWIN_BLOB_AREA` of the silhouette's (drawn in the window and
    parted as the blobs are); per blob the
    cell whose outline fits best (:func:`_shift_costs`) is a start. At most
    :data:`TWIN_BLOB_STARTS`, the likeliest under the prior first. Blobs clipped by the
    window are so started within a step of their best placement (their centroids are not:
    a hull half out of the window moves it by metres). Also whether the blob under the
    hull's centre is larger than :data:`TWIN_BLOB_AREA` allows a hull alone: sisters whose
    silhouettes lean into one another far from the nadir make one blob (a row of three
    yachts 1 m apart at 100 m, seen 65 m off the nadir: 2.4 hulls' area)."""
    uv = align.pixels(silhouette.points_h, params)
    uv = uv[np.isfinite(uv).all(axis=1)]
    rows, cols = ship.shape[0] // 2 * 2, ship.shape[1] // 2 * 2
    if len(uv) < 3 or min(rows, cols) < 4 or np.count_nonzero(ship) < 1.1 * cv2.contourArea(
            cv2.convexHull(uv.astype(np.float32))):
        return [], False    # too few ship pixels in the window for the hull and a twin

    def parted(mask: np.ndarray) -> np.ndarray:
        # eroded once, and at half the resolution a pixel set only where all four under it
        # are: blobs joined by a pixel or two part, and the labelling costs a quarter
        eroded = cv2.erode(mask, np.ones((3, 3), np.uint8))[:rows, :cols]
        return eroded[::2, ::2] & eroded[1::2, ::2] & eroded[::2, 1::2] & eroded[1::2, 1::2]

    drawn = _drawn_in_window(params, align, silhouette, ship.shape)
    area_px = float(np.count_nonzero(parted(drawn)))      # the hull's, in the window, as a blob's
    least_px, most_px = TWIN_BLOB_AREA[0] * area_px, TWIN_BLOB_AREA[1] * area_px
    if area_px < 1.0:
        return [], False
    count, blobs, stats, _ = cv2.connectedComponentsWithStats(parted(ship.view(np.uint8)), connectivity=8)
    point = homogeneous(np.array([silhouette.points_h[:3].mean(axis=1)]))
    at = align.pixels(point, params)[0] - align.origin.ravel()
    jacobian = np.column_stack([align.pixels(point, params + step)[0] - align.origin.ravel() - at
                                for step in (np.array([1.0, 0, 0, 0]), np.array([0, 1.0, 0, 0]))])
    if not (np.isfinite(at).all() and np.isfinite(jacobian).all()):
        return [], False

    def blob_at(de: np.ndarray, dn: np.ndarray) -> np.ndarray:
        col = np.floor(0.5 * (at[0] + jacobian[0, 0] * de + jacobian[0, 1] * dn)).astype(int)
        row = np.floor(0.5 * (at[1] + jacobian[1, 0] * de + jacobian[1, 1] * dn)).astype(int)
        inside = (row >= 0) & (row < blobs.shape[0]) & (col >= 0) & (col < blobs.shape[1])
        out = np.zeros(len(de), int)
        out[inside] = blobs[row[inside], col[inside]]
        return out

    own = int(blob_at(np.zeros(1), np.zeros(1))[0])
    areas = stats[:, cv2.CC_STAT_AREA]
    merged = own > 0 and areas[own] > most_px
    if count <= 2:
        return [], merged
    d2_best = _shift_d2(params, prior_diagonal)
    reach_m = min(prior_diagonal[0] ** -0.5 * math.sqrt(d2_best + TWIN_ODDS_D2), max_shift_m) + step_m
    n = math.ceil(reach_m / step_m)
    offsets = np.arange(-n, n + 1) * step_m
    east, north = (g.ravel() for g in np.meshgrid(offsets, offsets))      # shifts from the sensors'
    shortened = np.maximum(np.hypot(east, north) - step_m, 0.0)
    de, dn = east - params[0], north - params[1]                          # from the pose
    keep = (shortened ** 2 * prior_diagonal[0] < d2_best + TWIN_ODDS_D2) & (np.hypot(de, dn) >= apart_m)
    de, dn, shortened = de[keep], dn[keep], shortened[keep]
    label = blob_at(de, dn)
    alike = (areas >= least_px) & (areas <= most_px)
    on_other = (label > 0) & (label != own) & alike[label]
    if not on_other.any():
        return [], merged
    de, dn, shortened, label = de[on_other], dn[on_other], shortened[on_other], label[on_other]
    outline = silhouette.outline(align.pixels(silhouette.points_h, params))
    cost = _shift_costs(align, outline, params, de, dn, TWIN_BLOB_POINTS)
    if cost is None:
        return [], merged
    starts = []
    for blob in np.unique(label):
        cells = np.flatnonzero(label == blob)
        cell = cells[np.argmin(cost[cells])]
        starts.append((float(shortened[cell]), params + np.array([de[cell], dn[cell], 0.0, 0.0])))
    starts.sort(key=lambda item: item[0])
    return [start for _, start in starts[:TWIN_BLOB_STARTS]], merged


#: the hull at the sensors' pose is cut by the image's border when under this share of its
#: outline's samples are in view
CUT_IN_VIEW = 0.9
#: a hull so cut is aligned from this many outline points in view (half what an alignment
#: needs), to see whether what is in view fits the mask
CUT_MIN_POINTS = MIN_EDGE_POINTS // 2
#: how the reason for a pose kept because the hull where the sensors put it is cut by the
#: image's border, and cannot be told from the alignment's placement, begins
CUT_ALIKE = "the hull where the sensors put it runs out of the picture "


def _cut_hull(align: Alignment, silhouette: Silhouette, outline: np.ndarray,
              at_sensors: np.ndarray, params: np.ndarray, prior_diagonal: np.ndarray,
              edge_weight: float, fill, settings: PoseRefinementSettings
              ) -> tuple[tuple, bool, float] | None:
    """The placement of the hull the image's border cuts that joins the sisters' comparison
    (:func:`_cut_at_sensors`: ``(candidate, seen, in_view)``), or None: asked only when
    under :data:`CUT_IN_VIEW` of the outline (``outline``, its signed distances in view at
    the sensors' pose ``at_sensors``) is in view and the chosen correction ``params`` moves
    the hull :data:`TWIN_APART_BEAMS` beams or more. The hull is aligned from the sensors'
    pose on as few as :data:`CUT_MIN_POINTS` points; when that is refused or slides onto
    the chosen placement, again from :func:`_cut_starts` with the height held at the
    sensors' (a cut outline hardly measures the scale: a reviewer found the fit from the
    sensors' pose refused in 3 of 4 frames still laid on a sister, its silhouette on water
    or its height 4-8 m off, where a fit from the truth passed). When none fills the
    silhouette as an accepted placement must, the first that fills :data:`CUT_FILL_SHARE`
    of it joins."""
    in_view = len(at_sensors) / outline.shape[1]
    apart_m = TWIN_APART_BEAMS * float(np.ptp(silhouette.points_h[1]))
    if in_view >= CUT_IN_VIEW or math.hypot(*params[:2]) < apart_m:
        return None

    relaxed = align.with_min_points(CUT_MIN_POINTS)
    held = prior_diagonal.copy()
    held[3] = CUT_HELD_HEIGHT_M ** -2.0

    def alignments():
        first = gauss_newton(relaxed, silhouette, outline, SCHEDULES[1], np.zeros(4),
                             prior_diagonal, edge_weight)
        yield first
        for start in _cut_starts(relaxed, outline, params, prior_diagonal, apart_m, first[0]):
            yield gauss_newton(relaxed, silhouette, outline, SCHEDULES[1], start, held, edge_weight)

    # (a fit on the chosen placement never joins; the unseen sensors' pose comes only from
    # the first, which fails whenever under CUT_MIN_POINTS points are in view)
    short = None        # the first fit that fills only CUT_FILL_SHARE of what it must
    for solved in alignments():
        cut = _cut_at_sensors(solved, at_sensors, in_view, fill, settings)
        if cut is None or (cut[1] and math.hypot(*(cut[0][0][:2] - params[:2])) < apart_m):
            continue
        if not cut[1] or cut[0][4] >= settings.min_ship_fill:
            return cut
        short = short or cut
    return short


#: the share of an accepted placement's fill (``min_ship_fill``) a cut hull's placement
#: needs when none has that: aligned on so few points it lies up to a metre off along a
#: hull whose end is out of the picture, an end over water (fills of 0.72-0.87 were found
#: 0.4-0.9 m from the truth, where the sister beside it was laid on)
CUT_FILL_SHARE = 0.8
#: the height's prior (m) while a cut hull is aligned from a grid cell: held at the sensors'
CUT_HELD_HEIGHT_M = 1e-6
#: cells of the grid over the prior's reach that start such alignments
CUT_STARTS = 2


def _cut_starts(align: Alignment, outline: np.ndarray, params: np.ndarray,
                prior_diagonal: np.ndarray, apart_m: float, fitted: np.ndarray | None = None
                ) -> list[np.ndarray]:
    """Starts, ``apart_m`` or more from the chosen correction ``params``, for a cut hull's
    alignment with its height held: where the alignment from the sensors' pose ``fitted``
    it, at the sensors' height (a tilted camera's cut hull was fitted 0.4 m from the truth
    with its height 5 m off, beyond the limit); then the :data:`CUT_STARTS` cells of a grid
    over the prior's reach (2.5 sigma, steps of :data:`SEARCH_STEP_SIGMA` sigma) whose
    outline points in view (at least :data:`CUT_MIN_POINTS`) have the least mean Tukey
    cost at :data:`SEARCH_TUKEY_PX`, the nearer the sensors' pose first among equals. A
    mean, not :func:`_shift_costs`' sum with points out of view as outliers, which ranks
    every cut placement below one in full view (:func:`_shifted_window_xy`)."""
    starts = []
    if (fitted is not None and np.isfinite(fitted).all()
            and math.hypot(*(fitted[:2] - params[:2])) >= apart_m):
        starts.append(np.array([*fitted[:3], 0.0]))
    sigma_m = prior_diagonal[0] ** -0.5
    step_m = SEARCH_STEP_SIGMA * sigma_m
    n = int(2.5 * sigma_m // step_m)
    if n < 1 or outline.shape[1] == 0:
        return starts
    offsets = np.arange(-n, n + 1) * step_m
    de, dn = (g.ravel() for g in np.meshgrid(offsets, offsets))
    keep = (np.hypot(de, dn) <= 2.5 * sigma_m + 1e-9) & (np.hypot(de - params[0], dn - params[1]) >= apart_m)
    de, dn = de[keep], dn[keep]
    shifted = _shifted_window_xy(align, outline, np.zeros(4), de, dn) if len(de) else None
    if shifted is None:
        return starts
    xy, seen = shifted
    cost = np.zeros(seen.shape)
    cost[seen] = tukey_cost(align.sdf.sample(xy[seen].T)[0], SEARCH_TUKEY_PX)
    count = seen.sum(axis=1)
    mean = np.where(count >= CUT_MIN_POINTS, cost.sum(axis=1) / np.maximum(count, 1), np.inf)
    order = np.argsort(mean + 1e-3 * (de ** 2 + dn ** 2), kind="stable")
    return starts + [np.array([de[c], dn[c], 0.0, 0.0]) for c in order[:CUT_STARTS] if np.isfinite(mean[c])]


def _cut_at_sensors(solved: tuple, at_sensors: np.ndarray, in_view: float, fill,
                    settings: PoseRefinementSettings) -> tuple[tuple, bool, float] | None:
    """The placement of a hull the image's border cuts, near the sensors' pose, that the
    image cannot refute, whether any of it is seen, and ``in_view``: ``(candidate, seen,
    in_view)``, or None.

    ``solved`` is an alignment (:func:`gauss_newton`'s ``(params, information, cost,
    signed distances)``) on as few as :data:`CUT_MIN_POINTS` outline points in view;
    ``at_sensors`` the outline's signed distances in view at the sensors' pose,
    ``in_view`` their share of the outline. When that alignment fits what is in view as a
    placement would be accepted (inliers, residual, the silhouette's pixels in view ship,
    of these :data:`CUT_FILL_SHARE` of ``min_ship_fill`` at least), it is the placement,
    seen. When fewer
    than :data:`CUT_MIN_POINTS` points are in view at the sensors' pose, the image says
    nothing of the hull there: the sensors' pose itself, unseen. Otherwise what is in view
    is not this hull's edges: None."""
    params, information, cost, value = solved
    if np.isfinite(cost) and np.isfinite(params).all():
        fraction, residual_px, telling = outline_fit(value)
        filled = fill(params)
        if (telling >= CUT_MIN_POINTS and fraction >= settings.min_inlier_fraction
                and residual_px is not None and residual_px <= settings.max_residual_px
                and filled >= CUT_FILL_SHARE * settings.min_ship_fill
                and not any(_beyond(params, settings.max_shift_m, settings.max_rotation_deg,
                                    settings.max_height_change_m))):
            return (params, information, cost, value, filled), True, in_view
        return None
    if len(at_sensors) < CUT_MIN_POINTS and in_view < CUT_IN_VIEW:
        return (np.zeros(4), None, np.inf, at_sensors, fill(np.zeros(4))), False, in_view
    return None


#: a cut placement is another vessel's only when at most this share of its silhouette lies
#: under the chosen pose's
CUT_OVERLAP = 0.25


def _cut_alike(cut: np.ndarray, seen: bool, params: np.ndarray, align: Alignment,
               silhouette: Silhouette, shape: tuple[int, int]) -> bool:
    """Whether the placement ``cut`` of a hull the image's border cuts may be the vessel's
    as the chosen pose ``params`` may: at most :data:`CUT_OVERLAP` of its silhouette under
    the chosen pose's (sisters lie side by side or in line, apart), and, when part of it is
    ``seen``, its ends in view on edges. Laid from the sensors' pose onto a larger ship the
    vessel touches (a tug 6 m off at 40 m), the relaxed alignment fitted what was in view
    with an end on nothing; on a bench frame it slid the tug 7 m along its own image, an end
    out of the picture. The ring test of sisters' blobs (:func:`_row_rings`) is not asked: a
    placement from so few points lies up to 2 m off, and its ring catches the vessel's own
    pixels (0.2-0.4 of it, against a sister's 0.01-0.03)."""
    if seen and not _ends_on_edges(align, silhouette, cut, against_neighbours=True, unseen_ok=True):
        return False
    drawn = _drawn_in_window(cut, align, silhouette, shape)
    chosen = _drawn_in_window(params, align, silhouette, shape)
    area = 0 if drawn is None else np.count_nonzero(drawn)
    if area == 0 or chosen is None:     # (a hull wholly out of the window overlaps nothing)
        return area > 0 or not seen
    return np.count_nonzero(drawn & chosen) <= CUT_OVERLAP * area


def _twin_alongside(best: tuple, align: Alignment, silhouette: Silhouette, geometry: FrameGeometry,
                    settings: PoseRefinementSettings, prior_diagonal: np.ndarray, solve, fill,
                    ship: np.ndarray, cut: tuple[tuple, bool, float] | None = None,
                    solved: list[tuple] = ()) -> tuple[tuple, str | None]:
    """The placement to keep when the hull may be one of identical vessels moored side by
    side or in a row, and why none can be kept when the sensors cannot tell which.

    A vessel moored between two sister hulls, touching, makes one ship blob three beams
    wide whose every beam-wide strip holds a hull with its bow and stern on edges. The
    alignment's cost counts the outline's points deep inside ship pixels as misses, so a
    placement on an outer twin (one side on the blob's edge) beats the true one (both sides
    against the twins'): on schematic rafts at the documented sensor errors, 41 of 96 frames
    were laid one beam over and applied. Identical vessels moored apart (a marina's row of
    yachts 5 m apart) are separate blobs that fit alike, and the alignment goes to the one
    its start lies nearest: 19 of 96 frames of a 12 m yacht in a row of five were laid a
    berth over at the documented errors. The image cannot tell such placements apart, so
    the prior must. When ``best`` (a candidate ``(params, information, cost, signed
    distances, fill)``) has :data:`TWIN_DEEP_SHARE` of its outline deep in ship pixels, the
    alignment is run again from a beam to either side where the silhouette there is filled
    (``fill(params)`` its share of ship pixels; ``solve(start)`` returns a candidate); and
    from the other blobs of the hull's size the prior cannot rule out
    (:func:`_blob_starts`); the candidates the refinement ``solved`` already (from the
    sensors' pose and a beam to either side) are checked as those from blobs are, with no
    solve (a hull partly out of the picture, fitted 5 m off its sister from a start a beam
    over, lost to the sister on cost, its points out of view counted as misses, and was
    never compared). Of ``best`` and the placements that fit as one would be
    accepted (:func:`_fits_alike`), all :data:`TWIN_APART_BEAMS` beams or more apart, the
    one nearest the sensors' pose under the prior (of the shifts alone, :func:`_shift_d2`)
    is kept, when it is nearer than the next by :data:`TWIN_ODDS_D2`; otherwise the reason to keep the
    sensors' pose is returned with it.

    A hull the image's border cuts at the sensors' pose (``cut``, :func:`_cut_at_sensors`)
    has too few outline points in view to be scored against a sister in full view, which
    then wins on cost alone: a yacht in a row seen from 75 m to one side was laid a berth
    over on 35 of 144 frames, most of them with its own hull partly out of view. That
    placement joins the comparison; when it is the likelier, or the odds cannot tell, the
    sensors' pose is kept."""
    params, value = best[0], best[3]
    if not len(value):
        return best, None
    beam_m = float(np.ptp(silhouette.points_h[1]))
    heading = geometry.vessel_heading_rad + float(params[2])
    across = np.array([math.cos(heading), -math.sin(heading)])      # starboard, in ENU
    bow = np.array([math.sin(heading), math.cos(heading)])
    # (a step under half a beam lands on every sister's blob, however wide the prior)
    on_blobs, merged = _blob_starts(params, align, silhouette, ship, prior_diagonal,
                                    min(SEARCH_STEP_SIGMA * prior_diagonal[0] ** -0.5, 0.5 * beam_m),
                                    TWIN_APART_BEAMS * beam_m, settings.max_shift_m)
    # (start, or candidate already solved; whence: "solved", "beside" (not compared with
    # the chosen pose's fit, nor its ring) or "blob")
    starts = [(c, "solved") for c in solved if c is not best]
    if merged or np.count_nonzero(value < -DEEP_PX) >= TWIN_DEEP_SHARE * len(value):
        for side in (1.0, -1.0):
            start = params + side * beam_m * np.array([*across, 0.0, 0.0])
            if fill(start) >= settings.min_ship_fill:   # else water or a quay: no twin (a solve ~2 ms)
                starts.append((start, "beside"))
    starts += [(start, "blob") for start in on_blobs]
    best_fraction = None        # reckoned once, when a placement asks
    alike = [best]
    for start, whence in starts:
        found = start if isinstance(start, tuple) else solve(start)
        if not (all(math.hypot(*(found[0][:2] - c[0][:2])) >= TWIN_APART_BEAMS * beam_m for c in alike)
                and _fits_alike(found, align, silhouette, settings)):
            continue
        if whence != "beside":
            if best_fraction is None:
                best_fraction = outline_fit(value)[0]
            fraction, _, telling = outline_fit(found[3])
            below = (TWIN_BLOB_FRACTION if whence == "blob"
                     else max(TWIN_SOLVED_FRACTION, TWIN_SOLVED_MISSES / telling))
            if fraction < best_fraction - below:
                continue
            best_ring, found_ring = _row_rings(params, found[0], align, silhouette, ship)
            if found_ring > best_ring + TWIN_BLOB_RING:
                continue        # ship beyond its outline: a larger vessel of another shape
        alike.append(found)
    cut_at = None       # the index of the cut placement in ``alike``
    if cut is not None and all(math.hypot(*(cut[0][0][:2] - c[0][:2])) >= TWIN_APART_BEAMS * beam_m
                               for c in alike) and _cut_alike(cut[0][0], cut[1], params, align,
                                                              silhouette, ship.shape):
        alike.append(cut[0])
        cut_at = len(alike) - 1
    if len(alike) == 1:
        return best, None
    d2 = [_shift_d2(c[0], prior_diagonal) for c in alike]
    first, second = np.argsort(d2, kind="stable")[:2]
    odds = math.exp(0.5 * (d2[second] - d2[first]))
    offset_m = alike[second][0][:2] - alike[first][0][:2]
    if cut_at in (first, second):
        if first != cut_at and d2[second] - d2[first] >= TWIN_ODDS_D2:
            return alike[first], None
        said = (f"{100 * cut[2]:.0f} % of its outline in view"
                + (", fitting the mask there" if cut[1] else ""))
        apart_m = math.hypot(*offset_m)
        if first == cut_at and d2[second] - d2[first] >= TWIN_ODDS_D2:
            return best, (f"{CUT_ALIKE}({said}); a placement {apart_m:.1f} m from there fits the "
                          f"mask in full, but the sensors' pose favours the hull where they put it "
                          f"{odds:.0f} to 1")
        return best, (f"{CUT_ALIKE}({said}), and a placement {apart_m:.1f} m from there fits the "
                      f"mask as well: the sensors' pose tells them apart only {odds:.1f} to 1 "
                      f"(at least {math.exp(0.5 * TWIN_ODDS_D2):.0f} to 1 needed)")
    if d2[second] - d2[first] >= TWIN_ODDS_D2:
        return alike[first], None
    abeam = abs(float(offset_m @ across)) >= abs(float(offset_m @ bow))
    where = "abeam (a vessel alike alongside)" if abeam else "ahead or astern (a vessel alike in line)"
    return alike[first], (f"{TWIN_ALIKE}{math.hypot(*offset_m):.1f} m {where}, and the "
                      f"sensors' pose tells them apart only {odds:.1f} to 1 "
                      f"(at least {math.exp(0.5 * TWIN_ODDS_D2):.0f} to 1 needed)")


#: a refused correction that puts this much more of the outline on ship edges than the
#: sensors' pose contradicts the sensors (:func:`contradicts_sensors`)
CONTRADICTION_GAIN = 0.25
#: the share of the outline that must be in view for a correction to contradict the sensors
CONTRADICTION_MIN_IN_VIEW = 0.7
#: what a user should check when the image contradicts the sensors' pose
CONTRADICTION_ADVICE = ("check the GPS positions, the altitude (ellipsoidal or above the water), "
                        "the water level, the heading source (a course over ground while going "
                        "astern), the camera's yaw (from true north, not from the drone's nose) "
                        "and its pitch (a gimbal given as straight down, --mount stabilised, "
                        "that is not) and the camera's focal length (a video mode or "
                        "stabilisation that crops the sensor)")
#: the reasons that refuse a correction for its size alone
BEYOND_LIMITS = ("shift ", "rotation ", "height change ")
#: a correction that puts at least this share of the outline on ship edges, at most this
#: RMS residual (px), with the silhouette this full of ship pixels, fits the mask cleanly
CLEAN_FIT_FRACTION, CLEAN_FIT_RESIDUAL_PX, CLEAN_FIT_FILL = 0.95, 0.5, 0.99


def clean_fit(fraction: float, residual_px: float | None, ship_fill: float) -> bool:
    """Whether a correction fits the mask cleanly (:data:`CLEAN_FIT_FRACTION` and the
    rest): a height change beyond the limits that does is the image's own measure of the
    scale, and contradicts the frame's (:func:`contradicts_sensors`)."""
    return (fraction >= CLEAN_FIT_FRACTION and residual_px is not None
            and residual_px <= CLEAN_FIT_RESIDUAL_PX and ship_fill >= CLEAN_FIT_FILL)


def contradicts_sensors(fraction_before: float, fraction: float, ship_fill: float,
                        residual_px: float | None, settings: PoseRefinementSettings,
                        in_view: float = 1.0, scale_beyond: bool = False) -> bool:
    """Whether a correction refused for its size alone shows the sensors' pose wrong: it
    passes every test of fit (inliers, ship fill, residual), and the sensors' pose leaves
    fewer than ``min_inlier_fraction`` of the outline on a ship edge or
    :data:`CONTRADICTION_GAIN` fewer than the correction, or the correction is a height
    the image's scale calls for beyond the frame's (``scale_beyond``,
    :func:`_image_scale`: a scale error a few per cent off leaves most of the
    outline on edges at the sensors' pose). An altitude 5 m off (a water level
    left at 0 on a tide) or a magnetic heading taken for true 15 degrees off is such a case:
    the pose the distances are read with is then known to be wrong, by more than any sigma
    says (on the sample frames a quay 5.05 m away read 21.6 ± 2.3 m). Only a hull mostly in
    view (``in_view``, the share of the outline's samples in the image, at least
    :data:`CONTRADICTION_MIN_IN_VIEW`) can say so: of a bow alone, a wrong height and shift
    fit as well as the truth (a 30 m bench frame with 36 % of the hull in view "found" a
    height 10.7 m off)."""
    return (in_view >= CONTRADICTION_MIN_IN_VIEW
            and (fraction_before < settings.min_inlier_fraction
                 or fraction - fraction_before >= CONTRADICTION_GAIN or scale_beyond)
            and fraction >= settings.min_inlier_fraction
            and ship_fill >= settings.min_ship_fill
            and residual_px is not None and residual_px <= settings.max_residual_px)


def refinement_counts(refinements: list[dict[str, Any] | None]) -> dict[str, int]:
    """How a batch's frames came out: ``applied``, ``sensors_pose_fitted`` (kept, fitting as
    well), ``kept_sensors_pose`` (kept, the alignment not trusted) and ``off``; and, of them
    all, ``carried`` (the vessel's pose carried from earlier frames' images,
    :mod:`harborsight.flight.pose_carry`)."""
    given = [r for r in refinements if r]
    off = sum(r.get("reason") == "off" for r in given)
    applied = sum(bool(r.get("applied")) for r in given)
    fitted = sum(r.get("reason") == SENSORS_FIT for r in given)
    return {"applied": applied, "sensors_pose_fitted": fitted,
            "kept_sensors_pose": len(given) - off - applied - fitted, "off": off,
            "carried": sum(bool(r.get("carried_from")) for r in given)}


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
        line = (f"the image contradicts the sensors' pose on {contradicted} frame(s): their "
                "distances' lower bounds and clear reaches are 0; ") + line
    if counts["sensors_pose_fitted"]:
        line += f"; the sensors' pose fitted as well on {counts['sensors_pose_fitted']}"
    if counts["carried"]:
        line += (f"; the vessel's pose carried from earlier frames' images on "
                 f"{counts['carried']} (its reports too old)")
    kept = [str(r.get("reason") or "") for r in refinements
            if r and not r.get("applied") and r.get("reason") not in ("off", SENSORS_FIT)]
    if kept:
        kinds: dict[str, int] = {}
        for reason in kept:
            kind = " ".join("".join(ch for ch in reason if not (ch.isdigit() or ch in ".-+")).split())
            kinds[kind] = kinds.get(kind, 0) + 1
        top = sorted(kinds.items(), key=lambda kv: -kv[1])[:3]
        line += f"; the sensors' pose kept on {len(kept)} (" + "; ".join(
            f"{n}x {kind}" for kind, n in top) + ")"
    return line + _scale_note(refinements)


#: a batch whose frames' hulls put the scale off by this share (median) gets a note, from
#: :data:`SCALE_NOTE_MIN_FRAMES` frames whose correction was applied or the scale test fired
SCALE_NOTE_SHARE = 0.02
SCALE_NOTE_MIN_FRAMES = 5


def _scale_note(refinements: list[dict[str, Any] | None]) -> str:
    """A clause for a batch whose hulls, frame after frame, are larger or smaller in the
    image than the altitude and focal length say (``scale_change``, median over the frames
    that applied a correction or re-solved the scale): one frame's scale may be a mask's
    error, a flight's median is the camera's or the altimeter's. Held by its prior, a frame
    corrects only part of a focal length 5 % off (a median 2 % on the bench), so the note
    starts at :data:`SCALE_NOTE_SHARE`; with right sensors the bench's median was under
    0.5 %. "" when there is nothing to say."""
    changes = [float(r["scale_change"]) for r in refinements
               if r and r.get("scale_change") is not None
               and (r.get("applied") or r.get("scale_prior_m") is not None)]
    if len(changes) < SCALE_NOTE_MIN_FRAMES:
        return ""
    median = float(np.median(changes))
    if abs(median) < SCALE_NOTE_SHARE:
        return ""
    side = "lower" if median < 0 else "higher"
    return (f"; the hull's size in the image puts the drone a median {100 * abs(median):.1f} % "
            f"{side} than its altitude on {len(changes)} frame(s): check the camera's focal "
            "length (a video mode or stabilisation that crops the sensor) and the altitude")
