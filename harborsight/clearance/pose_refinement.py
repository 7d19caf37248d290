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
(:func:`prior_search.translation_search`), and the lowest final Tukey cost among the
filled candidates wins. When the pose kept or applied leaves its outline short of ship
edges, the whole image is searched for the hull (:mod:`harborsight.clearance.pose_search`):
a placement it finds within the limits is one more start, run whatever the first start
left.

**Where the parts live.** This module runs the refinement and decides what is applied;
:mod:`~harborsight.clearance.alignment` holds the signed distance, the projection and
Gauss-Newton; :mod:`~harborsight.clearance.prior_search` the window the outline can reach
and the coarse grid over the prior; :mod:`~harborsight.clearance.sister_hulls` the checks
for identical vessels that fit the mask as well and for a hull the border cuts;
:mod:`~harborsight.clearance.gross_errors` when the image contradicts the sensors (a
correction beyond the limits, the whole-image search's placement);
:mod:`~harborsight.clearance.refinement_summary` the line a batch prints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from harborsight.clearance.alignment import (
    MIN_EDGE_POINTS,
    SCHEDULES,
    Alignment,
    SignedDistance,
    Silhouette,
    corrected_geometry,
    gauss_newton,
    outline_fit,
    ship_fill,
    ship_holes_filled,
)
from harborsight.clearance.along_hull import along_direction, sees_along
from harborsight.clearance.camera_errors import camera_tilt_explaining, camera_yaw_explains
from harborsight.clearance.gross_errors import (
    BEYOND_LIMITS,
    CONTRADICTION_MIN_IN_VIEW,
    SEARCH_BELOW_SHARE,
    UNCONFIRMED_BELOW_SHARE,
    beyond,
    clean_fit,
    contradicts_sensors,
    correction_sizes,
    gross_error,
    gross_parts,
)
from harborsight.clearance.obstacles import IGNORE, SHIP
from harborsight.clearance.pose_search import edge_share
from harborsight.clearance.prior_search import prior_reach, search_window, translation_search
from harborsight.clearance.sister_hulls import CUT_ALIKE, TWIN_ALIKE, cut_hull, twin_alongside
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
    #: (:func:`gross_errors.contradicts_sensors`, or the whole-image search:
    #: :func:`gross_errors.gross_error`); or the image shows no vessel where the sensors put
    #: it, and nowhere else (:func:`_unconfirmed`)
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
    #: no outline edge in view told the hull's place along its length: the shift along it was held
    #: at the sensors' value, whose error in it the bars keep (:mod:`.along_hull`)
    along_hull_held: bool = False
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
            "along_hull_held": self.along_hull_held,
            "scale_change": (rounded(self.height_change_m / self.height_m, 4)
                             if self.height_m else None),
        }


OFF = PoseRefinement(applied=False, reason="off")



def refine_vessel_pose(
    labels: np.ndarray, geometry: FrameGeometry, vessel: VesselSpec,
    settings: PoseRefinementSettings = PoseRefinementSettings(),
) -> tuple[FrameGeometry, PoseRefinement]:
    """Align the vessel's projected silhouette to the mask's ship pixels (module docstring).

    Returns the geometry to measure with (refined, or the given one when the alignment is
    not trustworthy) and what was found. When the pose kept or applied leaves its outline
    short of ship edges, the whole image is searched for the hull
    (:func:`gross_errors.gross_error`). A placement found there within the limits becomes
    one more start of the refinement (whose result replaces the first only when it applies
    a correction); one beyond them in exactly one of shift, rotation and height, with the
    other two within the refinement's reach (2.5 sigma of the prior for shift and rotation,
    the limit for height), contradicts the sensors; a shift and a turn that one camera yaw
    error explains count as one
    (:func:`~harborsight.clearance.camera_errors.camera_yaw_explains`), and so do a shift
    and a height change (with a turn) that one camera tilt explains
    (:func:`~harborsight.clearance.camera_errors.camera_tilt_explaining`). Beyond in two at
    once, it is more often a bad mask than two gross sensor errors (on the bench with the
    default model, 6 of 130 frames with 2 m and 2 degree sensors had such placements); a
    height counts as gross only beyond :data:`gross_errors.GROSS_HEIGHT_SHARE` of the
    camera's height. When the search changes nothing and the sensors' pose kept leaves its
    outline off the ship's edges, that contradicts the sensors too (:func:`_unconfirmed`).
    A pose kept because vessels alike fit the mask as well, or because the hull where the
    sensors put it is cut by the image's border and a placement elsewhere cannot be told
    from it (:func:`sister_hulls.twin_alongside`), is not searched: the search would find
    one of them. Never raises for a failed alignment.
    """
    if not settings.enabled:
        return geometry, OFF
    # the fills read a blob's holes as ship: a model's patches of a deck took the true
    # placement under the gate (alignment.ship_holes_filled)
    ship_or_hole = ship_holes_filled(labels) == SHIP
    refined, found = _refine_within_prior(labels, ship_or_hole, geometry, vessel, settings)
    if (not settings.search_whole_image or found.sensors_contradicted or found.reason in NOT_IN_VIEW
            or (found.reason or "").startswith((TWIN_ALIKE, CUT_ALIKE))):
        return refined, found       # (the image holds vessels alike: it would find one of them)
    chosen, result = _search_whole_image(labels, ship_or_hole, geometry, refined, found, vessel,
                                         settings)
    if result is found:         # the search changed nothing: is the pose kept borne out?
        result = _unconfirmed(found, geometry, vessel)
    return chosen, result


def _unconfirmed(found: PoseRefinement, geometry: FrameGeometry, vessel: VesselSpec) -> PoseRefinement:
    """``found``, flagged ``sensors_contradicted`` when the sensors' pose is kept although
    under :data:`gross_errors.UNCONFIRMED_BELOW_SHARE` of its outline's points in view lie
    on a ship edge with the hull mostly in view
    (:data:`gross_errors.CONTRADICTION_MIN_IN_VIEW`) and the whole-image search placed it
    nowhere: the image does not show the vessel where the sensors put it.
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


def _search_whole_image(labels: np.ndarray, ship_or_hole: np.ndarray, geometry: FrameGeometry,
                        refined: FrameGeometry, found: PoseRefinement, vessel: VesselSpec,
                        settings: PoseRefinementSettings) -> tuple[FrameGeometry, PoseRefinement]:
    """What the whole-image search makes of the refinement's result (``refined``, ``found``):
    that result, unchanged, unless a placement corrects or contradicts it
    (:func:`refine_vessel_pose`)."""
    placement = gross_error(labels, ship_or_hole, geometry, found, vessel, settings)
    if placement is None:
        return refined, found
    shift_m, rotation_deg, height_change_m = correction_sizes(placement.params)
    limits = beyond(placement.params, settings.max_shift_m, settings.max_rotation_deg,
                     settings.max_height_change_m)
    if not any(limits):
        # within the limits, beyond the refinement's basin: refine again from there, and keep
        # the first result unless that applies a correction
        params = placement.params.copy()
        params[2] = math.radians(rotation_deg)
        again = _refine_within_prior(labels, ship_or_hole, geometry, vessel, settings,
                                     extra_start=params)
        return again if again[1].applied else (refined, found)
    gross = gross_parts(placement.params, geometry, settings)
    reach_shift_m, reach_rotation_deg, reach_height_m = prior_reach(settings)
    reach = beyond(placement.params, reach_shift_m, reach_rotation_deg, reach_height_m)
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



#: the refinement's reasons when the hull is not in view at the sensors' pose: nothing to
#: search for (a ship in view is another)
NOT_IN_VIEW = ("the hull does not project into the image", "the hull is not in the image")


#: the hull's size in the image disagrees with the frame's scale (its height and focal
#: length, :meth:`SensorSigmas.scale_height_m`) when the image's own estimate of the height
#: lies beyond this many sigma of the prior's (:func:`_image_scale`); a linear look at the
#: fit held by the prior screens for it first, from :data:`SCALE_SCREEN_Z`
SCALE_CONFLICT_Z = 3.0
SCALE_SCREEN_Z = 1.5


def _image_scale(align: Alignment, silhouette: Silhouette, outline: np.ndarray, params: np.ndarray,
                 information: np.ndarray, value: np.ndarray, prior_diagonal: np.ndarray,
                 edge_weight: float, geometry: FrameGeometry, edge_px: float,
                 held: np.ndarray | None = None) -> tuple[tuple, float] | None:
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
    again = gauss_newton(align, silhouette, outline, SCHEDULES[0], params, widened, edge_weight, held)
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
    labels: np.ndarray, ship_or_hole: np.ndarray, geometry: FrameGeometry, vessel: VesselSpec,
    settings: PoseRefinementSettings, extra_start: np.ndarray | None = None,
    hold_along: bool = False,
) -> tuple[FrameGeometry, PoseRefinement]:
    """The refinement proper, within the sensors' prior; ``ship_or_hole``, the ship pixels and
    their blobs' holes, which a placement's fill reads (:func:`refine_vessel_pose`);
    ``extra_start`` (a correction the whole-image search found within the limits) joins the
    starts, and the window reaches it. When no outline edge in view tells the hull's place
    along its length, at the sensors' pose nor at the correction found, it runs again with
    the shift along the hull held at the sensors' (``hold_along``, :mod:`.along_hull`)."""
    silhouette = Silhouette(vessel.alignment_layers)
    outline = silhouette.outline(_pixels(geometry, silhouette))
    if outline.shape[1] == 0:
        return geometry, PoseRefinement(False, reason=NOT_IN_VIEW[0])
    uv0 = geometry.camera.project(geometry.vessel_to_enu(outline[:3].T))[0]
    if extra_start is not None:
        moved = corrected_geometry(geometry, extra_start)
        uv0 = np.vstack((uv0, moved.camera.project(moved.vessel_to_enu(outline[:3].T))[0]))
    window = search_window(uv0, geometry, vessel, settings, labels.shape)
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

    held = along_direction(geometry.vessel_heading_rad) if hold_along else None

    def solve(schedule, start: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        return gauss_newton(align, silhouette, outline, schedule, start, prior_diagonal, edge_weight,
                            held)

    filled = ship_or_hole[window]
    known = (labels[window] != IGNORE) | filled

    def fill(params: np.ndarray) -> float:
        return ship_fill(silhouette.layers_uv(align.pixels(silhouette.points_h, params)), window,
                         filled, known)

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
                   for de, dn in translation_search(align, outline, settings, starts)]
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
                             edge_weight, geometry, settings.scale_edge_px, held)
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

        cut = cut_hull(align, silhouette, outline, at_sensors, params, prior_diagonal,
                        edge_weight, fill, settings)
        best, twin_alike = twin_alongside(best, align, silhouette, geometry, settings,
                                           prior_diagonal, solve_and_fill, fill, ship, cut,
                                           solved=candidates)
        params, information, _, value, fill_share = best

    if (not hold_along and np.isfinite(params).all() and not sees_along(align, silhouette, np.zeros(4))
            and not sees_along(align, silhouette, params, on_edges=True)):
        # with no edge across the hull's length in view the image cannot place it along it
        return _refine_within_prior(labels, ship_or_hole, geometry, vessel, settings, extra_start,
                                    hold_along=True)
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
                           scale_prior_m=scale_prior_m, along_hull_held=held is not None,
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
    elif residual_px is None:       # (reachable with min_inlier_fraction 0 only)
        reason = "no outline point within reach of a ship edge: no residual"
    elif residual_px > settings.max_residual_px:
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
