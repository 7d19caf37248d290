"""The bad-input matrix of issue #30: every kind of bad input, run through the command line in
a folder that also holds good frames, with the exit code the README documents, one line that
names the file and the field at fault, and the good frames beside it written.

Exit codes: a bad input to a whole command (``--vessel``, ``--camera``, ``--out``, one frame
given alone, a drone log that cannot be read) is 2 and nothing is written; a bad frame of a
folder or a bad line of a video's metadata is listed and skipped, the others are measured,
and the command exits 0 (1 only when every frame failed). The parsers' own tests
(``test_bad_input_parsers.py``, ``test_images.py``, ``test_vessel.py``, ``test_huge_numbers.py``)
check the messages in detail; this table checks that each reaches the user whole."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from harborsight.cli import app
from tests.test_bad_input_parsers import DEEP, GOOD_DIST, GOOD_MATRIX, HUGE, TOO_LONG, _filestorage, _srt
from tests.test_vessel import _write_obj

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
TUG = SAMPLES / "vessels" / "harbour-tug"
LOGS = SAMPLES / "flight" / "logs"
runner = CliRunner()


def _set_raw(path: Path, dotted: str, raw: str) -> None:
    """Put the JSON text ``raw`` at the key ``dotted`` of the frame file ``path``."""
    meta = json.loads(path.read_text())
    *parents, key = dotted.split(".")
    node = meta
    for parent in parents:
        node = node[parent]
    node[key] = "@@raw@@"
    path.write_text(json.dumps(meta).replace('"@@raw@@"', raw))


def _nan_mesh_vessel(folder: Path) -> Path:
    """A vessel.yaml whose hull mesh has a NaN vertex."""
    box = trimesh.creation.box(extents=(20, 6, 5))
    vertices = box.vertices.copy()
    vertices[0] = (np.nan, 0.0, 0.0)
    _write_obj(folder / "hull.obj", vertices, box.faces)
    path = folder / "nan-vessel.yaml"
    path.write_text("hull_mesh: hull.obj\nmesh_axes: [bow, port, up]\ngps_antenna: [0, 0, 0]\n")
    return path


def _binary_vessel(folder: Path) -> Path:
    path = folder / "binary-vessel.yaml"
    path.write_bytes(b"\xf1\xe8\xce\xea" + bytes(range(256)) * 4)
    return path


def _bad_calibration(folder: Path) -> Path:
    return _filestorage(folder, GOOD_MATRIX.replace("rows: 3", "rows: 4"), GOOD_DIST)


def _cut_jpeg(data: Path) -> str:
    """Frame 1's picture as a JPEG cut in half (libjpeg would fill the rest with grey)."""
    image = cv2.imread(str(data / "images" / "000001.png"))
    (data / "images" / "000001.png").unlink()
    encoded = cv2.imencode(".jpg", image)[1].tobytes()
    (data / "images" / "000001.jpg").write_bytes(encoded[: len(encoded) // 2])
    _set_raw(data / "frames" / "000001.json", "image", '"000001.jpg"')
    return "000001.jpg"


def _turned_jpeg(data: Path) -> str:
    """Frame 1's picture as a JPEG whose EXIF says it is stored turned by 180 degrees: the
    same size, so only the tag tells (OpenCV would turn it, and a 0.7 m contact read clear)."""
    from PIL import Image

    image = cv2.imread(str(data / "images" / "000001.png"))
    (data / "images" / "000001.png").unlink()
    exif = Image.Exif()
    exif[0x0112] = 3
    Image.fromarray(image[..., ::-1]).save(data / "images" / "000001.jpg", quality=95, exif=exif)
    _set_raw(data / "frames" / "000001.json", "image", '"000001.jpg"')
    return "000001.jpg"


def _vessel_spec_of_frame_2(make: Callable[[Path], Path]) -> Callable[[Path], str]:
    def breaking(data: Path) -> str:
        path = make(data)
        _set_raw(data / "frames" / "000002.json", "vessel_spec", json.dumps(str(path)))
        return path.name
    return breaking


def _calibration_of_frame_2(data: Path) -> str:
    path = _bad_calibration(data)
    _set_raw(data / "frames" / "000002.json", "camera", json.dumps({"calibration": str(path)}))
    return path.name


def _raw_in_frame_2(dotted: str, raw: str) -> Callable[[Path], str]:
    def breaking(data: Path) -> str:
        _set_raw(data / "frames" / "000002.json", dotted, raw)
        return "000002.json"
    return breaking


def _bytes_of_frame_2(content: bytes) -> Callable[[Path], str]:
    def breaking(data: Path) -> str:
        (data / "frames" / "000002.json").write_bytes(content)
        return "000002.json"
    return breaking


def _cut_mask(data: Path) -> str:
    mask = data / "labels" / "000003.png"
    mask.write_bytes(mask.read_bytes()[:300])
    return "000003.png"


def _far_vessel(data: Path) -> str:
    _set_raw(data / "frames" / "000002.json", "vessel.lat", "57.8")      # 180 km north
    return "000002.json"


@dataclass
class BatchCase:
    """One frame of the 5 sample frames broken by ``breaking`` (which returns the name of the
    file at fault); the error of the frame must name it and ``words``."""

    name: str
    breaking: Callable[[Path], str]
    words: tuple[str, ...]


BATCH = [
    BatchCase("cut JPEG", _cut_jpeg, ("cannot decode image", "JPEG")),
    BatchCase("JPEG stored turned (EXIF Orientation 3)", _turned_jpeg,
              ("Orientation", "stored turned")),
    BatchCase("cut PNG mask", _cut_mask, ("mask", "PNG cut short")),
    BatchCase("NaN hull mesh", _vessel_spec_of_frame_2(_nan_mesh_vessel),
              ("hull_mesh", "not finite")),
    BatchCase("binary vessel.yaml", _vessel_spec_of_frame_2(_binary_vessel),
              ("line 1", "not UTF-8")),
    BatchCase("malformed OpenCV calibration", _calibration_of_frame_2,
              ("camera_matrix", "3x3 matrix, got 4x3")),
    BatchCase("5000-digit whole number in a list", _raw_in_frame_2(
        "camera.distortion", f"[{TOO_LONG}, 0, 0, 0, 0]"), ("'distortion'", "5000 digits")),
    BatchCase("400-digit number", _raw_in_frame_2("uav.alt_m", HUGE), ("uav.alt_m", "finite")),
    BatchCase("JSON nested 100,000 deep", _bytes_of_frame_2(DEEP.encode()), ("nested too deep",)),
    BatchCase("Latin-1 byte in frame JSON", _bytes_of_frame_2(b'{"image": "caf\xe9.png"}'),
              ("not UTF-8", "0xe9")),
    BatchCase("vessel 180 km away", _far_vessel, ("vessel.lat", "km from the drone")),
    BatchCase("vessel_spec name too long to look up", _raw_in_frame_2(
        "vessel_spec", json.dumps("v" * 3000 + ".yaml")), ("vessel_spec", "file not found")),
]


@pytest.fixture
def samples(tmp_path) -> Path:
    data = tmp_path / "samples"
    shutil.copytree(SAMPLES, data, ignore=shutil.ignore_patterns("flight"))
    return data


@pytest.mark.parametrize("case", BATCH, ids=[c.name for c in BATCH])
@pytest.mark.parametrize("command", ["run", "measure"])
def test_a_bad_frame_in_a_folder_is_listed_and_the_others_are_written(samples, tmp_path, case,
                                                                      command):
    culprit = case.breaking(samples)
    out = tmp_path / "out"
    args = ([command, str(samples), "--masks", str(samples / "labels"), "--out", str(out)]
            + (["--no-video", "--no-overlays"] if command == "run" else ["--no-tables"]))
    result = runner.invoke(app, args, terminal_width=300)
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    named = [line for line in result.output.splitlines() if culprit in line
             and all(word in line for word in case.words)]
    assert len(named) == 1, result.output
    assert len(named[0]) < 400
    reports = out / "reports" if command == "run" else out
    assert len(list(reports.glob("*.json"))) == 4, result.output
    if command == "run":
        record = json.loads((out / "run.json").read_text())
        assert record["measured"] == 4 and len(record["skipped_frames"]) == 1


@dataclass
class WholeCase:
    """A bad input to a whole command: exit 2, one ``error:`` line naming ``culprit`` (a file
    name or an option) and ``words``, nothing written."""

    name: str
    args: Callable[[Path, Path], list[str]]     # (samples folder, out folder) -> arguments
    culprit: Callable[[Path], str]
    words: tuple[str, ...]


def _measure(*extra: str) -> Callable[[Path, Path], list[str]]:
    def args(data: Path, out: Path) -> list[str]:
        return ["measure", str(data), "--masks", str(data / "labels"), "--no-tables",
                "--out", str(out), *extra]
    return args


def _measure_with(option: str, make: Callable[[Path], Path]) -> Callable[[Path, Path], list[str]]:
    def args(data: Path, out: Path) -> list[str]:
        return _measure(option, str(make(data)))(data, out)
    return args


def _an_existing_file(data: Path) -> Path:
    path = data / "a-file"
    path.write_text("keep me")
    return path


def _absurd_vessel(data: Path) -> Path:
    path = data / "huge-vessel.yaml"
    path.write_text("dimensions: {to_bow: 1.0e+308, to_stern: 1.0e+308, to_port: 5, "
                    "to_starboard: 5}\n")
    return path


def _single_frame_5000_digits(data: Path, out: Path) -> list[str]:
    _set_raw(data / "frames" / "000000.json", "camera.distortion", f"[{TOO_LONG}, 0, 0, 0, 0]")
    return ["measure", str(data / "images" / "000000.png"), "--meta",
            str(data / "frames" / "000000.json"), "--mask", str(data / "labels" / "000000.png"),
            "--no-tables", "--out", str(out)]


def _single_frame_folder_as_mask(data: Path, out: Path) -> list[str]:
    return ["measure", str(data / "images" / "000000.png"), "--meta",
            str(data / "frames" / "000000.json"), "--mask", str(data / "labels"),
            "--no-tables", "--out", str(out)]


def _srt_in_year_9999(data: Path, out: Path) -> list[str]:
    srt = _srt(data, "9999-12-31 23:59:57")
    return ["telemetry", "video", str(srt), "--vessel-track", str(LOGS / "ship.nmea"), "--camera",
            "dji-mavic3", "--frames", "5", "--fps", "1", "--image-size", "640x360",
            "--utc-offset-h", "0", "--water-level-m", "0", "--out", str(out / "flight.jsonl")]


WHOLE = [
    WholeCase("binary vessel.yaml", _measure_with("--vessel", _binary_vessel),
              lambda d: "binary-vessel.yaml", ("line 1", "not UTF-8")),
    WholeCase("NaN hull mesh", _measure_with("--vessel", _nan_mesh_vessel),
              lambda d: "nan-vessel.yaml", ("hull_mesh", "not finite")),
    WholeCase("vessel of 1e308 m", _measure_with("--vessel", _absurd_vessel),
              lambda d: "huge-vessel.yaml", ("dimensions.to_bow", "beyond 1000")),
    WholeCase("malformed OpenCV calibration", _measure_with("--camera", _bad_calibration),
              lambda d: "calibration.yaml", ("camera_matrix", "4x3")),
    WholeCase("a folder as --vessel", _measure_with("--vessel", lambda d: d / "images"),
              lambda d: "images", ("is a folder, not a file",)),
    WholeCase("a folder as --camera", _measure_with("--camera", lambda d: d / "images"),
              lambda d: "images", ("is a folder, not a file",)),
    WholeCase("--out naming an existing file",
              lambda d, out: _measure()(d, _an_existing_file(d)),
              lambda d: "a-file", ("--out", "not a folder")),
    WholeCase("one frame with a 5000-digit number", _single_frame_5000_digits,
              lambda d: "000000.json", ("'distortion'", "5000 digits")),
    WholeCase("one frame with a folder as --mask", _single_frame_folder_as_mask,
              lambda d: "labels", ("mask", "is a folder, not a mask file")),
    WholeCase("SRT dates past the year 9999", _srt_in_year_9999,
              lambda d: "flight.srt", ("date", "after 9999")),
]


@pytest.mark.parametrize("case", WHOLE, ids=[c.name for c in WHOLE])
def test_a_bad_input_to_a_whole_command_is_one_line_and_exit_2(samples, tmp_path, case):
    out = tmp_path / "out"
    result = runner.invoke(app, case.args(samples, out), terminal_width=300)
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, result.output
    assert case.culprit(samples) in errors[0], errors[0]
    assert all(word in errors[0] for word in case.words), errors[0]
    assert not out.exists() or not any(out.rglob("*.json")), sorted(out.rglob("*"))
    if (samples / "a-file").exists():
        assert (samples / "a-file").read_text() == "keep me"


def test_a_folder_where_a_frame_image_is_expected_is_named(samples, tmp_path):
    image = samples / "images" / "000003.png"
    image.unlink()
    image.mkdir()
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(samples), "--masks", str(samples / "labels"),
                                 "--no-video", "--out", str(out)], terminal_width=300)
    assert result.exit_code == 0, result.output
    assert len(list((out / "reports").glob("*.json"))) == 4
    assert any(str(image) in line and "folder" in line for line in result.output.splitlines()), (
        result.output)


def test_bad_lines_of_a_videos_metadata_skip_those_frames_only(tmp_path):
    """A Latin-1 byte, a 5000-digit number and nesting 100,000 deep, each in one line of the
    bundled flight video's JSON lines: those three frames are listed, the other 45 measured
    (by the default model)."""
    lines = []
    for path in sorted((SAMPLES / "flight" / "frames").glob("*.json")):
        meta = json.loads(path.read_text())
        for key in ("image", "ground_truth", "simulation"):
            meta.pop(key, None)
        meta["vessel_spec"] = str(TUG / "vessel.yaml")
        lines.append(json.dumps(meta).encode())
    lines[1] = lines[1].replace(b'"schema"', b'"caf\xe9": 1, "schema"')
    lines[4] = lines[4].replace(b'"water_level_m": 0.0', b'"water_level_m": ' + TOO_LONG.encode())
    lines[7] = DEEP.encode()
    metadata = tmp_path / "flight.jsonl"
    metadata.write_bytes(b"\n".join(lines) + b"\n")
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(LOGS / "flight.mp4"), "--metadata", str(metadata),
                                 "--no-video", "--no-overlays", "--out", str(out)],
                           terminal_width=300)
    assert result.exit_code == 0, result.output
    record = json.loads((out / "run.json").read_text())
    assert record["measured"] == 45 and len(list((out / "reports").glob("*.json"))) == 45
    errors = {item["frame"]: item["error"] for item in record["skipped_frames"]}
    assert set(errors) == {1, 4, 7}
    assert errors[1].startswith(f"{metadata}:2: ") and "not UTF-8" in errors[1]
    assert errors[4].startswith(f"{metadata}:5: ") and "'water_level_m'" in errors[4]
    assert errors[7].startswith(f"{metadata}:8: ") and "nested too deep" in errors[7]
    for message in errors.values():
        assert sum(message in line for line in result.output.splitlines()) == 1


def test_a_torn_last_srt_block_is_left_out_with_a_note_and_the_rest_written(tmp_path):
    torn = tmp_path / "flight.SRT"
    torn.write_bytes((LOGS / "flight.SRT").read_bytes()[:-40])     # cut inside the last block
    out = tmp_path / "flight.jsonl"
    result = runner.invoke(app, ["telemetry", "video", str(torn), "--vessel-track",
                                 str(LOGS / "ship.nmea"), "--camera", "dji-mavic3", "--frames",
                                 "48", "--fps", "2", "--image-size", "640x360", "--video-start",
                                 "2026-05-01T12:00:00Z", "--water-level-m", "0", "--out", str(out)],
                           terminal_width=300)
    assert result.exit_code == 0, result.output
    notes = [line for line in result.output.splitlines() if str(torn) in line and "cut short" in line]
    assert len(notes) == 1, result.output
    assert len(out.read_text().splitlines()) == 47
