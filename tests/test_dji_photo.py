"""DJI still photos (issue #29): pose, intrinsics, accuracy and capture time from the XMP and
EXIF a DJI JPEG carries, through to frames and reports. Photos are written by ElementTree (the
XMP) and Pillow (JPEG, EXIF): see tests/dji_photos.py."""

from __future__ import annotations

import json
import math
import shutil
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np
import pytest
from pygeomag import GeoMag
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.telemetry.dji_photo import (
    capture_utc,
    photo_intrinsics,
    photo_track,
    read_dji_photo,
)
from tests.dji_photos import P4RTK_CALIBRATION, write_dji_photo
from tests.helpers import pixel_of_camera_block, torn_copies

runner = CliRunner()
FLIGHT = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples" / "flight"
GREY = np.full((48, 64, 3), 90, np.uint8)
POSE = {"GpsLatitude": "+56.151608098", "GpsLongitude": "+10.228217041",
        "AbsoluteAltitude": "+104.92", "RelativeAltitude": "+59.92",
        "GimbalYawDegree": "-30.33", "GimbalPitchDegree": "-87.57", "GimbalRollDegree": "-2.64",
        "FlightYawDegree": "-29.80", "FlightPitchDegree": "+1.20", "FlightRollDegree": "+0.30"}
LOCAL_TIME = {"DateTimeOriginal": "2026:05:01 14:00:05", "OffsetTimeOriginal": "+02:00"}


def _photo(tmp_path, xmp=None, name="DJI_0001.JPG", rgb=GREY, **options):
    return write_dji_photo(tmp_path / name, rgb, {**POSE, **(xmp or {})}, **options)


def test_dewarp_data_gives_the_intrinsics_scaled_to_a_resized_photo(tmp_path):
    # a Phantom 4 RTK calibration of its 5472x3648 photos, on a photo resized to 684x456
    photo = read_dji_photo(_photo(tmp_path, P4RTK_CALIBRATION, rgb=np.zeros((456, 684, 3), np.uint8)))
    intrinsics, how = photo_intrinsics(photo)
    assert "DewarpData" in how and "0.125" in how
    # DJI: camera matrix (fx, 0, W/2 + cx; 0, fy, H/2 + cy), pixel-corner origin
    assert intrinsics.fx == pytest.approx(3684.48 / 8)
    assert intrinsics.fy == pytest.approx(3677.57 / 8)
    assert intrinsics.cx == pytest.approx((2736 + 2.24) / 8 - 0.5)
    assert intrinsics.cy == pytest.approx((1824 + 22.05) / 8 - 0.5)
    assert intrinsics.distortion == pytest.approx(
        (-0.263482, 0.106788, 0.0000371107, -0.000327247, -0.0300783))
    # already undistorted in the camera: no distortion left
    undistorted = read_dji_photo(_photo(tmp_path, {**P4RTK_CALIBRATION, "DewarpFlag": "1"},
                                        name="b.jpg", rgb=np.zeros((456, 684, 3), np.uint8)))
    assert photo_intrinsics(undistorted)[0].distortion == (0.0,) * 5
    # another aspect than the calibration's: refused, naming the field
    cropped = read_dji_photo(_photo(tmp_path, P4RTK_CALIBRATION, name="c.jpg",
                                    rgb=np.zeros((400, 684, 3), np.uint8)))
    with pytest.raises(InputError, match=r"CalibratedOpticalCenterX.*aspect"):
        photo_intrinsics(cropped)


def test_intrinsics_from_the_models_sensor_and_the_35mm_equivalent(tmp_path):
    # Phantom 4 Pro, 4:3 photo (4864x3648 at full size) from its 3:2 1" sensor, 8.8 mm lens:
    # the photo spans the sensor's height; full-size fx = 8.8 / (13.2 / 5472) = 3648 px
    photo = read_dji_photo(_photo(tmp_path, model="FC6310", exif={"FocalLength": 8.8},
                                  rgb=np.zeros((456, 608, 3), np.uint8)))
    intrinsics, how = photo_intrinsics(photo)
    assert intrinsics.fx == pytest.approx(3648 / 8) and "height" in how
    assert (intrinsics.cx, intrinsics.cy) == (303.5, 227.5)
    # 16:9 photo: spans the sensor's width
    wide = read_dji_photo(_photo(tmp_path, model="FC6310", name="w.jpg", exif={"FocalLength": 8.8},
                                 rgb=np.zeros((342, 608, 3), np.uint8)))
    assert photo_intrinsics(wide)[0].fx == pytest.approx(8.8 / (13.2 / 608))
    # an unknown model: the 35 mm equivalent through the diagonal, 24 mm at 640x480
    other = read_dji_photo(_photo(tmp_path, model="FC9999", name="o.jpg",
                                  exif={"FocalLength": 4.5, "FocalLengthIn35mmFilm": 24},
                                  rgb=np.zeros((480, 640, 3), np.uint8)))
    assert photo_intrinsics(other)[0].fx == pytest.approx(24 * 800 / math.hypot(36, 24))
    # ... and a 16:9 photo of it crops that 4:3 sensor across its width: the same fx, where
    # the photo's own diagonal (734 px) read it 8.9 % short
    crop = read_dji_photo(_photo(tmp_path, model="FC9999", name="c.jpg",
                                 exif={"FocalLength": 4.5, "FocalLengthIn35mmFilm": 24},
                                 rgb=np.zeros((360, 640, 3), np.uint8)))
    intrinsics, how = photo_intrinsics(crop)
    assert intrinsics.fx == pytest.approx(24 * 800 / math.hypot(36, 24)) and "4:3 sensor" in how
    nothing = read_dji_photo(_photo(tmp_path, model="FC9999", name="n.jpg"))
    with pytest.raises(InputError, match="give --camera"):
        photo_intrinsics(nothing)


def test_tolerant_xmp_misspelt_longitude_elements_and_other_prefixes(tmp_path):
    fields = {**POSE, "RtkFlag": "50"}
    fields["GpsLongtitude"] = fields.pop("GpsLongitude")
    photo = read_dji_photo(write_dji_photo(tmp_path / "a.jpg", GREY, fields, prefix="dji",
                                           as_elements=("RtkFlag", "GimbalYawDegree")))
    assert photo.position_deg == pytest.approx((56.151608098, 10.228217041))
    assert photo.gimbal_deg == pytest.approx((-30.33, -87.57, -2.64))
    assert photo.rtk_flag == 50
    # no XMP at all: the position from EXIF's GPS block, and no attitude
    bare = read_dji_photo(write_dji_photo(tmp_path / "b.jpg", GREY, None,
                                          gps=(-33.8568, 151.2153)))
    assert bare.position_deg == pytest.approx((-33.8568, 151.2153), abs=1e-7)
    assert bare.gimbal_deg is None and any("EXIF alone" in n for n in bare.notes)
    with pytest.raises(InputError, match="RelativeAltitude: missing"):
        photo_track(bare)
    no_gimbal = read_dji_photo(write_dji_photo(tmp_path / "c.jpg", GREY, {
        k: v for k, v in POSE.items() if not k.startswith("Gimbal")}))
    with pytest.raises(InputError, match="GimbalYawDegree"):
        photo_track(no_gimbal)


def test_accuracy_from_the_rtk_fields(tmp_path):
    # RtkStdLat/Lon are one sigma per axis: the frame's per-axis figure is their RMS
    stated = read_dji_photo(_photo(tmp_path, {"RtkFlag": "50", "RtkStdLon": "0.01274",
                                              "RtkStdLat": "0.01122", "RtkStdHgt": "0.02394"}))
    assert stated.position_sigma_m()[0] == pytest.approx(math.sqrt((0.01274**2 + 0.01122**2) / 2))
    track = photo_track(stated, altitude="absolute")
    assert track.alt_m[0] == 104.92 and track.alt_sigma_m[0] == pytest.approx(0.02394)
    assert photo_track(stated).alt_sigma_m is None      # the barometric height: no RTK figure
    # a flag without figures: its class (RTK fixed 0.02 m DRMS; float 0.5 m)
    fixed = read_dji_photo(_photo(tmp_path, {"RtkFlag": "50"}, name="f.jpg"))
    assert fixed.position_sigma_m()[0] == pytest.approx(0.02 / math.sqrt(2))
    floating = read_dji_photo(_photo(tmp_path, {"RtkFlag": "34"}, name="g.jpg"))
    assert floating.position_sigma_m()[0] == pytest.approx(0.5 / math.sqrt(2))
    assert read_dji_photo(_photo(tmp_path, name="h.jpg")).position_sigma_m()[0] is None


def test_capture_time_clocks(tmp_path):
    local = read_dji_photo(_photo(tmp_path, exif=LOCAL_TIME))
    when, how = capture_utc(local, None)
    # a clock to the second truncates: the exposure lies in 14:00:05-06 local, its middle taken
    assert when == datetime(2026, 5, 1, 12, 0, 5, 500000, tzinfo=UTC) and "OffsetTimeOriginal" in how
    assert "to the second (its middle taken)" in how
    # the user's offset wins, with a note
    assert capture_utc(local, 3.0)[0] == datetime(2026, 5, 1, 11, 0, 5, 500000, tzinfo=UTC)
    assert any("overridden" in note for note in local.notes)
    # no zone: refused naming the field, unless the offset is given; sub-seconds kept
    zoneless = read_dji_photo(_photo(tmp_path, name="z.jpg", exif={
        "DateTimeOriginal": "2026:05:01 14:00:05", "SubSecTimeOriginal": "250"}))
    with pytest.raises(InputError, match=r"DateTimeOriginal.*--utc-offset-h"):
        capture_utc(zoneless, None)
    assert capture_utc(zoneless, 2)[0] == datetime(2026, 5, 1, 12, 0, 5, 250000, tzinfo=UTC)
    assert "to the second" not in capture_utc(zoneless, 2)[1]
    inline = read_dji_photo(_photo(tmp_path, name="i.jpg", exif={
        "DateTimeOriginal": "2026:05:01 14:00:05.75", "OffsetTimeOriginal": "+02:00"}))
    assert capture_utc(inline, None)[0] == datetime(2026, 5, 1, 12, 0, 5, 750000, tzinfo=UTC)
    # GPS time stamps are UTC and come before the local clock; UTCAtExposure before both
    gps = read_dji_photo(_photo(tmp_path, name="g.jpg", exif=LOCAL_TIME,
                                gps_time=("2026:05:01", (12, 0, 4.5))))
    assert capture_utc(gps, 5.0)[0] == datetime(2026, 5, 1, 12, 0, 4, 500000, tzinfo=UTC)
    exposure = read_dji_photo(_photo(tmp_path, {"UTCAtExposure": "2026:05:01 12:00:04.750000"},
                                     name="u.jpg", exif=LOCAL_TIME))
    assert capture_utc(exposure, None) == (datetime(2026, 5, 1, 12, 0, 4, 750000, tzinfo=UTC),
                                           "XMP UTCAtExposure (UTC)")


def test_a_magnetic_gimbal_yaw_gets_the_wmm_declination(tmp_path):
    photo = read_dji_photo(_photo(tmp_path, exif=LOCAL_TIME))
    when = capture_utc(photo, None)[0]
    true_yaw = photo_track(photo, when=when).yaw_deg[0]
    magnetic = photo_track(photo, yaw_reference="magnetic", when=when).yaw_deg[0]
    # pygeomag's WMM, called directly: 2026-05-01 is day 121 of 365
    expected = GeoMag(coefficients_file="wmm/WMM_2025.COF").calculate(
        glat=56.151608098, glon=10.228217041, alt=0, time=2026 + 120 / 365).d
    assert magnetic - true_yaw == pytest.approx(expected, abs=0.01)
    assert 3.0 < expected < 6.0           # Denmark, 2026: about 4.5 degrees east


def _utc(text: str) -> datetime:
    return datetime.fromisoformat(text.replace("Z", "+00:00"))


def _flight_photo(tmp_path: Path, index: int) -> Path:
    """Frame ``index`` of the bundled flight as a DJI photo: its pose in DJI's XMP with DJI's
    decimals, its intrinsics as DJI's calibrated values, its time as local time (CEST) in
    EXIF."""
    frame = json.loads((FLIGHT / "frames" / f"{index:06d}.json").read_text())
    rgb = cv2.imread(str(FLIGHT / "images" / frame["image"]))[:, :, ::-1]
    camera, attitude, uav = frame["camera"], frame["camera_attitude"], frame["uav"]
    stamp = datetime.fromisoformat(frame["timestamp"].replace("Z", "+00:00"))
    yaw = (attitude["yaw_deg"] + 180) % 360 - 180
    xmp = {"GpsLatitude": f"{uav['lat']:+.9f}", "GpsLongitude": f"{uav['lon']:+.9f}",
           "RelativeAltitude": f"{uav['alt_m']:+.2f}", "AbsoluteAltitude": f"{uav['alt_m'] + 45:+.2f}",
           "GimbalYawDegree": f"{yaw:+.2f}", "GimbalPitchDegree": f"{attitude['pitch_deg']:+.2f}",
           "GimbalRollDegree": f"{attitude['roll_deg']:+.2f}",
           "CalibratedFocalLength": f"{camera['fx']:.6f}",
           "CalibratedOpticalCenterX": f"{(camera['cx'] + 0.5):.6f}",
           "CalibratedOpticalCenterY": f"{(camera['cy'] + 0.5):.6f}"}
    exif = {"DateTimeOriginal": f"2026:05:01 {stamp.hour + 2:02d}:{stamp.minute:02d}:{stamp.second:02d}",
            "SubSecTimeOriginal": f"{stamp.microsecond // 1000:03d}", "OffsetTimeOriginal": "+02:00"}
    (tmp_path / "photos").mkdir(exist_ok=True)
    return write_dji_photo(tmp_path / "photos" / f"DJI_{index:04d}.JPG", rgb, xmp, model="L2D-20c",
                           exif=exif, quality=95)


def test_photos_of_the_bundled_flight_measure_as_its_frames(tmp_path):
    indices = (4, 16, 30)
    for index in indices:
        _flight_photo(tmp_path, index)
    (tmp_path / "photos" / "DJI_9999.JPG").write_bytes(b"\xff\xd8\xff\xe0 not a photo")
    masks = tmp_path / "masks"
    masks.mkdir()
    for index in indices:
        shutil.copy(FLIGHT / "labels" / f"{index:06d}.png", masks / f"DJI_{index:04d}.png")
    result = runner.invoke(app, ["telemetry", "photos", str(tmp_path / "photos"),
                                 "--vessel-track", str(FLIGHT / "logs" / "ship.nmea"),
                                 "--water-level-m", "0", "--out", str(tmp_path / "frames")])
    assert result.exit_code == 0, result.output
    assert "3 of 4 photo(s) written" in result.output
    assert "DJI_9999.JPG" in result.output                   # the bad one listed, the rest written
    for index in indices:
        written = json.loads((tmp_path / "frames" / f"DJI_{index:04d}.json").read_text())
        truth = json.loads((FLIGHT / "frames" / f"{index:06d}.json").read_text())
        assert written["image"] == f"../photos/DJI_{index:04d}.JPG"
        assert _utc(written["timestamp"]) == _utc(truth["timestamp"])
        for key in ("lat", "lon"):      # the ship's NMEA (2 Hz) at the photo's time: within 2 cm
            assert abs(written["vessel"][key] - truth["vessel"][key]) < 2e-7
        assert written["vessel"]["heading_deg"] == pytest.approx(truth["vessel"]["heading_deg"], abs=0.02)
        assert written["camera"]["cx"] == pytest.approx(truth["camera"]["cx"])
    result = runner.invoke(app, ["measure", str(tmp_path / "frames"), "--masks", str(masks),
                                 "--vessel", str(FLIGHT / "../vessels/harbour-tug/vessel.yaml"),
                                 "--out", str(tmp_path / "out"), "--no-refine-pose"])
    assert result.exit_code == 0, result.output
    errors = []
    for index in indices:
        report = json.loads((tmp_path / "out" / f"DJI_{index:04d}.json").read_text())
        truth = json.loads((FLIGHT / "frames" / f"{index:06d}.json").read_text())["ground_truth"]
        expected = {s["index"]: s["distance_m"] for s in truth["sections"]}
        errors += [abs(s["distance_m"] - expected[s["index"]]) for s in report["sections"]
                   if s["status"] == "ok" and expected.get(s["index"]) is not None]
    assert len(errors) >= 12
    assert np.median(errors) < 0.15 and max(errors) < 0.6


def test_telemetry_show_prints_a_photo(tmp_path):
    path = _photo(tmp_path, {**P4RTK_CALIBRATION, "RtkFlag": "16", "RtkStdLon": "1.36853",
                             "RtkStdLat": "1.49256"}, exif=LOCAL_TIME,
                  rgb=np.zeros((456, 684, 3), np.uint8))
    result = runner.invoke(app, ["telemetry", "show", str(path), "--json", str(tmp_path / "s.json")],
                           terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "DewarpData" in result.output and "2026-05-01T12:00:05.500000+00:00" in result.output
    summary = json.loads((tmp_path / "s.json").read_text())[0]
    assert summary["rtk_flag"] == 16 and summary["camera"]["fx"] == pytest.approx(460.56)
    (tmp_path / "x.jpg").write_bytes(b"GIF89a")
    result = runner.invoke(app, ["telemetry", "show", str(tmp_path / "x.jpg")])
    assert result.exit_code == 1 and "not a JPEG" in result.output


def test_a_torn_or_salted_photo_never_raises_and_keeps_what_came_before(tmp_path):
    whole = _photo(tmp_path, {**P4RTK_CALIBRATION, "RtkFlag": "50"}, exif=LOCAL_TIME,
                   rgb=np.random.default_rng(1).integers(0, 255, (120, 160, 3), np.uint8)).read_bytes()
    complete = read_dji_photo(tmp_path / "DJI_0001.JPG").xmp
    xmp_end = whole.find(b"<?xpacket end")
    for trial, cut, data in torn_copies(whole):
        path = tmp_path / "torn.jpg"
        path.write_bytes(data)
        try:
            photo = read_dji_photo(path)
            photo.summary()
        except InputError as exc:                   # a clear refusal, naming the file
            assert str(path) in str(exc)
            continue
        assert not photo.image_whole or trial % 2   # a cut JPEG is never taken as whole
        if trial % 2 == 0 and cut > xmp_end > 0:    # cut after the XMP: every field read
            assert photo.xmp == complete


def test_a_turned_photo_is_not_made_a_frame(tmp_path):
    """EXIF Orientation 3 (turned 180 degrees in an editor): OpenCV would decode it turned,
    the same size, and every distance would be measured in a mirrored scene."""
    from harborsight.telemetry.dji_photo import photo_frame
    from harborsight.telemetry.vessel_track import read_vessel_track

    path = _photo(tmp_path, {**P4RTK_CALIBRATION}, exif=LOCAL_TIME,
                  rgb=np.zeros((456, 684, 3), np.uint8))
    from PIL import Image

    with Image.open(path) as image:
        exif = image.getexif()
        exif[274] = 3
        image.save(tmp_path / "turned.jpg", exif=exif, xmp=image.info["xmp"], quality=92)
    photo = read_dji_photo(tmp_path / "turned.jpg")
    assert photo.orientation == 3
    with pytest.raises(InputError, match="Orientation 3"):
        photo_frame(photo, read_vessel_track(FLIGHT / "logs" / "ship.nmea"), image="turned.jpg",
                    water_level_m=0.0)


def test_a_digitally_zoomed_photo_gets_its_intrinsics_scaled(tmp_path):
    """EXIF DigitalZoomRatio 2: a centre crop of half the sensor, enlarged. The frame's
    intrinsics are the photo's own scaled by 2 about the image centre (a point projects
    where the unzoomed pixel lands once enlarged about the centre, by OpenCV), and the frame
    says so; a ratio of 0 (none used) changes nothing."""
    from harborsight.telemetry.dji_photo import photo_frame
    from harborsight.telemetry.vessel_track import read_vessel_track

    vessel = read_vessel_track(FLIGHT / "logs" / "ship.nmea")
    frames = {}
    for ratio in (0, 2):
        path = _photo(tmp_path, {**P4RTK_CALIBRATION, "UTCAtExposure": "2026:05:01 12:00:05.000"},
                      name=f"zoom{ratio}.jpg", rgb=np.zeros((456, 684, 3), np.uint8),
                      exif={**LOCAL_TIME, "DigitalZoomRatio": float(ratio)})
        frames[ratio] = photo_frame(read_dji_photo(path), vessel, image=path.name,
                                    water_level_m=0.0, max_gap_s=1e6)
    plain, zoomed = frames[0].frame, frames[2].frame
    assert plain is not None and zoomed is not None, (frames[0].reason, frames[2].reason)
    assert "digital_zoom" not in plain["telemetry"] and zoomed["telemetry"]["digital_zoom"] == 2.0
    assert any("digital zoom 2x" in note for note in frames[2].notes)
    def pixel(block: dict) -> np.ndarray:
        return pixel_of_camera_block(block, (1.5, -0.8, 20.0))

    centre = np.array([(684 - 1) / 2, (456 - 1) / 2])
    assert zoomed["camera"]["fx"] == pytest.approx(2 * plain["camera"]["fx"])
    assert pixel(zoomed["camera"]) == pytest.approx(centre + 2 * (pixel(plain["camera"]) - centre), abs=1e-6)


def test_a_given_lens_model_is_not_applied_to_a_photo_the_camera_undistorted(tmp_path):
    """DewarpFlag 1: the camera undistorted the photo. A --camera calibration of the raw lens
    (k1 -0.26) would bend its pixels a second time (a point 40 m from the nadir read 45.6 m,
    60 m up): its distortion is left out, with the reason."""
    from harborsight.telemetry.dji_photo import photo_frame
    from harborsight.telemetry.vessel_track import read_vessel_track

    path = _photo(tmp_path, {**P4RTK_CALIBRATION, "DewarpFlag": "1",
                             "UTCAtExposure": "2026:05:01 12:00:05.000"},
                  rgb=np.zeros((456, 684, 3), np.uint8), exif=LOCAL_TIME)
    camera = {"width": 684, "height": 456, "fx": 460.56, "fy": 459.7, "cx": 341.78, "cy": 230.26,
              "distortion": [-0.263482, 0.106788, 3.7e-05, -0.000327, -0.030078]}
    result = photo_frame(read_dji_photo(path), read_vessel_track(FLIGHT / "logs" / "ship.nmea"),
                         image=path.name, water_level_m=0.0, camera=camera, max_gap_s=1e6)
    assert result.frame is not None, result.reason
    assert result.frame["camera"]["distortion"] == [0.0] * 5
    assert result.frame["camera"]["fx"] == camera["fx"]
    assert "lens distortion left out" in result.frame["telemetry"]["camera_from"]


def test_a_six_coefficient_dewarp_model_not_read_is_said(tmp_path):
    """A Matrice 4 writes DewarpDataK6, which the reader does not take: the intrinsics come
    from CalibratedFocalLength without distortion, and how they were found says so."""
    fields = {k: v for k, v in P4RTK_CALIBRATION.items() if k != "DewarpData"}
    path = _photo(tmp_path, {**fields, "DewarpDataK6": "2024-01-01;3684.0,3677.0,2.2,22.0,"
                                                        "-0.26,0.1,0.0,0.0,-0.03,0.0,0.0,0.0"},
                  rgb=np.zeros((456, 684, 3), np.uint8))
    intrinsics, how = photo_intrinsics(read_dji_photo(path))
    assert intrinsics.distortion == (0.0,) * 5
    assert "DewarpDataK6" in how and "not read" in how


def test_a_phantom_4s_focal_length_agrees_with_its_35mm_equivalent(tmp_path):
    """FC330 (Phantom 4, 1/2.3", 4000 x 3000 pixels of 1.55 um): 3.61 mm over its 4:3 active
    area agrees with EXIF's 20 mm equivalent through the diagonal to 1 % (the nominal
    6.17 x 4.55 mm, not 4:3, read 3 % long)."""
    path = _photo(tmp_path, model="FC330", rgb=np.zeros((300, 400, 3), np.uint8),
                  exif={"FocalLength": 3.61, "FocalLengthIn35mmFilm": 20})
    intrinsics, how = photo_intrinsics(read_dji_photo(path))
    equivalent = 20 * math.hypot(400, 300) / math.hypot(36, 24)
    assert intrinsics.fx == pytest.approx(equivalent, rel=0.01) and "spans the sensor's width" in how


def test_an_rtk_altitude_type_names_the_ellipsoid(tmp_path):
    """AltitudeType RtkAlt (DJI's enterprise XMP): AbsoluteAltitude is the RTK receiver's
    ellipsoid height, and the track's altitude reference says so (a water level given above
    mean sea level would be off by the geoid's height)."""
    path = _photo(tmp_path, {"AltitudeType": "RtkAlt"})
    track = photo_track(read_dji_photo(path), altitude="absolute")
    assert "RtkAlt" in track.alt_reference and "ellipsoid" in track.alt_reference
    plain = photo_track(read_dji_photo(_photo(tmp_path, name="plain.jpg")), altitude="absolute")
    assert "mean sea level on most models" in plain.alt_reference


@pytest.mark.parametrize("flags", [{"CamReverse": "1"}, {"GimbalReverse": "1"},
                                   {"CamReverse": "true", "GimbalReverse": "0"}])
def test_a_camera_mounted_upside_down_is_not_made_a_frame(tmp_path, flags):
    """``CamReverse``/``GimbalReverse`` 1 (DJI's M3M and P1 XMP tables): a camera on a top
    gimbal port. The gimbal's angles are written as for an upright camera, and whether the
    photo was turned back to match them is not: every distance could be measured in a scene
    turned 180 degrees. Refused, naming the field; 0 changes nothing."""
    from harborsight.telemetry.dji_photo import photo_frame
    from harborsight.telemetry.vessel_track import read_vessel_track

    vessel = read_vessel_track(FLIGHT / "logs" / "ship.nmea")
    common = {**P4RTK_CALIBRATION, "UTCAtExposure": "2026:05:01 12:00:05.000"}
    plain = _photo(tmp_path, {**common, "CamReverse": "0", "GimbalReverse": "0"}, name="plain.jpg",
                   rgb=np.zeros((456, 684, 3), np.uint8), exif=LOCAL_TIME)
    made = photo_frame(read_dji_photo(plain), vessel, image="plain.jpg", water_level_m=0.0,
                       max_gap_s=1e6)
    assert made.frame is not None, made.reason
    turned = _photo(tmp_path, {**common, **flags}, name="turned.jpg",
                    rgb=np.zeros((456, 684, 3), np.uint8), exif=LOCAL_TIME)
    field = next(k for k, v in flags.items() if v != "0")
    with pytest.raises(InputError, match=f"{field}.*upside down"):
        photo_frame(read_dji_photo(turned), vessel, image="turned.jpg", water_level_m=0.0,
                    max_gap_s=1e6)


def test_a_camera_preset_spans_the_sensor_side_the_frame_fills():
    """A preset took fx from the frame's width whatever its shape: a Phantom 4 RTK 4:3 frame
    (4864x3648 from its 3:2 sensor) spans the sensor's height, and its fx is 8.8 / 8.8 x 3648 =
    3648 px, not 8.8 / 13.2 x 4864 = 3243 (distances 12.5 % long). 16:9 video spans the width."""
    from harborsight.sim.cameras import CAMERA_PRESETS

    p4rtk = CAMERA_PRESETS["dji-p4rtk"]
    assert p4rtk.intrinsics(4864, 3648).fx == pytest.approx(3648.0)
    assert p4rtk.intrinsics(1920, 1080).fx == pytest.approx(8.8 / 13.2 * 1920)
    assert p4rtk.intrinsics(5472, 3648).fx == pytest.approx(8.8 / 13.2 * 5472)    # the whole 3:2
    mavic3 = CAMERA_PRESETS["dji-mavic3"]
    assert mavic3.intrinsics(1920, 1080).fx == pytest.approx(12.29 / 17.3 * 1920)
    assert mavic3.intrinsics(1080, 1920).fx == pytest.approx(12.29 / 13.0 * 1920)  # portrait crop
