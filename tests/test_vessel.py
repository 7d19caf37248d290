"""Vessel specs, outlines from meshes and AIS dimensions, and equal-length sections."""

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
    assert spec.hull_points[:, 2].max() == pytest.approx(2.0)   # 2 m draft


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
])
def test_bad_specs_name_the_field(tmp_path, text, field):
    with pytest.raises(InputError, match=rf"vessel.yaml: {field}"):
        load_vessel_spec(write_spec(tmp_path, text))


def test_corrupt_mesh_names_the_file(tmp_path):
    (tmp_path / "hull.stl").write_bytes(b"solid broken\n this is not an stl at all")
    with pytest.raises(InputError, match=r"vessel.yaml: hull_mesh"):
        load_vessel_spec(write_spec(tmp_path, "hull_mesh: hull.stl\n"))


def test_outline_height_above_the_mesh_is_an_error(tmp_path):
    trimesh.creation.box(extents=(20, 6, 4)).export(tmp_path / "b.stl")
    with pytest.raises(InputError, match=r"outline: the mesh does not reach 30 m"):
        load_vessel_spec(write_spec(tmp_path, "hull_mesh: b.stl\noutline: 30\n"))
