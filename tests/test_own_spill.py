"""A contact with a ship blob may be the vessel's own pixels: the bar of such a reading reaches
to the first sure solid beyond that blob, walking outward from the antenna, by hand on a nadir
scene (10 cm a pixel)."""

import math

import cv2
import numpy as np
import pytest

from harborsight.clearance.pose_refinement import PoseRefinement
from harborsight.clearance.report import SectionClearance
from harborsight.clearance.uncertainty import add_section_uncertainty
from harborsight.perception.classes import OBSTACLE, SHIP, WATER
from tests.test_edge_confidence import SIZE_PX, Z_90, ZERO, _confidence_by_east, _nadir

#: the pixel grid's own term at 10 cm a pixel along east: (0.1 + 0) / sqrt(12)
GRID_M = 0.1 / math.sqrt(12.0)
HULL_E = 5.0                                  # the section's hull point, 5 m east of the antenna
BOX = np.array([[5.0, 2.0], [5.0, -2.0], [-5.0, -2.0], [-5.0, 2.0]])
NOT_REFINED = PoseRefinement(applied=False, reason="alignment refused")
REFINED = PoseRefinement(applied=True)


def _labels_by_east(geometry, classes_of_east) -> np.ndarray:
    """A label mask whose class at each pixel is ``classes_of_east(e)`` (e: east on the water)."""
    u, v = np.meshgrid(np.arange(SIZE_PX, dtype=float), np.arange(SIZE_PX, dtype=float))
    ground, _ = geometry.camera.back_project_to_plane(np.column_stack((u.ravel(), v.ravel())))
    return classes_of_east(ground[:, 0]).reshape(SIZE_PX, SIZE_PX).astype(np.uint8)


def _contact(geometry, labels, refinement=NOT_REFINED, confidence=None,
             vessel_points=None, distance_m: float = 0.0, margin_px: float = 0.0,
             rim_px: float = 0.0) -> SectionClearance:
    """A contact reading ``distance_m`` east of the hull point (5, 0), measured and given
    its uncertainty."""
    camera = geometry.camera
    hull_px = camera.project(np.array([[HULL_E, 0.0, 0.0]]))[0][0].tolist()
    obstacle_px = camera.project(np.array([[HULL_E + distance_m, 0.0, 0.0]]))[0][0].tolist()
    section = SectionClearance(0, "ok", [[0, 0], [1, 1]], 1.0, distance_m=distance_m, contact=True,
                               hull_point_enu=[HULL_E, 0.0],
                               obstacle_point_enu=[HULL_E + distance_m, 0.0],
                               hull_point_px=hull_px, obstacle_point_px=obstacle_px)
    add_section_uncertainty([section], geometry, np.column_stack((BOX, np.zeros(len(BOX)))),
                            refinement, ZERO, confidence=confidence, labels=labels,
                            vessel_points_enu=vessel_points, own_margin_px=margin_px,
                            own_rim_px=rim_px)
    return section


def test_a_contact_s_bound_reaches_past_what_the_own_region_may_hide():
    """The own region is the hull grown by its margin (2 px), and by a rim (4 px) of ship
    pixels: a neighbour moored against the hull, or a quay's face seen under the hull's
    skirt, is cut there, and its reading lies up to that many pixels beyond the true edge.
    At 10 cm a pixel: a ship contact 0.6 m out (truth 0) gets sigma + 0.6 / 1.645 and a
    bound of 0; an obstacle contact the margin's 0.2 m."""
    geometry = _nadir()
    neighbour = _labels_by_east(geometry, lambda e: np.where(e < 9.0, SHIP, WATER))
    section = _contact(geometry, neighbour, REFINED, distance_m=0.6, margin_px=2, rim_px=4)
    assert section.sigma_m == pytest.approx(GRID_M + 0.6 / 1.645, rel=1e-3)
    assert section.distance_lower_m == 0.0
    quay = _labels_by_east(geometry, lambda e: np.where(e < 9.0, OBSTACLE, WATER))
    section = _contact(geometry, quay, REFINED, distance_m=0.6, margin_px=2, rim_px=4)
    assert section.sigma_m == pytest.approx(GRID_M + 0.2 / 1.645, rel=1e-3)
    assert section.distance_lower_m == pytest.approx(0.6 - 0.2 - 1.645 * GRID_M, rel=1e-3)


def _own_spill_scene(e):
    """The vessel's own ship pixels reach 3 m past its outline (to e = 8), water to 12, a quay
    beyond."""
    return np.where((e > -5.0) & (e < 8.0), SHIP, np.where(e < 12.0, WATER, OBSTACLE))


def test_a_contact_with_a_ship_blob_reaches_to_the_first_solid_beyond_it():
    """Walking east from the hull point, past the ship blob, the quay is at 12 m: s_c - d is
    7 m, so sigma = 7 / Φ⁻¹(0.9) with the pixel grid in quadrature; the distance and its lower
    bound stay as read."""
    geometry = _nadir()
    section = _contact(geometry, _labels_by_east(geometry, _own_spill_scene))
    expected = math.hypot(7.0 / Z_90, GRID_M)
    assert section.sigma_m == pytest.approx(expected, abs=0.1 / Z_90)
    assert section.distance_m == 0.0 and section.distance_lower_m == 0.0


def test_a_contact_with_an_obstacle_or_without_a_mask_keeps_its_bar():
    """Only a ship blob can be the vessel itself: against an obstacle blob, or without the
    mask, the bar is the pixel grid's alone."""
    geometry = _nadir()
    quay = _labels_by_east(geometry, lambda e: np.where(e < 8.0, OBSTACLE, WATER))
    assert _contact(geometry, quay).sigma_m == pytest.approx(GRID_M, rel=1e-3)
    assert _contact(geometry, None).sigma_m == pytest.approx(GRID_M, rel=1e-3)


def test_when_the_image_placed_the_hull_a_contact_keeps_its_bar():
    """With the alignment applied the hull sits on its own pixels, so a contact with a ship
    blob is a reading (a neighbour alongside), not a doubt; with the sensors' pose it is."""
    geometry = _nadir()
    neighbour = _labels_by_east(geometry, lambda e: np.where(
        (e > -5.0) & (e < 4.7), SHIP, np.where(e < 4.95, WATER, np.where(
            e < 8.0, SHIP, np.where(e < 12.0, WATER, OBSTACLE)))))
    assert _contact(geometry, neighbour, REFINED).sigma_m == pytest.approx(GRID_M, rel=1e-3)
    assert _contact(geometry, neighbour, NOT_REFINED).sigma_m == pytest.approx(
        math.hypot(7.0 / Z_90, GRID_M), abs=0.1 / Z_90)


def test_with_a_model_the_first_pixel_it_is_sure_of_ends_the_walk():
    """With the model's probabilities the walk ends where it is sure (p >= 0.9), not at the
    first solid label: the quay's first 3 m are doubtful (p = 0.6), so s_c - d is 10 m."""
    geometry = _nadir()
    labels = _labels_by_east(geometry, _own_spill_scene)
    confidence = _confidence_by_east(geometry, lambda e: np.where(
        (e > -5.0) & (e < 8.0), 0.95, np.where(e < 12.0, 0.05, np.where(e < 15.0, 0.6, 0.95))))
    section = _contact(geometry, labels, confidence=confidence)
    assert section.sigma_m == pytest.approx(math.hypot(10.0 / Z_90, GRID_M), abs=0.15 / Z_90)


#: the box hull as a body 2 m high: its points on the water and 2 m above it
BODY = np.vstack((np.column_stack((BOX, np.zeros(4))), np.column_stack((BOX, np.full(4, 2.0)))))


def _blob_to(end_e: float):
    """The vessel's pixels, a gap, then a ship blob from its side to ``end_e``, water to 12 m
    and a quay beyond."""
    return lambda e: np.where((e > -5.0) & (e < 4.7), SHIP, np.where(e < 4.95, WATER, np.where(
        e < end_e, SHIP, np.where(e < 12.0, WATER, OBSTACLE))))


def test_when_the_image_placed_the_hull_a_blob_in_its_shadow_widens_the_bar():
    """With the sun known, a contact with a ship blob that ends inside the vessel's shadow
    may be that shadow, labelled ship by a model: the bar reaches to the quay as with the
    sensors' pose. The sun in the west at 30 degrees casts the 2 m body's shadow 3.46 m east
    of the hull (to e = 8.46): a blob to e = 8 ends in it. A blob to e = 10 ends beyond it
    (a neighbour), and with the sun in the east the shadow falls the other way: both keep
    the bar of a reading. The distance and its lower bound stay as read."""
    from dataclasses import replace

    west_sun = replace(_nadir(), sun_deg=(30.0, 270.0))
    labels = _labels_by_east(west_sun, _blob_to(8.0))
    section = _contact(west_sun, labels, REFINED, vessel_points=BODY)
    assert section.sigma_m == pytest.approx(math.hypot(7.0 / Z_90, GRID_M), abs=0.1 / Z_90)
    assert section.distance_m == 0.0 and section.distance_lower_m == 0.0
    beyond = _labels_by_east(west_sun, _blob_to(10.0))
    assert _contact(west_sun, beyond, REFINED, vessel_points=BODY).sigma_m == pytest.approx(
        GRID_M, rel=1e-3)
    east_sun = replace(_nadir(), sun_deg=(30.0, 90.0))
    assert _contact(east_sun, labels, REFINED, vessel_points=BODY).sigma_m == pytest.approx(
        GRID_M, rel=1e-3)
    # a run that ends within 3 px of the hull's own edge is the vessel drawn wide, not its
    # shadow: it keeps the bar of a reading whichever way the shadow falls
    rim = _labels_by_east(west_sun, _blob_to(5.2))
    for sun in (west_sun, east_sun):
        assert _contact(sun, rim, REFINED, vessel_points=BODY).sigma_m == pytest.approx(
            GRID_M, rel=1e-3)
    # without the vessel's points, or with the sun under 5 degrees, no shadow is predicted
    assert _contact(west_sun, labels, REFINED).sigma_m == pytest.approx(GRID_M, rel=1e-3)
    low_sun = replace(_nadir(), sun_deg=(4.0, 270.0))
    assert _contact(low_sun, labels, REFINED, vessel_points=BODY).sigma_m == pytest.approx(
        GRID_M, rel=1e-3)


def test_a_shadow_reaching_behind_the_camera_still_gives_its_near_part():
    """A low sun in the north casts the body's shadow 19 m south, behind an oblique camera
    looking north: the corners behind it are left out and the rest of the polygon is kept
    (it used to drop the term for the frame)."""
    from dataclasses import replace

    from harborsight.clearance.uncertainty import _own_shadow_px
    from harborsight.geometry.camera import Camera, CameraIntrinsics
    from harborsight.geometry.rotations import world_from_camera_rotation

    intrinsics = CameraIntrinsics(640, 360, 450.0, 450.0, 319.5, 179.5)
    rotation = world_from_camera_rotation(0.0, math.radians(-20.0), 0.0)
    geometry = replace(_nadir(), camera=Camera(intrinsics, np.array([0.0, -10.0, 10.0]), rotation),
                       sun_deg=(6.0, 0.0))
    behind, _ = geometry.camera.project(np.array([[0.0, -21.0, 0.0]]))
    assert not np.isfinite(behind).all()
    shadow, footprint = _own_shadow_px(geometry, BODY)
    assert len(shadow) >= 3 and len(footprint) == 4 and np.isfinite(shadow).all()
    # a point of the shadow in front of the camera is inside the polygon, one outside is not
    polygon = shadow.astype(np.float32).reshape(-1, 1, 2)
    for point_en, inside in (((0.0, -8.0), True), ((8.0, -8.0), False)):
        pixel, _ = geometry.camera.project(np.array([[*point_en, 0.0]]))
        assert (cv2.pointPolygonTest(polygon, tuple(map(float, pixel[0])), False) > 0) == inside
