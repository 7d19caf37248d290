"""Vessel specs, outlines from meshes and AIS dimensions, and equal-length sections."""

from pathlib import Path

import numpy as np
import pytest
import shapely
import trimesh
from shapely.geometry import Polygon

from harborsight.errors import InputError
from harborsight.vessel.hullgen import generate_hull_mesh
from harborsight.vessel.outline import outline_from_dimensions
from harborsight.vessel.sections import SectionedOutline
from harborsight.vessel.spec import load_vessel_spec
from tests.helpers import draw_vessel_as_seen, side_view


def write_spec(tmp_path, text: str):
    path = tmp_path / "vessel.yaml"
    path.write_text(text)
    return path


def test_dimensions_outline_is_the_ais_box_with_a_pointed_bow():
    outline = outline_from_dimensions(30, 10, 4, 6)
    poly = Polygon(outline)
    assert poly.bounds == (-10.0, -4.0, 30.0, 6.0)
    assert tuple(outline[0]) == (30.0, 1.0)          # bow tip on the centreline
    # box area minus the two bow triangles (bow length = beam = 10 m)
    assert poly.area == pytest.approx(40 * 10 - 2 * 0.5 * 10 * 5)
    assert outline[1][1] > outline[0][1]             # clockwise seen from above: starboard first


def test_box_mesh_waterline_and_axes(tmp_path):
    # a 20 x 6 x 5 m box; mesh axes: +x stern, +y starboard, +z up; waterline at z = 2
    box = trimesh.creation.box(extents=(20, 6, 5))
    box.apply_translation((0, 0, 2.5))               # z from 0 (keel) to 5
    box.export(tmp_path / "box.stl")
    path = write_spec(tmp_path, "hull_mesh: box.stl\nmesh_axes: [stern, starboard, up]\n"
                      "gps_antenna: [5.0, 1.0, 4.0]\nwaterline_m: 2.0\nsections: 4\n")
    spec = load_vessel_spec(path)
    # V x = -(mesh x - 5) spans -5..15; V y = mesh y - 1 spans -4..2
    assert Polygon(spec.outline).bounds == pytest.approx((-5.0, -4.0, 15.0, 2.0))
    assert spec.hull_points[:, 2].min() == pytest.approx(-3.0)  # 3 m above the waterline
    # the 2 m draft is under water: the image never shows it, so it is not in hull_points
    assert spec.hull_points[:, 2].max() == pytest.approx(0.0)
    assert Polygon(spec.hull_points[:, :2]).convex_hull.bounds == pytest.approx(
        (-5.0, -4.0, 15.0, 2.0))


def test_flared_hull_silhouette_is_wider_than_waterline(tmp_path):
    generate_hull_mesh().export(tmp_path / "hull.ply")
    specs = {}
    for mode in ("waterline", "silhouette", "2.0"):
        path = write_spec(tmp_path, f"hull_mesh: hull.ply\nmesh_axes: [bow, port, up]\n"
                          f"gps_antenna: [20, 0, 9]\noutline: {mode}\n")
        specs[mode] = load_vessel_spec(path)
    water, sil, high = (Polygon(specs[m].outline) for m in ("waterline", "silhouette", "2.0"))
    assert sil.area > high.area > water.area
    assert sil.buffer(1e-6).contains(water)


def test_sections_equal_length_clockwise_from_bow():
    outline = outline_from_dimensions(30, 10, 5, 5)
    sections = SectionedOutline.split(outline, 12)
    lengths = [shapely.LineString(sections.section_polyline(k)).length for k in range(12)]
    assert np.allclose(lengths, Polygon(outline).length / 12)
    assert tuple(sections.break_points[0]) == (30.0, 0.0)
    assert sections.section_polyline(0)[-1][1] > 0     # section 0 runs down the starboard side
    by_length = SectionedOutline.split(outline, section_length=10.0)
    assert by_length.n_sections == round(Polygon(outline).length / 10.0)


def test_blunt_bow_starts_on_the_centreline(tmp_path):
    box = trimesh.creation.box(extents=(20, 6, 4))
    box.export(tmp_path / "barge.obj")
    path = write_spec(tmp_path, "hull_mesh: barge.obj\nmesh_axes: [bow, port, up]\n"
                      "gps_antenna: [0, 0, 0]\nsections: 8\n")
    outline = load_vessel_spec(path).outline
    assert tuple(outline[0]) == pytest.approx((10.0, 0.0))


@pytest.mark.parametrize("text, field", [
    ("name: x\n", "hull_mesh"),
    ("hull_mesh: missing.stl\n", "hull_mesh"),
    ("dimensions: {to_bow: 10, to_stern: 5, to_port: -2, to_starboard: 3}\n", "dimensions.to_port"),
    ("dimensions: {to_bow: 10, to_stern: 5, to_port: 2, to_starboard: 3}\nsections: 0\n", "sections"),
    ("dimensions: {to_bow: 10, to_stern: 5, to_port: 2, to_starboard: 3}\noutline: keel\n", "outline"),
    ("dimensions: {to_bow: 10, to_stern: 5, to_port: 2, to_starboard: 3}\noutline_sigma_m: -0.1\n",
     "outline_sigma_m"),
    ("dimensions: {to_bow: 10, to_stern: 5, to_port: 2, to_starboard: 3}\noutline_sigma_m: .nan\n",
     "outline_sigma_m"),
    ("dimensions: {to_bow: 10, to_stern: 5, to_port: 2, to_starboard: 3}\noutline_sigma_m: 1e6\n",
     "outline_sigma_m"),
])
def test_bad_specs_name_the_field(tmp_path, text, field):
    with pytest.raises(InputError, match=rf"vessel.yaml: {field}"):
        load_vessel_spec(write_spec(tmp_path, text))


def test_corrupt_mesh_names_the_file(tmp_path):
    (tmp_path / "hull.stl").write_bytes(b"solid broken\n this is not an stl at all")
    with pytest.raises(InputError, match=r"vessel.yaml: hull_mesh"):
        load_vessel_spec(write_spec(tmp_path, "hull_mesh: hull.stl\n"))



def test_a_mesh_name_too_long_for_the_file_system_is_a_clear_error(tmp_path):
    """Found by the fuzzer (3 in 10,000 vessel files): pathlib's is_file() raises for a name
    over the file system's 255 bytes, a traceback outside the project's error type."""
    spec = tmp_path / "vessel.yaml"
    spec.write_text("name: x\nhull_mesh: " + "h" * 2000 + ".stl\n")
    with pytest.raises(InputError, match="cannot look for") as info:
        load_vessel_spec(spec)
    assert info.value.field == "hull_mesh"
    assert len(str(info.value)) < 400                   # the name is shortened in the message
    with pytest.raises(InputError, match="cannot look this file name up") as info:
        load_vessel_spec(tmp_path / ("v" * 3000 + ".yaml"))     # --vessel given such a name
    assert len(str(info.value)) < 400

def test_outline_height_above_the_mesh_is_an_error(tmp_path):
    trimesh.creation.box(extents=(20, 6, 4)).export(tmp_path / "b.stl")
    with pytest.raises(InputError, match=r"outline: the mesh does not reach 30 m"):
        load_vessel_spec(write_spec(tmp_path, "hull_mesh: b.stl\noutline: 30\n"))


def test_submerged_hull_does_not_hide_an_obstacle_beside_the_vessel():
    """The bundled tug (its mesh reaches 4 m under water) seen 60 m up from 40 m off its port
    side, camera tilted 20 deg toward it: a quay 0.5 m off the port waterline is measured at
    0.5 m, not pushed out by the projected bilge. The bilge at depth d, r from the nadir,
    would show d·r/(H + d) nearer the camera: about 1.5 m beyond the waterline here."""
    from importlib import resources

    import cv2

    from harborsight.clearance import ClearanceSettings, measure_clearance

    samples = Path(str(resources.files("harborsight") / "data" / "samples"))
    spec = load_vessel_spec(samples / "vessels" / "harbour-tug" / "vessel.yaml")
    assert spec.mesh.bounds[1, 2] > 3.0 and spec.hull_points[:, 2].max() <= 1e-9
    geometry, to_px = side_view(40.0, 60.0, 70.0, size=(640, 360), focal_px=454.66)

    port_y = spec.outline[:, 1].min()
    labels = np.zeros((360, 640), np.uint8)
    draw_vessel_as_seen(labels, spec.mesh, to_px)                       # what the image shows
    quay = np.array([[-5.0, port_y - 0.5, 0], [25.0, port_y - 0.5, 0],
                     [25.0, port_y - 15.5, 0], [-5.0, port_y - 15.5, 0]])
    cv2.fillPoly(labels, [to_px(quay)], 2, cv2.LINE_8, shift=4)
    report = measure_clearance(labels, geometry, spec, ClearanceSettings())
    assert report.min_distance_m == pytest.approx(0.5, abs=0.15)
    assert not any(s.contact for s in report.sections if s.status == "ok")


def _write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def test_a_mesh_with_non_finite_vertices_is_refused(tmp_path):
    """trimesh drops the faces of NaN vertices silently when it processes a mesh: the hull
    lost a corner and a 0.71 m clearance read 0.22 m (issue #30)."""
    box = trimesh.creation.box(extents=(20, 6, 5))
    vertices = box.vertices.copy()
    vertices[0] = (np.nan, 0.0, 0.0)
    _write_obj(tmp_path / "hull.obj", vertices, box.faces)
    path = write_spec(tmp_path, "hull_mesh: hull.obj\nmesh_axes: [bow, port, up]\n"
                      "gps_antenna: [0, 0, 0]\nsections: 4\n")
    with pytest.raises(InputError, match=r"hull_mesh: hull\.obj: 1 of 8 vertices are not finite"):
        load_vessel_spec(path)


def test_a_flat_line_of_a_mesh_is_refused(tmp_path):
    vertices = np.array([[0.0, 0, 0], [10.0, 0, 0], [20.0, 0, 0], [5.0, 0, 0]])
    _write_obj(tmp_path / "line.obj", vertices, np.array([[0, 1, 2], [0, 2, 3]]))
    path = write_spec(tmp_path, "hull_mesh: line.obj\nmesh_axes: [bow, port, up]\n"
                      "gps_antenna: [0, 0, 0]\nsections: 4\n")
    with pytest.raises(InputError, match=r"hull_mesh: line\.obj is degenerate"):
        load_vessel_spec(path)


def test_a_section_length_that_asks_for_millions_of_sections_is_refused(tmp_path):
    """0.000001 m on a 40 m hull asked for 80 million sections and ran out of memory."""
    path = write_spec(tmp_path, "dimensions: {to_bow: 30, to_stern: 10, to_port: 5, "
                      "to_starboard: 5}\nsection_length_m: 0.000001\n")
    with pytest.raises(InputError, match=r"section_length_m: .* more than 1000"):
        load_vessel_spec(path)
    path = write_spec(tmp_path, "dimensions: {to_bow: 30, to_stern: 10, to_port: 5, "
                      "to_starboard: 5}\nsections: 5000\n")
    with pytest.raises(InputError, match=r"sections: 5000 sections .* more than 1000"):
        load_vessel_spec(path)
    assert load_vessel_spec(write_spec(tmp_path, "dimensions: {to_bow: 30, to_stern: 10, "
                                       "to_port: 5, to_starboard: 5}\nsections: 1000\n"))


def test_a_mesh_whose_bow_end_is_the_blunter_one_is_noted(tmp_path):
    """A generated hull (pointed bow at +x, transom at -x) read with its axes right has no
    note; read with its x axis taken for aft, its full stern sits at +x and the spec says
    so, naming mesh_axes. A box (both ends alike) has none either way."""
    generate_hull_mesh().export(tmp_path / "hull.ply")
    right = load_vessel_spec(write_spec(tmp_path, "hull_mesh: hull.ply\nmesh_axes: [bow, port, up]\n"
                                        "gps_antenna: [20, 0, 9]\n"))
    assert right.notes == ()
    reversed_axes = load_vessel_spec(write_spec(
        tmp_path, "hull_mesh: hull.ply\nmesh_axes: [stern, starboard, up]\ngps_antenna: [20, 0, 9]\n"))
    assert len(reversed_axes.notes) == 1
    note = reversed_axes.notes[0]
    assert note.startswith("mesh_axes: ") and "is the bow at -x?" in note
    # the widths it quotes are the outline's own, 10 % in from each end (shapely)
    poly = Polygon(reversed_axes.outline)
    x_min, y_min, x_max, y_max = poly.bounds
    for x in (x_max - 0.1 * (x_max - x_min), x_min + 0.1 * (x_max - x_min)):
        across = poly.intersection(shapely.LineString([(x, y_min - 1), (x, y_max + 1)])).length
        assert f"{across:.1f} m" in note
    box = trimesh.creation.box(extents=(20, 6, 5))
    box.apply_translation((0, 0, 2.5))
    box.export(tmp_path / "box.stl")
    for axes in ("[bow, port, up]", "[stern, starboard, up]"):
        spec = load_vessel_spec(write_spec(tmp_path, f"hull_mesh: box.stl\nmesh_axes: {axes}\n"
                                           "gps_antenna: [5.0, 1.0, 4.0]\nwaterline_m: 2.0\n"))
        assert spec.notes == ()


def test_the_commands_say_a_spec_s_notes_once(tmp_path):
    """`measure` on two frames with a vessel whose bow looks aft says the note once, on
    standard error, naming the spec, and measures both frames."""
    import json
    import shutil
    from importlib import resources

    from typer.testing import CliRunner

    from harborsight.cli import app

    samples = Path(str(resources.files("harborsight") / "data" / "samples"))
    vessel_dir = tmp_path / "vessel"
    vessel_dir.mkdir()
    shutil.copy(samples / "vessels" / "harbour-tug" / "hull.stl", vessel_dir / "hull.stl")
    spec = vessel_dir / "vessel.yaml"
    spec.write_text("hull_mesh: hull.stl\nmesh_axes: [stern, starboard, up]\ngps_antenna: [12.0, 0.0, 9.0]\n")
    frames = tmp_path / "frames"
    frames.mkdir()
    for stem in ("000000", "000001"):
        shutil.copy(samples / "images" / f"{stem}.png", frames / f"{stem}.png")
        shutil.copy(samples / "frames" / f"{stem}.json", frames / f"{stem}.json")
    result = CliRunner().invoke(app, ["measure", str(frames), "--masks", str(samples / "labels"),
                                      "--vessel", str(spec), "--out", str(tmp_path / "out"), "--no-tables"])
    assert result.exit_code == 0, result.output
    assert result.stderr.count("is the bow at -x?") == 1
    assert f"note: {spec}: mesh_axes: " in result.stderr
    for stem in ("000000", "000001"):
        assert json.loads((tmp_path / "out" / f"{stem}.json").read_text())["sections"]


def test_a_hull_from_dimensions_says_how_far_it_may_be_off(tmp_path):
    """``outline_sigma_m`` is read where given (a mesh is taken as exact by default); a hull
    drawn from dimensions without it gets a note saying it is taken as exact."""
    dims = "dimensions: {to_bow: 10, to_stern: 5, to_port: 2, to_starboard: 3}\n"
    given = load_vessel_spec(write_spec(tmp_path, dims + "outline_sigma_m: 0.6\n"))
    assert given.outline_sigma_m == 0.6 and not given.notes
    bare = load_vessel_spec(write_spec(tmp_path, dims))
    assert bare.outline_sigma_m == 0.0
    assert len(bare.notes) == 1 and bare.notes[0].startswith("outline_sigma_m: not given")


def test_water_the_vessel_itself_hides_is_reported_and_a_band_hidden_in_full_is_not_clear():
    """A 20 x 8 m box 8 m tall, seen 30 m up from 22 m off its port side, 50 degrees off
    nadir: its starboard bands are hidden out to where the ray over the top starboard edge
    meets the water (9.45 m, by hand), and a buoy 1.5 m off that side is not in the picture.
    Those sections say so (``hidden_to_m``), and the live alarm does not count them as seen
    clear; the port side, facing the camera, hides nothing."""
    import cv2
    from shapely.geometry import Point

    from harborsight.clearance import ClearanceSettings, measure_clearance
    from harborsight.clearance.pose_refinement import PoseRefinementSettings
    from harborsight.vessel.outline import outline_from_dimensions
    from harborsight.vessel.spec import VesselSpec

    outline = outline_from_dimensions(10.0, 10.0, 4.0, 4.0, bow="box")
    hull_points = np.vstack((np.column_stack((outline, np.zeros(len(outline)))),
                             np.column_stack((outline, np.full(len(outline), -8.0)))))
    spec = VesselSpec("box", outline, hull_points, 12)
    geometry, to_px = side_view(22.0, 30.0, 50.0)

    labels = np.zeros((720, 1280), np.uint8)
    buoy = np.asarray(Point(0.0, 5.5).buffer(0.5).exterior.coords)[:-1]       # 1.5 m to starboard
    cv2.fillPoly(labels, [to_px(np.column_stack((buoy, np.zeros(len(buoy)))))], 2, cv2.LINE_8, shift=4)
    assert (labels == 2).sum() > 100
    cv2.fillConvexPoly(labels, cv2.convexHull(to_px(hull_points)), 1, cv2.LINE_8, shift=4)
    assert (labels == 2).sum() == 0                                  # the box hides it whole
    settings = ClearanceSettings(pose_refinement=PoseRefinementSettings(enabled=False))
    report = measure_clearance(labels, geometry, spec, settings)
    # the ray from the camera over the top starboard edge (4 m east, 8 m up) meets the water at
    # east = -22 + 30 / (30 - 8) * (4 + 22): 9.45 m beyond the side
    by_hand_m = -22.0 + 30.0 / 22.0 * 26.0 - 4.0
    sections = report.sections
    starboard = [s for s in sections if spec.sections().section_polyline(s.index)[:, 1].min() > 3.9]
    assert len(starboard) >= 2
    for s in starboard:
        assert s.status == "clear" and s.hidden_to_m == pytest.approx(by_hand_m, abs=0.15)
        assert s.to_dict()["hidden_to_m"] == pytest.approx(s.hidden_to_m, abs=1e-3)
    port = [s for s in sections if spec.sections().section_polyline(s.index)[:, 1].max() < -3.9]
    assert port and all(s.hidden_to_m is None for s in port)
