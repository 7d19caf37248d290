"""The model's doubt about an obstacle widens that section's sigma: the solid probability read
at frame pixels, and the far-side spread along the hull-obstacle ray, by hand."""

import json
import math
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest

from harborsight.clearance.edge_evidence import CONFIDENT_SOLID_P
from harborsight.clearance.measure import ClearanceSettings, measure_frame
from harborsight.clearance.pose_refinement import PoseRefinement
from harborsight.clearance.report import SectionClearance
from harborsight.clearance.uncertainty import add_section_uncertainty
from harborsight.frame import FrameGeometry, parse_frame_metadata
from harborsight.geometry.camera import Camera, CameraIntrinsics
from harborsight.geometry.geodesy import GeoOrigin
from harborsight.geometry.rotations import world_from_camera_rotation
from harborsight.geometry.sensor_sigmas import SensorSigmas
from harborsight.images import read_image
from harborsight.perception.confidence import SolidConfidence
from harborsight.perception.default_model import load_default_segmenter
from harborsight.pipeline import frame_labels
from harborsight.vessel.spec import load_vessel_spec

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
HEIGHT_M, FOCAL_PX, SIZE_PX = 50.0, 500.0, 1000
ZERO = SensorSigmas(uav_gps=0, vessel_gps=0, vessel_heading_deg=0, camera_yaw_deg=0,
                    camera_tilt_deg=0, height_m=0, water_level_m=0, focal_rel=0, clock_s=0,
                    edge_px=0, edge_m=0)
#: Φ⁻¹(0.9), computed by hand from a normal table
Z_90 = 1.2816


def _nadir() -> FrameGeometry:
    intrinsics = CameraIntrinsics(SIZE_PX, SIZE_PX, FOCAL_PX, FOCAL_PX, 499.5, 499.5)
    rotation = world_from_camera_rotation(0.0, math.radians(-90.0), 0.0)
    return FrameGeometry(GeoOrigin(56.0, 10.0, 0.0),
                         Camera(intrinsics, np.array([0.0, 0.0, HEIGHT_M]), rotation), 0.0)


def _confidence_by_east(geometry: FrameGeometry, p_solid_of_east) -> SolidConfidence:
    """Logits on the frame's own grid whose solid probability is ``p_solid_of_east(e)`` at
    each pixel centre (e the east coordinate where it meets the water)."""
    return _confidence_along(geometry, (1.0, 0.0), p_solid_of_east)


def _confidence_along(geometry: FrameGeometry, direction_en, p_solid_of_s) -> SolidConfidence:
    """Logits on the frame's own grid whose solid probability is ``p_solid_of_s(s)`` at each
    pixel centre, ``s`` the coordinate along the unit vector ``direction_en`` of the point
    where it meets the water."""
    u, v = np.meshgrid(np.arange(SIZE_PX, dtype=float), np.arange(SIZE_PX, dtype=float))
    ground, _ = geometry.camera.back_project_to_plane(np.column_stack((u.ravel(), v.ravel())))
    along = ground[:, :2] @ np.asarray(direction_en, float)
    p = np.clip(p_solid_of_s(along), 1e-6, 1 - 1e-6).reshape(SIZE_PX, SIZE_PX)
    logits = np.stack((np.log(1 - p), np.log(p), np.full_like(p, -30.0))).astype(np.float32)
    return SolidConfidence(logits, SIZE_PX, SIZE_PX)


def _sigma(geometry, confidence, hull_en=(5.0, 0.0), obstacle_en=(8.0, 0.0)) -> float:
    hull_en, obstacle_en = np.asarray(hull_en, float), np.asarray(obstacle_en, float)
    camera = geometry.camera
    section = SectionClearance(
        0, "ok", [[0, 0], [1, 1]], 1.0, distance_m=float(np.hypot(*(obstacle_en - hull_en))),
        hull_point_enu=hull_en.tolist(), obstacle_point_enu=obstacle_en.tolist(),
        hull_point_px=camera.project(np.array([[*hull_en, 0.0]]))[0][0].tolist(),
        obstacle_point_px=camera.project(np.array([[*obstacle_en, 0.0]]))[0][0].tolist())
    box = np.array([[4.0, 2.0], [4.0, -2.0], [-4.0, -2.0], [-4.0, 2.0], [5.0, 0.0]])
    add_section_uncertainty([section], geometry, np.column_stack((box, np.zeros(len(box)))),
                            PoseRefinement(applied=False, reason="off"), ZERO,
                            confidence=confidence)
    return section.sigma_m


def test_solid_probability_is_the_softmax_of_the_upsampled_logits():
    rng = np.random.default_rng(3)
    logits = cv2.GaussianBlur(rng.normal(0, 4, (18, 32, 3)).astype(np.float32), (0, 0), 2)
    frame_w, frame_h = 80, 45                       # 2.5x the model's grid
    upsampled = cv2.resize(logits, (frame_w, frame_h), interpolation=cv2.INTER_LINEAR)
    e = np.exp(upsampled - upsampled.max(axis=2, keepdims=True))
    expected = 1 - e[..., 0] / e.sum(axis=2)
    confidence = SolidConfidence(logits.transpose(2, 0, 1), frame_w, frame_h)
    u, v = np.meshgrid(np.arange(frame_w), np.arange(frame_h))
    got = confidence.solid_probability(np.column_stack((u.ravel(), v.ravel())))
    # cv2.remap interpolates on a 1/32-pixel grid, cv2.resize exactly
    assert np.abs(got - expected.ravel()).max() < 0.02
    assert np.isnan(confidence.solid_probability(np.array([[np.nan, 1.0]])))[0]
    with pytest.raises(ValueError, match="logits"):
        SolidConfidence(np.zeros((5, 5)), 5, 5)


def test_a_doubtful_obstacle_widens_sigma_to_the_first_sure_solid():
    """Hull at 5 m east, the model's obstacle edge at 8 m (p_solid 0.7, doubtful), a solid it
    is sure of (0.99) from 12 m: the edge may lie up to 4 m farther, so the sigma gains
    4 m / Φ⁻¹(0.9) in quadrature."""
    geometry = _nadir()
    base = _sigma(geometry, None)
    doubtful = _confidence_by_east(geometry, lambda e: np.select([e < 7.95, e < 12.0], [0.01, 0.7], 0.99))
    widened = _sigma(geometry, doubtful)
    extra = math.sqrt(widened ** 2 - base ** 2)
    assert extra == pytest.approx(4.0 / Z_90, abs=0.1)          # one 0.1 m pixel of slack


def test_a_sure_obstacle_keeps_its_sigma():
    geometry = _nadir()
    base = _sigma(geometry, None)
    sure = _confidence_by_east(geometry, lambda e: np.where(e < 7.95, 0.01, 0.99))
    assert _sigma(geometry, sure) == pytest.approx(base, abs=0.02)


def test_never_sure_reads_to_the_edge_of_the_image():
    """p_solid 0.7 all the way: the far point is the image's last pixel (e = 49.95 m)."""
    geometry = _nadir()
    base = _sigma(geometry, None)
    never = _confidence_by_east(geometry, lambda e: np.where(e < 7.95, 0.01, 0.7))
    extra = math.sqrt(_sigma(geometry, never) ** 2 - base ** 2)
    assert extra == pytest.approx((49.95 - 8.0) / Z_90, abs=0.15)
    # in contact (obstacle point on the hull point) there is no ray: no doubt term
    assert _sigma(geometry, never, (5.0, 0.0), (5.0, 0.0)) == pytest.approx(
        _sigma(geometry, None, (5.0, 0.0), (5.0, 0.0)))


_DIAGONAL = 0.5 ** 0.5


@pytest.mark.parametrize("direction_en", [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0),
                                          (-_DIAGONAL, _DIAGONAL), (_DIAGONAL, -_DIAGONAL)],
                         ids=["east", "west", "north", "south", "north-west", "south-east"])
def test_the_doubt_is_read_along_rays_heading_any_way_across_the_image(direction_en):
    """The scenes of the two tests above turned to face each image direction: a ray heading
    left or up in the image is read to its first sure solid and to the image's edge like one
    heading right or down (a sign slip once left those rays with no doubt term at all)."""
    geometry = _nadir()
    d = np.asarray(direction_en)
    hull, obstacle = 5.0 * d, 8.0 * d
    base = _sigma(geometry, None, hull, obstacle)
    doubtful = _confidence_along(geometry, d, lambda s: np.select([s < 7.95, s < 12.0], [0.01, 0.7], 0.99))
    extra = math.sqrt(_sigma(geometry, doubtful, hull, obstacle) ** 2 - base ** 2)
    assert extra == pytest.approx(4.0 / Z_90, abs=0.1)
    never = _confidence_along(geometry, d, lambda s: np.where(s < 7.95, 0.01, 0.7))
    extra = math.sqrt(_sigma(geometry, never, hull, obstacle) ** 2 - base ** 2)
    # the image's last pixel centre along the ray lies 49.95 m from the nadir across or
    # along the image, 49.95 sqrt(2) m on its diagonal (the ray leaves through a corner)
    edge_m = 49.95 / max(abs(d[0]), abs(d[1]))
    assert extra == pytest.approx((edge_m - 8.0) / Z_90, abs=0.15)


def test_the_default_model_gives_its_confidence_to_every_model_distance():
    frame = json.loads((SAMPLES / "frames" / "000000.json").read_text())
    meta = parse_frame_metadata(frame, SAMPLES / "frames" / "000000.json")
    vessel = load_vessel_spec(SAMPLES / frame["vessel_spec"])
    image = read_image(SAMPLES / "images" / frame["image"])
    segmenter = load_default_segmenter(None)
    mask = frame_labels(image, None, segmenter, "sample")
    assert mask.confidence is not None and not mask.from_file
    np.testing.assert_array_equal(mask.labels, segmenter.segment(image))
    # a frame of another size than the model's (smaller: enlarged and padded, as `segment
    # --mode auto` does): the labels and probabilities still agree
    from harborsight.perception.segment_images import SegmentMode, SegmentOptions, segment_labels

    small = cv2.resize(image, (400, 300), interpolation=cv2.INTER_AREA)
    labels, confidence = segmenter.segment_with_confidence(small)
    np.testing.assert_array_equal(labels, segment_labels(segmenter, small,
                                                         SegmentOptions(SegmentMode.auto)))
    v, u = np.nonzero(labels != 255)
    solid = confidence.solid_probability(np.column_stack((u, v)).astype(float)) > 0.5
    assert np.mean(solid == (labels[v, u] != 0)) > 0.99
    with_doubt = measure_frame(mask.labels, meta, vessel, ClearanceSettings(),
                               confidence=mask.confidence)
    without = measure_frame(mask.labels, meta, vessel, ClearanceSettings())
    assert with_doubt.uncertainty["confident_solid_p"] == CONFIDENT_SOLID_P
    assert without.uncertainty["confident_solid_p"] is None
    pairs = [(a.sigma_m, b.sigma_m) for a, b in zip(with_doubt.sections, without.sections, strict=True)
             if a.sigma_m is not None]
    assert pairs and all(a >= b - 1e-9 for a, b in pairs)
