"""When the image contradicts the sensors: the sizes of a correction, what makes one gross,
and the whole-image search's verdict on the pose the refinement kept or applied.

A correction the refinement refuses for its size alone, but which fits the mask as well as
an accepted one would, shows the sensors' pose wrong (:func:`contradicts_sensors`); so does
a placement of the hull the whole-image search
(:mod:`harborsight.clearance.pose_search`) finds where the pose kept leaves its outline off
the ship's edges (:func:`gross_error`). The frame's distances are then flagged, not
corrected (:func:`harborsight.clearance.pose_refinement.refine_vessel_pose`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from harborsight.clearance.alignment import DEEP_PX, Alignment, Silhouette, ship_fill
from harborsight.clearance.camera_errors import camera_yaw_explains
from harborsight.clearance.obstacles import IGNORE, SHIP
from harborsight.clearance.pose_search import (
    Placement,
    edge_share,
    place_hull,
    silhouette_overlap,
    whole_image_alignment,
)
from harborsight.clearance.prior_search import prior_reach
from harborsight.frame import FrameGeometry
from harborsight.vessel.spec import VesselSpec

if TYPE_CHECKING:
    from harborsight.clearance.pose_refinement import PoseRefinement, PoseRefinementSettings


def as_params(found: PoseRefinement) -> np.ndarray:
    """A refinement's correction as ``(de, dn, dpsi rad, dh)``."""
    return np.array([*found.shift_m, math.radians(found.rotation_deg), found.height_change_m])


def gross_parts(params: np.ndarray, geometry: FrameGeometry, settings: PoseRefinementSettings) -> list[bool]:
    """Which of shift, rotation and height of a correction are gross: beyond the limits, the
    height also beyond :data:`GROSS_HEIGHT_SHARE` of the camera's height."""
    return beyond(params, settings.max_shift_m, settings.max_rotation_deg, max(
        settings.max_height_change_m, GROSS_HEIGHT_SHARE * float(geometry.camera.position_enu[2])))


def correction_sizes(params: np.ndarray) -> tuple[float, float, float]:
    """``(shift m, rotation deg in [-180, 180), height change m)`` of a correction."""
    turn = (float(params[2]) + math.pi) % (2 * math.pi) - math.pi
    return float(np.hypot(*params[:2])), math.degrees(turn), float(params[3])


def beyond(params: np.ndarray, shift_m: float, rotation_deg: float, height_m: float) -> list[bool]:
    """Which of a correction's shift, rotation and height change exceed ``shift_m``,
    ``rotation_deg`` and ``height_m``."""
    shift, rotation, height = correction_sizes(params)
    return [shift > shift_m, abs(rotation) > rotation_deg, abs(height) > height_m]


#: a height change found by the whole-image search counts as a gross error only beyond this
#: share of the camera's height as well as the limit: a model's mask a pixel or two narrow
#: all round shrinks a hull 60 px long by several per cent (a 120 m bench frame "found" its
#: height 10 m off, 9 %; ellipsoidal heights read as heights above the water were 23 % and
#: more of the bench's altitudes)
GROSS_HEIGHT_SHARE = 0.15


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
    :func:`pose_refinement._image_scale`: a scale error a few per cent off leaves most of the
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


#: the whole image is searched when the pose kept or applied puts fewer of the outline's
#: points in view on a ship edge than this (:func:`pose_search.edge_share`)
SEARCH_BELOW_SHARE = 0.8
#: and slides the predicted silhouette over the whole image (a chamfer match of its outline,
#: :func:`pose_search._sliding_starts`) when the pose leaves under this share there: the
#: outline is then off its ship altogether, not pressed against a neighbour
SLIDE_BELOW_SHARE = 0.5
#: a sensors' pose kept with under this share of its outline's points in view on a ship
#: edge, and placed nowhere else by the search, is not borne out by the image
#: (:func:`pose_refinement._unconfirmed`)
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


def ends_on_edges(align: Alignment, silhouette: Silhouette, params: np.ndarray,
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


def gross_error(labels: np.ndarray, ship_or_hole: np.ndarray, geometry: FrameGeometry,
                found: PoseRefinement, vessel: VesselSpec, settings: PoseRefinementSettings
                ) -> Placement | None:
    """The image's own placement of the hull (:func:`pose_search.place_hull`) when it shows
    the pose the refinement kept or applied wrong: that pose puts under
    :data:`SEARCH_BELOW_SHARE` of its outline's points in view on a ship edge, and the
    placement puts :data:`SEARCH_GAIN` more there (and at least that share), passes
    every test of fit, has at least :data:`CONTRADICTION_MIN_IN_VIEW` of its outline in view
    and, when the pose sits on a ship (fills ship pixels and has :data:`HELD_FROM_SHARE` of
    its outline on edges, or both its ends: :func:`ends_on_edges`), overlaps it
    (:data:`SAME_SHIP_OVERLAP`). None otherwise."""
    share = found.edge_share or 0.0
    if share >= SEARCH_BELOW_SHARE:
        return None
    ship = labels == SHIP
    if not ship.any():
        return None
    align = whole_image_alignment(ship, geometry)
    silhouette = Silhouette(vessel.alignment_layers)
    chosen = as_params(found) if found.applied else np.zeros(4)
    # the fills read the blobs' holes as ship (``ship_or_hole``, alignment.ship_holes_filled);
    # the blobs' outer contours, which place the starts, are the same
    known = (labels != IGNORE) | ship_or_hole
    # the refinement's own correction, refused for its size, is a start too: the search's
    # blob starts may lay the hull on another ship (a 22 m shift at 150 m, exact labels)
    refused = (as_params(found),) if (found.reason or "").startswith(BEYOND_LIMITS) else ()
    chosen_uv = align.pixels(silhouette.points_h, chosen)
    whole = (slice(0, labels.shape[0]), slice(0, labels.shape[1]))
    on_a_ship = ((share >= HELD_FROM_SHARE or ends_on_edges(align, silhouette, chosen))
                 and ship_fill(silhouette.layers_uv(chosen_uv), whole, ship_or_hole, known)
                 >= settings.min_ship_fill)

    def elsewhere(params: np.ndarray) -> bool:
        """The pose sits on a ship, and ``params`` lay the hull on another one."""
        return on_a_ship and silhouette_overlap(
            chosen_uv, align.pixels(silhouette.points_h, params)) < SAME_SHIP_OVERLAP

    reach_shift_m = prior_reach(settings)[0]

    def gross_errors(params: np.ndarray) -> int:
        gross = gross_parts(params, geometry, settings)
        if (gross[0] or gross[1]) and camera_yaw_explains(params, geometry, reach_shift_m):
            return 1 + gross[2]             # shift and turn are one error: the camera's yaw
        return sum(gross)

    placement = place_hull(align, silhouette, ship_or_hole, known, settings.edge_sigma_px ** -2.0,
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
