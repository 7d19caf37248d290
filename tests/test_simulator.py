"""The Blender simulator on tiny frames: labels vs ray casts, ground truth vs shapely,
metadata round trip, determinism, resume, Dask and the CLI."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
import shapely
from shapely.geometry import MultiPoint, Point, Polygon

from harborsight.errors import InputError
from harborsight.frame import FrameGeometry, parse_frame_metadata
from harborsight.sim.dataset import SimulationConfig, plan_frame, simulate
from harborsight.sim.raycast import LabelCheckError, RayCast, check_labels
from harborsight.vessel.spec import load_vessel_spec

TINY = SimulationConfig(seed=11, preset="tiny", altitudes_m=(30.0, 40.0), vessel_pool=2)
N_FRAMES = 4


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "ds"
    summary = simulate(out, N_FRAMES, TINY)
    assert not summary.failed, [f.error for f in summary.failed]
    return out


def _frame(dataset: Path, index: int) -> dict:
    return json.loads((dataset / "frames" / f"{index:06d}.json").read_text())


def test_layout_and_dataset_json(dataset):
    doc = json.loads((dataset / "dataset.json").read_text())
    assert doc["seed"] == TINY.seed
    assert doc["classes"]["1"] == "ship"
    assert set(doc["split"]) == {f"{i:06d}" for i in range(N_FRAMES)}
    assert set(doc["split"].values()) <= {"train", "val"}
    assert doc["parameters"]["preset"] == "tiny"
    for i in range(N_FRAMES):
        image = cv2.imread(str(dataset / "images" / f"{i:06d}.png"))
        labels = cv2.imread(str(dataset / "labels" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        instances = cv2.imread(str(dataset / "instances" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert image.shape == (36, 64, 3) and labels.shape == (36, 64)
        assert instances.dtype == np.uint16
        assert set(np.unique(labels)) <= {0, 1, 2, 255}
        # class mask and instances agree: water is instance 0, the vessel instance 1 a ship
        assert np.all(labels[instances == 1] == 1)
        assert np.all((labels == 0) == ((instances == 0) & (labels != 255)))
        frame = _frame(dataset, i)
        assert frame["schema"] == "harborsight.frame/1"
        assert frame["simulation"]["label_agreement"] >= 0.995
        assert (dataset / frame["vessel_spec"]).is_file()


def test_labels_agree_with_independent_ray_cast(dataset):
    """Re-cast the rays from the *written metadata* and compare with the written instances
    (the renderer checked too; this checks the files a user reads)."""
    from harborsight.sim.dataset import FrameRenderer
    from harborsight.sim.raycast import ray_cast_ids, scene_triangles

    renderer = FrameRenderer(dataset, TINY)
    for i in range(N_FRAMES):
        frame = _frame(dataset, i)
        scene = plan_frame(TINY, i, renderer.vessels)
        geometry = FrameGeometry.from_metadata(parse_frame_metadata(frame))
        rendered = renderer.renderer.render(scene)
        cast = ray_cast_ids(geometry, *scene_triangles(scene, rendered.ocean_triangles))
        written = cv2.imread(str(dataset / "instances" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        cast_ids = cast.instances.copy()
        cast_ids[cast_ids == 65535] = 0
        assert np.mean(written == cast_ids) >= 0.995


def test_label_check_fails_loudly():
    ids = np.zeros((36, 64), np.uint16)
    cast = RayCast(ids.copy(), np.ones((36, 64)))
    assert check_labels(ids, cast, "x") == 1.0
    # a one-pixel shift of a vertical edge: 2 of 64 columns disagree (96.9 % < 99.5 %)
    halves = np.where(np.arange(64) < 32, 2, 0).astype(np.uint16)[None].repeat(36, 0)
    with pytest.raises(LabelCheckError, match="frame 000007"):
        check_labels(np.roll(halves, 1, axis=1), RayCast(halves, np.ones((36, 64))), "frame 000007")


def _brute_force_sections(outline_xy: np.ndarray, obstacles: shapely.Geometry, n_sections: int,
                          sections) -> list[float | None]:
    """Per section: sample obstacle boundaries every 2 cm, give each sample to the section
    holding its nearest outline point (outline sampled every 1 cm), keep the minimum."""
    hull = Polygon(outline_xy)
    ring = hull.exterior
    perimeter = ring.length
    s_outline = np.arange(0.0, perimeter, 0.01)
    outline_pts = np.array([[p.x, p.y] for p in (ring.interpolate(s) for s in s_outline)])
    section_of_outline = np.searchsorted(sections.break_position, s_outline, side="right") - 1
    best: list[float | None] = [None] * n_sections
    geoms = getattr(obstacles, "geoms", [obstacles])
    for g in geoms:
        boundary = g.exterior if isinstance(g, Polygon) else g.boundary
        length = boundary.length
        pts = np.array([[p.x, p.y] for p in (boundary.interpolate(s) for s in
                                                np.arange(0.0, length, 0.02))])
        if not len(pts):
            continue
        d2 = ((pts[:, None, :] - outline_pts[None, ::5, :]) ** 2).sum(-1)
        nearest = np.argmin(d2, axis=1) * 5
        for p, j in zip(pts, nearest, strict=True):
            d = float(hull.exterior.distance(Point(p)))
            k = int(section_of_outline[j])
            if d < 60.0 and (best[k] is None or d < best[k]):
                best[k] = d
    return best


def test_ground_truth_against_shapely(dataset):
    renderer_vessels = {p.parent.name: load_vessel_spec(p)
                        for p in (dataset / "vessels").glob("*/vessel.yaml")}
    for i in range(N_FRAMES):
        frame = _frame(dataset, i)
        scene = plan_frame(TINY, i, renderer_vessels)
        geometry = scene.geometry()
        truth = frame["ground_truth"]["sections"]
        # the minimum over sections is the outline's distance to every footprint
        footprints = [shapely.transform(fp, geometry.enu_to_vessel_xy)
                      for fp in scene.obstacle_footprints()]
        union = shapely.union_all(footprints)
        outline = Polygon(scene.vessel.outline)
        expected_min = float(outline.distance(union))
        got = [s["distance_all_m"] for s in truth if s["distance_all_m"] is not None]
        assert min(got) == pytest.approx(expected_min, abs=1e-6)
        # footprints are the vertical projections of the meshes above the water
        for obj in scene.objects[1:]:
            verts = np.vstack([p.mesh.vertices for p in obj.parts])
            above = verts[verts[:, 2] >= 0, :2]
            assert obj.footprint().buffer(1e-6).contains(MultiPoint(above))
            assert obj.footprint().area <= MultiPoint(verts[:, :2]).convex_hull.area + 1e-6
        # per section, by brute force (independent of the band polygons), near obstacles
        near = shapely.intersection(union, outline.buffer(15.0))
        brute = _brute_force_sections(scene.vessel.outline, near, len(truth),
                                      scene.vessel.sections())
        for k, b in enumerate(brute):
            t = truth[k]["distance_all_m"]
            if b is not None and b < 12.0:
                assert t is not None and t == pytest.approx(b, abs=0.05), (i, k)


def test_metadata_round_trip_vessel_lands_on_its_mask(dataset):
    """Project the vessel's hull with harborsight's geometry from the frame file alone."""
    for i in range(N_FRAMES):
        frame = _frame(dataset, i)
        meta = parse_frame_metadata(frame)
        geometry = FrameGeometry.from_metadata(meta)
        vessel = load_vessel_spec(dataset / frame["vessel_spec"])
        uv, front = geometry.camera.project(geometry.vessel_to_enu(vessel.mesh.vertices))
        silhouette = MultiPoint(uv[front]).convex_hull
        u, v = np.meshgrid(np.arange(64.0), np.arange(36.0))
        predicted = shapely.contains_xy(silhouette, u.ravel(), v.ravel()).reshape(36, 64)
        instances = cv2.imread(str(dataset / "instances" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        actual = instances == 1
        iou = (predicted & actual).sum() / (predicted | actual).sum()
        assert iou >= 0.9, (i, iou)


def test_deterministic_and_resumable(dataset, tmp_path):
    out = tmp_path / "again"
    simulate(out, 2, TINY)
    for i in range(2):
        for sub, ext in (("images", "png"), ("labels", "png"), ("instances", "png")):
            a = cv2.imread(str(dataset / sub / f"{i:06d}.{ext}"), cv2.IMREAD_UNCHANGED)
            b = cv2.imread(str(out / sub / f"{i:06d}.{ext}"), cv2.IMREAD_UNCHANGED)
            assert np.array_equal(a, b), (sub, i)
        assert _frame(dataset, i) == _frame(out, i)
    summary = simulate(out, 3, TINY)
    assert summary.skipped == 2 and [r.index for r in summary.rendered] == [2]
    with pytest.raises(InputError, match="other parameters"):
        simulate(out, 3, SimulationConfig(seed=12, preset="tiny", altitudes_m=(30.0, 40.0),
                                          vessel_pool=2))


def test_dask_cluster_renders_the_same_frames(dataset, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        out = tmp_path / "dask"
        summary = simulate(out, 2, TINY, scheduler=cluster.scheduler_address, chunk_size=2)
    assert not summary.failed, [f.error for f in summary.failed]
    for i in range(2):
        a = cv2.imread(str(dataset / "labels" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        b = cv2.imread(str(out / "labels" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(a, b)
    assert json.loads((out / "dataset.json").read_text())["split"].keys() == {"000000", "000001"}


def test_cli_simulate_and_contact_sheet(tmp_path):
    from typer.testing import CliRunner

    from harborsight.cli import app

    runner = CliRunner()
    out = tmp_path / "cli"
    result = runner.invoke(app, ["simulate", "--n", "1", "--out", str(out), "--seed", "5",
                                 "--preset", "tiny", "--altitudes", "40", "--split", "test"])
    assert result.exit_code == 0, result.output
    assert json.loads((out / "dataset.json").read_text())["split"] == {"000000": "test"}
    sheet = tmp_path / "sheet.png"
    result = runner.invoke(app, ["contact-sheet", str(out), "--out", str(sheet), "--tile-width", "128"])
    assert result.exit_code == 0, result.output
    assert cv2.imread(str(sheet)).shape[1] == 2 * 128
    result = runner.invoke(app, ["simulate", "--n", "1", "--out", str(tmp_path / "x"),
                                 "--preset", "tiny", "--camera", "nikon"])
    assert result.exit_code == 2 and "--camera" in result.output


def test_worker_processes_render_the_same_frames(dataset, tmp_path):
    out = tmp_path / "workers"
    summary = simulate(out, 2, TINY, workers=2)
    assert not summary.failed and sorted(r.index for r in summary.rendered) == [0, 1]
    for i in range(2):
        a = cv2.imread(str(dataset / "labels" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        b = cv2.imread(str(out / "labels" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(a, b)
        assert _frame(dataset, i)["ground_truth"] == _frame(out, i)["ground_truth"]


def test_flat_world_masks_match_footprints_projected_by_opencv(dataset):
    """Interior pixels of the flat-world masks equal footprints drawn with cv2.projectPoints
    and cv2.fillPoly (pixels on a drawn boundary are left out)."""
    from harborsight.evaluation.distance import flat_world_masks

    frame = _frame(dataset, 1)
    labels = flat_world_masks(dataset)(dataset, frame)
    vessels = {p.parent.name: load_vessel_spec(p)
               for p in sorted((dataset / "vessels").glob("*/vessel.yaml"))}
    scene = plan_frame(TINY, 1, vessels)
    camera = FrameGeometry.from_metadata(parse_frame_metadata(frame)).camera
    r_cw = camera.camera_from_world
    rvec, _ = cv2.Rodrigues(r_cw)
    tvec = -r_cw @ camera.position_enu
    intr = camera.intrinsics
    expected = np.zeros(labels.shape, np.uint8)
    boundary = np.zeros(labels.shape, np.uint8)
    own, *others = scene.objects
    for obj in others:
        polygons = getattr(obj.footprint(), "geoms", [obj.footprint()])
        for polygon in polygons:
            ring = np.column_stack((np.asarray(polygon.exterior.coords),
                                    np.zeros(len(polygon.exterior.coords))))
            uv, _ = cv2.projectPoints(ring.reshape(-1, 1, 3), rvec, tvec, intr.K, intr.dist_coeffs)
            pts = np.round(uv.reshape(-1, 2) * 16).astype(np.int32)
            cv2.fillPoly(expected, [pts], obj.class_id, shift=4)
            cv2.polylines(boundary, [pts], True, 1, 2, shift=4)
    # the vessel of interest: the convex hull of its projected hull points, as in the frame
    vessel = load_vessel_spec(dataset / frame["vessel_spec"])
    geometry = FrameGeometry.from_metadata(parse_frame_metadata(frame))
    hull_enu = geometry.vessel_to_enu(vessel.hull_points)
    uv, _ = cv2.projectPoints(hull_enu.reshape(-1, 1, 3), rvec, tvec, intr.K, intr.dist_coeffs)
    pts = np.round(cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2) * 16).astype(np.int32)
    cv2.fillPoly(expected, [pts], own.class_id, shift=4)
    cv2.polylines(boundary, [pts], True, 1, 2, shift=4)
    interior = cv2.dilate(boundary, np.ones((3, 3), np.uint8)) == 0
    assert interior.sum() > 0.5 * labels.size
    assert np.array_equal(labels[interior], expected[interior])
    assert set(np.unique(labels)) >= {0, 1}


def test_a_frame_that_fails_unexpectedly_is_reported_and_the_rest_rendered(
        dataset, tmp_path, monkeypatch):
    import shutil

    from harborsight.sim import dataset as sim_dataset

    original = sim_dataset.FrameRenderer.render_files

    def flaky(self, index):
        if index == 1:
            raise RuntimeError("Blender wrote no image")
        return original(self, index)

    monkeypatch.setattr(sim_dataset.FrameRenderer, "render_files", flaky)
    out = tmp_path / "ds"
    summary = simulate(out, 3, TINY)
    assert [f.index for f in summary.failed] == [1]
    assert "RuntimeError: Blender wrote no image" in summary.failed[0].error
    assert sorted(p.stem for p in (out / "frames").glob("*.json")) == ["000000", "000002"]
    broken = tmp_path / "broken"
    shutil.copytree(out, broken)
    (broken / "dataset.json").write_text("{broken")
    with pytest.raises(InputError, match=r"broken/dataset.json: not valid JSON"):
        simulate(broken, 3, TINY)


def test_a_given_vessel_is_copied_with_its_mesh_only(tmp_path):
    """`--vessel project/vessel.yaml` copied the spec's whole folder (a project root: .venv,
    data, the output folder itself). Only the spec and its mesh go into the dataset; a mesh
    outside the spec's folder lands beside the copy, which names it so."""
    from harborsight.sim.dataset import prepare_vessels

    tug = Path(__file__).resolve().parent.parent / "harborsight/data/samples/vessels/harbour-tug"
    project = tmp_path / "project"
    (project / "meshes").mkdir(parents=True)
    (project / "meshes" / "tug.stl").write_bytes((tug / "hull.stl").read_bytes())
    (project / "notes.txt").write_text("not part of the vessel")
    spec = (tug / "vessel.yaml").read_text().replace("hull.stl", "meshes/tug.stl")
    (project / "vessel.yaml").write_text(spec)
    out = project / "data" / "train"
    paths = prepare_vessels(out, SimulationConfig(seed=0, vessel_spec=str(project / "vessel.yaml")))
    (copied,) = paths.values()
    files = sorted(p.relative_to(copied.parent).as_posix() for p in copied.parent.rglob("*")
                   if p.is_file())
    assert files == ["meshes/tug.stl", "vessel.yaml"]
    assert load_vessel_spec(copied).mesh is not None

    elsewhere = tmp_path / "specs"
    elsewhere.mkdir()
    (elsewhere / "tug.yaml").write_text(
        (tug / "vessel.yaml").read_text().replace("hull.stl", str(project / "meshes" / "tug.stl")))
    paths = prepare_vessels(tmp_path / "ds2",
                            SimulationConfig(seed=0, vessel_spec=str(elsewhere / "tug.yaml")))
    (copied,) = paths.values()
    assert sorted(p.name for p in copied.parent.iterdir()) == ["tug.stl", "vessel.yaml"]
    assert load_vessel_spec(copied).mesh is not None


def test_pose_noise_writes_noisy_frames_with_the_true_pose_kept(dataset, tmp_path):
    """``simulate --pose-noise``: the frames carry sensor errors (and their sigmas), the true
    pose sits in the ground truth, and the errors are those ``dataset add-pose-noise`` draws
    for the same seed and frame."""
    from typer.testing import CliRunner

    from harborsight.cli import app
    from harborsight.sim.dataset import with_pose_noise
    from harborsight.sim.pose_noise import PoseNoise, add_pose_noise, frame_rng

    config = SimulationConfig(**{**TINY.to_dict(), "altitudes_m": (30.0, 40.0),
                                 "pose_noise": {"gps_m": 2.0, "heading_deg": 2.0, "height_m": 1.0}})
    exact = _frame(dataset, 0)
    noisy = with_pose_noise(exact, config, "000000")
    assert noisy["ground_truth"]["true_pose"]["uav"]["lat"] == exact["uav"]["lat"]
    assert noisy["uav"]["lat"] != exact["uav"]["lat"]
    assert noisy["vessel"]["position_sigma_m"] == pytest.approx(2.0 / 2 ** 0.5, abs=1e-4)
    assert noisy == add_pose_noise(exact, PoseNoise(2.0, 2.0, 1.0), frame_rng(TINY.seed, "000000"))
    assert with_pose_noise(exact, TINY, "000000") is exact
    parse_frame_metadata(noisy, "noisy.json")

    runner = CliRunner()
    for bad in ("standalone,2", "gnss,2,1", "standalone,-1,1"):
        result = runner.invoke(app, ["simulate", "--n", "1", "--out", str(tmp_path / "x"),
                                     "--preset", "tiny", "--pose-noise", bad])
        assert result.exit_code == 2 and "--pose-noise" in result.output, bad


def test_each_scene_object_is_one_blender_object_with_a_slot_for_each_material():
    """A scene object's parts become one Blender mesh: every part's faces, each with the
    slot of its own material, at the parts' world coordinates (the textures read them)."""
    from harborsight.sim.blender import PRESETS, BlenderRenderer
    from harborsight.sim.dataset import prepare_vessels

    config = SimulationConfig(seed=404, preset="tiny", scenario="marina")
    with tempfile.TemporaryDirectory() as tmp:
        vessels = {name: load_vessel_spec(p) for name, p in prepare_vessels(Path(tmp), config).items()}
    scene = plan_frame(config, 1, vessels)
    renderer = BlenderRenderer(PRESETS["tiny"])
    renderer.build(scene, cull=False)
    bpy = renderer.bpy
    meshes = {o.name: o for o in bpy.data.objects if o.type == "MESH" and o.name != "ocean"}
    assert len(meshes) == len(scene.objects) > 100
    for obj in scene.objects:
        blender_obj = meshes[obj.name]
        slots = [m.name for m in blender_obj.data.materials]
        assert slots == list(dict.fromkeys(p.material for p in obj.parts))
        index = np.zeros(len(blender_obj.data.polygons), np.int32)
        blender_obj.data.polygons.foreach_get("material_index", index)
        expected = np.concatenate([np.full(len(p.mesh.faces), slots.index(p.material)) for p in obj.parts])
        assert np.array_equal(index, expected)
        co = np.zeros(3 * len(blender_obj.data.vertices))
        blender_obj.data.vertices.foreach_get("co", co)
        assert np.allclose(co.reshape(-1, 3), np.vstack([p.mesh.vertices for p in obj.parts]), atol=1e-4)
        assert np.allclose(blender_obj.matrix_world, np.eye(4))


def test_flat_world_masks_of_a_noisy_dataset_use_the_true_pose(dataset, tmp_path):
    """A dataset with sensor noise writes the noisy pose in its frames (the truth keeps the
    true one): the flat-world masks were drawn with the noisy pose and agreed with the
    rendered labels on 86-88 % of pixels. They are drawn with the scene's own pose: the same
    masks as the exact dataset's."""
    from harborsight.evaluation.distance import flat_world_masks
    from harborsight.sim.pose_noise import PoseNoise, write_noisy_dataset

    noisy = tmp_path / "noisy"
    write_noisy_dataset(dataset, noisy, PoseNoise(gps_m=3.0, heading_deg=3.0), seed=2)
    exact_frame, noisy_frame = _frame(dataset, 1), _frame(noisy, 1)
    assert exact_frame["uav"] != noisy_frame["uav"] or exact_frame["vessel"] != noisy_frame["vessel"]
    assert np.array_equal(flat_world_masks(noisy)(noisy, noisy_frame),
                          flat_world_masks(dataset)(dataset, exact_frame))
