"""The simulator's fast geometry: primitives, convex meshes, waterline cuts, robust footprint
unions and the ray cast's view test, each against trimesh, scipy or a brute-force cast."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import shapely
import trimesh
from scipy.spatial import ConvexHull
from shapely.geometry import MultiPoint, Point

from harborsight.geometry.camera import Camera, CameraIntrinsics
from harborsight.geometry.rotations import world_from_camera_rotation
from harborsight.sim.dataset import SimulationConfig, plan_frame, prepare_vessels
from harborsight.sim.ground_truth import footprint_union
from harborsight.sim.layout import _box, _cylinder, convex_mesh
from harborsight.sim.raycast import triangles_in_view
from harborsight.sim.scene import waterline_crossings
from harborsight.vessel.spec import load_vessel_spec


def test_primitives_are_trimesh_s_own_vertex_for_vertex():
    rng = np.random.default_rng(3)
    for _ in range(50):
        lx, ly, lz = rng.uniform(0.05, 40.0, 3)
        x, y, z = rng.uniform(-300.0, 300.0, 3)
        box = trimesh.creation.box(extents=(lx, ly, lz))
        box.apply_translation((x, y, z + lz / 2))
        ours = _box(lx, ly, lz, x, y, z)
        assert np.array_equal(ours.vertices, box.vertices) and np.array_equal(ours.faces, box.faces)
        for sections in (6, 8, 12):
            cylinder = trimesh.creation.cylinder(radius=lx / 10, height=lz, sections=sections)
            cylinder.apply_translation((x, y, z + lz / 2))
            ours = _cylinder(lx / 10, lz, x, y, z, sections)
            assert np.array_equal(ours.vertices, cylinder.vertices)
            assert np.array_equal(ours.faces, cylinder.faces)


def test_convex_mesh_is_a_closed_outward_hull():
    rng = np.random.default_rng(5)
    for n in (6, 8, 30):
        points = rng.normal(size=(n, 3)) * (10.0, 3.0, 1.0) + rng.uniform(-100, 100, 3)
        mesh = convex_mesh(points)
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume == pytest.approx(ConvexHull(points).volume, rel=1e-9)   # > 0: outward
        assert mesh.volume == pytest.approx(trimesh.convex.convex_hull(points).volume, rel=1e-9)


def test_waterline_crossings_are_the_plane_cut_of_trimesh():
    rng = np.random.default_rng(8)
    for _ in range(20):
        mesh = trimesh.convex.convex_hull(rng.normal(size=(20, 3)) * (8.0, 3.0, 2.0))
        ours = waterline_crossings(np.asarray(mesh.vertices), np.asarray(mesh.faces))
        cut = np.asarray(trimesh.intersections.mesh_plane(mesh, (0, 0, 1), (0, 0, 0))).reshape(-1, 3)
        # the same points (each edge once per face that has it, in another order)
        gaps = np.linalg.norm(ours[:, None] - cut[None, :, :2], axis=2)
        assert gaps.min(axis=1).max() < 1e-9 and gaps.min(axis=0).max() < 1e-9
        assert MultiPoint(ours).convex_hull.symmetric_difference(
            MultiPoint(cut[:, :2]).convex_hull).area < 1e-9


def test_a_shore_of_slabs_sharing_edges_keeps_all_its_land():
    """Lake-shore frame 7 of seed 404: GEOS's plain union of the 24 land slabs, which share
    their side faces, dropped 17 % of the land (8,456 m²) before the union was made robust."""
    # (the scene as drawn then, before the lake shores' leisure craft)
    config = SimulationConfig(seed=404, preset="default", scenario="lakeshore", vessel_pool=6,
                              leisure_vessels=False)
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        vessels = {name: load_vessel_spec(path)
                   for name, path in prepare_vessels(Path(tmp), config).items()}
    scene = plan_frame(config, 7, vessels)
    land = next(o for o in scene.objects if o.name == "shore-land")
    slabs = []
    for part in land.parts:
        vertices = np.asarray(part.mesh.vertices)
        points = np.vstack((vertices[vertices[:, 2] >= 0, :2],
                            waterline_crossings(vertices, np.asarray(part.mesh.faces))))
        slabs.append(MultiPoint(points).convex_hull)
    assert len(slabs) == 24
    total = sum(s.area for s in slabs)         # the slabs only touch: the union is their sum
    assert land.footprint().area == pytest.approx(total, rel=1e-6)
    assert footprint_union(slabs).area == pytest.approx(total, rel=1e-6)


def test_triangles_out_of_view_are_never_hit():
    """The view test against a brute-force cast: no pixel's ray meets a triangle it drops,
    and every triangle a ray meets is kept (a tilted, distorted camera)."""
    intrinsics = CameraIntrinsics(64, 36, 50.0, 50.0, 31.5, 17.5, distortion=(-0.2, 0.05, 0.0, 0.0, 0.0))
    camera = Camera(intrinsics, np.array([3.0, -2.0, 40.0]),
                    world_from_camera_rotation(0.4, math.radians(-80), 0.05))
    rng = np.random.default_rng(2)
    centres = rng.uniform((-80, -80, -2), (80, 80, 30), (1200, 1, 3))
    triangles = centres + rng.normal(scale=2.0, size=(1200, 3, 3))
    u, v = np.meshgrid(np.arange(64.0), np.arange(36.0))
    xy = camera.normalized_coordinates(np.column_stack((u.ravel(), v.ravel())))
    kept = triangles_in_view(_geometry(camera), triangles, xy)
    assert 0 < len(kept) < len(triangles)
    dropped = np.setdiff1d(np.arange(len(triangles)), kept)
    directions = np.column_stack((xy, np.ones(len(xy)))) @ camera.world_from_camera.T
    origins = np.broadcast_to(camera.position_enu, directions.shape)

    def hit_triangles(indices: np.ndarray) -> set[int]:
        """Möller-Trumbore for every ray and triangle (t > 0, inside with a 1e-9 margin)."""
        a, b, c = (triangles[indices, k][None] for k in range(3))
        d = directions[:, None]
        e1, e2 = b - a, c - a
        p = np.cross(d, e2)
        det = np.einsum("rtk,rtk->rt", e1, p)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = origins[:, None] - a
            u = np.einsum("rtk,rtk->rt", s, p) / det
            q = np.cross(s, e1)
            v = np.einsum("rtk,rtk->rt", d, q) / det
            t = np.einsum("rtk,rtk->rt", e2, q) / det
        hit = (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9) & (t > 0)
        return {int(indices[i]) for i in np.flatnonzero(hit.any(axis=0))}

    assert hit_triangles(dropped) == set()
    assert hit_triangles(np.arange(len(triangles))) <= set(kept.tolist())


def _geometry(camera: Camera):
    class _Frame:          # triangles_in_view reads only the camera
        pass
    frame = _Frame()
    frame.camera = camera
    return frame


def test_a_ray_cast_with_nothing_in_view_is_all_sky():
    """Every triangle out of view (or none at all): every pixel is NO_HIT at infinite range,
    as before the view test, not an error from an empty Embree scene."""
    from harborsight.sim.raycast import ray_cast_ids
    from harborsight.sim.scene import NO_HIT

    camera = Camera(CameraIntrinsics(64, 36, 50.0, 50.0, 31.5, 17.5), np.array([0.0, 0.0, 40.0]),
                    world_from_camera_rotation(0.0, math.radians(-90), 0.0))
    far = np.array([[[500.0, 500.0, 0.0], [501.0, 500.0, 0.0], [500.0, 501.0, 0.0]]])
    for triangles in (far, np.zeros((0, 3, 3))):
        cast = ray_cast_ids(_geometry(camera), triangles, np.ones(len(triangles), np.int64))
        assert cast.instances.shape == (36, 64) and (cast.instances == NO_HIT).all()
        assert np.isinf(cast.range_m).all()
    near = np.array([[[-30.0, -30.0, 0.0], [30.0, -30.0, 0.0], [0.0, 30.0, 0.0]]])
    assert (ray_cast_ids(_geometry(camera), near, np.array([7])).instances == 7).any()


@pytest.mark.parametrize("delta_m", [1e-9, 1e-5, 4e-5])
def test_a_break_a_hair_past_a_corner_leaves_the_corner_s_wedge_to_the_section_before(delta_m):
    """A section break a fraction of a millimetre past a hull corner: section 1's band was
    started along the bisector (its normal was sampled across the corner), so it overlapped
    the corner's wedge, which the nearest-point rule gives section 0 (as the measurement's
    assignment does): a buoy there read 2.70 m in section 1 too (on AIS boxes of whole
    metres, a truth 0.1 m short). The band starts square to its own edge."""
    from harborsight.sim.ground_truth import section_distances
    from harborsight.vessel.sections import SectionedOutline

    verts = np.array([(10.0, 0.0), (4.0, 3.0), (-10.0, 3.0), (-10.0, -3.0), (4.0, -3.0)])
    b1 = verts[1] + delta_m * (verts[2] - verts[1]) / np.linalg.norm(verts[2] - verts[1])
    breaks = np.array([verts[0], b1, (-10.0, 0.0), verts[4] + 0.5 * (verts[0] - verts[4])])
    outline = SectionedOutline(verts, breaks, np.array([0, 1, 2, 4]))
    normal = 0.8 * np.array([3.0, 6.0]) / np.hypot(3, 6) + 0.2 * np.array([0.0, 1.0])
    centre = verts[1] + 3.0 * normal / np.linalg.norm(normal)
    buoy = Point(*centre).buffer(0.5, quad_segs=64)
    truth = section_distances(outline, buoy, None)
    assert int(outline.assign(np.array([centre])).section[0]) == 0
    assert truth[0]["distance_all_m"] == pytest.approx(2.5, abs=1e-3)
    assert truth[1]["distance_all_m"] is None


def test_the_truth_s_seen_water_ends_at_a_lens_fold_inside_the_image():
    """The ground truth's seen water (``image_ground_polygon``) under a wide barrel lens
    whose fold lies inside the image (k1 -0.34, fx 300 px, 640x360, 40 m up at nadir):
    water whose pixel lies past the fold (``Camera.project`` refuses it) is not seen, and
    water that projects at least 4 px inside the pixels with a ray is. The image's border
    alone, its samples past the fold dropped, closed the polygon with chords across the
    unseen corners: 628 of the grid's 13,848 points past the fold were inside it."""
    from harborsight.frame import FrameGeometry
    from harborsight.geometry.geodesy import GeoOrigin
    from harborsight.sim.ground_truth import image_ground_polygon

    intr = CameraIntrinsics(640, 360, 300.0, 300.0, 319.5, 179.5, (-0.34, 0.0, 0.0, 0.0, 0.0))
    camera = Camera(intr, np.array([0.0, 0.0, 40.0]),
                    world_from_camera_rotation(0.0, math.radians(-90.0), 0.0))
    geometry = FrameGeometry(GeoOrigin(56.0, 10.0, 0.0), camera, 0.0)
    seen = image_ground_polygon(geometry)
    e, n = np.meshgrid(np.linspace(-150, 150, 121), np.linspace(-150, 150, 121))
    ground = np.column_stack((e.ravel(), n.ravel(), np.zeros(e.size)))
    uv, _ = camera.project(ground)
    inside = shapely.contains_xy(seen, ground[:, 0], ground[:, 1])
    past_fold = ~np.isfinite(uv).all(axis=1)
    assert past_fold.sum() > 1000 and not inside[past_fold].any()
    grid = np.stack(np.meshgrid(np.arange(640.0), np.arange(360.0)), -1).reshape(-1, 2)
    has_ray = np.isfinite(camera.normalized_coordinates(grid)).all(axis=1).reshape(360, 640)
    deep = cv2.erode(has_ray.astype(np.uint8), np.ones((9, 9), np.uint8), borderType=cv2.BORDER_CONSTANT)
    pixel = np.rint(uv[~past_fold]).astype(int)
    in_frame = (pixel[:, 0] >= 0) & (pixel[:, 0] < 640) & (pixel[:, 1] >= 0) & (pixel[:, 1] < 360)
    well_inside = np.zeros(len(pixel), bool)
    well_inside[in_frame] = deep[pixel[in_frame, 1], pixel[in_frame, 0]] > 0
    assert well_inside.sum() > 100 and inside[~past_fold][well_inside].all()


def test_a_schematic_frame_of_a_long_hull_reaching_behind_an_oblique_camera(tmp_path):
    """A 180 m ship 28 m under a camera tilted 15 degrees: part of its outline lies behind
    the camera, and painting its deck from the outline's projected corners (NaN there) made
    shapely raise (12 of 200 such scenes in the fifty-third session's hunt). The deck is
    painted from the outline's image cut at the camera plane; the labels are the hull's."""
    from harborsight.sim.ground_truth import vessel_silhouette
    from harborsight.sim.schematic import render, sample_scene
    from harborsight.vessel.hullgen import HullParameters
    from tests.helpers import generated_hull_vessel

    ship = generated_hull_vessel(
        tmp_path, HullParameters(180.0, 28.0, 9.0, 8.0, 0.18, 0.03, (0.08, 0.18, 0.9, 22.0)),
        (25.0, 0.0, 40.0), sections=24, name="cargo")
    scene = sample_scene(ship, np.random.default_rng(55), altitude_m=28.016, tilt_deg=15.169,
                         scenario="alongside", gap_m=1.0)
    geometry = scene.geometry()
    outline_px = geometry.camera.project(geometry.vessel_to_enu(ship.outline))[0]
    assert not np.isfinite(outline_px).all()            # the case: corners behind the camera
    image, labels, _ = render(scene)
    assert image.shape == (*labels.shape, 3)
    rows, cols = np.nonzero(labels == 1)
    silhouette = vessel_silhouette(ship, geometry)
    assert shapely.contains_xy(silhouette, cols, rows).mean() > 0.9
