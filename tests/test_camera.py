"""Camera model: projection against cv2.projectPoints with rotations built by scipy,
back-projection by hand, GSD against a datasheet, calibration file loaders."""

import math

import cv2
import numpy as np
import pytest
import shapely
from scipy.spatial.transform import Rotation

from harborsight.errors import InputError
from harborsight.geometry.calibration_files import load_camera_calibration
from harborsight.geometry.camera import Camera, CameraIntrinsics
from harborsight.geometry.gsd import nadir_gsd_from_sensor, nadir_gsd_m_per_px
from harborsight.geometry.rotations import world_from_camera_rotation

INTR = CameraIntrinsics(640, 360, 457.1, 455.0, 321.2, 178.4, (-0.12, 0.05, 0.001, -0.0005, 0.0))


def scipy_world_from_camera(yaw, pitch, roll):
    """Independent R_W<-C: scipy's intrinsic ZYX Euler for NED<-gimbal, explicit axis swaps."""
    ned_from_gimbal = Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()
    enu_from_ned = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    # camera x (right) = gimbal y, camera y (down) = gimbal z, camera z (optical) = gimbal x
    gimbal_from_camera = np.column_stack(([0, 1, 0], [0, 0, 1], [1, 0, 0]))
    return enu_from_ned @ ned_from_gimbal @ gimbal_from_camera


@pytest.mark.parametrize("yaw, pitch, roll", [(0, -90, 0), (30, -90, 0), (215, -75, 2.5),
                                              (-40, -62, -4), (90, -85, 10)])
def test_projection_matches_cv2_projectPoints(yaw, pitch, roll):
    R_wc = world_from_camera_rotation(math.radians(yaw), math.radians(pitch), math.radians(roll))
    assert np.allclose(R_wc, scipy_world_from_camera(yaw, pitch, roll), atol=1e-12)
    centre = np.array([12.0, -7.0, 80.0])
    cam = Camera(INTR, centre, R_wc)
    rng = np.random.default_rng(0)
    pts = np.column_stack((rng.uniform(-40, 40, 50), rng.uniform(-25, 25, 50), np.zeros(50)))
    pts[:, :2] += centre[:2] + 80 * np.tan(np.radians(pitch + 90)) * np.array(
        [np.sin(np.radians(yaw)), np.cos(np.radians(yaw))])
    ours, front = cam.project(pts)
    R_cw = scipy_world_from_camera(yaw, pitch, roll).T
    rvec, _ = cv2.Rodrigues(R_cw)
    tvec = -R_cw @ centre
    theirs, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), rvec, tvec, INTR.K, INTR.dist_coeffs)
    assert front.all()
    assert np.allclose(ours, theirs.reshape(-1, 2), atol=1e-6)


def test_nadir_image_top_points_to_yaw():
    # yaw 90 deg (east): the image top looks east, the image right looks south
    cam = Camera(CameraIntrinsics(640, 360, 500, 500, 319.5, 179.5), np.array([0, 0, 100.0]),
                 world_from_camera_rotation(math.radians(90), math.radians(-90), 0.0))
    uv, _ = cam.project(np.array([[10.0, 0, 0], [0, -10.0, 0]]))
    assert np.allclose(uv[0], [319.5, 179.5 - 50.0])   # 10 m east -> 50 px up
    assert np.allclose(uv[1], [319.5 + 50.0, 179.5])   # 10 m south -> 50 px right


@pytest.mark.parametrize("pitch", [-90, -70])
def test_back_projection_inverts_projection(pitch):
    cam = Camera(INTR, np.array([3.0, 4.0, 60.0]),
                 world_from_camera_rotation(math.radians(20), math.radians(pitch), 0.02))
    uv = np.array([[10.0, 10.0], [320.0, 180.0], [630.0, 350.0], [100.0, 300.0]])
    ground, valid = cam.back_project_to_plane(uv)
    assert valid.all()
    assert np.allclose(ground[:, 2], 0.0)
    again, _ = cam.project(ground)
    assert np.allclose(again, uv, atol=1e-6)


def test_back_projection_hand_value():
    # nadir, yaw 0: a pixel 100 px right of centre at 50 m is 50*100/500 = 10 m east
    cam = Camera(CameraIntrinsics(640, 360, 500, 500, 319.5, 179.5), np.array([0, 0, 50.0]),
                 world_from_camera_rotation(0.0, math.radians(-90), 0.0))
    ground, valid = cam.back_project_to_plane(np.array([[419.5, 179.5]]))
    assert valid.all() and np.allclose(ground[0], [10.0, 0.0, 0.0])


def test_rays_above_horizon_are_invalid():
    cam = Camera(INTR, np.array([0, 0, 50.0]), world_from_camera_rotation(0.0, math.radians(-5), 0))
    _, valid = cam.back_project_to_plane(np.array([[320.0, 0.0], [320.0, 359.0]]))
    assert not valid[0] and valid[1]


def test_gsd_matches_phantom4_rtk_datasheet():
    # DJI Phantom 4 RTK: 1" sensor 13.2 x 8.8 mm, 8.8 mm lens, 5472 x 3648 px;
    # DJI's datasheet: GSD = H / 36.5 cm/px, i.e. 3.29 cm/px at 120 m
    gsd = nadir_gsd_from_sensor(120.0, 13.2, 8.8, 8.8, 5472, 3648)
    assert gsd * 100 == pytest.approx(120 / 36.5, rel=0.01)
    intr = CameraIntrinsics.from_sensor(5472, 3648, 13.2, 8.8, 8.8)
    assert nadir_gsd_m_per_px(120.0, intr.fx, intr.fy) == pytest.approx(gsd)


def test_load_opencv_filestorage_yaml_and_xml(tmp_path):
    K = np.array([[910.2, 0, 640.7], [0, 908.9, 362.1], [0, 0, 1]])
    dist = np.array([[-0.11, 0.09, 0.0004, -0.0002, -0.02]])
    for name in ("calib.yaml", "calib.xml"):
        fs = cv2.FileStorage(str(tmp_path / name), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", 1280)
        fs.write("image_height", 720)
        fs.write("camera_matrix", K)
        fs.write("distortion_coefficients", dist)
        fs.release()
        intr = load_camera_calibration(tmp_path / name)
        assert (intr.width, intr.height) == (1280, 720)
        assert (intr.fx, intr.fy, intr.cx, intr.cy) == (910.2, 908.9, 640.7, 362.1)
        assert np.allclose(intr.distortion, dist.ravel())


ROS_CAMERA_INFO = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [476.7030836014194, 0, 400.5, 0, 476.7030836014194, 400.5, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.01, -0.02, 0, 0, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [476.7030836014194, 0, 400.5, 0, 0, 476.7030836014194, 400.5, 0, 0, 0, 1, 0]
"""


def test_load_ros_camera_info(tmp_path):
    path = tmp_path / "camera_info.yaml"
    path.write_text(ROS_CAMERA_INFO)
    intr = load_camera_calibration(path)
    assert (intr.width, intr.height, intr.cx) == (640, 480, 400.5)
    assert intr.fx == pytest.approx(476.7030836014194)
    assert intr.distortion == (0.01, -0.02, 0, 0, 0)


def test_bad_calibration_names_file_and_field(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("image_width: 640\nimage_height: 480\n")
    with pytest.raises(InputError, match=r"bad.yaml: camera_matrix"):
        load_camera_calibration(path)


def test_strong_barrel_distortion_refuses_points_past_its_fold():
    """r_d = r(1 + k1 r^2) with k1 = -0.3 peaks at r = 1/sqrt(3 * 0.3) = 1.054 and turns back:
    cv2.projectPoints folds a point at r = 1.5 (r_d = 0.49) into the image. It has no true
    pixel; a point inside the fold (r = 0.5) still matches cv2.projectPoints."""
    intr = CameraIntrinsics(640, 360, 300.0, 300.0, 319.5, 179.5, (-0.3, 0.0, 0.0, 0.0, 0.0))
    cam = Camera(intr, np.zeros(3), world_from_camera_rotation(0.0, math.radians(-90), 0.0))
    # nadir camera at the origin, 10 m up is the plane z = -10; camera x is world east
    points = np.array([[5.0, 0.0, -10.0], [15.0, 0.0, -10.0]])
    uv, valid = cam.project(points)
    theirs, _ = cv2.projectPoints(np.array([[0.5, 0.0, 1.0]]), np.zeros(3), np.zeros(3),
                                  intr.K, intr.dist_coeffs)
    assert valid.tolist() == [True, False] and np.isnan(uv[1]).all()
    assert np.allclose(uv[0], theirs.reshape(2), atol=1e-6)
    folded, _ = cv2.projectPoints(np.array([[1.5, 0.0, 1.0]]), np.zeros(3), np.zeros(3),
                                  intr.K, intr.dist_coeffs)
    assert 0 <= folded.reshape(2)[0] < 640           # where OpenCV alone would have put it


def test_no_pixels_to_back_project_with_distortion():
    cam = Camera(INTR, np.array([0.0, 0.0, 50.0]),
                 world_from_camera_rotation(0.0, math.radians(-90), 0.0))
    xy, valid = cam.pixels_to_plane_xy(np.zeros((0, 2)))
    assert xy.shape == (0, 2) and valid.shape == (0,)


def _box_corners(x0, x1, y0, y1, z0, z1):
    return np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)])


@pytest.mark.parametrize("k1", [-0.2, 0.0, 0.05])
def test_convex_outline_follows_distorted_edges(k1):
    """A 28 x 14 x 8 m box seen from 60 m near the image corner: every point of its twelve
    edges, projected one by one by cv2.projectPoints, lies inside the outline's hull, and
    the hull reaches no farther than those points. With k1 = -0.2 the hull of the eight
    projected corners alone leaves more than a pixel of the bent edges outside."""
    intr = CameraIntrinsics(640, 360, 320.0, 320.0, 319.5, 179.5, (k1, 0.0, 0.0, 0.0, 0.0))
    cam = Camera(intr, np.array([0.0, 0.0, 60.0]),
                 world_from_camera_rotation(0.0, math.radians(-90), 0.0))
    corners = _box_corners(20.0, 48.0, -26.0, -12.0, 0.0, 8.0)
    t = np.linspace(0.0, 1.0, 400)[:, None]
    edges = np.vstack([a + t * (b - a) for i, a in enumerate(corners) for b in corners[i + 1:]
                       if np.count_nonzero(a != b) == 1])
    R_cw = cam.camera_from_world
    theirs, _ = cv2.projectPoints(edges.reshape(-1, 1, 3), cv2.Rodrigues(R_cw)[0],
                                  -R_cw @ cam.position_enu, intr.K, intr.dist_coeffs)
    theirs = theirs.reshape(-1, 2)
    assert cam.in_image(theirs).all()

    outline = shapely.MultiPoint(cam.project_convex_outline(corners)).convex_hull
    truth = shapely.MultiPoint(theirs).convex_hull
    outside = shapely.distance(outline, shapely.points(theirs)).max()
    assert outside < 0.05
    assert outline.hausdorff_distance(truth) < 0.05
    corners_only = shapely.MultiPoint(cam.project(corners)[0]).convex_hull
    spill = shapely.distance(corners_only, shapely.points(theirs)).max()
    assert (spill > 1.0) == (k1 < 0)


def test_pixels_just_inside_a_barrel_fold_back_project():
    """k1 = -0.2 folds at r = 1/sqrt(0.6) = 1.291. OpenCV's fixed-point undistortion is
    still 1e-3 off at r = 1.25 after 40 steps (and the pixel was refused); the Newton
    polish recovers points up to 0.2 % short of the fold to 1e-9."""
    intr = CameraIntrinsics(640, 360, 320.0, 320.0, 319.5, 179.5, (-0.2, 0.0, 0.0, 0.0, 0.0))
    cam = Camera(intr, np.zeros(3), world_from_camera_rotation(0.0, math.radians(-90), 0.0))
    direction = np.array([0.9, 0.436]) / np.hypot(0.9, 0.436)
    ideal = np.outer([0.5, 1.0, 1.2, 1.25, 1.28, 1.288], direction)
    pixels, _ = cv2.projectPoints(np.column_stack((ideal, np.ones(len(ideal)))).reshape(-1, 1, 3),
                                  np.zeros(3), np.zeros(3), intr.K, intr.dist_coeffs)
    assert np.allclose(cam.normalized_coordinates(pixels.reshape(-1, 2)), ideal, atol=1e-9)


@pytest.mark.parametrize("name, text", [
    ("deep.yaml", "%YAML:1.0\n---\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n"
                  "   cols: 5\n   dt: d\n   data: [ -0.26," + "[" * 100_000 + "\n"),
    ("deep.xml", '<?xml version="1.0"?>\n<opencv_storage>' + "<a>" * 100_000 + "</opencv_storage>\n"),
])
def test_calibration_nested_too_deep_is_refused_before_opencv_crashes(tmp_path, name, text):
    """Found by the 10,000-case fuzz: OpenCV's FileStorage parser recurses without a limit
    and a YAML list nested 100,000 deep ends the process with a segmentation fault (no
    exception to catch). Such files are refused, naming the line, before OpenCV reads them."""
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(InputError, match=r"nested \d+ levels deep: more than 32") as info:
        load_camera_calibration(path)
    assert info.value.field.startswith("line ")


def test_a_point_past_a_barrel_fold_is_not_projected_even_where_undistortion_finds_it():
    """k1 = -0.26 folds at r = 1/sqrt(3 x 0.26) = 1.132. A point at r = 2.7-3.1 distorts to a
    radius of the opposite sign, and the undistortion converges back to it (another root):
    it was projected, 200 px above a 256 px image, and a tug's outline reached there. Points
    at or past the fold radius are refused; the fold radius is the model's."""
    from harborsight.geometry.camera import fold_radius

    assert fold_radius((-0.26, 0.0, 0.0, 0.0, 0.0)) == pytest.approx(1 / math.sqrt(0.78), abs=2e-4)
    assert fold_radius((0.05, 0.0, 0.0, 0.0, 0.0)) == math.inf
    intr = CameraIntrinsics(256, 144, 64.0, 64.0, 127.5, 71.5, (-0.26, 0.0, 0.0, 0.0, 0.0))
    cam = Camera(intr, np.zeros(3), world_from_camera_rotation(0.0, math.radians(-90), 0.0))
    rays = np.array([[-1.15, 2.873, 1.0], [1.014, 2.498, 1.0], [0.5, 0.6, 1.0], [1.1, 0.0, 1.0]])
    points = rays @ cam.world_from_camera.T + cam.position_enu
    uv, ok = cam.project(points)
    assert ok.tolist() == [False, False, True, True]
    theirs, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), intr.K,
                                  intr.dist_coeffs)
    assert np.allclose(uv[2:], theirs.reshape(-1, 2)[2:], atol=1e-6)


def test_a_large_set_across_the_near_plane_is_cut_on_its_hull_edges(monkeypatch):
    """A convex set reaching behind the camera is cut at the near plane. Pairing every point
    ahead with every point behind found the cut's corners, but a scanned hull of 20,737
    points beside a drone 5 m up asked for 18 GB. Beyond ``_MAX_NEAR_PAIRS`` pairs only the
    edges of the set's 3-D convex hull are cut: the same solid (scipy's hull volumes agree
    to 1e-12), with a handful of points instead of one per pair."""
    from scipy.spatial import ConvexHull

    from harborsight.geometry import camera as camera_module

    rng = np.random.default_rng(3)
    points = rng.normal(size=(3000, 3)) * np.array([20.0, 5.0, 10.0])      # about half behind
    all_pairs = camera_module._ahead_of_camera(points)      # 1,500 x 1,500 pairs: over the limit
    assert len(all_pairs) < 10 * len(points)                 # cut on the hull's edges
    monkeypatch.setattr(camera_module, "_MAX_NEAR_PAIRS", 10 ** 12)
    every = camera_module._ahead_of_camera(points)           # every pair (54 MB here)
    assert len(every) > 10 ** 6
    assert ConvexHull(all_pairs).volume == pytest.approx(ConvexHull(every).volume, rel=1e-12)
    # a flat set (a deck's outline) is joggled into a hull, and cut the same
    flat = np.column_stack((rng.uniform(-10, 10, 600), rng.uniform(-3, 3, 600), np.zeros(600)))
    flat = flat @ Rotation.from_euler("x", 50, degrees=True).as_matrix().T
    monkeypatch.setattr(camera_module, "_MAX_NEAR_PAIRS", 0)
    cut = camera_module._ahead_of_camera(flat)
    monkeypatch.setattr(camera_module, "_MAX_NEAR_PAIRS", 10 ** 12)
    assert shapely.MultiPoint(cut[:, :2]).convex_hull.area == pytest.approx(
        shapely.MultiPoint(camera_module._ahead_of_camera(flat)[:, :2]).convex_hull.area, rel=1e-9)


def test_the_edge_of_the_pixels_with_a_ray_follows_a_fold_inside_the_image():
    """A barrel lens with tangential terms (k1 -0.337, k2 -0.023, p1 -0.0015, p2 0.0008 at
    fx 454.7) leaves 15 % of a 640x360 image past its fold, in the corners, and its edge
    lies up to 27 px from the image of the fold's circle. ``ray_edge_px`` traces it from the
    pixels themselves: every point of the loop has a ray and lies within 4 px of a pixel
    without one or of the image's border, and every pixel of the true edge inside the
    image lies within 3 px of the loop. Lenses whose border pixels all have rays (none,
    a mild barrel, a strong one folding outside the image) give None."""
    from scipy.spatial import cKDTree

    from harborsight.geometry.camera import ray_edge_px

    intr = CameraIntrinsics(640, 360, 454.7, 454.7, 319.5, 179.5,
                            (-0.3373, -0.02288, -0.0015, 0.00079, 0.0))
    loop = ray_edge_px(intr)
    camera = Camera(intr, np.zeros(3), np.eye(3))
    assert np.isfinite(camera.normalized_coordinates(loop)).all()
    grid = np.stack(np.meshgrid(np.arange(640.0), np.arange(360.0)), -1).reshape(-1, 2)
    has_ray = np.isfinite(camera.normalized_coordinates(grid)).all(axis=1)
    assert 0.8 < has_ray.mean() < 0.9
    without = cKDTree(grid[~has_ray])
    on_border = (loop[:, 0] == 0) | (loop[:, 0] == 639) | (loop[:, 1] == 0) | (loop[:, 1] == 359)
    assert (without.query(loop[~on_border])[0] <= 4.0).all()
    assert on_border.any() and (~on_border).any()
    # (past the fold a few single pixels find a ray of their own: only the main region counts)
    _, regions, stats, _ = cv2.connectedComponentsWithStats(has_ray.reshape(360, 640).astype(np.uint8))
    mask = (regions == 1 + np.argmax(stats[1:, cv2.CC_STAT_AREA])).astype(np.uint8)
    edge = mask & (1 - cv2.erode(mask, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE))
    rows, cols = np.nonzero(edge)
    assert cKDTree(loop).query(np.column_stack((cols, rows)))[0].max() <= 3.0
    for distortion in ((), (-0.1, 0.0, 0.0, 0.0, 0.0), (-0.34, 0.0, 0.0, 0.0, 0.0)):
        wide = CameraIntrinsics(640, 360, 900.0, 900.0, 319.5, 179.5, distortion)
        assert ray_edge_px(wide) is None
