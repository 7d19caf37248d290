"""Huge or absurd numbers (issue #30): a vessel whose dimensions overflow or are larger than
any ship, and whole numbers of 5000 digits inside lists, are one InputError naming the field
or key, never a traceback or a silent result."""

import json
import shutil
from importlib import resources
from pathlib import Path

import pytest

from harborsight.errors import InputError
from harborsight.frame import load_frame_metadata
from harborsight.text_formats import parse_json_text
from harborsight.vessel.spec import load_vessel_spec

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
TOO_LONG = "1" + "0" * 4999
BOX = "dimensions: {to_bow: 30, to_stern: 10, to_port: 5, to_starboard: 5}\n"


def _spec(tmp_path: Path, text: str) -> Path:
    shutil.copy(SAMPLES / "vessels" / "harbour-tug" / "hull.stl", tmp_path / "hull.stl")
    path = tmp_path / "vessel.yaml"
    path.write_text(text)
    return path


def _refused(path: Path, field: str, words: str) -> str:
    with pytest.raises(InputError) as info:
        load_vessel_spec(path)
    text = str(info.value)
    assert "\n" not in text and len(text) < 300, text
    assert text.startswith(f"{path}: {field}: ") and words in text, text
    return text


@pytest.mark.parametrize("text, field, words", [
    ("dimensions: {to_bow: 1.0e+308, to_stern: 1.0e+308, to_port: 5, to_starboard: 5}\n",
     "dimensions.to_bow", "beyond 1000"),
    ("dimensions: {to_bow: 1e308, to_stern: 1e308, to_port: 5, to_starboard: 5}\n",
     "dimensions.to_bow", "beyond 1000"),             # YAML 1.2 number syntax, read as one
    ("dimensions: {to_bow: 10, to_stern: 10, to_port: 1.0e+30, to_starboard: 5}\n",
     "dimensions.to_port", "1e+30 is beyond 1000"),
    ("dimensions: {to_bow: 600, to_stern: 600, to_port: 5, to_starboard: 5}\n",
     "dimensions", "length (to_bow + to_stern) is 1200 m"),
    ("dimensions: {to_bow: 1.0e-300, to_stern: 0, to_port: 5, to_starboard: 5}\n",
     "dimensions", "length (to_bow + to_stern) is 1e-300 m"),
    (BOX + "air_draft_m: 1.0e+308\n", "air_draft_m", "beyond 1000"),
    (BOX + "section_length_m: 1.0e-308\n", "section_length_m", "more than 1000 sections"),
    (BOX + "section_length_m: 1.0e+308\n", "section_length_m", "beyond 10000"),
    ("hull_mesh: hull.stl\ngps_antenna: [1.0e+300, 0, 0]\n", "gps_antenna", "x: 1e+300 is beyond"),
    ("hull_mesh: hull.stl\ngps_antenna: [5000.0, 0, 0]\n", "gps_antenna", "from the antenna"),
    ("hull_mesh: hull.stl\nwaterline_m: 1.0e+300\n", "waterline_m", "beyond"),
    ("hull_mesh: [hull.stl]\n", "hull_mesh", "expected a mesh file name"),
    (f"hull_mesh: hull.stl\ngps_antenna: [{TOO_LONG}, 0, 0]\n", "gps_antenna", "5000 digits"),
    (f"hull_mesh: hull.stl\ngps_antenna:\n- 0\n- {TOO_LONG}\n- 0\n", "gps_antenna", "5000 digits"),
    (f"dimensions:\n  to_bow: {TOO_LONG}\n  to_stern: 1\n", "dimensions.to_bow", "5000 digits"),
], ids=["sum-inf", "sum-inf-yaml12", "beam-1e30", "length-1200", "length-tiny", "air-draft",
        "section-tiny", "section-huge", "antenna-1e300", "antenna-far", "waterline",
        "mesh-list", "antenna-digits", "antenna-block-digits", "dims-block-digits"])
def test_absurd_vessel_numbers_name_the_field(tmp_path, text, field, words):
    _refused(_spec(tmp_path, text), field, words)


def test_a_mesh_in_millimetres_is_refused(tmp_path):
    import trimesh

    path = _spec(tmp_path, "hull_mesh: hull.stl\n")
    mesh = trimesh.load(tmp_path / "hull.stl")
    mesh.apply_scale(1000.0)
    mesh.export(tmp_path / "hull.stl")
    _refused(path, "hull_mesh", "(a mesh in millimetres?)")


def test_sane_numbers_still_load(tmp_path):
    spec = load_vessel_spec(_spec(tmp_path, "dimensions: {to_bow: 3e2, to_stern: 1e2, to_port: 25, "
                                             "to_starboard: 25}\nair_draft_m: 60\n"))
    assert spec.length_m == pytest.approx(400.0) and spec.beam_m == pytest.approx(50.0)


@pytest.mark.parametrize("edit, words", [
    (lambda m: m["camera"].__setitem__("distortion", ["@"]),
     "'distortion' holds a whole number of 5000 digits (at camera.distortion[0];"),
    (lambda m: m.__setitem__("notes", {"list": [1, ["@"]]}),
     "'list' holds a whole number of 5000 digits (at notes.list[1][0];"),
    (lambda m: m["uav"].__setitem__("alt_m", "@"),
     "'alt_m' holds a whole number of 5000 digits (at uav.alt_m;"),
])
def test_a_5000_digit_number_in_frame_json_names_its_key(tmp_path, edit, words):
    meta = json.loads((SAMPLES / "frames" / "000000.json").read_text())
    edit(meta)
    path = tmp_path / "000000.json"
    path.write_text(json.dumps(meta).replace('"@"', TOO_LONG))
    with pytest.raises(InputError) as info:
        load_frame_metadata(path)
    text = str(info.value)
    assert text.startswith(f"{path}: not valid JSON: ") and words in text, text
    assert len(text) < 300


def test_a_5000_digit_number_at_the_top_of_a_list():
    with pytest.raises(InputError, match=r"x: not valid JSON: \[2\] is a whole number of 5000"):
        parse_json_text(f"[1, 2, {TOO_LONG}]", "x")
    with pytest.raises(InputError, match=r"x: not valid JSON: the value is a whole number of 5000"):
        parse_json_text(TOO_LONG, "x")
    assert parse_json_text('{"a": [1, 2]}', "x") == {"a": [1, 2]}
