"""Bad input: one-line errors naming the file and the field; batches skip only bad frames."""

import json
import shutil
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.frame import load_frame_metadata

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
runner = CliRunner()


@pytest.fixture
def dataset(tmp_path) -> Path:
    target = tmp_path / "flight"
    shutil.copytree(SAMPLES, target)
    return target


def edit_frame(path: Path, edit) -> None:
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


@pytest.mark.parametrize("edit, field, message", [
    (lambda d: d["uav"].pop("alt_m"), "uav.alt_m", "missing"),
    (lambda d: d["uav"].update(lat=91.0), "uav.lat", "outside"),
    (lambda d: d["uav"].update(lon=float("nan")), "uav.lon", "must be finite"),
    (lambda d: d["uav"].update(alt_m=-1.0), "uav.alt_m", "at or below water_level_m"),
    (lambda d: d["camera_attitude"].update(pitch_deg=40.0), "camera_attitude.pitch_deg", "horizon"),
    (lambda d: d["camera"].update(fx="wide"), "camera.fx", "expected a number"),
    (lambda d: d["camera"].update(distortion=[0.1, 0.2, 0.3]), "camera.distortion", "4, 5, 8"),
    (lambda d: d.pop("vessel"), "vessel", "missing"),
    (lambda d: d.update(schema="other/1"), "schema", "expected"),
    (lambda d: d["camera"].update(calibration=5), "camera.calibration", "calibration file path"),
    (lambda d: d["camera"].update(width=float("inf")), "camera.width", "whole number"),
    (lambda d: d["camera"].update(height=float("nan")), "camera.height", "whole number"),
    (lambda d: d.update(timestamp=1714564800), "timestamp", "ISO 8601"),
    (lambda d: d.update(timestamp="noon"), "timestamp", "ISO 8601"),
    (lambda d: d.update(sun={"elevation_deg": 95.0, "azimuth_deg": 10.0}), "sun.elevation_deg",
     "outside"),
    (lambda d: d.update(sun={"elevation_deg": 40.0}), "sun.azimuth_deg", "missing"),
    (lambda d: d.update(sun=[40.0, 10.0]), "sun", "expected an object"),
    # a 16:9 frame from the Mavic 3's 4:3 sensor: a crop, so fy would be 340 px, not 455
    (lambda d: d.update(camera={"width": 640, "height": 360, "sensor_width_mm": 17.3,
                                "sensor_height_mm": 13.0, "focal_length_mm": 12.29}),
     "camera.sensor_height_mm", r"differ in aspect.*fx = fy = 454\.7\)"),
])
def test_bad_metadata_names_file_and_field(dataset, edit, field, message):
    frame = dataset / "frames" / "000000.json"
    edit_frame(frame, edit)
    if field == "camera_attitude.pitch_deg":
        from harborsight.frame import FrameGeometry
        with pytest.raises(InputError, match=rf"000000.json: {field}: .*{message}"):
            FrameGeometry.from_metadata(load_frame_metadata(frame))
        return
    with pytest.raises(InputError, match=rf"000000.json: {field}: .*{message}") as info:
        load_frame_metadata(frame)
    assert "\n" not in str(info.value)


def test_unknown_keys_are_kept(dataset):
    frame = dataset / "frames" / "000000.json"
    edit_frame(frame, lambda d: d.update(pilot_note="slow ahead"))
    meta = load_frame_metadata(frame)
    assert meta.extra["pilot_note"] == "slow ahead"
    assert meta.to_dict()["pilot_note"] == "slow ahead"


def measure_args(dataset: Path, stem: str = "000000") -> list[str]:
    return ["measure", str(dataset / "images" / f"{stem}.png"),
            "--meta", str(dataset / "frames" / f"{stem}.json"),
            "--vessel", str(dataset / "vessels" / "harbour-tug" / "vessel.yaml"),
            "--mask", str(dataset / "labels" / f"{stem}.png"),
            "--out", str(dataset / "out"), "--no-tables"]


def test_single_frame_writes_report_and_overlay(dataset):
    result = runner.invoke(app, measure_args(dataset))
    assert result.exit_code == 0, result.output
    report = json.loads((dataset / "out" / "000000.json").read_text())
    assert report["schema"] == "harborsight.report/1"
    assert report["method"] == "ground_plane"
    assert {"index", "hull_px", "status", "distance_m", "distance_px", "hull_point_px",
            "obstacle_point_px", "hull_point_enu", "obstacle_point_enu"} <= set(report["sections"][0])
    ok = [s for s in report["sections"] if s["status"] == "ok"]
    assert report["min_distance_m"] == min(s["distance_m"] for s in ok)
    overlay = cv2.imread(str(dataset / "out" / "000000.png"))
    assert overlay.shape == (360, 640, 3)


def test_gsd_method_and_section_override(dataset):
    result = runner.invoke(app, [*measure_args(dataset), "--method", "gsd", "--sections", "6"])
    assert result.exit_code == 0, result.output
    report = json.loads((dataset / "out" / "000000.json").read_text())
    assert report["method"] == "gsd" and len(report["sections"]) == 6


@pytest.mark.parametrize("breakage, expected", [
    (lambda d: (d / "images" / "000000.png").unlink(), "000000.png: image file not found"),
    (lambda d: (d / "images" / "000000.png").write_bytes(b"\x89PNG broken"), "cannot decode image"),
    (lambda d: cv2.imwrite(str(d / "labels" / "000000.png"), np.zeros((10, 10), np.uint8)),
     "000000.png: mask: size 10x10 differs from camera 640x360"),
    (lambda d: cv2.imwrite(str(d / "labels" / "000000.png"), np.full((360, 640), 7, np.uint8)),
     "mask: unknown class values [7]"),
    (lambda d: (d / "vessels" / "harbour-tug" / "hull.stl").write_bytes(b"garbage"),
     "vessel.yaml: hull_mesh"),
    (lambda d: edit_frame(d / "frames" / "000000.json",
                          lambda f: f["vessel"].update(lat=f["vessel"]["lat"] + 0.01)),
     "000000.json: vessel: no part of the hull outline is in the image"),
    # issue #30: these gave "ok" sections (-14.6 m at 180 km; kilometres with absurd optics)
    (lambda d: edit_frame(d / "frames" / "000000.json",
                          lambda f: f["uav"].update(lat=f["uav"]["lat"] + 1.62)),
     "000000.json: vessel.lat: the vessel is 180.4 km from the drone"),
    (lambda d: edit_frame(d / "frames" / "000000.json", lambda f: f["uav"].update(alt_m=1e6)),
     "000000.json: uav.alt_m: 1000000 m above the water"),
    (lambda d: edit_frame(d / "frames" / "000000.json",
                          lambda f: f["camera"].update(fx=0.01, fy=0.01)),
     "000000.json: vessel: the hull spans 0.0 px in the image"),
])
def test_single_frame_errors_exit_nonzero_with_one_line(dataset, breakage, expected):
    breakage(dataset)
    result = runner.invoke(app, measure_args(dataset))
    assert result.exit_code == 2
    assert expected in result.output.replace("\n", " ")
    assert result.output.strip().count("\n") == 0 or "error:" in result.output


def test_batch_skips_bad_frames_and_writes_the_rest(dataset):
    edit_frame(dataset / "frames" / "000001.json", lambda d: d["uav"].update(alt_m=float("nan")))
    cv2.imwrite(str(dataset / "labels" / "000003.png"), np.full((360, 640), 9, np.uint8))
    (dataset / "images" / "000004.png").write_bytes(b"")
    out = dataset / "out"
    result = runner.invoke(app, ["measure", str(dataset), "--out", str(out), "--no-tables"])
    assert result.exit_code == 0, result.output
    written = sorted(p.name for p in out.glob("*.json"))
    assert written == ["000000.json", "000002.json"]
    assert (out / "000000.png").is_file() and (out / "000002.png").is_file()
    text = result.output.replace("\n", " ")
    assert "3 frame(s) skipped" in text
    assert "uav.alt_m: must be finite" in text
    assert "unknown class values [9]" in text
    assert "000004.png: cannot decode image" in text


def test_batch_outputs_are_named_like_the_frame_jsons(dataset):
    """Two frames whose JSONs name one image used to overwrite each other's report."""
    edit_frame(dataset / "frames" / "000001.json", lambda d: d.update(image="000000.png"))
    out = dataset / "out"
    result = runner.invoke(app, ["measure", str(dataset), "--out", str(out), "--no-tables"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.glob("*.json")) == [f"{k:06d}.json" for k in range(5)]


@pytest.mark.parametrize("extra, expected", [
    (["--masks", "labels"], "--masks is for folders"),
    (["--sections", "8", "--section-length-m", "2"], "give either --sections or"),
])
def test_options_that_would_be_ignored_are_refused(dataset, extra, expected):
    extra = [str(dataset / e) if e == "labels" else e for e in extra]
    result = runner.invoke(app, [*measure_args(dataset), *extra])
    assert result.exit_code == 2 and expected in result.output


def test_single_image_options_on_a_folder_are_refused(dataset):
    result = runner.invoke(app, ["measure", str(dataset), "--mask",
                                 str(dataset / "labels" / "000000.png")])
    assert result.exit_code == 2 and "--mask is for a single image" in result.output


def test_batch_of_only_bad_frames_fails(dataset):
    for frame in (dataset / "frames").glob("*.json"):
        edit_frame(frame, lambda d: d.pop("camera"))
    result = runner.invoke(app, ["measure", str(dataset), "--out", str(dataset / "out")])
    assert result.exit_code == 1
    assert "camera: missing" in result.output


def test_a_camera_from_its_sensor_has_square_pixels_as_a_datasheet_gives_them(dataset):
    """The DJI Mavic 3's 4/3" sensor (17.3 x 13.0 mm, 12.29 mm lens) at 640x481, its own
    aspect: fx = 12.29 / 17.3 * 640 = 454.66 px, fy = 12.29 / 13.0 * 481 = 454.73 px."""
    frame = dataset / "frames" / "000000.json"
    edit_frame(frame, lambda d: d.update(camera={"width": 640, "height": 481,
                                                 "sensor_width_mm": 17.3, "sensor_height_mm": 13.0,
                                                 "focal_length_mm": 12.29}))
    camera = load_frame_metadata(frame).camera
    assert camera.fx == pytest.approx(454.66, abs=0.01)
    assert camera.fy == pytest.approx(454.73, abs=0.01)
    assert (camera.cx, camera.cy) == (319.5, 240.0)


@pytest.mark.parametrize("extra, field", [
    ("fisheye_model: 1\n", "fisheye_model"),
    ('distortion_model: "equidistant"\n', "distortion_model"),
])
def test_a_fisheye_calibration_is_refused_not_read_as_a_pinhole(tmp_path, extra, field):
    """OpenCV's fisheye calibration has four coefficients, as k1, k2, p1, p2 have: read as
    the pinhole model, its edge rays would be 15-20 % off."""
    from harborsight.geometry.calibration_files import load_camera_calibration

    path = tmp_path / "fisheye.yaml"
    path.write_text("%YAML:1.0\n---\nimage_width: 640\nimage_height: 360\n" + extra
                    + "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
                    "   data: [ 300., 0., 319.5, 0., 300., 179.5, 0., 0., 1. ]\n"
                    "distortion_coefficients: !!opencv-matrix\n   rows: 4\n   cols: 1\n   dt: d\n"
                    "   data: [ 0.05, -0.01, 0.002, -0.0004 ]\n")
    with pytest.raises(InputError, match=rf"fisheye.yaml: {field}: "):
        load_camera_calibration(path)
    plain = tmp_path / "plain.yaml"
    plain.write_text(path.read_text().replace(extra, 'distortion_model: "plumb_bob"\n'))
    assert load_camera_calibration(plain).distortion == (0.05, -0.01, 0.002, -0.0004)


def test_camera_calibration_override(dataset, tmp_path):
    meta = json.loads((dataset / "frames" / "000000.json").read_text())["camera"]
    fs = cv2.FileStorage(str(tmp_path / "calib.yaml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 360)
    fs.write("camera_matrix", np.array([[meta["fx"], 0, meta["cx"]], [0, meta["fy"], meta["cy"]],
                                        [0, 0, 1.0]]))
    fs.write("distortion_coefficients", np.zeros((1, 5)))
    fs.release()
    result = runner.invoke(app, [*measure_args(dataset), "--camera", str(tmp_path / "calib.yaml")])
    assert result.exit_code == 0, result.output


def test_help_documents_every_option():
    result = runner.invoke(app, ["measure", "--help"], terminal_width=200)
    assert result.exit_code == 0
    for option in ("--meta", "--vessel", "--mask", "--masks", "--out", "--method", "--sections",
                   "--section-length-m", "--camera", "--pose-margin-px", "--own-rim-px",
                   "--tables"):
        assert option in result.output


def test_cli_defaults_match_the_measurement_settings():
    """The CLI keeps its own copy of the rim default (it starts without the measurement
    code); the two must not drift apart."""
    from harborsight import cli
    from harborsight.clearance.measure import ClearanceSettings

    assert ClearanceSettings().own_rim_px == cli.OWN_RIM_PX
    with pytest.raises(ValueError, match="own_rim_px"):
        ClearanceSettings(own_rim_px=-1)


def test_a_sections_option_asking_for_millions_of_sections_is_one_line(dataset):
    result = runner.invoke(app, [*measure_args(dataset), "--sections", "80000000"])
    assert result.exit_code == 2, result.output
    assert "--sections" in result.output and "more than 1000" in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
