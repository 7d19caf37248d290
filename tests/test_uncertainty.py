"""A sigma for every distance: hand calculations of each term, and a Monte-Carlo check."""

import itertools
import json
import math
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest

from harborsight.clearance.measure import ClearanceSettings, measure_frame
from harborsight.clearance.pose_refinement import SENSORS_FIT, PoseRefinement, PoseRefinementSettings
from harborsight.clearance.report import SectionClearance
from harborsight.clearance.uncertainty import LOWER_BOUND_Z, add_section_uncertainty
from harborsight.frame import FrameGeometry, parse_frame_metadata
from harborsight.geometry.camera import Camera, CameraIntrinsics
from harborsight.geometry.geodesy import GeoOrigin
from harborsight.geometry.rotations import world_from_camera_rotation
from harborsight.geometry.sensor_sigmas import SensorSigmas, parse_sigma_option, sigmas_for_frame
from harborsight.sim.pose_noise import PoseNoise, add_pose_noise
from harborsight.vessel.spec import load_vessel_spec

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
HEIGHT_M, FOCAL_PX = 50.0, 500.0
GSD_M = HEIGHT_M / FOCAL_PX
QUANTISATION_M = GSD_M / math.sqrt(12.0)
ZERO = SensorSigmas(uav_gps=0, vessel_gps=0, vessel_heading_deg=0, camera_yaw_deg=0,
                    camera_tilt_deg=0, height_m=0, water_level_m=0, focal_rel=0, clock_s=0,
                    edge_px=0, edge_m=0)
BOX = np.array([[10.0, 3.0], [10.0, -3.0], [-10.0, -3.0], [-10.0, 3.0]])   # centred on (0, 0)


def _nadir(camera_east_m: float = 0.0) -> FrameGeometry:
    intrinsics = CameraIntrinsics(1000, 1000, FOCAL_PX, FOCAL_PX, 499.5, 499.5)
    rotation = world_from_camera_rotation(0.0, math.radians(-90.0), 0.0)
    camera = Camera(intrinsics, np.array([camera_east_m, 0.0, HEIGHT_M]), rotation)
    return FrameGeometry(GeoOrigin(56.0, 10.0, 0.0), camera, 0.0)


def _section(geometry: FrameGeometry, hull_en, obstacle_en) -> SectionClearance:
    hull_en, obstacle_en = np.asarray(hull_en, float), np.asarray(obstacle_en, float)
    obstacle_px = geometry.camera.project(np.array([[*obstacle_en, 0.0]]))[0][0]
    return SectionClearance(0, "ok", [[0, 0], [1, 1]], 1.0,
                            distance_m=float(np.hypot(*(obstacle_en - hull_en))),
                            hull_point_enu=hull_en.tolist(), obstacle_point_enu=obstacle_en.tolist(),
                            obstacle_point_px=obstacle_px.tolist())


def _sigma(geometry, hull_en, obstacle_en, sigmas, refinement=None) -> SectionClearance:
    section = _section(geometry, hull_en, obstacle_en)
    outline_enu = np.column_stack((BOX, np.zeros(len(BOX))))
    add_section_uncertainty([section], geometry, outline_enu,
                            refinement or PoseRefinement(applied=False, reason="off"), sigmas)
    return section


def test_pixel_grid_alone_is_a_uniform_pixel():
    section = _sigma(_nadir(), [5.0, 0.0], [8.0, 0.0], ZERO)
    assert section.sigma_m == pytest.approx(QUANTISATION_M, rel=1e-3)
    assert section.sigma_random_m == pytest.approx(QUANTISATION_M, rel=1e-3)
    assert section.distance_lower_m == pytest.approx(3.0 - LOWER_BOUND_Z * QUANTISATION_M)


def test_height_scales_the_obstacle_about_the_nadir():
    # camera 20 m east of the antenna: the obstacle at east 8 m is 12 m west of the nadir,
    # and a 1 m height error moves it by 12/50 m along u
    section = _sigma(_nadir(20.0), [5.0, 0.0], [8.0, 0.0],
                     SensorSigmas(**{**ZERO.to_dict(), "height_m": 1.0}))
    assert section.sigma_m == pytest.approx(math.hypot(12.0 / HEIGHT_M, QUANTISATION_M), rel=1e-3)
    # the water level's error adds to the altitude's: 0.6 and 0.8 m make 1 m
    section = _sigma(_nadir(20.0), [5.0, 0.0], [8.0, 0.0],
                     SensorSigmas(**{**ZERO.to_dict(), "height_m": 0.6, "water_level_m": 0.8}))
    assert section.sigma_m == pytest.approx(math.hypot(12.0 / HEIGHT_M, QUANTISATION_M), rel=1e-3)


def test_a_focal_length_error_scales_the_scene_as_a_height_error():
    # 2 % of the focal length at 50 m is a metre of height: the obstacle 12 m from the
    # nadir moves by 12/50 m (by hand: X = u·h/f, so dX/X = -df/f = dh/h)
    section = _sigma(_nadir(20.0), [5.0, 0.0], [8.0, 0.0],
                     SensorSigmas(**{**ZERO.to_dict(), "focal_rel": 0.02}))
    assert section.sigma_m == pytest.approx(math.hypot(12.0 / HEIGHT_M, QUANTISATION_M), rel=1e-3)
    # with a height error, in quadrature
    assert SensorSigmas(height_m=0.6, water_level_m=0.0, focal_rel=0.016).scale_height_m(50.0) == \
        pytest.approx(1.0)
    # refused as every sigma is when negative
    with pytest.raises(ValueError, match="focal_rel"):
        SensorSigmas(focal_rel=-0.01)


def test_vessel_heading_turns_the_hull_point_about_the_antenna():
    # hull point 10 m north of the antenna, the obstacle east of it: a 2 deg heading error
    # moves the hull point 10 · 2 · pi/180 m along u
    section = _sigma(_nadir(), [0.0, 10.0], [3.0, 10.0],
                     SensorSigmas(**{**ZERO.to_dict(), "vessel_heading_deg": 2.0}))
    expected = 10.0 * math.radians(2.0)
    assert section.sigma_m == pytest.approx(math.hypot(expected, QUANTISATION_M), rel=1e-3)


def test_gps_of_both_receivers_adds_per_axis():
    # 2 m DRMS each: sqrt(2) m per axis each, so 2 m along u together
    section = _sigma(_nadir(), [5.0, 0.0], [8.0, 0.0],
                     SensorSigmas(**{**ZERO.to_dict(), "uav_gps": 2.0, "vessel_gps": 2.0}))
    assert section.sigma_m == pytest.approx(math.hypot(2.0, QUANTISATION_M), rel=1e-3)
    assert section.sigma_random_m == pytest.approx(QUANTISATION_M, rel=1e-3)


def test_the_alignments_prior_follows_the_frames_sensors():
    """The refinement's shift and heading priors are its defaults (3 m per axis, 3 deg) for
    the default sensors, scaled by the frame's sensors against them; by hand at 60 m with
    the hull 10 m from the nadir: receivers per axis (DRMS / sqrt 2), a 0.5 deg tilt moves
    the scene 0.524 m, a 2 deg yaw 0.349 m across (half per axis)."""
    from harborsight.clearance.measure import alignment_settings

    settings = ClearanceSettings()
    tilt_m2, yaw_m2 = (60 * math.tan(math.radians(0.5))) ** 2, 0.5 * (10 * math.radians(2.0)) ** 2
    default_m = math.sqrt(2.0 + 2.0 + tilt_m2 + yaw_m2)                  # 2.07 m
    for sigmas, shift_m, heading_deg in (
            (SensorSigmas(), 3.0, 3.0),
            (SensorSigmas(uav_gps=0.5, vessel_gps=0.5, vessel_heading_deg=0.3),
             3.0 * math.sqrt(0.125 + 0.125 + tilt_m2 + yaw_m2) / default_m,   # 1.05 m
             3.0 * math.hypot(0.3, 2.0) / math.hypot(2.0, 2.0)),              # 2.15 deg
            (SensorSigmas(vessel_gps=6.0),                                       # dead reckoned
             3.0 * math.sqrt(2.0 + 18.0 + tilt_m2 + yaw_m2) / default_m, 3.0)):
        prior = alignment_settings(settings, sigmas, 60.0, 10.0)
        assert prior.prior_shift_m == pytest.approx(shift_m, rel=1e-12)
        assert prior.prior_heading_deg == pytest.approx(heading_deg, rel=1e-12)
    exact = SensorSigmas(uav_gps=0, vessel_gps=0, vessel_heading_deg=0, camera_yaw_deg=0,
                         camera_tilt_deg=0)
    prior = alignment_settings(settings, exact, 60.0, 10.0)
    assert prior.prior_shift_m > 0 and prior.prior_heading_deg > 0        # a prior still


def test_mask_edge_adds_its_pixels_in_metres():
    section = _sigma(_nadir(), [5.0, 0.0], [8.0, 0.0], SensorSigmas(**{**ZERO.to_dict(),
                                                                      "edge_px": 2.0}))
    assert section.sigma_m == pytest.approx(math.hypot(2.0 * GSD_M, QUANTISATION_M), rel=1e-3)


def test_the_edges_metric_floor_adds_in_quadrature_at_any_pixel_size():
    section = _sigma(_nadir(), [5.0, 0.0], [8.0, 0.0], SensorSigmas(**{**ZERO.to_dict(),
                                                                      "edge_m": 0.5}))
    assert section.sigma_m == pytest.approx(math.hypot(0.5, QUANTISATION_M), rel=1e-3)
    assert section.sigma_random_m == pytest.approx(section.sigma_m)


def test_an_image_placed_hull_absorbs_drone_shift_and_yaw_but_not_height():
    placed = PoseRefinement(applied=True, covariance=np.zeros((3, 3)))
    gps_and_yaw = SensorSigmas(**{**ZERO.to_dict(), "uav_gps": 2.0, "vessel_gps": 2.0,
                                  "vessel_heading_deg": 2.0, "camera_yaw_deg": 2.0})
    section = _sigma(_nadir(20.0), [5.0, 0.0], [8.0, 0.0], gps_and_yaw, placed)
    # (to first order: a finite 2 deg turn leaves a few millimetres)
    assert section.sigma_m == pytest.approx(QUANTISATION_M, rel=3e-2)
    # a height error scales the scene about the nadir; the hull, aligned to the scaled
    # silhouette, keeps its centre's share: u · (O - c) = 8 m remains (not O - nadir = -12 m)
    height = SensorSigmas(**{**ZERO.to_dict(), "height_m": 1.0})
    section = _sigma(_nadir(20.0), [5.0, 0.0], [8.0, 0.0], height, placed)
    assert section.sigma_m == pytest.approx(math.hypot(8.0 / HEIGHT_M, QUANTISATION_M), rel=2e-2)


def test_a_hull_held_along_its_length_keeps_the_receivers_error_along_it():
    # the vessel heads north (the hull's axis a = north); a distance read along
    # u = (0.6, 0.8) keeps (u·a)² (σ_uav² + σ_vessel²) per axis of the receivers' error when
    # the alignment placed the hull across but held its place along it (no end in view)
    gps_and_yaw = SensorSigmas(**{**ZERO.to_dict(), "uav_gps": 2.0, "vessel_gps": 1.0,
                                  "camera_yaw_deg": 2.0})
    held = PoseRefinement(applied=True, covariance=np.zeros((3, 3)), along_hull_held=True)
    section = _sigma(_nadir(20.0), [5.0, 0.0], [8.0, 4.0], gps_and_yaw, held)
    per_axis_m2 = (2.0 ** 2 + 1.0 ** 2) / 2.0
    # the camera's yaw turns the scene about the nadir, 20 m east: the hull's motion along
    # its length at the antenna (20 m · 2 deg) is no longer absorbed, and reads 0.8 of it
    yaw_m = 0.8 * 20.0 * math.radians(2.0)
    # (a pixel's quantisation read along u: (0.6 + 0.8) of a uniform pixel)
    quantisation_m = (0.6 + 0.8) * QUANTISATION_M
    expected = math.sqrt(0.8 ** 2 * per_axis_m2 + yaw_m ** 2 + quantisation_m ** 2)
    assert section.sigma_m == pytest.approx(expected, rel=1e-2)
    placed = PoseRefinement(applied=True, covariance=np.zeros((3, 3)))
    section = _sigma(_nadir(20.0), [5.0, 0.0], [8.0, 4.0], gps_and_yaw, placed)
    assert section.sigma_m == pytest.approx(quantisation_m, rel=3e-2)


def test_the_alignments_covariance_enters_as_a_random_part():
    from harborsight.clearance.uncertainty import REFINEMENT_COVARIANCE_SCALE

    covariance = np.diag([0.01, 0.04, 0.0])       # east 0.1 m, north 0.2 m
    placed = PoseRefinement(applied=True, covariance=covariance)
    section = _sigma(_nadir(), [5.0, 0.0], [8.0, 0.0], ZERO, placed)
    expected = math.sqrt(REFINEMENT_COVARIANCE_SCALE * 0.01 + QUANTISATION_M ** 2)
    assert section.sigma_m == pytest.approx(expected, rel=1e-3)
    assert section.sigma_random_m == pytest.approx(expected, rel=1e-3)


def test_sigma_options_and_frame_figures():
    assert parse_sigma_option("uav_gps=rtk") == ("uav_gps", 0.02)
    assert parse_sigma_option("vessel-heading-deg=gnss") == ("vessel_heading_deg", 0.3)
    assert parse_sigma_option("height_m=0.4") == ("height_m", 0.4)
    assert parse_sigma_option("focal-rel=0.02") == ("focal_rel", 0.02)
    for bad, message in (("height_m", "NAME=VALUE"), ("speed=1", "unknown sigma"),
                         ("height_m=-1", "from 0 to 1000"), ("uav_gps=nan", "from 0 to 1000")):
        with pytest.raises(ValueError, match=message):
            parse_sigma_option(bad)
    # a frame's per-axis position sigma becomes the DRMS the sigmas hold
    sigmas = sigmas_for_frame(SensorSigmas(), {"uav_gps": 0.1, "vessel_heading_deg": 0.5})
    assert sigmas.uav_gps == pytest.approx(0.1 * math.sqrt(2)) and sigmas.uav_axis_m == pytest.approx(0.1)
    assert sigmas.vessel_heading_deg == 0.5 and sigmas.vessel_gps == 2.0


def test_the_report_and_the_frame_fields(tmp_path):
    frame = json.loads((SAMPLES / "frames" / "000000.json").read_text())
    frame["uav"]["position_sigma_m"] = 0.02
    frame["vessel"]["position_sigma_m"] = 0.02
    meta = parse_frame_metadata(frame, SAMPLES / "frames" / "000000.json")
    labels = cv2.imread(str(SAMPLES / "labels" / "000000.png"), cv2.IMREAD_UNCHANGED)
    vessel = load_vessel_spec(SAMPLES / frame["vessel_spec"])
    report = measure_frame(labels, meta, vessel, ClearanceSettings(), mask_from_file=True)
    assert report.uncertainty["from_frame"] == ["uav_gps", "vessel_gps"]
    assert report.uncertainty["sigmas"]["edge_px"] == 1.0          # a mask file's default
    assert report.uncertainty["sigmas"]["edge_m"] == 0.0           # and no metric floor
    ok = [s for s in report.sections if s.status == "ok"]
    assert ok and all(0 < s.sigma_random_m <= s.sigma_m for s in ok)
    assert all(s.distance_lower_m == pytest.approx(min(
        max(0.0, s.distance_m - LOWER_BOUND_Z * s.sigma_m),
        math.inf if s.clear_to_m is None else s.clear_to_m)) for s in ok)
    written = report.to_dict()["sections"]
    assert all(w["sigma_m"] is None for w, s in zip(written, report.sections, strict=True)
               if s.status != "ok")
    with pytest.raises(Exception, match=r"vessel\.position_sigma_m"):
        bad = json.loads(json.dumps(frame))
        bad["vessel"]["position_sigma_m"] = -1
        parse_frame_metadata(bad, "x.json")


def test_monte_carlo_spread_matches_the_propagated_sigma():
    """Independent check: perturb the frame's geodetic pose (add_pose_noise: lat/lon, heading,
    yaw, altitude) with small errors, measure each draw with the same exact labels and no pose
    refinement, and compare the spread of each section's distance with the sigma propagated
    for those sensor sigmas (its systematic part: the labels do not change between draws)."""
    stem = "000002"
    frame = json.loads((SAMPLES / "frames" / f"{stem}.json").read_text())
    labels = cv2.imread(str(SAMPLES / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
    vessel = load_vessel_spec(SAMPLES / frame["vessel_spec"])
    noise = PoseNoise(gps_m=0.2, heading_deg=0.3, height_m=0.5)
    focal_rel = 0.02        # the focal length drawn too (a datasheet's), the larger error here
    settings = ClearanceSettings(pose_refinement=PoseRefinementSettings(enabled=False),
                                 sigma_options=(("camera_tilt_deg", 0.0), ("focal_rel", focal_rel)))
    rng = np.random.default_rng(1)
    predicted = None
    draws = []
    for _ in range(150):
        noisy = add_pose_noise(frame, noise, rng)
        scale = 1.0 + rng.normal(0.0, focal_rel)
        noisy["camera"] = {**noisy["camera"], "fx": noisy["camera"]["fx"] * scale,
                           "fy": noisy["camera"]["fy"] * scale}
        meta = parse_frame_metadata(noisy, "noisy.json")
        report = measure_frame(labels, meta, vessel, settings, mask_from_file=True)
        if predicted is None:        # the frame carries the sigmas it was drawn with
            # sections well clear of the hull: within a few pixels of it, the vessel's own
            # pixels left outside its shifted region clamp the distance (not first order)
            # and not on the image's border, where the obstacle is cut by the frame
            h, w = labels.shape
            predicted = {s.index: math.sqrt(s.sigma_m ** 2 - s.sigma_random_m ** 2)
                         for s in report.sections
                         if s.status == "ok" and s.distance_m > 2.0
                         and 1.0 < s.obstacle_point_px[0] < w - 2 and 1.0 < s.obstacle_point_px[1] < h - 2}
        draws.append({s.index: s.distance_m for s in report.sections if s.status == "ok"})
    checked = 0
    for k, sigma in predicted.items():
        values = np.array([d[k] for d in draws if k in d])
        if len(values) < 140:
            continue
        checked += 1
        # a robust spread (1.4826 MAD): a draw may put another obstacle nearest, a jump
        # that no first-order sigma describes
        spread = 1.4826 * np.median(np.abs(values - np.median(values)))
        assert spread == pytest.approx(sigma, rel=0.3), k
    assert checked >= 3


def test_run_writes_sigmas_and_filtered_values_and_takes_sigma_options(tmp_path):
    from typer.testing import CliRunner

    from harborsight.cli import app

    flight = SAMPLES / "flight"
    out = tmp_path / "run"
    runner = CliRunner()
    result = runner.invoke(app, ["run", str(flight), "--masks", str(flight / "labels"),
                                 "--out", str(out), "--no-video", "--no-overlays",
                                 "--sigma", "uav_gps=rtk", "--sigma", "vessel_gps=0.05"],
                           terminal_width=200)
    assert result.exit_code == 0, result.output
    import csv

    rows = list(csv.DictReader((out / "sections.csv").open()))
    ok = [r for r in rows if r["status"] == "ok"]
    assert ok and all(r["sigma_m"] and r["distance_lower_m"] for r in ok)
    assert any(r["filtered_distance_m"] and r["closing_speed_mps"] for r in ok)
    assert {r["track_state"] for r in rows} <= {"updated", "new", "held", "coasting", "clear",
                                                "none"}
    clear = [r for r in rows if r["status"] == "clear"]
    assert clear and any(r["clear_to_m"] for r in clear)
    # an ok section carries it only when its band leaves the picture nearer than its
    # obstacle: then its lower bound is no farther (the CSV rounds clear_to_m to 0.01 m)
    assert all(float(r["distance_lower_m"]) <= float(r["clear_to_m"]) + 0.005
               for r in ok if r["clear_to_m"])
    assert all(float(r["clear_to_m"]) >= 0 for r in clear if r["clear_to_m"])
    assert {r["pose_contradicted"] for r in rows} == {"0"}
    record = json.loads((out / "run.json").read_text())
    assert record["settings"]["sigma_options"] == {"uav_gps": 0.02, "vessel_gps": 0.05}
    report = json.loads(next((out / "reports").glob("*.json")).read_text())
    assert report["uncertainty"]["sigmas"]["uav_gps"] == 0.02

    bad = runner.invoke(app, ["run", str(flight), "--masks", str(flight / "labels"),
                              "--out", str(tmp_path / "bad"), "--sigma", "height=1"])
    assert bad.exit_code == 2
    assert "--sigma" in bad.output and "unknown sigma 'height'" in bad.output


# --- the batched back-projections against the propagation done one camera at a time ---

def _reference_sigmas(sections, geometry, outline_enu, refinement, sigmas, velocities=None):
    """``(sigma_m, sigma_random_m)`` of each section by the module docstring's recipe with
    every back-projection its own Camera.back_project_to_plane call and every rigid fit its
    own (how add_section_uncertainty was first written, before it shared them)."""
    from harborsight.clearance.pose_refinement import SENSORS_FIT
    from harborsight.clearance.uncertainty import (
        REFINEMENT_COVARIANCE_SCALE,
        _perturbed_cameras,
    )

    def back(camera, uv):
        return camera.back_project_to_plane(uv)[0][:, :2]

    camera = geometry.camera
    obstacle = np.array([s.obstacle_point_enu for s in sections])
    hull = np.array([s.hull_point_enu for s in sections])
    obstacle_px = np.array([s.obstacle_point_px for s in sections])
    direction = obstacle - hull
    length = np.hypot(*direction.T)
    direction = np.where((length > 1e-6)[:, None], direction, hull - geometry.vessel_position_enu)
    u = direction / np.hypot(*direction.T)[:, None]
    systematic, random = np.zeros(len(sections)), np.zeros(len(sections))
    refined = refinement.applied or (refinement.reason == SENSORS_FIT
                                     and refinement.covariance is not None)
    outline_px = camera.project(np.column_stack((outline_enu[:, :2], np.zeros(len(outline_enu)))))[0]
    outline_px = outline_px[np.isfinite(outline_px).all(axis=1)]
    here, outline_here = back(camera, obstacle_px), back(camera, outline_px)
    for moved in _perturbed_cameras(camera, sigmas):
        shift_o, shift_h = back(moved, obstacle_px) - here, np.zeros((len(sections), 2))
        if refined and len(outline_here) >= 3:
            moved_by = back(moved, outline_px) - outline_here
            usable = np.isfinite(moved_by).all(axis=1)
            if usable.sum() >= 3:
                points, moved_by = outline_here[usable], moved_by[usable]
                centre, t = points.mean(axis=0), moved_by.mean(axis=0)
                rel, rest = points - centre, moved_by - t
                turn = (rel[:, 0] * rest[:, 1] - rel[:, 1] * rest[:, 0]).sum() / (rel ** 2).sum()
                offset = hull - centre
                shift_h = t + turn * np.column_stack((-offset[:, 1], offset[:, 0]))
        systematic += np.nan_to_num(np.einsum("ij,ij->i", u, shift_o - shift_h)) ** 2
    r = hull - geometry.vessel_position_enu
    if not refined:
        systematic += sigmas.uav_axis_m ** 2 + sigmas.vessel_axis_m ** 2
        turn_h = math.radians(sigmas.vessel_heading_deg) * np.column_stack((r[:, 1], -r[:, 0]))
        systematic += np.einsum("ij,ij->i", u, turn_h) ** 2
        if velocities is not None:
            relative = np.subtract(velocities.uav_en_mps, velocities.vessel_en_mps)
            systematic += (sigmas.clock_s * (u @ relative)) ** 2
    elif refinement.covariance is not None:
        gradient = np.column_stack((u[:, 0], u[:, 1], u[:, 0] * r[:, 1] - u[:, 1] * r[:, 0]))
        random += np.einsum("ij,jk,ik->i", gradient,
                            REFINEMENT_COVARIANCE_SCALE * refinement.covariance, gradient)
    du, dv = np.array([0.5, 0.0]), np.array([0.0, 0.5])
    step_u = back(camera, obstacle_px + du) - back(camera, obstacle_px - du)
    step_v = back(camera, obstacle_px + dv) - back(camera, obstacle_px - dv)
    along_u, along_v = (np.abs(np.einsum("ij,ij->i", u, s)) for s in (step_u, step_v))
    random += np.nan_to_num(((along_u + along_v) / math.sqrt(12.0)) ** 2
                            + sigmas.edge_px ** 2 * (along_u ** 2 + along_v ** 2)) + sigmas.edge_m ** 2
    return np.sqrt(systematic + random), np.sqrt(random)


def _oblique(distortion=(), pitch_deg=-35.0, vessel_north_m=40.0) -> FrameGeometry:
    """A camera 10 m up looking north, the vessel ``vessel_north_m`` ahead and turned."""
    intrinsics = CameraIntrinsics(1000, 1000, 500.0, 500.0, 499.5, 499.5, tuple(distortion))
    rotation = world_from_camera_rotation(0.0, math.radians(pitch_deg), math.radians(3.0))
    camera = Camera(intrinsics, np.array([1.5, 0.0, 10.0]), rotation)
    return FrameGeometry(GeoOrigin(56.0, 10.0, 0.0), camera, math.radians(20.0),
                         np.array([2.0, vessel_north_m]))


def _box_outline(geometry: FrameGeometry, per_side: int = 10) -> np.ndarray:
    """The BOX outline, ``per_side`` points along each side, on the water in ENU."""
    corners = np.vstack((BOX, BOX[:1]))
    t = np.arange(per_side)[:, None] / per_side
    points = np.vstack([a + t * (b - a) for a, b in itertools.pairwise(corners)])
    return geometry.vessel_to_enu(points)


def _sections_around(geometry: FrameGeometry, outline_enu: np.ndarray) -> list[SectionClearance]:
    """Obstacles 0.5-6 m off a few outline points (and one in contact), measured as
    measure_clearance does: the obstacle placed on the water from its pixel. Each lies
    off the line from the antenna through its hull point (35 degrees to it), where a turn
    of the hull about the antenna moves the hull point toward the obstacle."""
    centre = geometry.vessel_position_enu
    c, s = math.cos(math.radians(35.0)), math.sin(math.radians(35.0))
    sections = []
    for i, (k, gap) in enumerate([(0, 3.0), (7, 0.5), (13, 6.0), (22, 0.0), (31, 2.0)]):
        hull = outline_enu[k, :2]
        east, north = (hull - centre) / np.hypot(*(hull - centre))
        away = np.array([c * east - s * north, s * east + c * north])
        obstacle_px = geometry.camera.project(np.array([[*(hull + gap * away), 0.0]]))[0][0]
        obstacle = geometry.camera.back_project_to_plane(obstacle_px[None])[0][0, :2]
        sections.append(SectionClearance(
            i, "ok", [[0, 0], [1, 1]], 1.0, distance_m=float(np.hypot(*(obstacle - hull))),
            hull_point_enu=hull.tolist(), obstacle_point_enu=obstacle.tolist(),
            obstacle_point_px=obstacle_px.tolist()))
    return sections


PLACED = PoseRefinement(applied=True, covariance=np.diag([0.01, 0.04, 1e-4]))
FITTED = PoseRefinement(applied=False, reason=SENSORS_FIT, covariance=np.diag([0.02, 0.01, 4e-4]))
OFF = PoseRefinement(applied=False, reason="off")


@pytest.mark.parametrize("distortion", [(), (-0.12, 0.03, 0.0, 0.0, 0.0)])
def test_the_plane_points_of_all_cameras_are_each_cameras_back_projection(distortion):
    from harborsight.clearance.uncertainty import _perturbed_cameras, _plane_points

    geometry = _oblique(distortion, pitch_deg=-8.0)
    camera = geometry.camera
    cameras = [camera, *_perturbed_cameras(camera, SensorSigmas(camera_tilt_deg=4.0))]
    # the whole image: above the horizon (v < 429) too, where the rays miss the water
    uv = np.stack(np.meshgrid(np.linspace(-3, 1003, 23), np.linspace(-3, 1003, 29)), -1).reshape(-1, 2)
    planes = _plane_points(cameras, uv)
    for each, points in zip(cameras, planes, strict=True):
        expected = each.back_project_to_plane(uv)[0][:, :2]
        np.testing.assert_array_equal(points, expected)
    assert np.isnan(planes).any() and np.isfinite(planes).any()


@pytest.mark.parametrize("refinement", [PLACED, FITTED, OFF], ids=["placed", "fitted", "off"])
@pytest.mark.parametrize("distortion", [(), (-0.12, 0.03, 0.0, 0.0, 0.0)])
def test_shared_back_projections_give_the_sigmas_of_one_camera_at_a_time(refinement, distortion):
    from harborsight.clearance.uncertainty import FrameVelocities

    geometry = _oblique(distortion)
    outline_enu = _box_outline(geometry)
    sigmas = SensorSigmas(camera_tilt_deg=1.0, height_m=0.8)
    velocities = FrameVelocities((1.0, -0.5), (0.3, 0.2))
    expected = _reference_sigmas(_sections_around(geometry, outline_enu), geometry, outline_enu,
                                 refinement, sigmas, velocities)
    outline_px = geometry.camera.project(outline_enu)[0]
    for given in (None, outline_px):        # projected here, or handed over by the caller
        sections = _sections_around(geometry, outline_enu)
        add_section_uncertainty(sections, geometry, outline_enu, refinement, sigmas, velocities,
                                outline_px=given)
        np.testing.assert_allclose([s.sigma_m for s in sections], expected[0], rtol=1e-12)
        np.testing.assert_allclose([s.sigma_random_m for s in sections], expected[1], rtol=1e-12)


def test_a_correction_found_and_not_applied_leaves_the_sensors_bar():
    """The alignment kept the sensors' pose as fitting the mask as well, but the correction
    it found is a height 1.2 m off, six of its own (scaled) sigmas: that error stays in the
    distances, so the bar is the sensors' (height, GPS, compasses), not the alignment's. A
    correction within its 99 % ellipse of zero places the hull, as before."""
    from harborsight.clearance.uncertainty import image_confirms_sensors

    covariance = np.diag([0.02, 0.01, 4e-4, 0.0016])      # height: 0.04 m, 0.2 m scaled
    found = PoseRefinement(applied=False, reason=SENSORS_FIT, height_change_m=-1.2,
                           covariance=covariance)
    near_zero = PoseRefinement(applied=False, reason=SENSORS_FIT, shift_m=(0.3, -0.2),
                               height_change_m=0.3, covariance=covariance)
    assert not image_confirms_sensors(found) and image_confirms_sensors(near_zero)
    assert not image_confirms_sensors(PoseRefinement(applied=True, covariance=covariance))
    geometry = _oblique()
    outline_enu = _box_outline(geometry)
    sigmas = SensorSigmas(camera_tilt_deg=1.0, height_m=1.0)

    def bars(refinement):
        sections = _sections_around(geometry, outline_enu)
        add_section_uncertainty(sections, geometry, outline_enu, refinement, sigmas)
        return np.array([s.sigma_m for s in sections])

    np.testing.assert_allclose(bars(found), bars(OFF), rtol=1e-12)
    assert (bars(near_zero) < bars(OFF)).all()


def test_a_nearest_point_where_an_oblique_quay_leaves_its_band_slides_with_the_hull(tmp_path):
    """A quay whose edge runs 22 degrees off the hull's side (e = 9 + 0.4 n): in every band
    beside it the nearest point is where the edge leaves the band, on its boundary ray, and
    a turn of the hull turns the ray and slides that point along the edge. Read with the
    point held fixed, the bar's heading part was 0.00-0.10 m a degree where the distances
    move 0.36-1.33 m a degree; read along the slide, each section's heading part is within
    10 % of the finite difference over +-1 degree (or above it, never below)."""
    import dataclasses

    import yaml

    from harborsight.clearance.measure import measure_clearance
    from harborsight.perception.classes import OBSTACLE, SHIP, WATER

    (tmp_path / "box.yaml").write_text(yaml.safe_dump({"dimensions": {
        "to_bow": 10, "to_stern": 10, "to_port": 3, "to_starboard": 3}}))
    vessel = load_vessel_spec(tmp_path / "box.yaml")
    geometry = _nadir()
    u, v = np.meshgrid(np.arange(1000.0), np.arange(1000.0))
    ground, _ = geometry.camera.back_project_to_plane(np.column_stack((u.ravel(), v.ravel())))
    east, north = ground[:, 0].reshape(1000, 1000), ground[:, 1].reshape(1000, 1000)
    labels = np.full((1000, 1000), WATER, np.uint8)
    labels[east >= 9.0 + 0.4 * north] = OBSTACLE
    hull_enu = geometry.vessel_to_enu(vessel.outline)[:, :2]
    hull_px = geometry.camera.project(np.column_stack((hull_enu, np.zeros(len(hull_enu)))))[0]
    cv2.fillPoly(labels, [np.rint(hull_px).astype(np.int32)], SHIP)
    settings = ClearanceSettings(pose_refinement=PoseRefinementSettings(enabled=False))

    def measured(heading_deg: float, sigmas: SensorSigmas) -> dict[int, SectionClearance]:
        turned = dataclasses.replace(
            geometry, vessel_heading_rad=geometry.vessel_heading_rad + math.radians(heading_deg))
        report = measure_clearance(labels, turned, vessel, settings, sigmas=sigmas)
        return {s.index: s for s in report.sections if s.status == "ok"}

    with_heading = measured(0.0, dataclasses.replace(ZERO, vessel_heading_deg=1.0))
    without = measured(0.0, ZERO)
    left, right = measured(-1.0, ZERO), measured(1.0, ZERO)
    sliding = 0
    for k, section in with_heading.items():
        slope = abs(right[k].distance_m - left[k].distance_m) / 2.0
        heading_part = math.sqrt(max(section.sigma_m ** 2 - without[k].sigma_m ** 2, 0.0))
        assert 0.9 * slope <= heading_part <= 1.6 * slope + 0.05, (k, slope, heading_part)
        sliding += section.crossing_edge_px is not None and slope > 0.3
    assert sliding >= 4


def test_rigid_fits_leave_out_what_a_perturbed_camera_puts_past_the_horizon():
    """The hull 53-73 m ahead of a camera 10 m up (10.7 to 7.8 degrees below the horizon): a
    9 degree tilt error puts the far part of the outline past the horizon for the camera
    tilted up, so that camera's rigid fit takes only the points it still places on the water
    (and the height error's fit still takes all of them)."""
    from harborsight.clearance.uncertainty import _perturbed_cameras

    geometry = _oblique(pitch_deg=-8.0, vessel_north_m=63.0)
    outline_enu = _box_outline(geometry)
    sigmas = SensorSigmas(**{**ZERO.to_dict(), "camera_tilt_deg": 9.0, "height_m": 1.0})
    outline_px = geometry.camera.project(outline_enu)[0]
    assert np.isfinite(outline_px).all()
    lost = [int(np.isnan(moved.back_project_to_plane(outline_px)[0][:, 0]).sum())
            for moved in _perturbed_cameras(geometry.camera, sigmas)]
    assert 0 in lost and any(0 < n < len(outline_px) - 3 for n in lost), lost
    for refinement in (PLACED, FITTED):
        expected = _reference_sigmas(_sections_around(geometry, outline_enu), geometry,
                                     outline_enu, refinement, sigmas)
        sections = _sections_around(geometry, outline_enu)
        add_section_uncertainty(sections, geometry, outline_enu, refinement, sigmas)
        np.testing.assert_allclose([s.sigma_m for s in sections], expected[0], rtol=1e-12)
        np.testing.assert_allclose([s.sigma_random_m for s in sections], expected[1], rtol=1e-12)


def test_the_gsd_method_s_bar_holds_its_nadir_error_on_tilted_frames():
    """The paper's gsd method reads pixels times the nadir GSD; the bundled sample frames are
    6-10 degrees off nadir, where that is 4-8 % of a distance. Without its own term, 15 of
    38 sections of the five frames lay outside two sigma and 5 under their lower bound
    (measured 2026-11-28); with it, none, against the simulator's shapely distances."""
    from harborsight.images import read_mask

    vessel = load_vessel_spec(SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml")
    checked = 0
    for stem in ("000001", "000003"):
        frame = json.loads((SAMPLES / "frames" / f"{stem}.json").read_text())
        meta = parse_frame_metadata(frame, SAMPLES / "frames" / f"{stem}.json")
        truth = [s["distance_m"] for s in frame["ground_truth"]["sections"]]
        report = measure_frame(read_mask(SAMPLES / "labels" / f"{stem}.png"), meta, vessel,
                               ClearanceSettings(method="gsd"), mask_from_file=True)
        for s, t in zip(report.sections, truth, strict=True):
            if s.status != "ok" or t is None:
                continue
            plane_m = math.dist(s.hull_point_enu, s.obstacle_point_enu)
            assert s.sigma_m >= abs(s.distance_m - plane_m) - 1e-9
            assert abs(s.distance_m - t) <= 2 * s.sigma_m and t >= s.distance_lower_m, (s.index, t)
            checked += 1
    assert checked >= 15



# --- a camera tilt the sensors' stated accuracy does not explain ---

def test_the_points_at_their_own_heights_are_each_cameras_back_projection():
    """The silhouette's points are back-projected onto the plane at their own height (the
    deck's edge), each camera at once: the same points as Camera.back_project_to_plane."""
    from harborsight.clearance.uncertainty import _perturbed_cameras, _points_at_heights

    geometry = _oblique((-0.12, 0.03, 0.0, 0.0, 0.0), pitch_deg=-60.0)
    cameras = [geometry.camera, *_perturbed_cameras(geometry.camera, SensorSigmas(camera_tilt_deg=4.0))]
    uv = np.stack(np.meshgrid(np.linspace(0, 999, 7), np.linspace(0, 999, 9)), -1).reshape(-1, 2)
    heights = np.resize([0.0, 1.5, 3.2, 6.0], len(uv))
    points = _points_at_heights(cameras, uv, heights)
    for camera, found in zip(cameras, points, strict=True):
        for z in np.unique(heights):
            at = heights == z
            expected = camera.back_project_to_plane(uv[at], z)[0][:, :2]
            np.testing.assert_allclose(found[at], expected, atol=1e-9, equal_nan=True)


def _told_straight_down(seed: int, scenario: str, altitude_m: float, tilt_deg: float):
    """A schematic scene whose camera looks ``tilt_deg`` off nadir, its metadata saying
    straight down (a stabilised mount's default), and the truth's distances (shapely)."""
    from dataclasses import replace

    from harborsight.sim.schematic import ground_truth
    from tests.test_pose_refinement import TUG, scene_and_labels

    scene, labels = scene_and_labels(seed, scenario, altitude_m, tilt_deg=tilt_deg)
    meta = scene.metadata("frame.png")
    told = FrameGeometry.from_metadata(replace(meta, pitch_deg=-90.0, roll_deg=0.0))
    truth = [s["distance_m"] for s in ground_truth(scene)["sections"]]
    return labels, told, TUG, truth, 90.0 + meta.pitch_deg


FILE_SIGMAS = SensorSigmas(edge_px=1.0, edge_m=0.0)


@pytest.mark.parametrize("seed", [1, 21])
def test_a_gimbal_7_degrees_off_nadir_given_as_straight_down_widens_the_bars(monkeypatch, seed):
    """At 60 m a camera 7 degrees off nadir told as straight down shows the hull 7 m from
    the sensors' pose: the refinement applies that as a vessel shift, but the obstacles are
    back-projected with the wrong tilt and the hull's deck edge moves less than the water
    (parallax). A 7 m shift is 3.5 sigma of two standalone receivers: the tilt that would
    explain it enters the bars, and every lower bound holds against the truth. Without
    that term a 6.65 m gap read 7.11 m with its lower bound at 6.71 m (seed 1); that
    section's band also leaves the picture 3.9 m out, which now bounds it as well, so the
    check without the term leaves that bound out too."""
    from harborsight.clearance import measure, uncertainty
    from harborsight.clearance.measure import measure_clearance

    labels, told, vessel, truth, tilt_deg = _told_straight_down(seed, "alongside", 60, 7.0)
    report = measure_clearance(labels, told, vessel, sigmas=FILE_SIGMAS)
    assert report.pose_refinement["applied"] and not report.sensors_contradicted
    unexplained = report.uncertainty["unexplained_shift"]
    assert unexplained is not None and unexplained["shift_sigmas"] > 3.0
    assert unexplained["tilt_deg"] == pytest.approx(tilt_deg, abs=1.0)
    pairs = [(s, t) for s, t in zip(report.sections, truth, strict=True)
             if s.status == "ok" and t is not None]
    assert len(pairs) >= 6
    assert all(s.distance_lower_m <= t for s, t in pairs)
    assert all(abs(s.distance_m - t) <= 2 * s.sigma_m for s, t in pairs)
    if seed == 1:       # the term is what holds the bound
        monkeypatch.setattr(uncertainty, "UNEXPLAINED_SHIFT_CHI2", math.inf)
        monkeypatch.setattr(measure, "_bound_by_what_was_seen", lambda results: None)
        before = measure_clearance(labels, told, vessel, sigmas=FILE_SIGMAS)
        assert any(s.distance_lower_m > t for s, t in zip(before.sections, truth, strict=True)
                   if s.status == "ok" and t is not None)


def test_a_shift_the_receivers_explain_leaves_the_bars_alone():
    """The same scene with the tilt given right and the vessel's fix 2.3 m off: the shift is
    the receivers' to explain, and nothing is added."""
    from dataclasses import replace

    from harborsight.clearance.measure import measure_clearance
    from tests.test_pose_refinement import TUG, scene_and_labels

    scene, labels = scene_and_labels(1, "alongside", 60, tilt_deg=7.0)
    meta = scene.metadata("frame.png")
    east_m, north_m = 1.8, -1.5
    told = FrameGeometry.from_metadata(meta)
    told = replace(told, vessel_position_enu=told.vessel_position_enu + np.array([east_m, north_m]))
    report = measure_clearance(labels, told, TUG, sigmas=FILE_SIGMAS)
    assert report.pose_refinement["applied"]
    assert report.pose_refinement["shift_m"] == pytest.approx([-east_m, -north_m], abs=0.1)
    assert report.uncertainty["unexplained_shift"] is None


def test_a_hull_drawn_from_dimensions_widens_every_bar_by_its_outline_sigma(tmp_path):
    """The sample tug as `vessel from-ais` would draw it (its outline's extents from the
    antenna in whole metres, a pointed bow): with ``outline_sigma_m`` every ``ok`` section's
    sigma grows by exactly that in quadrature (a systematic term: ``sigma_random_m`` keeps),
    the distances stay, and the report says the sigma it used."""
    import yaml

    mesh = load_vessel_spec(SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml")
    o = mesh.outline
    dims = {"to_bow": round(float(o[:, 0].max())), "to_stern": round(float(-o[:, 0].min())),
            "to_port": round(float(-o[:, 1].min())), "to_starboard": round(float(o[:, 1].max()))}
    stem = "000001"
    frame = json.loads((SAMPLES / "frames" / f"{stem}.json").read_text())
    meta = parse_frame_metadata(frame, SAMPLES / "frames" / f"{stem}.json")
    labels = cv2.imread(str(SAMPLES / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
    reports = []
    for sigma_m in (0.0, 0.6):
        path = tmp_path / f"vessel-{sigma_m}.yaml"
        path.write_text(yaml.safe_dump({"dimensions": dims, "outline_sigma_m": sigma_m}))
        reports.append(measure_frame(labels, meta, load_vessel_spec(path), ClearanceSettings(),
                                     mask_from_file=True))
    exact, widened = reports
    assert widened.uncertainty["outline_sigma_m"] == 0.6 and exact.uncertainty["outline_sigma_m"] == 0.0
    pairs = [(a, b) for a, b in zip(exact.sections, widened.sections, strict=True) if a.status == "ok"]
    assert len(pairs) >= 4
    for a, b in pairs:
        assert b.distance_m == a.distance_m and b.sigma_random_m == pytest.approx(a.sigma_random_m)
        if not a.contact:        # a contact's cut is added to the sigma, not in quadrature
            assert b.sigma_m ** 2 - a.sigma_m ** 2 == pytest.approx(0.36, abs=1e-9)
        assert b.sigma_m > a.sigma_m and b.distance_lower_m <= a.distance_lower_m
    assert sum(not a.contact for a, _ in pairs) >= 4


def test_a_height_raised_from_a_thin_mask_widens_the_bound_of_what_it_lengthens():
    """A model that draws every solid 3 px thin (the water grown 3 px over ship and
    obstacle pixels) shrinks the vessel's blob, which the pose refinement reads as a higher
    camera: in a slip 80 m up, 15 degrees off nadir, from sensors 2 m and 2.3 degrees off,
    +4.0 m, and the sections reading the quay 34.55 m off the bow read 38.0 m. The bound
    reaches the reading at the sensors' height too, and holds the truth (it was 35.8 m, over
    it). On the exact mask the camera moves 1 cm and the bounds by under a centimetre."""
    from harborsight.clearance import measure_clearance
    from harborsight.clearance.alignment import corrected_geometry
    from harborsight.sim.schematic import ground_truth, render, sample_scene

    tug = load_vessel_spec(resources.files("harborsight.data") / "samples" / "vessels"
                           / "harbour-tug" / "vessel.yaml")
    scene = sample_scene(tug, np.random.default_rng(1197), altitude_m=80.0, tilt_deg=15.0,
                         scenario="slip", gap_m=2.2142)
    _, labels, _ = render(scene)
    truth = ground_truth(scene)["sections"]
    off = corrected_geometry(scene.geometry(), np.array([-1.2399, -1.5330, -0.039995]))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
    water_grown = cv2.dilate((labels == 0).astype(np.uint8), disk).astype(bool)
    thin = np.where(water_grown & ((labels == 1) | (labels == 2)), 0, labels).astype(np.uint8)
    exact = measure_clearance(labels, off, tug)
    report = measure_clearance(thin, off, tug)
    assert report.pose_refinement["applied"] and report.pose_refinement["height_change_m"] > 3.5
    for k in (0, 15):
        section = report.sections[k]
        assert section.distance_m > truth[k]["distance_m"] + 3.0           # read long
        assert section.distance_lower_m < truth[k]["distance_m"]            # the bound holds
        # the bound reaches the reading at the sensors' height: at least dh/h of the distance
        # from the nadir further in than the propagated bound alone
        assert section.distance_lower_m < section.distance_m - 3.0
        assert abs(exact.pose_refinement["height_change_m"]) < 0.05
        assert exact.sections[k].distance_lower_m < truth[k]["distance_m"]
