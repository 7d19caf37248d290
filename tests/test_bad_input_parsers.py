"""Bad bytes, huge numbers, deep nesting and impossible dates in the parsers' inputs (issue #30):
each is one InputError naming the file and the field, never a traceback, and a bad frame or
metadata line is skipped without losing the others."""

import json
import shutil
from datetime import UTC, datetime
from importlib import resources
from pathlib import Path

import pytest
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.frame import FrameMetadata, load_frame_metadata

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
VESSEL_DIR = SAMPLES / "vessels" / "harbour-tug"
runner = CliRunner()

HUGE = "1" + "0" * 399          # 400 digits: past a float (OverflowError)
TOO_LONG = "1" + "0" * 4999     # 5000 digits: past Python's int parsing limit (ValueError)
DEEP = "[" * 100_000 + "]" * 100_000


def check_message(exc: InputError, source: Path | str, field: str | None) -> str:
    """One short line that starts with the file, then the field."""
    text = str(exc)
    assert "\n" not in text and len(text) < 300, text
    assert text.startswith(f"{source}: {field}:" if field else f"{source}: "), text
    return text


def frame_text(**replace: str) -> str:
    """The first sample frame's JSON with some values replaced by raw JSON text."""
    meta = json.loads((SAMPLES / "frames" / "000000.json").read_text())
    marks = {}
    for n, (dotted, _) in enumerate(replace.items()):
        *parents, key = dotted.split(".")
        node = meta
        for parent in parents:
            node = node[parent]
        node[key] = marks[dotted] = f"@@{n}@@"
    text = json.dumps(meta)
    for dotted, raw in replace.items():
        text = text.replace(json.dumps(marks[dotted]), raw)
    return text


# -- frame JSON -------------------------------------------------------------------------------

@pytest.mark.parametrize("dotted, field", [
    ("uav.alt_m", "uav.alt_m"),
    ("camera.fx", "camera.fx"),
    ("camera.width", "camera.width"),
    ("camera.distortion", "camera.distortion"),
])
def test_frame_number_of_400_digits_names_the_field(tmp_path, dotted, field):
    path = tmp_path / "000000.json"
    raw = f"[{HUGE}, 0, 0, 0, 0]" if dotted == "camera.distortion" else HUGE
    path.write_text(frame_text(**{dotted: raw}))
    with pytest.raises(InputError) as info:
        load_frame_metadata(path)
    check_message(info.value, path, field)
    assert HUGE not in str(info.value)


@pytest.mark.parametrize("text, words", [
    (frame_text(**{"uav.alt_m": TOO_LONG}), "'alt_m' holds a whole number of 5000 digits"),
    (DEEP, "nested too deep"),
    (b'{"image": "caf\xe9.png"}', "not UTF-8 text: byte 0xe9"),
])
def test_frame_json_python_cannot_read_names_the_file(tmp_path, text, words):
    path = tmp_path / "000000.json"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(InputError) as info:
        load_frame_metadata(path)
    message = check_message(info.value, path, None)
    assert f"{path}: not valid JSON: " in message and words in message


def test_meta_given_a_folder_says_so(tmp_path):
    result = runner.invoke(app, ["measure", str(SAMPLES / "images" / "000000.png"), "--meta",
                                 str(tmp_path), "--mask", str(SAMPLES / "labels" / "000000.png"),
                                 "--no-tables", "--out", str(tmp_path / "out")], terminal_width=200)
    assert result.exit_code == 2, result.output
    assert result.output.strip() == f"error: {tmp_path}: is a folder, not a file"


# -- JSON-lines metadata ----------------------------------------------------------------------

def _metadata_line(**replace: str) -> bytes:
    return frame_text(**replace).replace('"image": "000000.png", ', "").encode()


@pytest.mark.parametrize("bad, words", [
    (b'{"schema": "harborsight.frame/1", "image": "caf\xe9.png"}', "not UTF-8 text: byte 0xe9"),
    (_metadata_line(**{"uav.alt_m": TOO_LONG}), "'alt_m' holds a whole number of 5000 digits"),
    (DEEP.encode(), "nested too deep"),
    (_metadata_line(**{"uav.alt_m": HUGE}), "uav.alt_m: not a finite number"),
])
def test_one_bad_metadata_line_is_that_frame_only(tmp_path, bad, words):
    from harborsight.flight.sources import read_metadata_lines

    path = tmp_path / "flight.jsonl"
    good = _metadata_line()
    path.write_bytes(b"\n".join([good, bad, good]) + b"\n")
    by_frame, orphans, line_of, _ = read_metadata_lines(path, "flight")
    assert orphans == [] and line_of == {0: 1, 1: 2, 2: 3}
    assert isinstance(by_frame[0], FrameMetadata) and isinstance(by_frame[2], FrameMetadata)
    assert isinstance(by_frame[1], str)
    assert by_frame[1].startswith(f"{path}:2: ") and words in by_frame[1], by_frame[1]
    assert "\n" not in by_frame[1] and len(by_frame[1]) < 300


def test_a_frame_index_of_400_digits_is_refused_briefly(tmp_path):
    from harborsight.flight.sources import read_metadata_lines

    meta = json.loads(_metadata_line())
    path = tmp_path / "flight.jsonl"
    path.write_text(json.dumps({**meta, "frame_index": 0}) + "\n"
                    + json.dumps(meta)[:-1] + f', "frame_index": {HUGE}}}\n')
    by_frame, orphans, _, _ = read_metadata_lines(path, "flight")
    assert set(by_frame) == {0}
    [orphan] = orphans
    assert orphan.startswith(f"{path}:2: frame_index: expected a frame number from 0 to ")
    assert HUGE not in orphan and len(orphan) < 200


def test_a_folder_run_skips_only_the_frame_nested_too_deep(tmp_path):
    data = tmp_path / "flight"
    shutil.copytree(SAMPLES, data)
    (data / "frames" / "000002.json").write_text(DEEP)
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(data), "--masks", str(data / "labels"), "--no-video",
                                 "--no-overlays", "--out", str(out)], terminal_width=200)
    assert result.exit_code == 0, result.output
    record = json.loads((out / "run.json").read_text())
    assert record["measured"] == 4
    [skipped] = record["skipped_frames"]
    assert skipped["frame"] == 2
    assert skipped["error"] == (f"{data / 'frames' / '000002.json'}: not valid JSON: arrays or "
                                "objects nested too deep to read")


# -- vessel.yaml ------------------------------------------------------------------------------

def _vessel(tmp_path: Path, old: str | None = None, new: str = "") -> Path:
    shutil.copy(VESSEL_DIR / "hull.stl", tmp_path / "hull.stl")
    text = (VESSEL_DIR / "vessel.yaml").read_text()
    if old is not None:
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "vessel.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("old, new, field, words", [
    ("- 20.0", "- .nan", "gps_antenna", "x: expected a finite number of metres, got nan"),
    ("- 0.0", "- .inf", "gps_antenna", "y: expected a finite number of metres, got inf"),
    ("- 20.0", f"- {HUGE}", "gps_antenna", "x: expected a finite number of metres, got 1000"),
    ("- 20.0", f"- {TOO_LONG}", "gps_antenna", "5000 digits) on line 10: a whole number of more"),
    ("waterline_m: 0.0", "waterline_m: .nan", "waterline_m", "got nan"),
    ("waterline_m: 0.0", "waterline_m: abc", "waterline_m", "got 'abc'"),
    ("waterline_m: 0.0", "waterline_m: [1]", "waterline_m", "got [1]"),
    ("waterline_m: 0.0", f"waterline_m: {HUGE}", "waterline_m", "(a whole number of 400 digits)"),
    ("name: harbour-tug", "name: caf\xe9", "line 3", "not UTF-8 text (byte 0xe9)"),
])
def test_bad_vessel_values_name_the_field(tmp_path, old, new, field, words):
    path = _vessel(tmp_path, old, new)
    if "\xe9" in new:
        path.write_bytes(path.read_text().encode("latin-1"))
    from harborsight.vessel.spec import load_vessel_spec

    with pytest.raises(InputError) as info:
        load_vessel_spec(path)
    assert words in check_message(info.value, path, field)


@pytest.mark.parametrize("content, appended, words", [
    (b"\xf1\xe8\xce\xea" + bytes(range(256)) * 4, False, "line 1: not UTF-8 text (byte 0xf1)"),
    (("extra: " + DEEP + "\n").encode(), True, "not valid YAML: nested too deep"),
])
def test_vessel_yaml_that_cannot_be_read_names_the_file(tmp_path, content, appended, words):
    from harborsight.vessel.spec import load_vessel_spec

    path = _vessel(tmp_path)
    path.write_bytes((path.read_bytes() if appended else b"") + content)
    with pytest.raises(InputError) as info:
        load_vessel_spec(path)
    assert words in check_message(info.value, path, None)


def test_vessel_and_calibration_given_a_folder_say_so(tmp_path):
    from harborsight.geometry.calibration_files import load_camera_calibration
    from harborsight.vessel.spec import load_vessel_spec

    for load in (load_vessel_spec, load_camera_calibration):
        with pytest.raises(InputError) as info:
            load(tmp_path)
        assert "is a folder, not a file" in check_message(info.value, tmp_path, None)


# -- camera calibration -----------------------------------------------------------------------

GOOD_MATRIX = "rows: 3\n   cols: 3\n   dt: d\n   data: [ 454.66, 0., 319.5, 0., 454.66, 179.5, 0., 0., 1. ]"
GOOD_DIST = "rows: 1\n   cols: 5\n   dt: d\n   data: [ 0., 0., 0., 0., 0. ]"


def _filestorage(tmp_path: Path, matrix: str = GOOD_MATRIX, dist: str = GOOD_DIST,
                 width: str = "640") -> Path:
    path = tmp_path / "calibration.yaml"
    path.write_text(f"%YAML:1.0\n---\nimage_width: {width}\nimage_height: 360\n"
                    f"camera_matrix: !!opencv-matrix\n   {matrix}\n"
                    f"distortion_coefficients: !!opencv-matrix\n   {dist}\n")
    return path


@pytest.mark.parametrize("matrix, dist, field, words", [
    (GOOD_MATRIX.replace("rows: 3", "rows: 4"), GOOD_DIST, "camera_matrix", "3x3 matrix, got 4x3"),
    (GOOD_MATRIX.replace(", 0., 0., 1. ]", " ]"), GOOD_DIST, "camera_matrix.data",
     "expected 9 numbers (3x3), got 6"),
    (GOOD_MATRIX.replace("1. ]", "1., 7. ]"), GOOD_DIST, "camera_matrix.data", "got 10"),
    (GOOD_MATRIX.split("\n   data")[0], GOOD_DIST, "camera_matrix.data", "got nothing"),
    (GOOD_MATRIX.replace("dt: d", "dt: q"), GOOD_DIST, "camera_matrix.dt", "got 'q'"),
    (GOOD_MATRIX.replace("rows: 3", "rows: -3"), GOOD_DIST, "camera_matrix.rows", "got -3"),
    # OpenCV allocates 51 GB for this one, then fails
    (GOOD_MATRIX.replace("rows: 3", "rows: three"), GOOD_DIST, "camera_matrix.rows", "got 'three'"),
    (GOOD_MATRIX.replace("454.66, 0.,", "abc, 0.,"), GOOD_DIST, "camera_matrix.data",
     "element 1 is not a number: 'abc'"),
    (GOOD_MATRIX.replace("rows: 3", "rows: 3000000000"), GOOD_DIST, "camera_matrix.rows",
     "too large a whole number"),
    ("[ 454.66, 0., 319.5, 0., 454.66, 179.5, 0., 0., 1. ]", GOOD_DIST, "camera_matrix",
     "expected an opencv-matrix"),
    (GOOD_MATRIX, GOOD_DIST.replace("[ 0.,", "[ x,"), "distortion_coefficients.data",
     "element 1 is not a number: 'x'"),
], ids=["rows-4", "data-short", "data-long", "no-data", "dt-q", "rows-negative", "rows-three",
        "data-text", "rows-10-digits", "plain-sequence", "distortion-text"])
def test_malformed_opencv_matrix_names_the_field(tmp_path, matrix, dist, field, words):
    from harborsight.geometry.calibration_files import load_camera_calibration

    if matrix.startswith("["):      # a plain sequence, no !!opencv-matrix tag
        path = _filestorage(tmp_path)
        path.write_text(path.read_text().replace(
            "camera_matrix: !!opencv-matrix\n   " + GOOD_MATRIX, "camera_matrix: " + matrix))
    else:
        path = _filestorage(tmp_path, matrix, dist)
    with pytest.raises(InputError) as info:
        load_camera_calibration(path)
    assert words in check_message(info.value, path, field)


def test_opencv_yaml_syntax_error_names_the_file_and_line(tmp_path):
    """OpenCV's parser raises its error wrapped in a SystemError."""
    from harborsight.geometry.calibration_files import load_camera_calibration

    path = _filestorage(tmp_path, GOOD_MATRIX.replace("1. ]", "1.,]"))
    with pytest.raises(InputError) as info:
        load_camera_calibration(path)
    message = check_message(info.value, path, None)
    assert "OpenCV can read: line 9: Incorrect indentation" in message


def test_malformed_opencv_xml_matrix_names_the_field(tmp_path):
    from harborsight.geometry.calibration_files import load_camera_calibration

    path = tmp_path / "calibration.xml"
    path.write_text('<?xml version="1.0"?>\n<opencv_storage>\n<image_width>640</image_width>\n'
                    '<image_height>360</image_height>\n<camera_matrix type_id="opencv-matrix">\n'
                    "  <rows>4</rows>\n  <cols>3</cols>\n  <dt>d</dt>\n"
                    "  <data>454.66 0. 319.5 0. 454.66 179.5 0. 0. 1.</data></camera_matrix>\n"
                    "</opencv_storage>\n")
    with pytest.raises(InputError) as info:
        load_camera_calibration(path)
    assert "expected a 3x3 matrix, got 4x3" in check_message(info.value, path, "camera_matrix")


@pytest.mark.parametrize("width, words", [
    ("wide", "got 'wide'"),
    (HUGE, "(400 digits) on line 3 is too large"),
])
def test_opencv_image_width_is_checked_in_the_calibration(tmp_path, width, words):
    from harborsight.geometry.calibration_files import load_camera_calibration

    path = _filestorage(tmp_path, width=width)
    with pytest.raises(InputError) as info:
        load_camera_calibration(path)
    assert words in check_message(info.value, path, "image_width")


ROS = """image_width: {width}
image_height: 360
camera_name: x
camera_matrix:
  rows: 3
  cols: 3
  data: [{fx}, 0, 319.5, 0, 454.66, 179.5, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0, 0, 0, 0, 0]
"""


@pytest.mark.parametrize("width, fx, field, words", [
    ("640", HUGE, "camera_matrix.data", "too large to be finite"),
    (HUGE, "454.66", "image_width", "(a whole number of 400 digits)"),
    ("wide", "454.66", "image_width", "got 'wide'"),
    ("640", TOO_LONG, "camera_matrix.data", "5000 digits) on line 7: a whole number of more"),
])
def test_ros_camera_info_numbers_name_the_field(tmp_path, width, fx, field, words):
    from harborsight.geometry.calibration_files import load_camera_calibration

    path = tmp_path / "camera_info.yaml"
    path.write_text(ROS.format(width=width, fx=fx))
    with pytest.raises(InputError) as info:
        load_camera_calibration(path)
    assert words in check_message(info.value, path, field)


# -- dates ------------------------------------------------------------------------------------

def _srt(tmp_path: Path, first_date: str, blocks: int = 5) -> Path:
    """A DJI SRT (Air 2S style) of one block a second; ``first_date`` 'YYYY-MM-DD HH:MM:SS'."""
    day, clock = first_date.split()
    h, m, s = (int(v) for v in clock.split(":"))
    text = []
    for k in range(blocks):
        total = h * 3600 + m * 60 + s + k
        stamp = f"{day} {total // 3600:02d}:{total // 60 % 60:02d}:{total % 60:02d},500,000"
        text.append(f"{k + 1}\n00:00:{k:02d},000 --> 00:00:{k:02d},033\n"
                    f'<font size="36">SrtCnt : {k + 1}, DiffTime : 33ms\n{stamp}\n'
                    f"[iso : 100] [latitude: 41.42472{k}] [longitude: 2.234156] "
                    "[altitude: 117.000000] </font>\n")
    path = tmp_path / "flight.srt"
    path.write_text("\n".join(text))
    return path


@pytest.mark.parametrize("first_date, offset_h", [
    ("0001-01-01 00:00:10", 14.0),
    ("9999-12-31 23:59:40", -14.0),
    ("9999-12-31 23:59:57", 0.0),      # its last block is in the year 10000
])
def test_srt_dates_outside_the_years_1_to_9999_in_utc_are_refused(tmp_path, first_date, offset_h):
    from harborsight.telemetry.dji_srt import read_dji_srt

    path = _srt(tmp_path, first_date)
    with pytest.raises(InputError) as info:
        read_dji_srt(path, utc_offset_h=offset_h)
    assert "before the year 1 or after 9999" in check_message(info.value, path, "date")
    read_dji_srt(path)          # without an offset the local times are only shown


@pytest.mark.parametrize("given_start", [True, False])
def test_a_video_running_past_the_year_9999_is_refused(tmp_path, given_start):
    from harborsight.telemetry.dji_srt import read_dji_srt
    from harborsight.telemetry.metadata import build_video_metadata
    from harborsight.telemetry.track import Track

    srt = _srt(tmp_path, "9999-12-31 23:59:40" if not given_start else "2022-08-07 13:40:40")
    drone = read_dji_srt(srt, utc_offset_h=0.0)
    vessel = Track(source=tmp_path / "vessel.csv", kind="csv", t_s=[0.0, 1.0],
                   lat_deg=[41.4247, 41.4247], lon_deg=[2.2342, 2.2342], heading_deg=[90.0, 90.0],
                   utc_start=datetime(2022, 8, 7, 13, 40, tzinfo=UTC))
    start = datetime(9999, 12, 31, 23, 59, 59, tzinfo=UTC) if given_start else None
    with pytest.raises(InputError) as info:
        build_video_metadata(drone, vessel, {"width": 640}, 100, 0.5, water_level_m=0.0,
                             video_start_utc=start)
    text = str(info.value)
    assert "\n" not in text and "after the year 9999" in text
    assert text.startswith("--video-start: " if given_start else f"{srt}: date: ")


@pytest.mark.parametrize("text, expected", [
    ("2024-05-01T12:00:00Z", datetime(2024, 5, 1, 12, tzinfo=UTC)),
    ("2024-05-01T14:00:00+02:00", datetime(2024, 5, 1, 12, tzinfo=UTC)),
    ("2024-05-01 12:00", datetime(2024, 5, 1, 12, tzinfo=UTC)),
    ("9999-12-31T23:59:59-01:00", "is before the year 1 or after 9999 in UTC"),
    ("0001-01-01T00:00:00+01:00", "is before the year 1 or after 9999 in UTC"),
    ("noon", "not an ISO 8601 time: 'noon'"),
])
def test_parse_utc_time(text, expected):
    from harborsight.telemetry.metadata import parse_utc_time

    if isinstance(expected, datetime):
        assert parse_utc_time(text, "--video-start") == expected
        return
    with pytest.raises(InputError) as info:
        parse_utc_time(text, "--video-start")
    assert str(info.value).startswith("--video-start: ") and expected in str(info.value)
