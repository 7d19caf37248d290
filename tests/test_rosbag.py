"""ROS 1 and ROS 2 bags (issue #29): topics found, the drone's track and the bag's images made
frames, through to reports; bags cut short or salted. Bags are written by rosbags' own writers
from the bundled flight (tests/ros_bags.py)."""

from __future__ import annotations

import json
import shutil
from datetime import datetime

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.telemetry import read_drone_log
from harborsight.telemetry.rosbag import choose_topics, ned_euler_deg, read_bag_track
from harborsight.telemetry.rosbag_io import open_bag
from tests.helpers import torn_copies
from tests.ros_bags import ELLIPSOID_OFFSET_M, FLIGHT, flight_frame, write_flight_bag

runner = CliRunner()
VESSEL = FLIGHT.parent / "vessels" / "harbour-tug" / "vessel.yaml"
KINDS = {"ros1": "flight.bag", "sqlite3": "flight-db3", "mcap": "flight-mcap"}


@pytest.mark.parametrize(("rotation", "expected"), [
    (Rotation.identity(), (90.0, 0.0, 0.0)),                            # nose east, level
    (Rotation.from_euler("z", 90, degrees=True), (0.0, 0.0, 0.0)),      # nose north
    # north, then +45 deg about the body's left axis: the nose goes down 45 deg (REP 103)
    (Rotation.from_euler("ZY", [90, 45], degrees=True), (0.0, -45.0, 0.0)),
    # north, then +30 deg about the forward axis: left side up, i.e. a roll to the right
    (Rotation.from_euler("ZX", [90, 30], degrees=True), (0.0, 0.0, 30.0)),
    (Rotation.from_euler("z", 180, degrees=True), (-90.0, 0.0, 0.0)),   # nose west
])
def test_enu_flu_orientations_become_ned_yaw_pitch_roll(rotation, expected):
    """Hand-worked cases of ROS's REP 103 convention against the frame's NED ZYX angles."""
    yaw, pitch, roll = ned_euler_deg(np.array([rotation.as_quat()]), "enu")[0]
    assert ((yaw + 180) % 360 - 180, pitch, roll) == pytest.approx(expected, abs=1e-9)
    # the same attitude stated in NED/FRD is read as it is
    ned = Rotation.from_euler("ZYX", expected, degrees=True)
    assert ned_euler_deg(np.array([ned.as_quat()]), "ned")[0] == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_bag_becomes_a_flight_that_measures_as_the_original(tmp_path, kind):
    indices = (6, 18, 30, 42)
    bag = write_flight_bag(tmp_path / KINDS[kind], kind, indices)
    reader = open_bag(bag)
    assert not reader.damaged
    topics = choose_topics(reader)
    assert (topics.image, topics.fix, topics.attitude, topics.attitude_of, topics.rel_alt) == (
        "/camera/image_raw/compressed", "/mavros/global_position/global", "/gimbal/attitude",
        "gimbal", "/mavros/global_position/rel_alt")
    out = tmp_path / "flight"
    result = runner.invoke(app, ["telemetry", "bag", str(bag), "--vessel-track",
                                 str(FLIGHT / "logs" / "ship.nmea"), "--water-level-m", "0",
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "4 of 4 image(s)" in result.output
    masks = tmp_path / "masks"
    masks.mkdir()
    for n, index in enumerate(indices):
        written = json.loads((out / "frames" / f"{n:06d}.json").read_text())
        truth = flight_frame(index)
        assert written["uav"]["lat"] == pytest.approx(truth["uav"]["lat"], abs=1e-8)
        assert written["uav"]["alt_m"] == pytest.approx(truth["uav"]["alt_m"], abs=1e-3)
        assert written["uav"]["position_sigma_m"] == pytest.approx(0.5)
        for key in ("yaw_deg", "pitch_deg", "roll_deg"):
            assert (written["camera_attitude"][key] - truth["camera_attitude"][key] + 180) % 360 \
                - 180 == pytest.approx(0, abs=1e-3)
        for key in ("lat", "lon"):      # the ship's NMEA at the image's stamp
            assert abs(written["vessel"][key] - truth["vessel"][key]) < 2e-7
        assert (out / "images" / written["image"]).read_bytes() == \
            (FLIGHT / "images" / truth["image"]).read_bytes()
        shutil.copy(FLIGHT / "labels" / f"{index:06d}.png", masks / f"{n:06d}.png")
    result = runner.invoke(app, ["measure", str(out), "--masks", str(masks), "--vessel",
                                 str(VESSEL), "--out", str(tmp_path / "reports"), "--no-tables"])
    assert result.exit_code == 0, result.output
    errors = []
    for n, index in enumerate(indices):
        report = json.loads((tmp_path / "reports" / f"{n:06d}.json").read_text())
        truth = {s["index"]: s["distance_m"] for s in flight_frame(index)["ground_truth"]["sections"]}
        errors += [abs(s["distance_m"] - truth[s["index"]]) for s in report["sections"]
                   if s["status"] == "ok" and truth.get(s["index"]) is not None]
    assert len(errors) >= 16 and np.median(errors) < 0.15 and max(errors) < 0.6


def test_the_airframe_topic_and_the_ellipsoid_altitude_when_asked(tmp_path):
    bag = write_flight_bag(tmp_path / "f.bag", "ros1", (0, 1, 2), with_images=False)
    reader = open_bag(bag)
    topics = choose_topics(reader, attitude="/mavros/imu/data", attitude_of="auto")
    assert topics.attitude_of == "vehicle"
    topics.rel_alt = None
    track = read_bag_track(bag, reader=reader, topics=topics)
    assert track.attitude_of == "vehicle" and "ellipsoid" in track.alt_reference
    assert track.alt_m[0] == pytest.approx(flight_frame(0)["uav"]["alt_m"] + ELLIPSOID_OFFSET_M)
    assert track.pitch_deg == pytest.approx([0, 0, 0], abs=1e-9)
    with pytest.raises(InputError, match="--fix-topic"):
        choose_topics(reader, fix="/mavros/imu/data")


def test_telemetry_show_lists_the_topics_and_video_reads_a_bag(tmp_path):
    bag = write_flight_bag(tmp_path / "bag2", "mcap", range(0, 12), with_images=False)
    result = runner.invoke(app, ["telemetry", "show", str(bag)], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "/gimbal/attitude" in result.output and "attitude (gimbal)" in result.output
    assert "take-off point" in result.output
    out = tmp_path / "frames.jsonl"
    result = runner.invoke(app, ["telemetry", "video", str(bag), "--vessel-track",
                                 str(FLIGHT / "logs" / "ship.nmea"), "--camera", "dji-mavic3",
                                 "--image-size", "640x360", "--frames", "10", "--fps", "2",
                                 "--video-start", "2026-05-01T12:00:00Z", "--water-level-m", "0",
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    frames = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(frames) == 10
    for frame in frames:
        truth = flight_frame(frame["frame_index"])
        assert frame["uav"]["lon"] == pytest.approx(truth["uav"]["lon"], abs=1e-8)
    lone = next(bag.glob("*.mcap"))       # the storage file, in its folder with metadata.yaml
    assert len(read_drone_log(lone)) == 12


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_torn_or_salted_bag_never_raises_and_keeps_what_came_before(tmp_path, kind):
    bag = write_flight_bag(tmp_path / KINDS[kind], kind, range(48), with_images=False)
    storage = bag if kind == "ros1" else next(p for p in bag.iterdir() if p.suffix != ".yaml")
    whole = storage.read_bytes()
    read_from_cut = []
    for trial, cut, data in torn_copies(whole):
        target = tmp_path / ("torn" + storage.suffix)      # a lone file: no metadata.yaml
        target.write_bytes(data)
        try:
            track = read_bag_track(target)
        except InputError as exc:
            assert str(target) in str(exc)
            continue
        assert np.all(np.abs(track.lat_deg) <= 90) and len(track) <= 48
        if trial % 2 == 0:
            read_from_cut.append((cut / len(whole), len(track)))
    # cut only: the fixes before the cut are read (ROS 1 and MCAP records, in a chunk cut
    # short too; the SQLite file's surviving pages), so a cut near the end loses few
    late = [n for fraction, n in read_from_cut if fraction > 0.9]
    assert late and min(late) >= 38
    early = [n for fraction, n in read_from_cut if fraction < 0.5]
    assert max(early, default=0) <= 30


def test_a_damaged_bag_too_large_to_read_whole_is_refused_with_the_repair(tmp_path, monkeypatch):
    from harborsight.telemetry import rosbag_io

    bag = write_flight_bag(tmp_path / "f.bag", "ros1", range(4), with_images=False)
    torn = tmp_path / "torn.bag"
    torn.write_bytes(bag.read_bytes()[:-200])
    monkeypatch.setattr(rosbag_io, "MAX_DAMAGED_BYTES", 1000)
    with pytest.raises(InputError, match="rosbag reindex"):
        open_bag(torn)


def test_a_rectified_image_topic_takes_p_and_no_distortion():
    """ROS's image_proc publishes ``image_rect`` undistorted, its intrinsics in CameraInfo's
    P; K and D describe the raw image. Distorting a rectified image again would move its
    edges by the lens's whole distortion."""
    from types import SimpleNamespace

    from harborsight.telemetry.rosbag import camera_from_info, is_rectified_topic

    info = SimpleNamespace(k=[500.0, 0, 320, 0, 500.0, 180, 0, 0, 1], d=[-0.2, 0.05, 0, 0, 0],
                           p=[480.0, 0, 318, 0, 0, 481.0, 178, 0, 0, 0, 1, 0],
                           distortion_model="plumb_bob", width=640, height=360)
    raw = camera_from_info(info)
    assert (raw["fx"], raw["cx"], raw["distortion"][0]) == (500.0, 320.0, -0.2)
    rect = camera_from_info(info, rectified=True)
    assert (rect["fx"], rect["fy"], rect["cx"], rect["cy"]) == (480.0, 481.0, 318.0, 178.0)
    assert not any(rect["distortion"])
    # image_proc rectifies a fisheye camera to a pinhole P too
    fisheye = SimpleNamespace(**{**vars(info), "distortion_model": "equidistant"})
    assert camera_from_info(fisheye, rectified=True)["fx"] == 480.0
    assert [is_rectified_topic(t) for t in ("/cam/image_rect", "/cam/image_rect_color/compressed",
                                            "/cam/image_raw", "/cam/image_raw/compressed",
                                            "image_rect")] == [True, True, False, False, True]



def test_a_dropout_of_the_height_topic_is_a_gap_not_a_straight_line(tmp_path):
    """MAVROS' rel_alt silent for 8 s while the fixes go on: the fixes in between have no
    height (the drone may have climbed or sunk), so frames there are skipped, with a note."""
    stamps = [datetime.fromisoformat(flight_frame(i)["timestamp"].replace("Z", "+00:00")).timestamp()
              for i in range(48)]
    silent = (stamps[10], stamps[26])          # 8 s at 2 Hz: frames 11-25 have no height

    def dropout(topic: str, seconds: float) -> bool:
        return topic.endswith("rel_alt") and silent[0] < seconds < silent[1]

    bag = write_flight_bag(tmp_path / "gap.bag", "ros1", range(48), with_images=False,
                           leave_out=dropout)
    track = read_bag_track(bag)
    assert np.isnan(track.alt_m[11:26]).all() and np.isfinite(track.alt_m[:11]).all()
    assert any("gaps (up to 8.0 s)" in note for note in track.notes)
    sampled = track.sample(track.t_s[[5, 18, 40]], max_gap_s=1.0)["alt_m"]
    assert np.isfinite(sampled[[0, 2]]).all() and np.isnan(sampled[1])
