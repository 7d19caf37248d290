"""Per-section clearance of one frame: label mask + poses + vessel -> report.

Pipeline (paper Sec. III, with the changes noted in ``docs/geometry.md``):

1. project the hull outline and the whole vessel into the image
   (``T_IV = K · T_CB · T_BW · T_WV``);
2. obstacles = solid (not water) minus the vessel's own image region; contours with
   ``cv2.findContours``; image-border points dropped;
3. assign every contour point to the section whose band holds it and take, per section,
   the nearest one:

   * ``ground_plane`` (default): contour pixels are back-projected onto the water plane
     with the full camera pose, and bands and distances are computed there, in metres;
   * ``gsd`` (the paper's): bands and distances in pixels, times the nadir GSD
     ``a · max(1/fx, 1/fy)``;

4. pixel-boundary correction: a contour pixel is the centre of the outermost solid pixel,
   so the chosen obstacle point is moved toward the hull by its depth inside the edge,
   estimated from a line through its contour neighbours where the edge is straight, else
   to where the ray leaves its square (0.5 to 0.71 px; :mod:`~harborsight.clearance.pixel_edge`),
   before its distance is taken (not where the move would cross a barrel lens's fold); a section
   whose nearest point has no place in the image or on the water is ``out_of_view``;
5. band edges: a contour pixel whose square (not only its centre) reaches into a
   neighbouring band is also a candidate of that band, so an obstacle corner poking less
   than a pixel into a band is not missed (see ``band_edge_pixels``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
import shapely
from shapely.geometry import LinearRing

from harborsight.clearance.band_edges import (
    Candidates,
    band_crossings,
    band_edge_pixels,
    beside_a_boundary_ray,
)
from harborsight.clearance.band_margin import cap_by_neighbours_margins, pose_kept_unconfirmed
from harborsight.clearance.edge_evidence import CONFIDENT_SOLID_P
from harborsight.clearance.obstacles import (
    LABEL_VALUES,
    hidden_water_edge,
    obstacle_contours,
    own_vessel_region,
)
from harborsight.clearance.own_motion import add_own_rates
from harborsight.clearance.pixel_edge import edge_shift_px
from harborsight.clearance.pose_refinement import PoseRefinementSettings, refine_vessel_pose
from harborsight.clearance.report import (
    STATUS_CLEAR,
    STATUS_OK,
    STATUS_OUT_OF_VIEW,
    ClearanceReport,
    SectionClearance,
)
from harborsight.clearance.uncertainty import (
    LOWER_BOUND_QUANTILE,
    FrameVelocities,
    add_nadir_approximation,
    add_section_uncertainty,
)
from harborsight.errors import InputError
from harborsight.frame import FrameGeometry, FrameMetadata
from harborsight.geometry.camera import CameraIntrinsics, ray_edge_px
from harborsight.geometry.gsd import nadir_gsd_m_per_px
from harborsight.geometry.sensor_sigmas import (
    LABEL_FILE_EDGE_M,
    LABEL_FILE_EDGE_PX,
    MAX_DEAD_RECKONED_S,
    SensorSigmas,
    dead_reckoning_drift,
    sigmas_for_frame,
)
from harborsight.perception.confidence import SolidConfidence
from harborsight.vessel.sections import SectionAssignment, SectionedOutline
from harborsight.vessel.spec import VesselSpec

METHODS = ("ground_plane", "gsd")
_VISIBILITY_SAMPLES_PER_SECTION = 16


@dataclass(frozen=True)
class ClearanceSettings:
    """How to measure: method, the own-vessel margin, an optional section override and
    the pose refinement (on by default)."""

    method: str = "ground_plane"
    pose_margin_px: float = 2.0
    own_rim_px: int = 4
    n_sections: int | None = None
    section_length_m: float | None = None
    pose_refinement: PoseRefinementSettings = field(default_factory=PoseRefinementSettings)
    #: ``--sigma NAME=VALUE`` pairs: the sensor sigmas of frames that do not carry their own
    sigma_options: tuple[tuple[str, float], ...] = ()
    #: each section's own rate from the frame's vessel velocity, when it gives one
    #: (:mod:`harborsight.clearance.own_motion`; ``--no-own-motion`` turns it off)
    own_motion: bool = True

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if not np.isfinite(self.pose_margin_px) or self.pose_margin_px < 0:
            raise ValueError(f"pose_margin_px must be >= 0, got {self.pose_margin_px}")
        if self.own_rim_px < 0:
            raise ValueError(f"own_rim_px must be >= 0, got {self.own_rim_px}")
        SensorSigmas().with_values(dict(self.sigma_options))     # names and values checked

    def sensor_sigmas(self, meta: FrameMetadata | None = None, mask_from_file: bool = False
                      ) -> SensorSigmas:
        """The sigmas of one frame: its own figures, else ``sigma_options``, else the
        defaults (a mask read from a file has the file default's edge sigma)."""
        base = (SensorSigmas(edge_px=LABEL_FILE_EDGE_PX, edge_m=LABEL_FILE_EDGE_M)
                if mask_from_file else SensorSigmas())
        base = base.with_values(dict(self.sigma_options))
        return (sigmas_for_frame(base, meta.sensor_sigmas, meta.vessel_dead_reckoned_s)
                if meta is not None else base)


def check_label_mask(labels: np.ndarray, width: int, height: int, source: str | None) -> None:
    """Raise :class:`InputError` for a mask of the wrong size, type or class values."""
    if labels.ndim != 2:
        raise InputError(source, "mask", f"expected one channel, got shape {labels.shape}")
    if labels.shape != (height, width):
        raise InputError(
            source, "mask",
            f"size {labels.shape[1]}x{labels.shape[0]} differs from camera {width}x{height}",
        )
    if labels.dtype != np.uint8:
        raise InputError(source, "mask", f"expected uint8 labels, got {labels.dtype}")
    values = np.flatnonzero(np.bincount(labels.ravel(), minlength=256))
    unknown = sorted(set(values.tolist()) - set(LABEL_VALUES))
    if unknown:
        raise InputError(
            source, "mask",
            f"unknown class values {unknown[:8]} (expected 0 water, 1 ship, 2 obstacle, 255 ignore)",
        )


def measure_frame(
    labels: np.ndarray, meta: FrameMetadata, vessel: VesselSpec,
    settings: ClearanceSettings = ClearanceSettings(), mask_source: str | None = None,
    *, mask_from_file: bool = False, confidence: SolidConfidence | None = None,
) -> ClearanceReport:
    """Measure one frame from its metadata (validates the mask against the camera).
    ``mask_from_file``: the labels were read from a file, not segmented by a model (it sets
    the default edge sigma of the distances' uncertainty); ``confidence``: the model's
    probabilities behind ``labels``, which widen the sigma where it doubts an obstacle."""
    check_label_mask(labels, meta.camera.width, meta.camera.height, mask_source or meta.source)
    check_dead_reckoning(meta)
    geometry = FrameGeometry.from_metadata(meta)
    velocities = FrameVelocities(meta.uav_velocity_en_mps, meta.vessel_velocity_en_mps,
                                 meta.vessel_velocity_sigma_mps, meta.vessel_yaw_rate_deg_s,
                                 meta.vessel_yaw_rate_sigma_deg_s)
    report = measure_clearance(labels, geometry, vessel, settings,
                               sigmas=settings.sensor_sigmas(meta, mask_from_file),
                               velocities=velocities, confidence=confidence)
    report.image = meta.image
    report.timestamp = meta.timestamp
    if report.uncertainty is not None:
        report.uncertainty["from_frame"] = sorted(meta.sensor_sigmas)
        report.uncertainty["velocities"] = (meta.uav_velocity_en_mps is not None
                                            and meta.vessel_velocity_en_mps is not None)
    return report


def check_dead_reckoning(meta: FrameMetadata) -> None:
    """Raise :class:`InputError` for a vessel pose dead-reckoned longer than
    :data:`~harborsight.geometry.sensor_sigmas.MAX_DEAD_RECKONED_S`."""
    age_s = meta.vessel_dead_reckoned_s
    if age_s is not None and age_s > MAX_DEAD_RECKONED_S:
        raise InputError(
            meta.source, "vessel.dead_reckoned_s",
            f"the vessel's pose was carried {age_s:.0f} s from its last position report, "
            f"beyond the {MAX_DEAD_RECKONED_S:g} s it is measured with "
            f"({dead_reckoning_drift(age_s)[0]:.0f} m of drift, one sigma); `run` and `live` "
            "measure such a frame where the frames "
            "before it placed the vessel in the image")


@dataclass(frozen=True)
class _SectionsInImage:
    """Where the sections lie in the image under one pose (:func:`_sections_in_image`)."""

    #: share of each section's length that projects inside the image
    visible_fraction: np.ndarray
    #: pixels of each section's start and end break ``(n, 2, 2)``
    ends_px: np.ndarray
    #: pixels of the outline's vertices ``(V, 2)`` (NaN where they do not project)
    vertices_px: np.ndarray


@lru_cache(maxsize=32)
def _section_points(sections_v: SectionedOutline) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The vessel-frame points :func:`_sections_in_image` projects, made once per outline:
    ``(points, section, count)``, ``points`` the visibility samples (``section`` says whose,
    ``count`` how many each section has), then the break points, then the vertices."""
    n = sections_v.n_sections
    samples, section = sections_v.samples(_VISIBILITY_SAMPLES_PER_SECTION * n)
    points = np.concatenate((samples, sections_v.break_points, sections_v.vertices))
    points.flags.writeable = False
    return points, section, np.maximum(np.bincount(section, minlength=n), 1)


def _sections_in_image(sections_v: SectionedOutline, geometry: FrameGeometry) -> _SectionsInImage:
    """The sections' visibility (``_VISIBILITY_SAMPLES_PER_SECTION`` samples each), their ends'
    pixels and the outline vertices' pixels, from one projection of all those points."""
    n = sections_v.n_sections
    points, section, count = _section_points(sections_v)
    uv, _ = geometry.camera.project(geometry.vessel_to_enu(points))
    m = len(section)
    visible = geometry.camera.in_image(uv[:m])
    breaks_px = uv[m:m + n]
    return _SectionsInImage(
        visible_fraction=np.bincount(section, weights=visible, minlength=n) / count,
        ends_px=np.stack((breaks_px, np.concatenate((breaks_px[1:], breaks_px[:1]))), axis=1),
        vertices_px=uv[m + n:])


#: a hull smaller than this in the image (pixels, longest extent) cannot be measured: the
#: frame's height or focal length is wrong, or the vessel is a speck
MIN_HULL_SPAN_PX = 8.0


#: how far the mask's ship edge may lie off the hull all round, for the refinement's scale
#: test: this share of the frame's edge sigma (a model's 4 px: 2.4 px), at least
#: ``PoseRefinementSettings.scale_edge_px`` (1 px, a mask file's). At 1 px for the model's
#: masks, five of the bench's 260 frames with right sensors were flagged for a hull the model
#: drew 5-10 % too large or small
SCALE_EDGE_SHARE = 0.6
#: a height change within this many sigma of the frame's scale prior is never refused for
#: its size (the default limit, 4 m, is 4 sigma of a barometer's metre)
HEIGHT_LIMIT_SIGMAS = 4.0


#: the least prior (m, deg) the sensors' sigmas can give the alignment: sigmas of zero say
#: the pose is exact, and a prior of zero would be no prior at all
MIN_PRIOR_SHIFT_M = 0.02
MIN_PRIOR_HEADING_DEG = 0.05


def alignment_settings(settings: ClearanceSettings, sigmas: SensorSigmas,
                       height_m: float, nadir_offset_m: float = 0.0) -> PoseRefinementSettings:
    """The pose refinement's settings for a frame at ``height_m`` above the water with the
    vessel's antenna ``nadir_offset_m`` from the camera's nadir.

    The shift's and the heading's priors are the refinement's own (3 m per axis and 3° by
    default, for standalone receivers and magnetic compasses) scaled by the frame's sensors
    against the default ones: the hull's shift sigma
    (:meth:`~harborsight.geometry.sensor_sigmas.SensorSigmas.hull_shift_axis_m`) and
    heading sigma of the frame's sigmas over those of :class:`SensorSigmas`' defaults at
    the same height and offset. Default sensors keep the default priors; DGPS on both
    receivers narrows the shift's to about 1 m, RTK to 0.8 m (the camera's attitude is left),
    a pose carried by dead reckoning widens it. The prior decides between sister hulls the
    image cannot tell apart (:func:`~harborsight.clearance.sister_hulls.twin_alongside`),
    so it must say what the sensors can.

    The height's prior is the frame's own scale sigma, its height's and its focal length's
    (an RTK altitude and a calibrated camera hold the scale, a barometer or a datasheet's
    focal length let the hull's size in pixels correct it), and the height's limit at least
    :data:`HEIGHT_LIMIT_SIGMAS` of it; the scale test's mask edge :data:`SCALE_EDGE_SHARE`
    of the frame's edge sigma."""
    alignment = settings.pose_refinement
    default = SensorSigmas()
    shift_scale = (sigmas.hull_shift_axis_m(height_m, nadir_offset_m)
                   / default.hull_shift_axis_m(height_m, nadir_offset_m))
    heading_scale = sigmas.hull_heading_deg / default.hull_heading_deg
    alignment = replace(
        alignment,
        prior_shift_m=max(alignment.prior_shift_m * shift_scale, MIN_PRIOR_SHIFT_M),
        prior_heading_deg=max(alignment.prior_heading_deg * heading_scale, MIN_PRIOR_HEADING_DEG))
    if not alignment.refine_height:
        return alignment
    prior_m = max(sigmas.scale_height_m(height_m), 1e-3)
    return replace(alignment, prior_height_m=prior_m,
                   max_height_change_m=max(alignment.max_height_change_m, HEIGHT_LIMIT_SIGMAS * prior_m),
                   scale_edge_px=max(alignment.scale_edge_px, SCALE_EDGE_SHARE * sigmas.edge_px))


#: spacing of the image-border points a clear section's reach is measured on, pixels
BORDER_STEP_PX = 2


@functools.lru_cache(maxsize=8)
def _border_points(width: int, height: int, step_px: float = BORDER_STEP_PX) -> np.ndarray:
    """Pixel centres on the image's border every ``step_px`` (read-only: one array per image
    size, made once)."""
    u = np.arange(0.0, width, step_px)
    v = np.arange(0.0, height, step_px)
    points = np.vstack((np.column_stack((u, np.zeros_like(u))),
                      np.column_stack((u, np.full_like(u, height - 1.0))),
                      np.column_stack((np.zeros_like(v), v)),
                      np.column_stack((np.full_like(v, width - 1.0), v))))
    points.flags.writeable = False
    return points


@functools.lru_cache(maxsize=8)
def _seen_edge_points(intrinsics: CameraIntrinsics) -> np.ndarray:
    """Pixels along the edge of what the image shows, every :data:`BORDER_STEP_PX` at
    most: the image's border, or where a barrel lens's fold lies inside the image, the edge
    of the pixels with a ray (:func:`~harborsight.geometry.camera.ray_edge_px`). Past the
    fold no pixel has a place on the water: a band that leaves the view there was read as
    seen on to the far border or the horizon (a lens with k1 -0.34 at 23 m: "clear" to 28.6
    m and to the horizon where its band left the seen water 0.02-0.17 m out), and an ``ok``
    section's lower bound was not held to what was seen."""
    loop = ray_edge_px(intrinsics)
    if loop is None:
        return _border_points(intrinsics.width, intrinsics.height)
    # every BORDER_STEP_PX at most along each of its segments (the ring's closing point left out)
    points = (np.asarray(shapely.segmentize(LinearRing(loop), BORDER_STEP_PX).coords)[:-1]
              if len(loop) >= 3 else np.array(loop, float).reshape(-1, 2))
    points.flags.writeable = False
    return points


def _band_reach(section: np.ndarray, distance: np.ndarray, valid: np.ndarray,
                n_sections: int) -> np.ndarray:
    """How far each section's band is seen, from the image-border points (their section,
    distance to the hull on the water, and whether they reach the water): the distance to
    the nearest one in the band, in the outline's units; inf where none is (the band runs
    to the horizon). A ``clear`` section says only that nothing solid lies nearer."""
    seen = valid & (section >= 0) & np.isfinite(distance)
    reach = np.full(n_sections, np.inf)
    np.minimum.at(reach, section[seen], distance[seen])
    return reach


#: water the vessel hides out to fewer pixels than this (at the nadir's scale) beyond its
#: waterline grown by the pose margin is not reported (the pixels' own rounding)
HIDDEN_MIN_PX = 2.0


def _band_hidden(section: np.ndarray, distance: np.ndarray, valid: np.ndarray,
                 n_sections: int) -> np.ndarray:
    """How far out each band's water is hidden by the vessel itself, from the edge points of
    the hidden water (:func:`~harborsight.clearance.obstacles.hidden_water_edge`): the
    farthest in the band, in the outline's units; NaN where none is."""
    seen = valid & (section >= 0) & np.isfinite(distance)
    far = np.full(n_sections, -np.inf)
    np.maximum.at(far, section[seen], distance[seen])
    return np.where(np.isfinite(far), far, np.nan)


def _bound_by_what_was_seen(results: list[SectionClearance]) -> None:
    """An ``ok`` section whose band leaves the picture nearer than its obstacle (it carries
    that distance as ``clear_to_m``) may have a nearer obstacle out of view: nothing solid
    lies nearer than ``clear_to_m`` in what was seen, and nothing is known beyond it, so its
    lower bound is at most ``clear_to_m`` (8 % of the seed-7 bench's ``ok`` sections)."""
    for result in results:
        if (result.status == STATUS_OK and result.clear_to_m is not None
                and result.distance_lower_m is not None):
            result.distance_lower_m = min(result.distance_lower_m, result.clear_to_m)


def _distrust(results: list[SectionClearance]) -> None:
    """The sections of a frame whose pose the image contradicts: each reading keeps its
    value, but its sigma becomes at least the reading itself and its lower bound 0 (the
    hull's own region and bands were placed with a pose known to be off, so a quay 5 m away
    can read 21 m, beyond any propagated sigma). A ``clear`` section's ``clear_to_m``
    becomes 0: its band was not where the section is (with the vessel 14 m off, sections
    0.7 m from a ship read ``clear``)."""
    for result in results:
        if result.status == STATUS_OK:
            result.sigma_m = max(result.sigma_m or 0.0, result.distance_m)
            result.sigma_random_m = max(result.sigma_random_m or 0.0, result.distance_m)
            result.distance_lower_m = 0.0
        if result.clear_to_m is not None:
            result.clear_to_m = 0.0


def measure_clearance(
    labels: np.ndarray, geometry: FrameGeometry, vessel: VesselSpec,
    settings: ClearanceSettings = ClearanceSettings(), *, sigmas: SensorSigmas | None = None,
    velocities: FrameVelocities | None = None, confidence: SolidConfidence | None = None,
) -> ClearanceReport:
    """The clearance of every section (see module docstring). ``labels`` must match the
    camera's size (use :func:`check_label_mask`); ``confidence``, the model's probabilities
    behind them, when they came from a model."""
    camera = geometry.camera
    intr = camera.intrinsics
    height_m = float(camera.position_enu[2])
    gsd = nadir_gsd_m_per_px(height_m, intr.fx, intr.fy)
    try:
        sections_v = vessel.sections(settings.n_sections, settings.section_length_m)
    except ValueError as exc:  # a section count or length from the command line
        option = "--section-length-m" if settings.section_length_m else "--sections"
        raise InputError(None, option, str(exc)) from None

    def vessel_to_px(points_v: np.ndarray) -> np.ndarray:
        return camera.project(geometry.vessel_to_enu(points_v))[0]

    in_image = _sections_in_image(sections_v, geometry)
    if not np.any(in_image.visible_fraction > 0):
        centre_px = vessel_to_px(np.zeros((1, 2)))[0]
        raise InputError(
            geometry.source, "vessel",
            f"no part of the hull outline is in the image (vessel antenna projects to "
            f"pixel ({centre_px[0]:.0f}, {centre_px[1]:.0f}) in a {intr.width}x{intr.height} image)",
        )

    # align the vessel to its own pixels; the sensors' pose stays when that is not trustworthy
    sigmas = sigmas or settings.sensor_sigmas()
    nadir_offset_m = float(np.hypot(*(geometry.vessel_position_enu[:2] - camera.position_enu[:2])))
    geometry, refinement = refine_vessel_pose(
        labels, geometry, vessel, alignment_settings(settings, sigmas, height_m, nadir_offset_m))
    if refinement.applied:      # the hull moved (and the camera's height): all once more
        in_image = _sections_in_image(sections_v, geometry)
        camera = geometry.camera
        height_m = float(camera.position_enu[2])
        gsd = nadir_gsd_m_per_px(height_m, intr.fx, intr.fy)
    visible_fraction = in_image.visible_fraction

    vessel_outline_px = camera.project_convex_outline(geometry.vessel_to_enu(vessel.hull_points))
    finite = vessel_outline_px[np.isfinite(vessel_outline_px).all(axis=1)]
    if not len(finite):
        raise InputError(
            geometry.source, "vessel",
            "the hull's outline has no pixel near the image: it lies behind the camera, past "
            "the lens model's fold or far outside the picture (check camera_attitude, the "
            "vessel's position against the drone's, and the distortion coefficients)")
    span_px = float(np.ptp(finite, axis=0).max())
    if span_px < MIN_HULL_SPAN_PX:
        raise InputError(
            geometry.source, "vessel",
            f"the hull spans {span_px:.1f} px in the image, too few to measure clearances "
            f"(at {height_m:.0f} m above the water with fx {intr.fx:.3g} px: check uav.alt_m, "
            "water_level_m and the camera's focal length)")
    own_layers_px = ([vessel_outline_px] if len(vessel.own_layers) == 1 else
                     camera.project_convex_outlines([geometry.vessel_to_enu(layer)
                                                     for layer in vessel.own_layers]))
    own = own_vessel_region(own_layers_px, labels.shape, settings.pose_margin_px)
    contours = obstacle_contours(labels, own, settings.own_rim_px)
    points_px = contours.points_px.astype(float)

    if settings.method == "ground_plane":
        outline = sections_v
        # geometry.pixels_to_vessel_xy, with the map to the vessel frame made once
        vessel_from_world = geometry.vessel_from_world_2d()

        def to_outline(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return camera.pixels_to_plane_xy(uv, 0.0, post=vessel_from_world)
    else:
        # sections_v.transformed(vessel_to_px), from the pixels projected with the visibility
        vertices_px, breaks_px = in_image.vertices_px, in_image.ends_px[:, 0]
        if not (np.isfinite(vertices_px).all() and np.isfinite(breaks_px).all()):
            # behind the camera or past its lens model's edge
            raise InputError(geometry.source, "vessel",
                             "the hull crosses the camera's horizon or the edge of its lens "
                             "model: the gsd method cannot be used; use the ground_plane method")
        try:
            outline = SectionedOutline(vertices_px, breaks_px, sections_v.break_edge)
        except ValueError:      # a distorted lens can fold the outline onto a line
            raise InputError(geometry.source, "vessel",
                             "the hull outline projects to a line in the image: the gsd method "
                             "cannot be used; use the ground_plane method") from None

        def to_outline(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return uv, np.ones(len(uv), bool)
    # the image's border, and the edge of the water the vessel hides, go through the same map
    # and assignment: how far each band is seen, and how far out its water is hidden
    border_px = _seen_edge_points(intr)
    hidden_px = hidden_water_edge(own_layers_px, camera.project_convex_outline(
        geometry.vessel_to_enu(vessel.outline)), labels.shape, settings.pose_margin_px)
    n_contour, n_border = len(points_px), len(border_px)
    mapped, mapped_valid = to_outline(np.vstack((points_px, border_px, hidden_px)))
    everything = outline.assign(np.where(mapped_valid[:, None], mapped, 0.0))
    n_bands = len(in_image.visible_fraction)
    on_border = slice(n_contour, n_contour + n_border)
    reach = _band_reach(everything.section[on_border], everything.distance[on_border],
                        mapped_valid[on_border], n_bands)
    on_hidden = slice(n_contour + n_border, None)
    hidden = _band_hidden(everything.section[on_hidden], everything.distance[on_hidden],
                          mapped_valid[on_hidden], n_bands)
    points, valid = mapped[:n_contour], mapped_valid[:n_contour]
    assignment = SectionAssignment(everything.section[:n_contour], everything.distance[:n_contour],
                                   everything.nearest[:n_contour])
    section = np.where(valid, assignment.section, -1)
    candidates = Candidates.joined(
        Candidates(section=section, distance=assignment.distance, nearest=assignment.nearest,
                    points_px=points_px, contact=contours.contact, on_border=contours.on_border,
                    edge_px=np.zeros((len(points_px), 2))),
        band_crossings(outline, points, points_px, section, contours),
        band_edge_pixels(outline, to_outline, points, points_px, section, contours))

    # nearest candidate per visible section
    inband = np.flatnonzero((candidates.section >= 0)
                            & (visible_fraction[np.maximum(candidates.section, 0)] > 0))
    order = inband[np.lexsort((candidates.distance[inband], candidates.section[inband]))]
    first = (np.concatenate(([True], np.diff(candidates.section[order]) != 0)) if len(order)
             else order.astype(bool))
    best = order[first]
    best_section = candidates.section[best]
    crossing_edge_px = candidates.edge_px[best].copy()
    on_ray = beside_a_boundary_ray(outline, points, best[best < n_contour], section,
                                    assignment.distance, contours)
    crossing_edge_px[np.flatnonzero(best < n_contour)[on_ray[0]]] = on_ray[1]

    results = [
        SectionClearance(index=k, status=STATUS_OUT_OF_VIEW if fraction == 0 else STATUS_CLEAR,
                         hull_px=ends, visible_fraction=fraction)
        for k, (ends, fraction) in enumerate(zip(in_image.ends_px.tolist(),
                                                 visible_fraction.tolist(), strict=True))
    ]
    if len(best):
        obstacle_px = candidates.points_px[best]
        nearest = candidates.nearest[best]
        if outline is sections_v:
            hull_enu = geometry.vessel_to_enu(nearest)
            hull_px = camera.project(hull_enu)[0]
        else:
            hull_px = nearest
        # pixel-boundary correction: the chosen pixel's depth inside the obstacle's edge,
        # from a line through its contour neighbours where the edge is straight, else the
        # whole square (harborsight.clearance.pixel_edge)
        toward = hull_px - obstacle_px
        norm = np.hypot(*toward.T)
        unit = toward / np.maximum(norm, 1e-12)[:, None]
        shift = np.minimum(edge_shift_px(contours, np.where(best < n_contour, best, -1), unit),
                           norm)
        moved_px = obstacle_px + unit * shift[:, None]
        moved_enu, moved_ok = camera.back_project_to_plane(moved_px)
        if not moved_ok.all():
            # near a barrel lens's fold the half-pixel move can cross it, where no ray meets
            # the water: those points keep their unmoved pixel (no correction)
            back = ~moved_ok
            shift[back] = 0.0
            moved_px[back] = obstacle_px[back]
            moved_enu[back] = camera.back_project_to_plane(obstacle_px[back])[0]
        if outline is sections_v:
            # geometry.enu_to_vessel_xy(moved_enu)
            moved_v = moved_enu[:, :2] @ vessel_from_world[:2, :2].T + vessel_from_world[:2, 2]
            distance_m = np.hypot(*(moved_v - nearest).T)
            distance_m[norm <= shift] = 0.0
            distance_px = np.hypot(*(hull_px - moved_px).T)
        else:
            hull_enu, _ = camera.back_project_to_plane(hull_px)
            distance_px = norm - shift
            distance_m = distance_px * gsd
        # the nearest obstacle point or hull point may have no place in the image or on the
        # water (past a barrel lens's fold): no distance can be given, and "clear" would
        # claim there is no obstacle
        finite = (np.isfinite(distance_m) & np.isfinite(distance_px)
                  & np.isfinite(hull_px).all(axis=1) & np.isfinite(moved_px).all(axis=1))
        for k, ok, d_m, d_px, h_px, o_px, h_enu, o_enu, contact, truncated, edge in zip(
                best_section.tolist(), finite.tolist(), distance_m.tolist(), distance_px.tolist(),
                hull_px.tolist(), moved_px.tolist(), hull_enu[:, :2].tolist(),
                moved_enu[:, :2].tolist(), candidates.contact[best].tolist(),
                candidates.on_border[best].tolist(), crossing_edge_px.tolist(),
                strict=True):
            result = results[k]
            if not ok:
                result.status = STATUS_OUT_OF_VIEW
                continue
            result.status = STATUS_OK
            result.distance_m, result.distance_px = d_m, d_px
            result.hull_point_px, result.obstacle_point_px = h_px, o_px
            result.hull_point_enu, result.obstacle_point_enu = h_enu, o_enu
            result.contact, result.truncated = contact, truncated
            result.crossing_edge_px = edge if any(edge) else None

    metres_per_unit = 1.0 if outline is sections_v else gsd
    for result in results:
        seen_m = float(reach[result.index]) * metres_per_unit
        if np.isfinite(seen_m) and (result.status == STATUS_CLEAR or (
                result.status == STATUS_OK and seen_m < result.distance_m)):
            # a clear band's reach; an ok one's when it leaves the picture nearer than its
            # obstacle (one nearer may be out of view)
            result.clear_to_m = seen_m
        hidden_m = float(hidden[result.index]) * metres_per_unit
        if result.status != STATUS_OUT_OF_VIEW and hidden_m > HIDDEN_MIN_PX * gsd:
            result.hidden_to_m = hidden_m
            if result.status == STATUS_CLEAR and hidden_m >= (result.clear_to_m or np.inf):
                result.clear_to_m = 0.0     # all of the band in the picture is hidden
    unexplained = add_section_uncertainty(
        results, geometry, geometry.vessel_to_enu(sections_v.vertices), refinement, sigmas,
        velocities, outline_px=in_image.vertices_px, confidence=confidence, labels=labels,
        vessel_points_enu=geometry.vessel_to_enu(vessel.hull_points),
        vessel_layers_enu=[geometry.vessel_to_enu(layer) for layer in vessel.alignment_layers],
        outline_sigma_m=vessel.outline_sigma_m, own_margin_px=settings.pose_margin_px,
        own_rim_px=settings.own_rim_px)
    if settings.method == "gsd":
        add_nadir_approximation(results)
    if pose_kept_unconfirmed(refinement) or refinement.along_hull_held:
        # obstacles a neighbour's band took that the sensors' errors may put in a band
        # (all of them; or only their place along a hull the image placed across only)
        points_v = (points if outline is sections_v
                    else geometry.pixels_to_vessel_xy(points_px)[0])
        cap_by_neighbours_margins(results, sections_v, points_v, points_px, section, geometry,
                                  refinement, sigmas, velocities)
    _bound_by_what_was_seen(results)
    if velocities is not None and settings.own_motion:
        ends = sections_v.section_endpoints()
        add_own_rates(results, geometry.vessel_position_enu, velocities.vessel_en_mps,
                      velocities.vessel_sigma_mps, velocities.vessel_yaw_rate_deg_s,
                      velocities.vessel_yaw_rate_sigma_deg_s,
                      half_lengths_m=0.5 * np.hypot(*(ends[:, 1] - ends[:, 0]).T),
                      gsd_m_per_px=gsd)
    if refinement.sensors_contradicted:
        _distrust(results)
    return ClearanceReport(
        image="", timestamp=None, altitude_m=height_m, gsd_m_per_px=gsd,
        method=settings.method, sections=results, vessel=vessel.name,
        enu_origin=geometry.origin.to_dict(), pose_refinement=refinement.to_dict(),
        uncertainty={"sigmas": sigmas.to_dict(), "outline_sigma_m": vessel.outline_sigma_m,
                     "lower_bound_quantile": LOWER_BOUND_QUANTILE,
                     "confident_solid_p": CONFIDENT_SOLID_P if confidence is not None else None,
                     "unexplained_shift": unexplained},
    )
