"""The whole-image search for the hull: gross sensor errors (a fix tens of metres off, an
ellipsoidal height, a heading reversed) are found in the image and flag the frame, where
the refinement alone kept or applied a wrong pose without a word."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from shapely.geometry import MultiPoint

from harborsight.clearance import gross_errors, pose_refinement, prior_search, sister_hulls
from harborsight.clearance.alignment import Silhouette, corrected_geometry
from harborsight.clearance.measure import ClearanceSettings, measure_clearance
from harborsight.clearance.pose_refinement import PoseRefinementSettings, refine_vessel_pose
from harborsight.clearance.pose_search import (
    _region,
    _silhouette,
    _starts,
    edge_share,
    silhouette_overlap,
    whole_image_alignment,
)
from harborsight.clearance.refinement_summary import refinement_summary
from harborsight.geometry.sensor_sigmas import SensorSigmas
from harborsight.sim.ground_truth import vessel_silhouette_px
from harborsight.sim.schematic import ground_truth, render, sample_scene
from harborsight.vessel.spec import parse_vessel_spec
from tests.test_pose_refinement import TUG, pose_error, scene_and_labels

NO_SEARCH = ClearanceSettings(pose_refinement=PoseRefinementSettings(search_whole_image=False))


def _flagged_with_nothing_standing(report) -> None:
    assert report.sensors_contradicted and not report.pose_refinement["applied"]
    assert report.min_distance_m is None and report.closest_section is None
    for section in report.sections:
        if section.status == "ok":
            assert section.distance_lower_m == 0.0 and section.sigma_m >= section.distance_m
        if section.status == "clear":
            assert section.clear_to_m == 0.0


def test_the_report_and_the_overlay_show_where_the_image_puts_the_hull():
    """A flagged frame's report carries the silhouette where the image puts the hull (within
    a pixel of the true hull's), and the overlay draws it in magenta; an unflagged frame
    has neither."""
    from harborsight.viz.overlay import MAGENTA, draw_overlay

    scene, labels = scene_and_labels(21, "alongside", 60)
    true = scene.geometry()
    report = measure_clearance(labels, corrected_geometry(true, np.array([14.0, 0.0, 0.0, 0.0])), TUG)
    drawn = np.asarray(report.pose_refinement["image_hull_px"])
    uv = true.camera.project(true.vessel_to_enu(TUG.hull_points))[0]
    corners = cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2)
    # every drawn corner lies on the true silhouette's outline, and the areas agree
    assert max(abs(cv2.pointPolygonTest(corners, (float(u), float(v)), True)) for u, v in drawn) < 1.0
    assert cv2.contourArea(drawn.astype(np.float32)) == pytest.approx(cv2.contourArea(corners), rel=0.02)
    blank = np.zeros((*labels.shape, 3), np.uint8)
    magenta = np.all(draw_overlay(blank, report) == MAGENTA, axis=2)
    assert magenta.sum() > 100
    exact = measure_clearance(labels, true, TUG)
    assert exact.pose_refinement["image_hull_px"] is None
    assert not np.all(draw_overlay(blank, exact) == MAGENTA, axis=2).any()


@pytest.mark.parametrize(("offset_e_m", "offset_n_m"), [(14.0, 0.0), (0.0, -25.0)])
def test_a_vessel_far_from_its_fix_is_found_in_the_image_and_flags_the_frame(offset_e_m, offset_n_m):
    """A fix 14 or 25 m off (a stale position, the wrong antenna): the refinement's search
    reaches 7.5 m, its outline lies on water and it keeps the sensors' pose; on the sample
    frames that read a quay 5.05 m away as 9.9 m and sections 12-17 m from a ship as
    `clear`. The whole-image search finds the hull where it is and the frame is flagged."""
    scene, labels = scene_and_labels(21, "alongside", 60)
    true = scene.geometry()
    told = corrected_geometry(true, np.array([offset_e_m, offset_n_m, 0.0, 0.0]))
    assert measure_clearance(labels, told, TUG, NO_SEARCH).sensors_contradicted is False
    report = measure_clearance(labels, told, TUG)
    _flagged_with_nothing_standing(report)
    found = report.pose_refinement
    assert found["shift_m"] == pytest.approx([-offset_e_m, -offset_n_m], abs=0.3)
    assert abs(found["rotation_deg"]) < 1.0 and abs(found["height_change_m"]) < 0.5
    assert found["reason"].startswith("the image puts the hull")


def test_an_ellipsoidal_height_is_no_longer_corrected_into_a_wrong_pose():
    """A height 40 m too high (an ellipsoidal height read as height above the water): the
    hull projects at half its size, and the refinement nestled that small outline into a
    corner of the ship's pixels and applied it (points deep inside the ship cannot tell).
    The search lays the hull at its true size, 40 m lower, and flags the frame; since the
    twenty-ninth session the refinement's own scale test (the hull's size against the
    frame's height and focal length) finds the 40 m and flags it even without the search."""
    scene, labels = scene_and_labels(21, "alongside", 100)
    true = scene.geometry()
    told = corrected_geometry(true, np.array([0.0, 0.0, 0.0, 40.0]))
    alone = measure_clearance(labels, told, TUG, NO_SEARCH)
    _flagged_with_nothing_standing(alone)
    assert "the altitude or the focal length is off" in alone.pose_refinement["reason"]
    assert alone.pose_refinement["height_change_m"] == pytest.approx(-40.0, abs=1.0)
    report = measure_clearance(labels, told, TUG)
    _flagged_with_nothing_standing(report)
    assert report.pose_refinement["height_change_m"] == pytest.approx(-40.0, abs=1.0)


def test_a_reversed_heading_is_caught():
    """A course over ground taken for the heading while the vessel goes astern: 180 degrees
    off. The refinement fitted the reversed outline with a shift and applied it, so the bow's
    sections read the stern's water. The search turns the hull back and flags the frame."""
    scene, labels = scene_and_labels(21, "alongside", 60)
    true = scene.geometry()
    told = replace(true, vessel_heading_rad=true.vessel_heading_rad + math.pi)
    report = measure_clearance(labels, told, TUG)
    _flagged_with_nothing_standing(report)
    turn = report.pose_refinement["rotation_deg"]
    assert abs(abs(turn) - 180.0) < 2.0


@pytest.mark.parametrize(("seed", "turn_deg"), [(21, 60.0), (1, -45.0), (21, -90.0)])
def test_a_heading_far_off_either_way_is_found_along_the_blob_s_axis(seed, turn_deg):
    """A compass 45-90 degrees off (a magnetometer near steel): the start turns the hull by
    the angle between the blob's axis and the predicted silhouette's, in the sense the
    image turns with the heading."""
    scene, labels = scene_and_labels(seed, "alongside", 60)
    true = scene.geometry()
    told = replace(true, vessel_heading_rad=true.vessel_heading_rad + math.radians(turn_deg))
    report = measure_clearance(labels, told, TUG)
    _flagged_with_nothing_standing(report)
    assert report.pose_refinement["rotation_deg"] == pytest.approx(-turn_deg, abs=1.0)


def test_an_ellipsoidal_height_with_a_gps_error_is_found_at_its_scale():
    """A height 40 m too high and a fix 3 m off: the start's shift must be taken at the
    hull's true scale (pixels per metre go as one over the height)."""
    scene, labels = scene_and_labels(21, "alongside", 100)
    true = scene.geometry()
    told = corrected_geometry(true, np.array([2.5, -2.0, 0.0, 40.0]))
    report = measure_clearance(labels, told, TUG)
    _flagged_with_nothing_standing(report)
    found = report.pose_refinement
    assert found["height_change_m"] == pytest.approx(-40.0, abs=1.0)
    assert found["shift_m"] == pytest.approx([-2.5, 2.0], abs=0.3)


def test_a_start_puts_the_silhouette_s_centroid_on_the_blob_s():
    """The starts' one Newton step, with the centroid's Jacobian taken at the sensors'
    height and scaled to the start's: on a mask holding only the hull, drawn 40 m lower and
    7 m away from where the sensors put it, the start at the blob's scale and heading puts
    the silhouette's centroid within a pixel of the blob's."""
    scene, _ = scene_and_labels(21, "alongside", 100)
    true = scene.geometry()
    uv = true.camera.project(true.vessel_to_enu(TUG.hull_points))[0]
    mask = np.zeros((true.camera.intrinsics.height, true.camera.intrinsics.width), np.uint8)
    cv2.fillConvexPoly(mask, np.round(cv2.convexHull(uv.astype(np.float32))).astype(np.int32), 1)
    told = corrected_geometry(true, np.array([5.0, -5.0, 0.0, 40.0]))
    ship = mask.astype(bool)
    align = whole_image_alignment(ship, told)
    hull_h = Silhouette([TUG.hull_points])
    starts = _starts(align, hull_h, ship)
    start = min(starts, key=lambda s: abs(s[3] + 40.0) + abs(s[2]))
    assert start[3] == pytest.approx(-40.0, abs=4.0) and abs(start[2]) < math.radians(5)
    blob = _region(cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)[0][0].reshape(-1, 2))
    assert _silhouette(align, hull_h, start)[1] == pytest.approx(blob[1], abs=1.0)


@pytest.mark.parametrize("yaw_error_deg", [36.0, -84.0, 180.0])
def test_a_camera_yaw_off_is_one_error_and_flags_the_frame(yaw_error_deg):
    """A camera yaw given from the drone's nose instead of true north turns the whole scene
    about the camera: the hull the image shows is turned and shifted at once, which the
    "one gross error" rule took for a bad mask. The shift is the turn of the antenna about
    the camera's ground point, so it is one error: flagged, and named."""
    from harborsight.frame import FrameGeometry

    scene, labels = scene_and_labels(21, "alongside", 60)
    meta = scene.metadata("frame.png")
    told = FrameGeometry.from_metadata(replace(meta, yaw_deg=meta.yaw_deg + yaw_error_deg))
    alone = measure_clearance(labels, told, TUG, NO_SEARCH)
    assert not alone.sensors_contradicted
    report = measure_clearance(labels, told, TUG)
    _flagged_with_nothing_standing(report)
    # named where the shift alone is beyond the refinement's 7.5 m reach; a turn with a
    # small shift is as well the vessel's compass
    named = f"as a camera yaw {abs(round(yaw_error_deg))} deg off would" in report.pose_refinement["reason"]
    assert named == (float(np.hypot(*report.pose_refinement["shift_m"])) > 7.5)
    assert report.pose_refinement["rotation_deg"] == pytest.approx(
        (yaw_error_deg + 180) % 360 - 180, abs=1.0) or abs(yaw_error_deg) == 180.0


def test_a_placement_within_the_limits_is_refined_and_applied():
    """A fix 10 m off is within the 12 m limit, beyond the refinement's own basin (its
    translation search reaches 7.5 m): the image's placement becomes one more start, and
    the corrected distances come back to the truth."""
    scene, labels = scene_and_labels(21, "alongside", 60)
    true = scene.geometry()
    told = corrected_geometry(true, np.array([-7.0, 7.5, 0.0, 0.0]))
    alone = refine_vessel_pose(labels, told, TUG, PoseRefinementSettings(search_whole_image=False))[1]
    assert not alone.applied and "fits a ship edge" in alone.reason
    found, refinement = refine_vessel_pose(labels, told, TUG)
    assert refinement.applied and not refinement.sensors_contradicted, refinement.reason
    shift, turn = pose_error(found, true)
    assert shift < 0.3 and turn < 0.5
    truth = [s["distance_m"] for s in ground_truth(scene)["sections"]]
    report = measure_clearance(labels, told, TUG)
    errors = [abs(s.distance_m - t) for s, t in zip(report.sections, truth, strict=True)
              if s.status == "ok" and t is not None]
    assert len(errors) >= 4 and max(errors) < 0.3


@pytest.mark.parametrize(("seed", "scenario", "altitude_m"), [
    (1, "alongside", 60), (4, "touching", 60), (3, "open", 100)])
def test_a_right_pose_is_neither_searched_nor_flagged(monkeypatch, seed, scenario, altitude_m):
    """The search runs only where the pose kept or applied leaves the outline short of ship
    edges; a touching neighbour does not make it flag a right pose."""
    scene, labels = scene_and_labels(seed, scenario, altitude_m)
    noisy = corrected_geometry(scene.geometry(), np.array([1.2, -0.9, math.radians(1.5), 0.0]))
    called = []
    original = gross_errors.place_hull
    monkeypatch.setattr(gross_errors, "place_hull", lambda *a, **k: called.append(1) or original(*a, **k))
    _, refinement = refine_vessel_pose(labels, noisy, TUG)
    assert refinement.applied and not refinement.sensors_contradicted
    assert called == [] or scenario == "touching"


def _with_a_twin(labels: np.ndarray, geometry) -> np.ndarray:
    """``labels`` with a clean copy of the vessel's silhouette drawn on open water in view,
    20-40 m from it."""
    hull = TUG.hull_points
    h, w = labels.shape
    for distance_m in (20.0, 30.0, 40.0):
        for bearing_deg in range(0, 360, 30):
            offset = distance_m * np.array([math.sin(math.radians(bearing_deg)),
                                            math.cos(math.radians(bearing_deg)), 0.0, 0.0])
            moved = corrected_geometry(geometry, offset)
            uv = moved.camera.project(moved.vessel_to_enu(hull))[0]
            if not np.isfinite(uv).all() or uv.min() < 5 or (uv.max(axis=0) > (w - 5, h - 5)).any():
                continue
            twin = np.zeros_like(labels)
            cv2.fillConvexPoly(twin, np.round(cv2.convexHull(uv.astype(np.float32))).astype(np.int32), 1)
            grown = cv2.dilate(twin, np.ones((9, 9), np.uint8)).astype(bool)
            if (labels[grown] == 0).all():
                out = labels.copy()
                out[twin.astype(bool)] = 1
                return out
    raise AssertionError("no open water for the twin")


def test_a_hull_on_another_ship_does_not_contradict_a_pose_on_its_own(monkeypatch):
    """A vessel touching a neighbour leaves a third of its outline deep in ship pixels, so
    the search runs; a clean twin of its hull on open water fits better. When the pose sits
    on ship pixels, only a placement overlapping its own silhouette (the same ship, seen
    larger or turned) can flag it: a bench frame "found" its hull 26 m away, turned 177
    degrees and 72 m higher, on another boat."""
    scene, labels = scene_and_labels(4, "touching", 60)
    true = scene.geometry()
    labels = _with_a_twin(labels, true)
    _, refinement = refine_vessel_pose(labels, true, TUG)
    assert not refinement.sensors_contradicted, refinement.reason
    monkeypatch.setattr(gross_errors, "SAME_SHIP_OVERLAP", 0.0)     # without the rule
    _, refinement = refine_vessel_pose(labels, true, TUG)
    assert refinement.sensors_contradicted


def test_a_fix_on_a_larger_neighbour_does_not_hold_the_hull_there(monkeypatch):
    """The sensors' fix 17 m abeam (a camera tilt given wrong, a gross fix) lays the hull over
    a larger neighbour: the hull fills ship pixels but most of its outline lies inside the
    blob, off its edges, and the refinement's scale to the neighbour is refused. The own
    vessel, on open water, takes the hull cleanly: the frame is flagged, naming where the
    image puts the hull. While a pose that merely fills a ship held the hull to it (the rule
    above), the frame was measured from inside the neighbour with nothing said (on the bench,
    three frames with the pitch given as -90 read sections 8-25 m long)."""
    scene, labels = scene_and_labels(3, "open", 100)
    true = scene.geometry()
    heading = true.vessel_heading_rad
    abeam = np.array([math.cos(heading), -math.sin(heading)])     # to starboard, east-north
    ahead = np.array([math.sin(heading), math.cos(heading)])

    def silhouette(offset_en: np.ndarray, scale: float = 1.0) -> np.ndarray:
        moved = corrected_geometry(true, np.array([*offset_en, 0.0, 0.0]))
        uv = cv2.convexHull(moved.camera.project(moved.vessel_to_enu(TUG.hull_points))[0]
                            .astype(np.float32)).reshape(-1, 2)
        centre = uv.mean(axis=0)
        return np.round(centre + scale * (uv - centre)).astype(np.int32)

    with_neighbour = labels.copy()
    for along_m in (0.0, 8.0):      # a neighbour 16 m abeam, 1.15 times the hull and longer
        drawn = np.zeros_like(labels)
        cv2.fillConvexPoly(drawn, silhouette(16.0 * abeam + along_m * ahead, 1.15), 1)
        with_neighbour[drawn > 0] = 1                            # ship
    told = corrected_geometry(true, np.array([*(17.0 * abeam), 0.0, 0.0]))
    report = measure_clearance(with_neighbour, told, TUG)
    _flagged_with_nothing_standing(report)
    assert report.pose_refinement["reason"].startswith("the image puts the hull 17")
    drawn_px = np.asarray(report.pose_refinement["image_hull_px"], np.float32)
    own_px = silhouette(np.zeros(2)).astype(np.float32)
    assert cv2.contourArea(drawn_px) == pytest.approx(cv2.contourArea(own_px), rel=0.03)
    monkeypatch.setattr(gross_errors, "HELD_FROM_SHARE", 0.0)     # any filled pose holds
    held = measure_clearance(with_neighbour, told, TUG)
    assert not held.sensors_contradicted and held.min_distance_m is not None


def _abeam_m(geometry) -> np.ndarray:
    """The vessel's starboard beam direction, east and north."""
    heading = geometry.vessel_heading_rad
    return np.array([math.cos(heading), -math.sin(heading)])


def _rafted_between_sisters(labels: np.ndarray, true) -> np.ndarray:
    """``labels`` with a sister hull drawn touching the vessel on either side (0.98 of a beam
    abeam: one ship blob three hulls wide), on the water only."""
    beam_m = float(np.ptp(TUG.outline[:, 1]))
    rafted = labels.copy()
    for side in (-1, 1):
        moved = corrected_geometry(true, np.array([*(side * 0.98 * beam_m * _abeam_m(true)), 0.0, 0.0]))
        uv = moved.camera.project(moved.vessel_to_enu(TUG.hull_points))[0]
        drawn = np.zeros_like(labels)
        cv2.fillConvexPoly(drawn, np.round(cv2.convexHull(uv.astype(np.float32))).astype(np.int32), 1)
        rafted[(drawn > 0) & (labels == 0)] = 1                          # ship, on the water
    return rafted


def _compare_no_solved_candidates(patch: pytest.MonkeyPatch) -> None:
    """Have the twin check leave out the candidates the refinement solved before it (as it
    did before the forty-third session), so a test shows what its own check catches."""
    twin_alongside = pose_refinement.twin_alongside

    def without_solved(*args, **kwargs):
        return twin_alongside(*args, **{**kwargs, "solved": ()})

    patch.setattr(pose_refinement, "twin_alongside", without_solved)


def _laid_a_berth_over_without(rule_away, labels, told, true, off_m: float,
                               settings: PoseRefinementSettings | None = None) -> None:
    """With ``rule_away(patch)`` the yacht is laid ``off_m`` or more from the truth, applied."""
    with pytest.MonkeyPatch.context() as patch:
        rule_away(patch)
        laid, unchecked = refine_vessel_pose(labels, told, YACHT, settings or PoseRefinementSettings())
    assert unchecked.applied and pose_error(laid, true)[0] > off_m


def _kept_for(reason: str, labels, told, settings: PoseRefinementSettings | None = None):
    """The yacht's sensors' pose is kept, not flagged, for a reason that begins ``reason``:
    ``(geometry, refinement)``."""
    kept, refinement = refine_vessel_pose(labels, told, YACHT, settings or PoseRefinementSettings())
    assert not refinement.applied and not refinement.sensors_contradicted
    assert refinement.reason.startswith(reason), refinement.reason
    return kept, refinement


@pytest.mark.parametrize(("seed", "altitude_m"), [(5, 100), (3, 60)])
def test_a_vessel_rafted_between_sister_hulls_is_not_laid_on_one_of_them(seed, altitude_m):
    """Rafted between two sister hulls, touching, with the sensors 2.5 m toward one of them
    (and 1 m ahead, 1 degree turned): an outer twin puts one side on the blob's edge, the
    true pose neither, and the alignment's cost took the twin, one beam (10.7 m) off,
    applied and unflagged. Of the placements that fit alike, the prior now picks the one
    nearest the sensors' pose."""
    scene, labels = scene_and_labels(seed, "open", altitude_m)
    true = scene.geometry()
    rafted = _rafted_between_sisters(labels, true)
    error = np.array([*(2.5 * _abeam_m(true) + 1.0 * _abeam_m(true) @ [[0, -1], [1, 0]]),
                      math.radians(1.0), 0.0])
    found, refinement = refine_vessel_pose(rafted, corrected_geometry(true, error), TUG)
    assert refinement.applied, refinement.reason
    assert pose_error(found, true)[0] < 0.3
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sister_hulls, "TWIN_DEEP_SHARE", 1.01)        # no twin check
        patch.setattr(sister_hulls, "TWIN_BLOB_AREA", (0.4, 99.0))
        _compare_no_solved_candidates(patch)
        laid, unchecked = refine_vessel_pose(rafted, corrected_geometry(true, error), TUG)
    assert unchecked.applied and not unchecked.sensors_contradicted
    assert pose_error(laid, true)[0] > 9.0


def test_sister_hulls_the_sensors_cannot_tell_apart_keep_the_sensors_pose():
    """The sensors half a beam (5.4 m) toward one sister: the true pose and the twin are
    about as near the sensors' pose, so the image cannot say which hull is the vessel. The
    sensors' pose is kept with its own error bars, and the report says why; it is not a
    contradiction of the sensors (the frame is measured, not flagged)."""
    scene, labels = scene_and_labels(5, "open", 100)
    true = scene.geometry()
    rafted = _rafted_between_sisters(labels, true)
    told = corrected_geometry(true, np.array([*(5.4 * _abeam_m(true)), 0.0, 0.0]))
    _, refinement = refine_vessel_pose(rafted, told, TUG)
    assert not refinement.applied and not refinement.sensors_contradicted
    assert refinement.reason.startswith(sister_hulls.TWIN_ALIKE)
    assert "10.7 m abeam" in refinement.reason
    report = measure_clearance(rafted, told, TUG)
    assert not report.sensors_contradicted and not report.pose_refinement["applied"]
    assert report.pose_refinement["reason"].startswith(sister_hulls.TWIN_ALIKE)
    assert report.min_distance_m is not None          # measured, with the sensors' bars
    truth = {s.index: s for s in measure_clearance(rafted, true, TUG).sections if s.status == "ok"}
    bounded = [(s.distance_lower_m, truth[s.index].distance_m) for s in report.sections
               if s.status == "ok" and s.index in truth]
    assert bounded and all(lower <= true_m for lower, true_m in bounded)


#: a 12 m yacht drawn from its dimensions, 4 m in beam; berths 5 m apart
YACHT = parse_vessel_spec({"name": "yacht", "air_draft_m": 1.5, "dimensions": {
    "to_bow": 8.0, "to_stern": 4.0, "to_port": 2.0, "to_starboard": 2.0}}, Path("yacht.yaml"))
YACHT_BERTH_M = 5.0


def _paint_sisters(labels: np.ndarray, true, vessel, abeam_m: tuple[float, ...]) -> None:
    """Draw ``vessel``'s silhouette as ship into ``labels`` at each offset ``abeam_m``
    (metres to starboard of the true pose)."""
    for offset_m in abeam_m:
        moved = corrected_geometry(true, np.array([*(offset_m * _abeam_m(true)), 0.0, 0.0]))
        for polygon in vessel_silhouette_px(vessel, moved):
            cv2.fillPoly(labels, [np.round(polygon).astype(np.int32)], 1)


def _yacht_in_a_row(seed: int, altitude_m: float):
    """The yacht in the open scene with four sister yachts moored in a row beside it, a
    metre of water between hulls (five ship blobs): ``(labels, true geometry)``."""
    scene = sample_scene(YACHT, np.random.default_rng(seed), altitude_m=altitude_m, tilt_deg=3.0,
                         scenario="open")
    labels = render(scene)[1].copy()
    true = scene.geometry()
    _paint_sisters(labels, true, YACHT, tuple(k * YACHT_BERTH_M for k in (-2, -1, 1, 2)))
    return labels, true


@pytest.mark.parametrize(("seed", "altitude_m"), [(3, 60), (8, 30)])
def test_a_yacht_in_a_row_of_sisters_is_not_laid_on_the_next_berth(seed, altitude_m):
    """A marina's row of identical yachts, 5 m apart, with the sensors 3 m toward the next
    berth (the documented errors reach that): the alignment went to the nearer blob, the
    neighbour, and applied it unflagged (19 of 96 frames of a row of five at the documented
    errors). The other blobs of the hull's size are fitted too, and the prior cannot tell
    the two apart at 20 to 1: the sensors' pose is kept, measured, and the reason says so."""
    labels, true = _yacht_in_a_row(seed, altitude_m)
    told = corrected_geometry(true, np.array([*(3.0 * _abeam_m(true)), math.radians(1.0), 0.5]))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sister_hulls, "TWIN_BLOB_STARTS", 0)        # no other blob fitted
        laid, unchecked = refine_vessel_pose(labels, told, YACHT)
    assert unchecked.applied and not unchecked.sensors_contradicted
    assert pose_error(laid, true)[0] > 4.5
    _, refinement = refine_vessel_pose(labels, told, YACHT)
    assert not refinement.applied and not refinement.sensors_contradicted
    assert refinement.reason.startswith(sister_hulls.TWIN_ALIKE)
    said = refinement.reason[len(sister_hulls.TWIN_ALIKE):]
    apart_m = float(said.split(" m abeam (a vessel alike alongside)")[0])
    assert apart_m == pytest.approx(YACHT_BERTH_M, abs=0.3)
    report = measure_clearance(labels, told, YACHT)
    assert not report.sensors_contradicted and report.min_distance_m is not None


def test_a_prior_of_a_kilometre_still_finds_the_sisters_blobs():
    """A receiver without a fix states a prior of a kilometre, and with sisters 5 m apart
    the image cannot say which hull is the vessel. The blobs' grid stepped a third of the
    prior, 485 m, never landed on a sister's blob, and the hull was laid a berth over (a
    reviewer's probe with such a prior: 26 of 144 frames of a row of three). The grid steps
    at most half a beam, reaches no farther than a correction may move, and the sensors'
    pose is kept."""
    labels, true = _yacht_in_a_row(3, 60)
    told = corrected_geometry(true, np.array([2.49, 3.26, 0.0, -1.96]))
    settings = PoseRefinementSettings(prior_shift_m=1000.0, prior_heading_deg=1000.0)
    blob_starts = sister_hulls._blob_starts

    def stepped_by_the_prior(params, align, silhouette, ship, prior_diagonal, step_m, apart_m,
                             max_shift_m=math.inf):
        return blob_starts(params, align, silhouette, ship, prior_diagonal,
                           prior_search.SEARCH_STEP_SIGMA * prior_diagonal[0] ** -0.5, apart_m)

    _laid_a_berth_over_without(lambda patch: patch.setattr(sister_hulls, "_blob_starts",
                                                           stepped_by_the_prior),
                               labels, told, true, 4.5, settings)
    _kept_for(sister_hulls.TWIN_ALIKE, labels, told, settings)


def test_sister_yachts_are_checked_where_the_outline_has_few_points():
    """At 84 m the yacht's outline has 41-46 points; scored with every second of them the
    sister blobs' cells had fewer than the 24 a score needs, nothing was tried, and the hull
    was laid a berth over (a reviewer's find: 22 of 108 frames at 80-88 m)."""
    labels, true = _yacht_in_a_row(5, 84)
    told = corrected_geometry(true, np.array([*(3.0 * _abeam_m(true)), math.radians(1.0), 0.5]))
    _, refinement = refine_vessel_pose(labels, told, YACHT)
    assert not refinement.applied and refinement.reason.startswith(sister_hulls.TWIN_ALIKE)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sister_hulls, "TWIN_BLOB_POINTS", 40)
        laid, scored_short = refine_vessel_pose(labels, told, YACHT)
    assert scored_short.applied and pose_error(laid, true)[0] > 4.5


def test_sister_yachts_leaning_into_one_blob_far_from_the_nadir_are_told_apart():
    """The row of three seen from a drone 75 m to one side at 100 m: the 1.5 m air draft leans
    each silhouette over the metre of water, and the three yachts make one ship blob, 2.4
    hulls' area, so no other blob of the hull's size was tried. The true pose, both sides
    against a sister, fits worse than an outer sister with one side on the water, and the
    hull was laid a berth over from every sensor error tried (1-3 m abeam, a reviewer's
    probe: 12 of 12 frames of this scene). A blob larger than the hull now has the hull tried
    a beam to either side, and the prior cannot tell the placements apart."""
    scene = sample_scene(YACHT, np.random.default_rng(3), altitude_m=100, tilt_deg=3.0, scenario="open")
    yaw = math.radians(scene.yaw_deg)
    image_right = np.array([math.cos(yaw), -math.sin(yaw), 0.0])
    scene = replace(scene, uav_enu=scene.uav_enu + 75.0 * image_right)
    labels = render(scene)[1].copy()
    true = scene.geometry()
    _paint_sisters(labels, true, YACHT, (-YACHT_BERTH_M, YACHT_BERTH_M))
    assert cv2.connectedComponents((labels == 1).astype(np.uint8))[0] == 2      # one blob
    told = corrected_geometry(true, np.array([*(2.0 * _abeam_m(true)), math.radians(1.0), 0.5]))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sister_hulls, "TWIN_BLOB_AREA", (0.4, 99.0))      # no blob too large
        _compare_no_solved_candidates(patch)
        laid, unchecked = refine_vessel_pose(labels, told, YACHT)
    assert unchecked.applied and pose_error(laid, true)[0] > 4.5
    _, refinement = refine_vessel_pose(labels, told, YACHT)
    assert not refinement.applied and not refinement.sensors_contradicted
    assert refinement.reason.startswith(sister_hulls.TWIN_ALIKE)
    assert "m abeam (a vessel alike alongside)" in refinement.reason


def test_a_sister_between_two_others_half_a_metre_apart_is_one_of_the_row():
    """A 14 m yacht (4.6 m beam) between two sisters 5 m apart, so half a metre of water on
    either side, at 95 m, the sensors 3 m toward one sister: the 1 px ring just outside the
    true pose touches both sisters, an outer sister's only one, and the ring test (meant
    for a box's corners) turned the true pose away: the hull was laid a berth over (a
    reviewer's probe: 21 of 108 frames at 95-105 m). The ring now leaves out what a row of
    sisters at that spacing covers."""
    yacht14 = parse_vessel_spec({"name": "yacht14", "air_draft_m": 1.5, "dimensions": {
        "to_bow": 9.3, "to_stern": 4.7, "to_port": 2.3, "to_starboard": 2.3}}, Path("yacht14.yaml"))
    scene = sample_scene(yacht14, np.random.default_rng(3), altitude_m=95, tilt_deg=3.0, scenario="open")
    labels = render(scene)[1].copy()
    true = scene.geometry()
    _paint_sisters(labels, true, yacht14, (-YACHT_BERTH_M, YACHT_BERTH_M))
    abeam = _abeam_m(true)
    ahead = np.array([-abeam[1], abeam[0]])                 # (sin h, cos h): the bow's way
    told = corrected_geometry(true, np.array([*(-3.0 * abeam - 2.0 * ahead), math.radians(1.0), 0.5]))

    def rings_alone(best, found, align, silhouette, ship):
        return (sister_hulls._ring_ship_share(best, align, silhouette, ship),
                sister_hulls._ring_ship_share(found, align, silhouette, ship))

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sister_hulls, "_row_rings", rings_alone)
        laid, ringed_alone = refine_vessel_pose(labels, told, yacht14)
    assert ringed_alone.applied and pose_error(laid, true)[0] > 4.5
    _, refinement = refine_vessel_pose(labels, told, yacht14)
    assert not refinement.applied and not refinement.sensors_contradicted
    assert refinement.reason.startswith(sister_hulls.TWIN_ALIKE)


def _row_of_three_seen_from_aside(seed: int, altitude_m: float, sisters: bool = True,
                                  ahead: bool = False, tilt_deg: float = 3.0):
    """The yacht with a sister 5 m to either side, the drone 0.75 of its height to the
    image's right of where the scene puts it (``ahead``: 0.38 of it toward the image's
    top): ``(labels, true geometry)``."""
    scene = sample_scene(YACHT, np.random.default_rng(seed), altitude_m=altitude_m,
                         tilt_deg=tilt_deg, scenario="open")
    yaw = math.radians(scene.yaw_deg)
    image_right = np.array([math.cos(yaw), -math.sin(yaw), 0.0])
    image_up = np.array([math.sin(yaw), math.cos(yaw), 0.0])
    moved_m = 0.38 * altitude_m * image_up if ahead else 0.75 * altitude_m * image_right
    scene = replace(scene, uav_enu=scene.uav_enu + moved_m)
    labels = render(scene)[1].copy()
    true = scene.geometry()
    _paint_sisters(labels, true, YACHT, (-YACHT_BERTH_M, YACHT_BERTH_M) if sisters else ())
    return labels, true


def test_a_yacht_the_border_cuts_is_not_laid_on_a_sister_in_full_view():
    """The row of three at 100 m with the yacht at the image's left border (its stern out of
    the picture) and the sensors 2 m ahead: the hull where the sensors put it has too few
    outline points in view to be scored, the sister beside it in full view fits cleanly,
    and the hull was laid on the sister, 4.9 m off (a reviewer's probe: most of the 35 of
    144 frames still laid a berth over with the camera so far aside). What is in view is
    aligned from fewer points; it fits, so it joins the comparison with the sister, and the
    prior cannot choose: the sensors' pose is kept. Alone on the water the yacht is refined."""
    labels, true = _row_of_three_seen_from_aside(5, 100)
    ahead = np.array([-_abeam_m(true)[1], _abeam_m(true)[0]])
    error = np.array([*(2.0 * ahead), math.radians(1.0), 0.5])
    told = corrected_geometry(true, error)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sister_hulls, "CUT_IN_VIEW", 0.0)          # no hull counts as cut
        laid, unchecked = refine_vessel_pose(labels, told, YACHT)
    assert unchecked.applied and pose_error(laid, true)[0] > 4.5
    _, refinement = refine_vessel_pose(labels, told, YACHT)
    assert not refinement.applied and not refinement.sensors_contradicted
    assert refinement.reason.startswith(sister_hulls.CUT_ALIKE), refinement.reason
    assert "of its outline in view, fitting the mask there" in refinement.reason
    report = measure_clearance(labels, told, YACHT)
    assert not report.sensors_contradicted and report.min_distance_m is not None
    alone, true_alone = _row_of_three_seen_from_aside(5, 100, sisters=False)
    found, refined = refine_vessel_pose(alone, corrected_geometry(true_alone, error), YACHT)
    assert refined.applied and pose_error(found, true_alone)[0] < 0.6, refined.reason


def test_a_yacht_rafted_between_two_sisters_is_not_laid_on_an_outer_one():
    """The yacht rafted between two sisters, hulls touching (4 m apart, the beam), at 100 m,
    the sensors 2 m toward one of them: the true placement's sides lie deep in the
    neighbours' pixels, leaving 23 outline points that can tell, under the 24 an alignment
    needs, while an outer sister has a free side; so only the outer one fitted alike and was
    applied, 4 m over (a reviewer's probe: 34 of 144 frames). A placement among sisters now
    fits alike with half as many telling points, and the prior cannot choose."""
    scene = sample_scene(YACHT, np.random.default_rng(3), altitude_m=100, tilt_deg=3.0, scenario="open")
    labels = render(scene)[1].copy()
    true = scene.geometry()
    _paint_sisters(labels, true, YACHT, (-4.0, 4.0))
    told = corrected_geometry(true, np.array([*(2.0 * _abeam_m(true)), math.radians(1.0), 0.5]))
    _laid_a_berth_over_without(lambda patch: patch.setattr(sister_hulls, "ALIKE_MIN_TELLING",
                                                           sister_hulls.MIN_EDGE_POINTS),
                               labels, told, true, 3.5)
    _kept_for(sister_hulls.TWIN_ALIKE, labels, told)


def test_a_cut_hull_whose_fit_from_the_sensors_fails_is_found_from_the_grid():
    """The row of three at 30 m with the drone 11 m ahead: the yacht's stern is out of the
    picture, and the sensors are 2 m abeam and 2 m ahead. Aligned from the sensors' pose on
    what is in view, the cut hull's silhouette lands half on water and is refused, so it
    never joined the comparison, and the hull was laid on a sister 5 m over (a reviewer
    found so in 3 of 4 such frames still wrong). Started from the grid cell whose points in
    view fit best, height held, it joins, and the sensors' pose is kept."""
    labels, true = _row_of_three_seen_from_aside(5, 30, ahead=True)
    abeam = _abeam_m(true)
    ahead = np.array([-abeam[1], abeam[0]])
    told = corrected_geometry(true, np.array([*(2.0 * abeam + 2.0 * ahead), math.radians(1.0), 0.5]))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sister_hulls, "CUT_STARTS", 0)
        laid, unchecked = refine_vessel_pose(labels, told, YACHT)
    assert unchecked.applied and pose_error(laid, true)[0] > 4.5
    _, refinement = refine_vessel_pose(labels, told, YACHT)
    assert not refinement.applied and not refinement.sensors_contradicted
    assert refinement.reason.startswith((sister_hulls.CUT_ALIKE, sister_hulls.TWIN_ALIKE))


def test_a_cut_hull_fitted_with_an_end_over_water_still_joins_the_comparison():
    """The row of three at 100 m with the drone 38 m ahead: half the yacht's outline is out
    of the picture and the sensors are 2 m off. Aligned on the 13 outline points in view,
    the cut hull lies 0.4 m from the truth along its length, its bow over water: 83 % of
    its silhouette is ship, under the 90 % an accepted placement needs, so it never joined
    the comparison and the hull was laid on the sister 4.9 m over (a reviewer's probe: 8
    of 12 such frames at 100 m). A cut hull's placement that fills 80 % of the 90 % now
    joins, and the prior cannot choose."""
    labels, true = _row_of_three_seen_from_aside(8, 100, ahead=True)
    told = corrected_geometry(true, np.array([-0.34, 2.05, -0.01, 0.81]))
    _laid_a_berth_over_without(lambda patch: patch.setattr(sister_hulls, "CUT_FILL_SHARE", 1.0),
                               labels, told, true, 4.5)
    kept, refinement = _kept_for(sister_hulls.CUT_ALIKE, labels, told)
    assert "fitting the mask there" in refinement.reason
    assert pose_error(kept, true)[0] < 2.5


def test_a_placement_solved_a_beam_over_is_compared_with_the_sister():
    """The row of three at 30 m with the drone 11 m ahead, the sensors 2.8 m toward a
    sister: the refinement's start a beam to the other side finds the true placement (every
    point in view on an edge), but 16 % of its outline is out of the picture and counts as
    misses, so the sister, in full view, wins on cost, and the hull was laid 5 m over. The
    twin check solved again only from its own starts and never compared the two; the
    candidates already solved are now checked as sisters' placements are, and the prior
    cannot choose between them."""
    labels, true = _row_of_three_seen_from_aside(3, 30, ahead=True)
    told = corrected_geometry(true, np.array([-0.56, -2.8, 0.04, -0.08]))
    _laid_a_berth_over_without(_compare_no_solved_candidates, labels, told, true, 4.5)
    _kept_for(sister_hulls.TWIN_ALIKE, labels, told)


def test_a_cut_hull_whose_fit_runs_off_in_height_is_fitted_again_at_the_sensors_height():
    """The row of three at 30 m, the drone 11 m ahead and its camera tilted 15 degrees: the
    cut hull aligned from the sensors' pose lies 0.4 m from the truth but 5-6 m too high (a
    cut outline hardly measures the scale), beyond the height's limit, and the grid's cells
    lay it on water; so the sister in full view was laid on, 5 m over. Aligned again from
    where that fit lay, at the sensors' height, it fits, joins the comparison, and the
    sensors' pose is kept."""
    labels, true = _row_of_three_seen_from_aside(8, 30, ahead=True, tilt_deg=15.0)
    told = corrected_geometry(true, np.array([0.99, 1.45, -0.11, 0.95]))
    cut_starts = sister_hulls._cut_starts

    def grid_only(align, outline, params, prior_diagonal, apart_m, fitted=None):
        return cut_starts(align, outline, params, prior_diagonal, apart_m)

    _laid_a_berth_over_without(lambda patch: patch.setattr(sister_hulls, "_cut_starts", grid_only),
                               labels, told, true, 4.5)
    kept, _ = _kept_for("", labels, told)
    assert pose_error(kept, true)[0] < 2.5


def test_a_box_of_the_yacht_s_footprint_alongside_is_no_sister():
    """A 12 x 4 m box (a work float) moored 5.5 m abeam of the 12 m yacht, the sensors 1.5 m
    toward it: the yacht's outline laid inside the box passes every test of a placement, and
    the box was taken for a sister (the sensors' pose kept on 80 of 144 such frames in a
    reviewer's probe). Ship pixels just outside that placement (the box's corners) tell it
    from a sister: the alignment's pose is applied."""
    box = parse_vessel_spec({"name": "box", "air_draft_m": 1.5, "dimensions": {
        "to_bow": 8.0, "to_stern": 4.0, "to_port": 2.0, "to_starboard": 2.0, "bow": "box"}},
        Path("box.yaml"))
    scene = sample_scene(YACHT, np.random.default_rng(3), altitude_m=60, tilt_deg=3.0, scenario="open")
    labels = render(scene)[1].copy()
    true = scene.geometry()
    moved = corrected_geometry(true, np.array([*(5.5 * _abeam_m(true)), 0.0, 0.0]))
    for polygon in vessel_silhouette_px(box, moved):
        cv2.fillPoly(labels, [np.round(polygon).astype(np.int32)], 1)
    told = corrected_geometry(true, np.array([*(1.5 * _abeam_m(true)), math.radians(1.0), 0.3]))
    found, refinement = refine_vessel_pose(labels, told, YACHT)
    assert refinement.applied, refinement.reason
    assert pose_error(found, true)[0] < 0.3
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sister_hulls, "TWIN_BLOB_RING", 99.0)          # no ring test
        _, unringed = refine_vessel_pose(labels, told, YACHT)
    assert not unringed.applied and unringed.reason.startswith(sister_hulls.TWIN_ALIKE)



def test_a_larger_ship_the_yacht_touches_is_no_sister(tmp_path):
    """A 13 m yacht (antenna on its port stern rail) touching a larger moored ship, 59 m up,
    the sensors 1.9 m and 2.9 degrees off (seed 1455 of the fifty-third session's hunt with
    other hulls). The alignment finds the correction to 2 cm; the twin check's start a beam
    over fitted the yacht's outline inside the neighbour's bow (with 3.4 m of height), and,
    as a start a beam over, skipped the ring test that tells a larger vessel from a sister.
    The sensors' pose was kept and the stern section read 10.7 m (bound 3.7 m) for 2.8 m.
    Every placement's ring is tested now: the correction is applied."""
    from harborsight.vessel.hullgen import HullParameters
    from tests.helpers import generated_hull_vessel

    yacht = generated_hull_vessel(
        tmp_path, HullParameters(13.0, 4.2, 1.0, 1.5, 0.45, 0.12, (0.3, 0.65, 0.6, 2.2)),
        (0.4, 1.9, 3.0), sections=12, name="yacht13")
    scene = sample_scene(yacht, np.random.default_rng(1455), altitude_m=59.27, tilt_deg=0.0,
                         scenario="touching", gap_m=2.17)
    labels = render(scene)[1]
    true = scene.geometry()
    told = corrected_geometry(true, np.array([1.898, 0.272, math.radians(-2.855)]))
    found, refinement = refine_vessel_pose(labels, told, yacht)
    assert refinement.applied, refinement.reason
    assert pose_error(found, true)[0] < 0.3
    report = measure_clearance(labels, told, yacht)
    truth = ground_truth(scene)["sections"]
    read = [(s.distance_m, t["distance_m"]) for s, t in zip(report.sections, truth, strict=True)
            if s.status == "ok" and t["distance_m"] is not None]
    assert read and max(abs(d - t) for d, t in read) < 0.5

def test_a_tighter_prior_tells_sister_yachts_apart():
    """The same row with the sensors 1.5 m toward the next berth: under a 3 m prior the
    true pose is 3 to 1 likelier than the neighbour, kept so; under a 1 m prior (DGPS on
    both receivers) it is about 25,000 to 1, and the alignment's pose is applied. A frame's
    sensors set that prior in ``measure_clearance``."""
    labels, true = _yacht_in_a_row(3, 60)
    told = corrected_geometry(true, np.array([*(1.5 * _abeam_m(true)), 0.0, 0.0]))
    _, default = refine_vessel_pose(labels, told, YACHT)
    assert not default.applied and default.reason.startswith(sister_hulls.TWIN_ALIKE)
    found, tight = refine_vessel_pose(labels, told, YACHT, PoseRefinementSettings(prior_shift_m=1.0))
    assert tight.applied, tight.reason
    assert pose_error(found, true)[0] < 0.3
    # the frame's own sensors set that prior: DGPS on both receivers gives about 1 m
    dgps = measure_clearance(labels, told, YACHT, sigmas=SensorSigmas(uav_gps=0.5, vessel_gps=0.5))
    assert dgps.pose_refinement["applied"], dgps.pose_refinement["reason"]
    assert not measure_clearance(labels, told, YACHT).pose_refinement["applied"]


def test_a_vessel_rafted_between_two_others_is_held_there_by_its_ends():
    """Moored between two sister ships, the right pose puts only 40 % of its outline on ship
    edges (its sides lie against theirs), and a third sister on open water fits cleanly 30 m
    away. The pose's bow and stern are on edges, so the hull stays held to its ship: nothing
    is flagged. By the share alone it was (a reviewer's case)."""
    scene, labels = scene_and_labels(3, "open", 60)
    true = scene.geometry()
    rafted = _with_a_twin(_rafted_between_sisters(labels, true), true)
    _, refinement = refine_vessel_pose(rafted, true, TUG)
    assert refinement.edge_share < gross_errors.HELD_FROM_SHARE
    assert not refinement.sensors_contradicted, refinement.reason
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(gross_errors, "ENDS_ON_EDGES_SHARE", 1.01)        # by the share alone
        _, by_share = refine_vessel_pose(rafted, true, TUG)
    assert by_share.sensors_contradicted


def test_the_overlap_of_two_silhouettes_matches_shapely():
    a = np.array([[0, 0], [40, 0], [40, 10], [0, 10], [np.nan, np.nan]], float)
    b = np.array([[30, -5], [70, 2], [65, 20], [28, 12]], float)
    expected = (MultiPoint(a[:4]).convex_hull.intersection(MultiPoint(b).convex_hull).area
                / min(MultiPoint(a[:4]).convex_hull.area, MultiPoint(b).convex_hull.area))
    assert silhouette_overlap(a, b) == pytest.approx(expected, rel=1e-4)
    assert silhouette_overlap(a, b + 100) == 0.0
    assert silhouette_overlap(a[:2], b) == 0.0


def test_a_region_s_axis_and_length_match_its_rotated_rectangle():
    """The principal axis and the ``sqrt(12 lambda_1)`` length of a drawn bar, against the
    rectangle OpenCV's minAreaRect fits to it."""
    mask = np.zeros((200, 300), np.uint8)
    corners = cv2.boxPoints(((150.0, 100.0), (160.0, 30.0), 25.0))
    cv2.fillConvexPoly(mask, np.round(corners).astype(np.int32), 1)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    area, centroid, angle, length = _region(contours[0].reshape(-1, 2))
    (cx, cy), (w, h), rect_angle = cv2.minAreaRect(cv2.findNonZero(mask))
    long_side, long_angle = (w, rect_angle) if w >= h else (h, rect_angle + 90)
    assert length == pytest.approx(long_side, rel=0.03)
    assert math.degrees(angle) % 180 == pytest.approx(long_angle % 180, abs=1.0)
    assert centroid == pytest.approx([cx, cy], abs=1.0)
    assert area == pytest.approx(160 * 30, rel=0.05)     # the contour runs through pixel centres


def test_the_edge_share_counts_points_deep_inside_against_a_placement():
    assert edge_share(np.array([0.3, -1.5, -9.0, 6.0])) == 0.5
    assert edge_share(np.array([])) == 0.0


def test_a_camera_tilted_12_degrees_given_as_straight_down_is_one_error_and_flags_the_frame():
    """At 100 m a camera 12 degrees off nadir told as straight down shows the hull 21 m from
    the sensors' pose and at a scale 4 m of height away: two gross components, which the
    "one gross error" rule took for a bad mask, and the distances were read with the wrong
    pose without a word. One camera tilt explains both (camera_errors): flagged, and the
    tilt named within a degree."""
    import re

    from harborsight.frame import FrameGeometry

    scene, labels = scene_and_labels(3, "open", 100, tilt_deg=12.0)
    meta = scene.metadata("frame.png")
    told = FrameGeometry.from_metadata(replace(meta, pitch_deg=-90.0, roll_deg=0.0))
    true_tilt_deg = math.degrees(math.acos(math.cos(math.radians(90 + meta.pitch_deg))
                                           * math.cos(math.radians(meta.roll_deg))))
    alone = measure_clearance(labels, told, TUG, NO_SEARCH)
    assert not alone.sensors_contradicted
    report = measure_clearance(labels, told, TUG)
    _flagged_with_nothing_standing(report)
    reason = report.pose_refinement["reason"]
    named = re.search(r"as a camera tilted (\d+) deg more than stated would", reason)
    assert named and abs(int(named.group(1)) - true_tilt_deg) <= 1.0, reason


def test_the_refinement_s_refused_correction_is_a_start_of_the_search(monkeypatch):
    """The refinement may find the hull beyond its limits while the search's blob starts lay
    it on another ship (a bench frame at 150 m: a 22 m shift, a half-size hull on a
    neighbour). The refused correction joins the starts, and the search keeps it."""
    from harborsight.clearance import pose_search
    from harborsight.clearance.obstacles import SHIP
    from harborsight.clearance.pose_search import place_hull

    scene, labels = scene_and_labels(21, "alongside", 60)
    told = corrected_geometry(scene.geometry(), np.array([16.0, 0.0, 0.0, 0.0]))
    ship = labels == SHIP
    align = whole_image_alignment(ship, told)
    hull_h = Silhouette([TUG.hull_points])
    monkeypatch.setattr(pose_search, "_starts", lambda *args: [])    # no blob start fits
    assert place_hull(align, hull_h, ship, labels != 255) is None
    refused = np.array([-15.2, 0.6, 0.01, 0.3])                       # near the truth
    placement = place_hull(align, hull_h, ship, labels != 255, extra_starts=(refused,))
    assert placement is not None and placement.edge_share > 0.9
    assert placement.params[:2] == pytest.approx([-16.0, 0.0], abs=0.2)


def test_the_sliding_search_finds_a_hull_no_blob_start_reaches(monkeypatch):
    """The predicted silhouette slid over the whole image (a chamfer match of its outline
    against the ship edges) finds the hull 16 m from its fix where the blob starts give
    nothing (they lay the silhouette's centroid on a blob's, which misses a hull moored
    against a neighbour)."""
    from harborsight.clearance import pose_search
    from harborsight.clearance.obstacles import SHIP
    from harborsight.clearance.pose_search import _sliding_starts, place_hull

    scene, labels = scene_and_labels(21, "alongside", 60)
    told = corrected_geometry(scene.geometry(), np.array([16.0, -5.0, 0.0, 0.0]))
    ship = labels == SHIP
    align = whole_image_alignment(ship, told)
    hull_h = Silhouette([TUG.hull_points])
    starts = _sliding_starts(align, hull_h)
    assert 1 <= len(starts) <= 6
    nearest = min(starts, key=lambda s: np.hypot(s[0] + 16.0, s[1] - 5.0) + abs(s[2]))
    assert np.hypot(nearest[0] + 16.0, nearest[1] - 5.0) < 1.5 and nearest[2] == 0.0
    monkeypatch.setattr(pose_search, "_starts", lambda *args: [])
    known = labels != 255
    assert place_hull(align, hull_h, ship, known) is None
    placement = place_hull(align, hull_h, ship, known, slide=True)
    assert placement is not None and placement.edge_share > 0.9
    assert placement.params[:2] == pytest.approx([-16.0, 5.0], abs=0.2)


def test_a_tilt_given_wrong_over_a_vessel_against_its_neighbour_is_flagged(monkeypatch):
    """At 130 m a camera 10 degrees off nadir told as straight down puts the hull 23 m from
    its fix, the vessel touching a neighbour. The blob starts' best clean fit was a hull
    shrunk and turned onto other edges (three gross errors, so nothing was said); the
    sliding starts and the preference for the fewest gross errors find the own vessel:
    flagged, saying where the image puts it. Without them only the last rule (no vessel
    where the sensors put it) flags the frame, and cannot say where the hull is."""
    from harborsight.clearance import pose_search
    from harborsight.frame import FrameGeometry

    scene, labels = scene_and_labels(1, "touching", 130, tilt_deg=10.0)
    meta = scene.metadata("frame.png")
    told = FrameGeometry.from_metadata(replace(meta, pitch_deg=-90.0, roll_deg=0.0))
    report = measure_clearance(labels, told, TUG)
    _flagged_with_nothing_standing(report)
    assert report.pose_refinement["reason"].startswith("the image puts the hull 2")
    assert report.pose_refinement["image_hull_px"]
    original = pose_search.place_hull
    monkeypatch.setattr(gross_errors, "place_hull", lambda *args, slide=False, gross_errors=None, **kw:
                        original(*args, **kw))
    without = measure_clearance(labels, told, TUG).pose_refinement
    assert not without["reason"].startswith("the image puts the hull") and not without["image_hull_px"]


def test_a_pose_the_image_shows_no_vessel_at_is_not_trusted():
    """The vessel's pixels gone from the mask (a model that missed it; or, alike, a pose off
    by more than the search can tell): the sensors' pose is kept with none of its outline on
    a ship edge, the whole image holds no placement, and the distances (read against
    whatever lies where the hull should be) are not trusted. Without the search, as before,
    they were."""
    from harborsight.clearance.obstacles import SHIP, WATER

    scene, labels = scene_and_labels(3, "open", 100)
    true = scene.geometry()
    uv = true.camera.project(true.vessel_to_enu(TUG.hull_points))[0]
    erased = labels.copy()
    own = np.zeros(labels.shape, np.uint8)
    cv2.fillConvexPoly(own, np.round(cv2.convexHull(uv.astype(np.float32))).astype(np.int32), 1)
    erased[(own > 0) & (labels == SHIP)] = WATER
    assert (labels == SHIP).sum() > (erased == SHIP).sum()
    report = measure_clearance(erased, true, TUG)
    _flagged_with_nothing_standing(report)
    assert report.pose_refinement["reason"].startswith("only 0 % of the hull's outline lies on a ship edge")
    assert not measure_clearance(erased, true, TUG, NO_SEARCH).sensors_contradicted
    assert not measure_clearance(labels, true, TUG).sensors_contradicted


def test_frames_kept_for_sister_hulls_are_one_kind_in_the_batch_line():
    """A flight beside sister hulls keeps the sensors' pose on many frames, each with its own
    distance and odds: the batch line counts them as one reason, and no frame is said to
    contradict the sensors."""
    kept = [{"applied": False, "reason": f"{sister_hulls.TWIN_ALIKE}{apart} m abeam (a vessel "
             f"alike alongside), and the sensors' pose tells them apart only {odds} to 1 (at "
             "least 20 to 1 needed)", "sensors_contradicted": False}
            for apart, odds in (("10.7", "2.2"), ("10.9", "11.0"), ("8.4", "16.8"))]
    applied = [{"applied": True, "reason": None, "sensors_contradicted": False}]
    line = refinement_summary(kept + applied)
    assert line.startswith("pose refined on 1 of 4 frame(s)")
    assert "the sensors' pose kept on 3 (3x the hull fits the mask as well" in line
    assert "contradicts" not in line
