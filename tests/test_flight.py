"""`harborsight run`: folders and videos, closing speeds, bad frames skipped."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import shutil
import types
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from harborsight.clearance.report import ClearanceReport, SectionClearance
from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.flight.sources import read_metadata_lines
from harborsight.flight.timeline import ClearanceTimeline, least_squares_slope
from tests.helpers import copy_sample_frames

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
runner = CliRunner()


def _report(distances: list[float | None], image: str = "x.png") -> ClearanceReport:
    sections = [SectionClearance(i, "ok" if d is not None else "clear", [[0, 0], [1, 1]], 1.0,
                                 distance_m=d, distance_px=None if d is None else d * 10)
                for i, d in enumerate(distances)]
    return ClearanceReport(image, None, 50.0, 0.1, "ground_plane", sections)


def test_least_squares_slope_by_hand():
    # points (0, 1), (1, 3), (2, 2): t̄ = 1, v̄ = 2, slope = (−1·−1 + 0 + 1·0) / 2 = 0.5
    assert least_squares_slope([0.0, 1.0, 2.0], [1.0, 3.0, 2.0]) == pytest.approx(0.5)


def test_closing_speed_and_time_to_contact_of_a_steady_approach():
    timeline = ClearanceTimeline(window_s=2.0, min_samples=3)
    speed = 0.4                      # section 0 closes at 0.4 m/s, section 1 opens at 0.1 m/s
    trends = {}
    for k in range(9):               # 2 Hz
        t = 0.5 * k
        trends, rows, warning = timeline.add(k, t, _report([10.0 - speed * t, 5.0 + 0.1 * t,
                                                            None]))
        assert warning is None
        assert len(rows) == 3
        if k < 2:
            assert trends[0].closing_speed_raw_mps is None
            assert trends[0].closing_speed_mps is None
    assert trends[0].closing_speed_raw_mps == pytest.approx(speed)
    assert trends[1].closing_speed_raw_mps == pytest.approx(-0.1)
    # the tracker's (filtered) speed and time to contact, from exact readings
    assert trends[0].closing_speed_mps == pytest.approx(speed, abs=0.02)
    assert trends[0].time_to_contact_s == pytest.approx((10.0 - speed * 4.0) / speed, rel=0.05)
    assert trends[1].closing_speed_mps == pytest.approx(-0.1, abs=0.02)
    assert trends[1].time_to_contact_s is None          # opening: no contact
    assert trends[2].closing_speed_mps is None          # never measured
    assert trends[2].closing_speed_raw_mps is None
    # the fit only spans the window: a speed change shows within window_s
    for k in range(9, 20):
        t = 0.5 * k
        trends, _, _ = timeline.add(k, t, _report([6.8 - 1.0 * (t - 4.0), 5.0, None]))
    assert trends[0].closing_speed_raw_mps == pytest.approx(1.0)
    assert trends[0].closing_speed_mps == pytest.approx(1.0, abs=0.1)
    # a frame before the previous one: measured (its rows), but no speed, and a warning
    trends, rows, warning = timeline.add(99, 1.0, _report([1.0, 1.0, 1.0]))
    assert len(rows) == 3 and trends[0].closing_speed_mps is None
    assert trends[0].closing_speed_raw_mps is None
    assert "1.000 s after the start is before the previous frame's 9.500 s" in warning


def _section_report(distance_m: float, truncated: bool = False) -> ClearanceReport:
    report = _report([distance_m])
    report.sections[0].truncated = truncated
    return report


def test_a_time_glitch_ahead_costs_only_its_own_frame():
    """Frame 3's GPS time is 30 min ahead: frames 4 and 5 are behind it (measured, no speed);
    at frame 6 three frames in a row agree, frame 3's time is dropped from the fits and the
    speeds come back, computed without it."""
    timeline = ClearanceTimeline(window_s=2.0, min_samples=3)
    times = [0.0, 0.5, 1.0, 1800.0, 2.0, 2.5, 3.0, 3.5]
    warnings, trends = [], {}
    for k, t in enumerate(times):
        trends, _, warning = timeline.add(k, t, _section_report(20.0 - 0.5 * min(t, 4.0)))
        warnings.append(warning)
    assert warnings[:4] == [None] * 4 and warnings[7] is None
    assert "before the previous frame's 1800.000 s" in warnings[4]
    assert "before the previous frame's 1800.000 s" in warnings[5]
    assert "the time of frame(s) 3 is taken as wrong" in warnings[6]
    assert trends[0].closing_speed_raw_mps == pytest.approx(0.5)
    assert timeline._off_clock_frames == {3}


def test_equal_times_are_in_order_and_truncated_distances_stay_out_of_the_fit():
    timeline = ClearanceTimeline(window_s=5.0, min_samples=3)
    for k, (t, d, cut) in enumerate([(0.0, 10.0, False), (1.0, 9.0, False), (1.0, 9.0, False),
                                     (2.0, 3.0, True), (3.0, 7.0, False)]):
        trends, _, warning = timeline.add(k, t, _section_report(d, cut))
        # whole-second stamps at 2 fps are in order; the first shared one is noted once
        assert warning is None if k != 2 else "coarser than the frames" in warning
        if cut:
            assert trends[0].closing_speed_raw_mps is None
            assert trends[0].estimate.state == "coasting"    # the tracker skips it too
    # fit over (0, 10), (1, 9), (1, 9), (3, 7): slope -1; the truncated 3.0 m would bend it
    assert trends[0].closing_speed_raw_mps == pytest.approx(1.0)


def test_a_frame_whose_pose_the_image_contradicts_stays_out_of_the_tracks():
    """Its distances were read with a pose known to be off (a quay 5 m away read 21 m):
    neither the closing-speed fit nor the tracker takes them; the frames around it do."""
    timeline = ClearanceTimeline(window_s=5.0, min_samples=3)
    for k, (t, d, contradicted) in enumerate([(0.0, 10.0, False), (1.0, 9.0, False),
                                              (2.0, 21.0, True), (3.0, 7.0, False)]):
        report = _report([d])
        report.pose_refinement = {"applied": False, "sensors_contradicted": contradicted}
        trends, _, _ = timeline.add(k, t, report)
        if contradicted:
            assert trends[0].closing_speed_raw_mps is None
            assert trends[0].estimate.state == "coasting"
    assert trends[0].closing_speed_raw_mps == pytest.approx(1.0)     # (0, 10), (1, 9), (3, 7)


def test_without_times_there_are_no_speeds():
    timeline = ClearanceTimeline()
    for k in range(5):
        trends, rows, _ = timeline.add(k, None, _report([3.0 - k * 0.1]))
    assert trends[0].closing_speed_mps is None and rows[0]["time_s"] is None


def _timed_copy_of_samples(root: Path, interval_s: float = 0.5) -> Path:
    data = root / "flight"
    shutil.copytree(SAMPLES, data)
    for k, path in enumerate(sorted((data / "frames").glob("*.json"))):
        meta = json.loads(path.read_text())
        meta["timestamp"] = f"2026-05-01T12:00:{k * interval_s:06.3f}Z"
        path.write_text(json.dumps(meta))
    return data


def _video_frame_count(path: Path) -> int:
    capture = cv2.VideoCapture(str(path))
    count = 0
    while capture.read()[0]:
        count += 1
    capture.release()
    return count


def test_run_on_a_folder_skips_bad_frames_and_keeps_the_rest(tmp_path):
    data = _timed_copy_of_samples(tmp_path)
    (data / "images" / "000001.png").write_bytes(b"not a png")        # unreadable image
    bad = json.loads((data / "frames" / "000003.json").read_text())
    bad["uav"]["alt_m"] = "high"                                      # bad field
    (data / "frames" / "000003.json").write_text(json.dumps(bad))
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(data), "--masks", str(data / "labels"),
                                 "--out", str(out)], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "3 of 5 frame(s) measured" in result.output
    record = json.loads((out / "run.json").read_text())
    assert record["schema"] == "harborsight.run/1" and record["measured"] == 3
    errors = {item["frame"]: item["error"] for item in record["skipped_frames"]}
    assert set(errors) == {1, 3}
    assert "000001.png" in errors[1] and "cannot decode" in errors[1]
    assert "000003.json" in errors[3] and "uav.alt_m" in errors[3]
    assert sorted(p.name for p in (out / "reports").iterdir()) == [
        "000000.json", "000002.json", "000004.json"]
    assert len(list((out / "overlays").glob("*.png"))) == 3
    rows = list(csv.DictReader((out / "sections.csv").open()))
    n_sections = len(json.loads((out / "reports" / "000000.json").read_text())["sections"])
    assert len(rows) == 3 * n_sections
    # the CSV says what the reports say
    report = json.loads((out / "reports" / "000002.json").read_text())
    for row in (r for r in rows if r["image"] == "000002.png"):
        section = report["sections"][int(row["section"])]
        assert row["status"] == section["status"]
        if section["distance_m"] is not None:
            assert float(row["distance_m"]) == pytest.approx(section["distance_m"], abs=1e-3)
    assert {r["time_s"] for r in rows} == {"0.0", "1.0", "2.0"}
    # the video keeps every frame in flight order: the unreadable one as a dark frame that
    # says why, so that the video keeps the flight's timing
    assert _video_frame_count(out / "annotated.mp4") == 5
    assert (out / "timeline.png").stat().st_size > 10_000


def _run_with_a_frame_edited(tmp_path: Path, edit, frame: str = "000002",
                             prepare=None) -> tuple:
    """`run` over the timed samples with ``frame``'s JSON changed by ``edit`` (after
    ``prepare(dataset folder)``, if given); (result, out)."""
    data = _timed_copy_of_samples(tmp_path)
    if prepare is not None:
        prepare(data)
    path = data / "frames" / f"{frame}.json"
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(data), "--masks", str(data / "labels"),
                                 "--out", str(out)], terminal_width=200)
    assert result.exit_code == 0, result.output
    return result, out


@pytest.mark.parametrize("edit, field", [
    (lambda m: m["camera"].update(calibration=5), "camera.calibration"),
    (lambda m: m["camera"].update(width=float("inf")), "camera.width"),
    (lambda m: m.update(vessel_spec=5), "vessel_spec"),
])
def test_run_skips_a_frame_whatever_its_field_holds(tmp_path, edit, field):
    """Fields of the wrong type (not only missing or out of range) skip that frame only:
    the run finishes and writes run.json, the timeline and the video."""
    _, out = _run_with_a_frame_edited(tmp_path, edit)
    record = json.loads((out / "run.json").read_text())
    assert record["measured"] == 4
    [skipped] = record["skipped_frames"]
    assert skipped["frame"] == 2
    assert f"000002.json: {field}:" in skipped["error"]
    assert (out / "timeline.png").is_file() and _video_frame_count(out / "annotated.mp4") == 5


def test_a_frame_without_a_time_is_measured_without_a_speed(tmp_path):
    """The run is timed by timestamps (its first frame has one); frame 2 has none. (A
    malformed timestamp is a malformed frame file: skipped with the field named.)"""
    result, out = _run_with_a_frame_edited(tmp_path, lambda meta: meta.pop("timestamp"))
    record = json.loads((out / "run.json").read_text())
    assert record["measured"] == 5 and record["skipped_frames"] == []
    [warning] = record["warnings"]
    assert warning["frame"] == 2 and "000002.json: timestamp:" in warning["warning"]
    assert "left out of the closing speeds" in warning["warning"]
    rows = [r for r in csv.DictReader((out / "sections.csv").open()) if r["frame"] == "2"]
    assert rows and all(r["time_s"] == "" and r["closing_speed_mps"] == "" for r in rows)
    assert "1 warning(s)" in result.output


def test_an_overlay_that_cannot_be_drawn_keeps_the_measurement(tmp_path, monkeypatch):
    import harborsight.flight.runner as flight_runner

    real = flight_runner.draw_overlay

    def failing(image, report, **kwargs):
        if report.image == "000003.png":
            raise RuntimeError("drawing failed")
        return real(image, report, **kwargs)

    monkeypatch.setattr(flight_runner, "draw_overlay", failing)
    data = _timed_copy_of_samples(tmp_path)
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(data), "--masks", str(data / "labels"),
                                 "--out", str(out)], terminal_width=200)
    assert result.exit_code == 0, result.output
    record = json.loads((out / "run.json").read_text())
    assert record["measured"] == 5 and len(list((out / "reports").iterdir())) == 5
    assert "overlay not drawn (RuntimeError: drawing failed)" in record["warnings"][0]["warning"]
    assert _video_frame_count(out / "annotated.mp4") == 5


def test_run_json_is_written_when_a_run_is_interrupted(tmp_path):
    from harborsight.flight import FolderSource, run_flight
    from harborsight.pipeline import VesselCache

    data = _timed_copy_of_samples(tmp_path)
    source = FolderSource(data, data / "labels")

    def stop_at_frame_2(frame):
        if frame.index == 2:
            raise KeyboardInterrupt

    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        run_flight(source.frames(), out, VesselCache(), None, on_frame=stop_at_frame_2)
    record = json.loads((out / "run.json").read_text())
    assert record["measured"] == 3 and (out / "timeline.png").is_file()
    assert (record["completed"], record["aborted"]) == (False, "KeyboardInterrupt")
    assert _video_frame_count(out / "annotated.mp4") == 3


def test_a_second_run_into_the_same_folder_leaves_only_its_own_outputs(tmp_path):
    data = _timed_copy_of_samples(tmp_path)
    out = tmp_path / "out"
    (out / "reports").mkdir(parents=True)
    (out / "reports" / "old-flight-000123.json").write_text("{}")
    (out / "notes.txt").write_text("the operator's own file")
    for frame in ("000003", "000004"):
        (data / "frames" / f"{frame}.json").unlink()
    result = runner.invoke(app, ["run", str(data), "--masks", str(data / "labels"),
                                 "--out", str(out), "--no-video"], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (out / "reports").iterdir()) == [
        "000000.json", "000001.json", "000002.json"]
    assert (out / "notes.txt").is_file()


def test_a_report_that_cannot_be_written_skips_only_its_frame(tmp_path):
    """Frame 1's image key is a valid string but no valid file name (too long): its report
    cannot be written, so it is skipped like a bad input, with nothing of it in the CSV; the
    frames after it are measured."""
    _, out = _run_with_a_frame_edited(tmp_path, lambda m: m.update(image="x" * 300 + ".png"),
                                      frame="000001")
    record = json.loads((out / "run.json").read_text())
    assert record["completed"] is True and record["measured"] == 4
    [skipped] = record["skipped_frames"]
    assert skipped["frame"] == 1 and "000001.json: image: its report" in skipped["error"]
    assert len(list((out / "reports").iterdir())) == 4
    assert not list((out / "reports").glob("*.part"))
    assert "1" not in {r["frame"] for r in csv.DictReader((out / "sections.csv").open())}
    assert _video_frame_count(out / "annotated.mp4") == 5


def test_a_video_that_cannot_be_written_is_a_warning(tmp_path, monkeypatch):
    """An OpenCV build whose mp4 writer will not open (no codec, a read-only medium): the run
    measures every frame without the video and says why."""
    import harborsight.flight.runner as runner_module

    class _RefusingWriter:
        def __init__(self, *args, **kwargs):
            pass

        def isOpened(self):
            return False

        def release(self):
            pass

    monkeypatch.setattr(runner_module.cv2, "VideoWriter", _RefusingWriter)
    data = _timed_copy_of_samples(tmp_path)
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(data), "--masks", str(data / "labels"),
                                 "--out", str(out)], terminal_width=200)
    assert result.exit_code == 0, result.output
    record = json.loads((out / "run.json").read_text())
    assert record["completed"] is True and record["measured"] == 5
    assert "video" not in record["outputs"] and not (out / "annotated.mp4").exists()
    assert any("no annotated video" in w["warning"] for w in record["warnings"])


def test_closing_speeds_when_the_first_frame_has_no_timestamp(tmp_path):
    """Before, the untimed first frame fixed the run's clock to "none": no speeds at all."""
    _, out = _run_with_a_frame_edited(tmp_path, lambda meta: meta.pop("timestamp"),
                                      frame="000000")
    rows = list(csv.DictReader((out / "sections.csv").open()))
    assert {r["time_s"] for r in rows if r["frame"] == "0"} == {""}
    assert {r["time_s"] for r in rows if r["frame"] != "0"} == {"0.0", "0.5", "1.0", "1.5"}
    # the samples are five different scenes: the window fit gives (meaningless) speeds, the
    # tracker sees each jump as a new obstacle, so the clock is checked on the raw speeds
    assert any(r["closing_speed_raw_mps"] for r in rows)


def test_a_skipped_frame_found_by_its_image_key_stays_in_the_video(tmp_path):
    """The image is named only by the (otherwise broken) frame JSON: the frame is skipped,
    but its picture keeps its place in the video."""
    def rename_image(data: Path) -> None:
        (data / "images" / "000002.png").rename(data / "images" / "cam_2.png")

    def edit(meta: dict) -> None:
        meta["image"] = "cam_2.png"
        del meta["uav"]["alt_m"]

    _, out = _run_with_a_frame_edited(tmp_path, edit, prepare=rename_image)
    record = json.loads((out / "run.json").read_text())
    assert record["measured"] == 4 and [s["frame"] for s in record["skipped_frames"]] == [2]
    assert _video_frame_count(out / "annotated.mp4") == 5


def test_implausible_container_frame_rates_are_ignored():
    from harborsight.flight.sources import plausible_fps

    assert plausible_fps(29.97) == 29.97 and plausible_fps(1000.0) == 1000.0
    assert [plausible_fps(v) for v in (0.0, float("nan"), 90000.0, None)] == [None] * 4


def test_image_size_mismatch_names_the_field_that_differs():
    from harborsight.frame import load_frame_metadata
    from harborsight.pipeline import check_image_size

    meta = load_frame_metadata(SAMPLES / "frames" / "000000.json")
    w, h = meta.camera.width, meta.camera.height
    with pytest.raises(InputError, match=r"f: camera\.height: "):
        check_image_size(np.zeros((h + 1, w, 3), np.uint8), meta, "f")
    with pytest.raises(InputError, match=r"f: camera\.width: "):
        check_image_size(np.zeros((h, w - 1, 3), np.uint8), meta, "f")


def test_frames_in_natural_order_and_dji_style_images(tmp_path):
    from harborsight.pipeline import discover_jobs, natural_key

    assert sorted(["frame_10", "frame_9", "frame_1", "Frame_2"], key=natural_key) == [
        "frame_1", "Frame_2", "frame_9", "frame_10"]
    data = tmp_path / "dji"
    for folder in ("frames", "images", "labels"):
        (data / folder).mkdir(parents=True)
    shutil.copytree(SAMPLES / "vessels", data / "vessels")
    for k, name in enumerate(["DJI_0009", "DJI_0010", "DJI_0100"]):
        meta = json.loads((SAMPLES / "frames" / f"00000{k}.json").read_text())
        meta["image"] = f"{name}.JPG"
        (data / "frames" / f"{name}.json").write_text(json.dumps(meta))
        (data / "images" / f"{name}.JPG").write_bytes(       # decoded by content, not suffix
            (SAMPLES / "images" / f"00000{k}.png").read_bytes())
        shutil.copy(SAMPLES / "labels" / f"00000{k}.png", data / "labels" / f"{name}.png")
    jobs = discover_jobs(data, data / "labels")
    assert [j.stem for j in jobs] == ["DJI_0009", "DJI_0010", "DJI_0100"]
    assert [j.image_path.name for j in jobs] == ["DJI_0009.JPG", "DJI_0010.JPG", "DJI_0100.JPG"]
    # an image the JSON names, not named like the JSON: found in images/
    (data / "frames" / "DJI_0100.json").rename(data / "frames" / "flight_0100.json")
    (data / "labels" / "DJI_0100.png").rename(data / "labels" / "flight_0100.png")
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(data), "--masks", str(data / "labels"),
                                 "--out", str(out)], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert json.loads((out / "run.json").read_text())["measured"] == 3


def test_frames_naming_one_image_do_not_overwrite_each_other(tmp_path):
    data = _timed_copy_of_samples(tmp_path)
    for path in sorted((data / "frames").glob("*.json"))[:3]:
        meta = json.loads(path.read_text())
        meta["image"] = "flight.png"      # every frame names one picture (found by its stem)
        path.write_text(json.dumps(meta))
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(data), "--masks", str(data / "labels"),
                                 "--out", str(out)], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (out / "reports").iterdir()) == [
        "000003.json", "000004.json", "flight-000001.json", "flight-000002.json", "flight.json"]


def _write_timed_video(path: Path, times_s: list[float], size=(64, 36)) -> None:
    """An H.264 MP4 (PyAV) whose frames are shown at ``times_s``, each frame k a grey level
    of 8 k with a white block in its top-left corner (the stored picture's own corner)."""
    from fractions import Fraction

    import av

    base = Fraction(1, 90000)
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = size[0], size[1], "yuv420p"
        stream.time_base = stream.codec_context.time_base = base
        stream.options = {"bf": "0"}
        for k, t in enumerate(times_s):
            picture = np.full((size[1], size[0], 3), 8 * k, np.uint8)
            picture[:8, :8] = 255
            frame = av.VideoFrame.from_ndarray(picture, format="bgr24")
            frame.pts, frame.time_base = round(t / base), base
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)


def _turn_video(path: Path, size=(64, 36)) -> None:
    """Set the MP4 track header's display matrix to a 180 degree turn, as a phone held upside
    down writes it (tkhd: version, flags, then 20 or 32 bytes of times and ids, 16 of
    layer, group and volume, then the 3x3 matrix in 16.16 and 2.30 fixed point)."""
    import struct

    data = bytearray(path.read_bytes())
    tkhd = data.find(b"tkhd")
    matrix_at = tkhd + 8 + (20 if data[tkhd + 4] == 0 else 32) + 16
    one = 1 << 16
    data[matrix_at:matrix_at + 36] = struct.pack(">9i", -one, 0, 0, 0, -one, 0, size[0] * one,
                                                 size[1] * one, 1 << 30)
    path.write_bytes(bytes(data))


def _one_metadata_line(path: Path) -> None:
    """A metadata file with one line (the bundled flight's first frame, for video frame 0)."""
    record = json.loads((SAMPLES / "flight" / "frames" / "000000.json").read_text())
    path.write_text(json.dumps({**record, "frame_index": 0}) + "\n")


def test_a_video_its_container_turns_is_read_as_stored(tmp_path):
    """A container asking players to turn the picture (a phone video held upside down: 180
    degrees) is read with OpenCV's auto-rotation off: the frames are the camera's pixels as
    stored, which the metadata describes (the white block stays top-left), and the run
    records the rotation asked for. It was refused as if OpenCV turned the frames."""
    from harborsight.flight import sources

    video = tmp_path / "flight.mp4"
    _write_timed_video(video, [k / 30 for k in range(3)])
    _turn_video(video)
    _one_metadata_line(tmp_path / "flight.jsonl")
    capture = cv2.VideoCapture(str(video))
    assert sources.video_rotation_deg(capture) == 180.0
    capture.release()
    source = sources.VideoSource(video, tmp_path / "flight.jsonl")
    frames = [f for f in source.frames() if f.is_frame]
    assert source.rotation_deg == 180.0 and len(frames) == 3
    for frame in frames:
        assert frame.image.shape == (36, 64, 3)
        assert frame.image[:8, :8].mean() > 240 and frame.image[-8:, -8:].mean() < 40
    real = cv2.VideoCapture(str(SAMPLES / "flight" / "logs" / "flight.mp4"))
    assert sources.video_rotation_deg(real) == 0.0          # the bundled flight has none


def test_a_video_frame_s_time_is_its_presentation_time_not_its_index_over_the_mean_rate(tmp_path):
    """A variable-frame-rate video (15 frames at 30 fps, then 15 at 10 fps, as a phone or a
    drone in low light records): the container's mean rate is 15 fps, and frame 14 shown at
    0.467 s was taken as 0.933 s. Each frame's time is now its presentation time, in `run`
    and in the frame times `telemetry video` pairs with the logs."""
    from harborsight.flight import sources

    times = [k / 30 for k in range(15)] + [14 / 30 + (k + 1) / 10 for k in range(15)]
    video = tmp_path / "vfr.mp4"
    _write_timed_video(video, times)
    _one_metadata_line(tmp_path / "vfr.jsonl")
    source = sources.VideoSource(video, tmp_path / "vfr.jsonl")
    read = [f.video_time_s for f in source.frames() if f.is_frame]
    np.testing.assert_allclose(read, times, atol=1e-3)
    np.testing.assert_allclose(sources.video_frame_times_s(video), times, atol=1e-3)
    assert abs(14 / source.container_fps - times[14]) > 0.4       # what the index gave


def test_overlay_labels_do_not_cover_each_other(monkeypatch):
    """Labels that would stack (neighbouring sections, a long ``>14.7m``) move outward, then
    sideways; the banner keeps its line. Measured by the labels' black boxes: each label is
    drawn in a box of its own."""
    from harborsight.viz import overlay

    image = np.full((360, 640, 3), 90, np.uint8)
    drawn = []
    real_rectangle = overlay.cv2.rectangle

    def spy(img, p0, p1, colour, thickness, *args):
        if colour == overlay.BLACK and thickness == -1:
            drawn.append((*p0, *p1))
        return real_rectangle(img, p0, p1, colour, thickness, *args)

    anchor, outward = np.array([320.0, 30.0]), np.array([0.0, 1.0])
    labels = [(f"{k}.0+-0.1m", anchor, outward, overlay.WHITE) for k in range(5)]
    monkeypatch.setattr(overlay.cv2, "rectangle", spy)
    overlay._place_labels(image, labels, 0.4, [(0, 0, 640, 22)])
    assert len(drawn) == 5
    for i, box in enumerate(drawn):
        assert box[1] >= 22                                  # below the banner
        assert not overlay._overlaps(box, drawn[:i])


def test_overlay_of_a_point_projected_far_out_of_the_image():
    from harborsight.viz.overlay import draw_overlay

    report = _report([3.0, 4.0])
    report.sections[0].hull_px = [[3e8, 100.0], [300.0, 100.0]]   # just in front of the camera
    report.sections[0].hull_point_px, report.sections[0].obstacle_point_px = [3e8, 100.0], [5, 5]
    report.sections[1].hull_point_px, report.sections[1].obstacle_point_px = [1, 1], [9, 9]
    image = np.zeros((360, 640, 3), np.uint8)
    out = draw_overlay(image, report)
    assert out.shape == image.shape and out[100, 320:639].any()     # the visible part is drawn


def test_overlay_of_a_measured_section_with_one_end_behind_the_camera():
    """An oblique camera can see a section's hull point while one of its ends lies behind
    the camera (NaN pixels): its measurement is still drawn and labelled, at the hull point."""
    from harborsight.viz.overlay import YELLOW, draw_overlay

    report = _report([3.0, 30.0])
    section = report.sections[0]
    section.hull_px = [[float("nan"), float("nan")], [300.0, 200.0]]
    section.hull_point_px, section.obstacle_point_px = [300.0, 200.0], [300.0, 120.0]
    report.sections[1].hull_px = [[400.0, 200.0], [500.0, 200.0]]
    report.sections[1].hull_point_px, report.sections[1].obstacle_point_px = [450, 200], [450, 40]
    out = draw_overlay(np.zeros((360, 640, 3), np.uint8), report)
    line = out[160, 297:304].astype(int)                 # the line to its obstacle point
    assert (np.abs(line - YELLOW).sum(axis=1) < 60).any()
    assert (out[150:200, 200:300] > 0).any()             # its label, outward of the hull point


def test_flight_clock_is_fixed_by_the_first_frame():
    from harborsight.flight.runner import FlightClock
    from harborsight.flight.sources import FlightFrame
    from harborsight.frame import load_frame_metadata

    meta = load_frame_metadata(SAMPLES / "frames" / "000000.json")
    untimed = dataclasses.replace(meta, timestamp=None)
    clock = FlightClock()      # first frame untimed, in a video: the video position rules
    assert clock.seconds(FlightFrame(0, "f0", meta=untimed, video_time_s=4.0)) == 4.0
    timed = dataclasses.replace(meta, timestamp="2026-05-01T12:00:09Z")
    assert clock.seconds(FlightFrame(1, "f1", meta=timed, video_time_s=4.5)) == 4.5
    clock = FlightClock()      # first frame timed: a later untimed one is refused
    assert clock.seconds(FlightFrame(0, "f0", meta=timed, video_time_s=4.0)) == 0.0
    with pytest.raises(InputError, match="f1: timestamp: missing"):
        clock.seconds(FlightFrame(1, "f1", meta=untimed, video_time_s=4.5))
    clock = FlightClock()      # a folder whose first frame is untimed: the next timed one rules
    assert clock.seconds(FlightFrame(0, "f0", meta=untimed)) is None
    assert clock.seconds(FlightFrame(1, "f1", meta=timed)) == 0.0
    later = dataclasses.replace(meta, timestamp="2026-05-01T12:00:10.5Z")
    assert clock.seconds(FlightFrame(2, "f2", meta=later)) == 1.5
    clock = FlightClock()      # video positions count from the video's start
    assert clock.seconds(FlightFrame(90, "f90", meta=untimed, video_time_s=3.0)) == 3.0


def test_a_repeated_presentation_time_costs_that_frame_only(monkeypatch, tmp_path):
    """A variable-frame-rate video (2 s at 30 fps, then 5 fps) whose frame 30 repeats frame
    29's time: that frame is timed a frame interval after the previous one, and the next
    frames by their own times again (the first version went on timing them by n / fps, up
    to 2.5 s off)."""
    from harborsight.flight import sources

    times_ms = ([1000 / 30 * k for k in range(30)] + [1000 / 30 * 29]
                + [1000 / 30 * k for k in range(30, 60)] + [2000 + 200 * k for k in range(20)])

    from harborsight.flight.video_decode import DecodedPicture

    class Capture:
        def get(self, prop):
            return {cv2.CAP_PROP_FPS: 80 / 6,
                    cv2.CAP_PROP_FRAME_COUNT: float(len(times_ms))}.get(prop, 0.0)

        def release(self):
            pass

    monkeypatch.setattr(sources, "open_video", lambda video: Capture())
    monkeypatch.setattr(sources, "read_video_frames", lambda video: (
        DecodedPicture(k, t / 1000, np.zeros((4, 4, 3), np.uint8)) for k, t in enumerate(times_ms)))
    monkeypatch.setattr(sources, "read_metadata_lines", lambda *args, **kwargs: ({}, [], {}, {}))
    (tmp_path / "v.mp4").write_bytes(b"x")
    source = sources.VideoSource(tmp_path / "v.mp4", tmp_path / "v.jsonl")
    read = [f.video_time_s for f in source.frames() if f.is_frame]
    expected = [t / 1000 for t in times_ms]
    expected[30] = expected[29] + 6 / 80                    # the repeat: one mean interval on
    np.testing.assert_allclose(read, expected, atol=1e-9)


def test_timestamps_that_drift_from_the_video_are_said_once():
    """Metadata lines at the telemetry's 1 Hz paired one to one with a 2 fps video's frames:
    the timestamps run twice as fast as the video (closing speeds halved). A constant offset
    between the two clocks is fine; a drift past a quarter second is said, once."""
    from harborsight.flight.runner import FlightClock
    from harborsight.flight.sources import FlightFrame
    from harborsight.frame import load_frame_metadata

    meta = load_frame_metadata(SAMPLES / "frames" / "000000.json")

    def at(k: int, stamp_s: float, video_s: float) -> FlightFrame:
        stamp = f"2026-05-01T12:00:{stamp_s:06.3f}Z"
        return FlightFrame(k, f"f{k}", meta=dataclasses.replace(meta, timestamp=stamp),
                           video_time_s=video_s)

    clock = FlightClock()      # offset by 7 s, in step
    for k in range(6):
        clock.seconds(at(k, 7.0 + 0.5 * k, 0.5 * k))
    assert clock.drift_warning is None
    clock = FlightClock()      # 1 Hz lines on 2 fps frames
    said = []
    for k in range(6):
        clock.seconds(at(k, 1.0 * k, 0.5 * k))
        said.append(clock.drift_warning)
        clock.drift_warning = None
    assert said[0] is None and "drift apart" in said[1] and "frame_index" in said[1]
    assert not any(said[2:])


def _write_video(path: Path, images: list[Path], fps: float) -> None:
    first = cv2.imread(str(images[0]))
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                             (first.shape[1], first.shape[0]))
    for image in images:
        writer.write(cv2.imread(str(image)))
    writer.release()


def test_run_on_a_video_with_json_lines(tmp_path, untrained_model):
    frames = sorted((SAMPLES / "frames").glob("*.json"))
    video = tmp_path / "flight.mp4"
    _write_video(video, [SAMPLES / "images" / f"{p.stem}.png" for p in frames], fps=2.0)
    vessel = SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml"
    lines = []
    for path in frames:
        meta = json.loads(path.read_text())
        for key in ("image", "ground_truth", "simulation", "vessel_spec"):
            meta.pop(key, None)
        lines.append(json.dumps(meta))
    lines[2] = lines[2][:40]                          # a broken line: frame 2 is skipped
    metadata = tmp_path / "flight.jsonl"
    metadata.write_text("\n".join(lines[:4]) + "\n")  # no line for frame 4
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(video), "--metadata", str(metadata), "--model",
                                 str(untrained_model), "--vessel", str(vessel), "--out",
                                 str(out)], terminal_width=200)
    assert result.exit_code == 0, result.output
    record = json.loads((out / "run.json").read_text())
    assert (record["frames"], record["measured"], record["without_metadata"]) == (5, 3, 1)
    assert [item["frame"] for item in record["skipped_frames"]] == [2]
    assert f"{metadata}:3" in record["skipped_frames"][0]["error"]
    assert sorted(p.name for p in (out / "reports").iterdir()) == [
        "flight-000000.json", "flight-000001.json", "flight-000003.json"]
    rows = list(csv.DictReader((out / "sections.csv").open()))
    assert {r["time_s"] for r in rows} == {"0.0", "0.5", "1.5"}   # video time at 2 fps
    assert _video_frame_count(out / "annotated.mp4") == 5


def test_run_with_test_time_flips_records_them(tmp_path, untrained_model):
    """``run --flips 2`` segments every frame with its mirror image and says so in run.json;
    with --masks there is no model to flip, and --flips 3 is no flip set: one line each."""
    frames = copy_sample_frames(SAMPLES, tmp_path / "frames", 2)
    vessel = SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml"
    common = ["--vessel", str(vessel), "--no-video", "--no-overlays"]
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(frames), "--model", str(untrained_model), "--flips",
                                 "2", "--out", str(out), *common], terminal_width=200)
    assert result.exit_code == 0, result.output
    record = json.loads((out / "run.json").read_text())
    assert record["measured"] == 2 and record["settings"]["flips"] == 2
    result = runner.invoke(app, ["run", str(frames), "--model", str(untrained_model), "--flips",
                                 "3", "--out", str(tmp_path / "out3"), *common], terminal_width=200)
    assert result.exit_code == 2 and "--flips" in result.output
    result = runner.invoke(app, ["run", str(SAMPLES), "--masks", str(SAMPLES / "labels"), "--flips",
                                 "2", "--out", str(tmp_path / "masks"), *common], terminal_width=200)
    assert result.exit_code == 2 and "--flips" in result.output
    # measure too: a folder labelled by the model, and a folder whose frames all have masks
    result = runner.invoke(app, ["measure", str(frames), "--model", str(untrained_model),
                                 "--flips", "4", "--vessel", str(vessel), "--out",
                                 str(tmp_path / "measured"), "--no-tables"], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "4 flipped copies a frame" in result.output
    assert len(list((tmp_path / "measured").glob("*.json"))) == 2
    result = runner.invoke(app, ["measure", str(SAMPLES), "--flips", "2", "--out",
                                 str(tmp_path / "masked")], terminal_width=200)
    assert result.exit_code == 2 and "--flips" in result.output
    for wrong in (["--model", str(untrained_model), "--flips", "3"], ["--flips", "2"]):
        result = runner.invoke(app, ["evaluate", "distance", "--data", str(SAMPLES), *wrong,
                                     "--out", str(tmp_path / "distance")], terminal_width=200)
        assert result.exit_code == 2 and "--flips" in result.output
        assert not (tmp_path / "distance").exists()          # refused before anything is written
    assert not (tmp_path / "out3").exists()
    import copy
    import pickle

    from harborsight.perception.flips import FlippedSegmenter

    wrapped = FlippedSegmenter(types.SimpleNamespace(path=Path("m.onnx")), 4)
    assert copy.copy(wrapped).flips == 4 and wrapped.path == Path("m.onnx")
    with pytest.raises(AttributeError):
        _ = wrapped.input_width
    assert pickle.loads(pickle.dumps(wrapped)).flips == 4


def test_explicit_frame_indices(tmp_path):
    meta = json.loads((SAMPLES / "frames" / "000000.json").read_text())
    path = tmp_path / "m.jsonl"
    path.write_text("\n".join([
        json.dumps({**meta, "frame_index": 3}),
        json.dumps({**meta, "frame_index": 3}),          # duplicate
        json.dumps({**meta, "frame_index": -1}),         # not a frame
        "{broken",
        json.dumps({**meta, "frame_index": 7, "uav": {"lat": 56.0}}),   # bad record
    ]))
    by_frame, orphans, line_of, _ = read_metadata_lines(path, "v")
    assert set(by_frame) == {3, 7}
    assert by_frame[3].image == "000000.png"
    assert line_of == {3: 1, 7: 5}
    assert "uav.lon" in by_frame[7] or "uav.alt_m" in by_frame[7]
    assert len(orphans) == 3
    assert any("already has" in o for o in orphans) and any(":4" in o for o in orphans)


def test_run_refuses_unclear_inputs(tmp_path):
    result = runner.invoke(app, ["run", str(tmp_path / "flihgts")])
    assert result.exit_code == 2 and "flihgts: not found" in result.output
    (tmp_path / "clip.mp4").write_bytes(b"")
    result = runner.invoke(app, ["run", str(tmp_path / "clip.mp4")])
    assert result.exit_code == 2 and "--metadata" in result.output
    result = runner.invoke(app, ["run", str(SAMPLES), "--metadata", str(tmp_path / "x.jsonl")])
    assert result.exit_code == 2 and "for videos" in result.output


def test_metadata_past_the_video_end_is_reported_not_counted(tmp_path, untrained_model):
    frames = sorted((SAMPLES / "frames").glob("*.json"))[:3]
    video = tmp_path / "short.mp4"
    _write_video(video, [SAMPLES / "images" / f"{p.stem}.png" for p in frames], fps=2.0)
    lines = []
    for path in frames + frames[:2]:                  # 5 lines for a 3-frame video
        meta = json.loads(path.read_text())
        for key in ("image", "ground_truth", "simulation", "vessel_spec"):
            meta.pop(key, None)
        lines.append(json.dumps(meta))
    metadata = tmp_path / "short.jsonl"
    metadata.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(video), "--metadata", str(metadata), "--model",
                                 str(untrained_model), "--vessel",
                                 str(SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml"),
                                 "--out", str(out)], terminal_width=200)
    assert result.exit_code == 0, result.output
    record = json.loads((out / "run.json").read_text())
    assert (record["frames"], record["measured"]) == (3, 3)
    errors = [item["error"] for item in record["skipped_frames"]]
    assert len(errors) == 2 and all("past the video's end (3 frames)" in e for e in errors)
    assert f"{metadata}:4:" in errors[0] and f"{metadata}:5:" in errors[1]


@pytest.mark.parametrize("command", ["run", "measure"])
def test_a_missing_masks_folder_is_one_error(tmp_path, command):
    """A --masks folder that is not there: one line naming it, exit 2, nothing measured
    (it used to be one 'mask file not found' per frame)."""
    missing = tmp_path / "no-such-masks"
    result = runner.invoke(app, [command, str(SAMPLES), "--masks", str(missing),
                                 "--out", str(tmp_path / "out")], terminal_width=200)
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert lines == [f"error: {missing}: --masks: no such folder"]


def test_an_unreadable_timestamp_is_measured_untimed_in_a_folder(tmp_path):
    """As the runner's doc says: a frame whose timestamp cannot be read is measured (its
    distances do not depend on the time), left out of the closing speeds and warned about;
    it used to be skipped."""
    _, out = _run_with_a_frame_edited(tmp_path, lambda m: m.update(timestamp="not a time"))
    record = json.loads((out / "run.json").read_text())
    assert record["measured"] == 5 and record["skipped_frames"] == []
    [warning] = record["warnings"]
    assert warning["frame"] == 2 and "000002.json: timestamp: expected an ISO 8601 time" in \
        warning["warning"] and "left out of the closing speeds" in warning["warning"]
    rows = [r for r in csv.DictReader((out / "sections.csv").open()) if r["frame"] == "2"]
    assert rows and {r["time_s"] for r in rows} == {""}
    assert (out / "reports" / "000002.json").is_file()


def test_an_unreadable_timestamp_is_measured_untimed_in_json_lines(tmp_path):
    meta = json.loads((SAMPLES / "frames" / "000000.json").read_text())
    path = tmp_path / "m.jsonl"
    path.write_text("\n".join([json.dumps({**meta, "timestamp": "2026-05-01T12:00:00Z"}),
                               json.dumps({**meta, "timestamp": "yesterday"})]) + "\n")
    by_frame, orphans, _, time_errors = read_metadata_lines(path, "v")
    assert orphans == [] and by_frame[1].timestamp is None
    assert list(time_errors) == [1] and f"{path}:2: timestamp" in time_errors[1]


@pytest.mark.parametrize("rate_hz", [4, 10])
def test_whole_second_stamps_at_several_frames_a_second_keep_the_speed_honest(rate_hz):
    """Frames stamped to the whole second at 4 and 10 a second: each frame's time lies
    anywhere in its second, which the tracker now allows for (Reading.time_sigma_s, the
    step over sqrt 12). Before, frames of one stamp were one instant: a steady 0.4 m/s
    approach read from -0.13 to +0.48 m/s at 10 Hz, 8 of its sigmas off, and tracks were
    restarted 16 times; exact stamps are the reference."""
    def run(whole_seconds: bool):
        rng = np.random.default_rng(0)
        timeline, shown, notes = ClearanceTimeline(), [], []
        for i in range(30 * rate_hz):
            t = i / rate_hz
            truth = 40.0 - 0.4 * t
            report = _section_report(truth + rng.normal(0, 0.05))
            report.sections[0].sigma_m = report.sections[0].sigma_random_m = 0.05   # honest
            _, rows, warning = timeline.add(i, math.floor(t) if whole_seconds else t, report)
            notes += [warning] if warning else []
            row = rows[0]
            if t >= 10:
                shown.append((row["closing_speed_mps"], row["closing_speed_sigma_mps"],
                              row["filtered_distance_m"] - truth, row["filtered_sigma_m"],
                              row["track_state"]))
        return shown, notes

    shown, notes = run(True)
    assert len(notes) == 1 and "coarser than the frames" in notes[0]
    assert all(state == "updated" for *_, state in shown)
    assert max(abs(v - 0.4) / s for v, s, *_ in shown) < 2.0
    assert max(abs(e) / s for _, _, e, s, _ in shown) < 2.0
    assert min(v for v, *_ in shown) > 0.3
    exact, notes = run(False)
    assert notes == [] and max(abs(v - 0.4) / s for v, s, *_ in exact) < 3.0


def test_overlay_label_of_each_section_state():
    """What each measured section shows: a distance with its sigma (``!`` touching), ``??``
    under a contradicted pose, the reach of a clear band, ``unseen`` for a band that leaves
    the picture at the hull (``>0.0m`` read like a clearance), the hidden water, ``clear``."""
    from harborsight.clearance.report import SectionClearance
    from harborsight.viz.overlay import RED, WHITE, section_label

    def section(status, **fields):
        return SectionClearance(index=0, status=status, hull_px=[[0, 0], [1, 0]],
                                visible_fraction=1.0, **fields)

    ok = section("ok", distance_m=3.24, sigma_m=0.41, contact=False)
    assert section_label(ok, False, 2.0, RED) == ("3.2+-0.4m", RED)
    assert section_label(section("ok", distance_m=0.0, contact=True), False, 2.0, RED) == ("0.0m!", RED)
    assert section_label(section("clear", clear_to_m=14.7), True, 2.0, RED) == ("??", WHITE)
    assert section_label(section("clear", clear_to_m=14.7), False, 2.0, RED) == (">14.7m", WHITE)
    assert section_label(section("clear", clear_to_m=0.0), False, 2.0, RED) == ("unseen", WHITE)
    assert section_label(section("clear", clear_to_m=0.04), False, 2.0, RED)[0] == "unseen"
    assert section_label(section("clear", clear_to_m=0.3), False, 2.0, RED)[0] == ">0.3m"
    assert section_label(section("clear", clear_to_m=0.0, hidden_to_m=2.5), False, 2.0,
                         RED)[0] == "hid 2.5m"
    assert section_label(section("clear", clear_to_m=6.0, hidden_to_m=2.5), False, 2.0,
                         RED)[0] == ">6.0m hid 2.5m"
    assert section_label(section("clear", clear_to_m=6.0, hidden_to_m=1.5), False, 2.0,
                         RED)[0] == ">6.0m"
    assert section_label(section("clear"), False, 2.0, RED) == ("clear", WHITE)
