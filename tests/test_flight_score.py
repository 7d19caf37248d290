"""harborsight evaluate flight: a run's distances (per frame and filtered), error bars and
closing speeds against a simulated flight's ground truth, per scene."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.evaluation.flight import score_flight

SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"
COLUMNS = ["image", "section", "status", "distance_m", "sigma_m", "distance_lower_m",
           "filtered_distance_m", "closing_speed_mps", "pose_contradicted"]


def _flight(root: Path, scenes: list[tuple[float, float, float]], frames: int = 5) -> list[str]:
    """Frame JSONs of scenes ``(d0, speed, height)``, each with its own clock from 0:
    section 0 closes from d0 at ``speed``, section 1 has no obstacle (truth None)."""
    (root / "frames").mkdir(parents=True)
    images = []
    for scene, (d0, speed, height_m) in enumerate(scenes):
        for frame in range(frames):
            t = 0.5 * frame
            image = f"{len(images):06d}.png"
            truth = {"sections": [{"distance_m": d0 - speed * t}, {"distance_m": None}],
                     "sequence": {"scene": scene, "frame": frame, "time_s": t, "speed_mps": speed}}
            meta = {"image": image, "ground_truth": truth, "uav": {"alt_m": height_m + 2.0},
                    "water_level_m": 2.0}
            (root / "frames" / f"{len(images):06d}.json").write_text(json.dumps(meta))
            images.append(image)
    return images


def _csv(path: Path, rows: list[dict]) -> Path:
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, COLUMNS, restval="")
        writer.writeheader()
        writer.writerows(rows)
    return path


def test_errors_bars_and_speeds_are_scored_per_scene_from_the_chosen_frame(tmp_path):
    """Scene 0 read 0.1 m long per frame and 0.05 m short filtered, sigma 0.04 m (so the
    truth lies beyond two sigma) and its lower bound 0.2 m under the reading; scene 1 read
    exactly with a false reading in section 1 on frame 4. Hand values: frames 2-4 compared
    (from_frame 2), MAE 0.1 / 0.05 m and 0 / 0 m."""
    images = _flight(tmp_path, [(10.0, 0.4, 30.0), (40.0, 1.0, 100.0)])
    rows = []
    for index, image in enumerate(images):
        scene, frame = divmod(index, 5)
        d0, speed = ((10.0, 0.4), (40.0, 1.0))[scene]
        d = d0 - speed * 0.5 * frame
        read = d + 0.1 if scene == 0 else d
        rows.append({"image": image, "section": 0, "status": "ok", "distance_m": read,
                     "sigma_m": 0.04, "distance_lower_m": read - 0.2,
                     "filtered_distance_m": d - 0.05 if scene == 0 else d,
                     "closing_speed_mps": speed + (0.02 if scene == 0 else 0.0),
                     "pose_contradicted": 0})
        false = scene == 1 and frame == 4
        rows.append({"image": image, "section": 1, "status": "ok" if false else "clear",
                     "distance_m": 3.0 if false else "", "pose_contradicted": 0})
    first, second = score_flight(tmp_path, _csv(tmp_path / "s.csv", rows), from_frame=2)
    assert (first.scene, second.scene) == (0, 1)
    assert (first.altitude_m, second.altitude_m) == (30.0, 100.0)
    assert first.frames == first.frames_measured == 5 and first.estimates == 3
    assert first.mae_m == pytest.approx(0.1) and first.mae_filtered_m == pytest.approx(0.05)
    assert first.within_2_sigma_share == 0.0 and first.lower_bound_share == 1.0
    assert (first.missed, first.false) == (0, 0)
    # frames 1-3 have both neighbours; every one read 0.02 m/s fast
    assert first.closing.samples == 3
    assert first.closing.median_abs_error_mps == pytest.approx(0.02)
    assert first.closing.true_mps == pytest.approx(0.4)
    assert first.still_speed_mps is None and first.still_frames == 0     # never still
    assert second.mae_m == 0.0 and second.mae_filtered_m == 0.0 and second.false == 1
    assert second.within_2_sigma_share == 1.0
    assert second.closing.true_mps == pytest.approx(1.0)


def test_the_share_within_one_sigma_is_scored_beside_two(tmp_path):
    """Frames 0-4 of one scene read 0.1 m long with sigmas 0.2, 0.08, 0.2, 0.04 and 0.05 m:
    within one sigma 2 of 5 (0.1 <= 0.2), within two sigma 4 of 5 (0.1 <= 0.16, 0.1 <= 0.1;
    not 0.08)."""
    images = _flight(tmp_path, [(10.0, 0.4, 30.0)])
    rows = [{"image": image, "section": 0, "status": "ok", "distance_m": 10.0 - 0.2 * k + 0.1,
             "sigma_m": sigma, "distance_lower_m": 0.0, "pose_contradicted": 0}
            for k, (image, sigma) in enumerate(
                zip(images, (0.2, 0.08, 0.2, 0.04, 0.05), strict=True))]
    rows += [{"image": image, "section": 1, "status": "clear", "pose_contradicted": 0}
             for image in images]
    score, = score_flight(tmp_path, _csv(tmp_path / "s.csv", rows), from_frame=0)
    assert score.estimates == 5
    assert score.within_sigma_share == pytest.approx(0.4)
    assert score.within_2_sigma_share == pytest.approx(0.8)


def test_a_missed_obstacle_and_a_contradicted_pose_are_counted_apart(tmp_path):
    """A clear section with an obstacle in the truth is missed; a frame whose pose the image
    contradicts counts in the error but not in the bars' shares."""
    images = _flight(tmp_path, [(10.0, 0.0, 50.0)], frames=2)
    rows = [{"image": images[0], "section": 0, "status": "clear", "pose_contradicted": 0},
            {"image": images[0], "section": 1, "status": "clear", "pose_contradicted": 0},
            {"image": images[1], "section": 0, "status": "ok", "distance_m": 4.0, "sigma_m": 0.1,
             "distance_lower_m": 3.8, "filtered_distance_m": 4.0, "pose_contradicted": 1},
            {"image": images[1], "section": 1, "status": "clear", "pose_contradicted": 1}]
    (score,) = score_flight(tmp_path, _csv(tmp_path / "s.csv", rows), from_frame=0)
    assert score.missed == 1 and score.estimates == 1 and score.mae_m == pytest.approx(6.0)
    assert score.within_2_sigma_share is None and score.lower_bound_share is None
    assert score.closing is None            # a vessel standing still: nothing to compare


def test_bad_inputs_name_the_file_and_the_field(tmp_path):
    images = _flight(tmp_path, [(10.0, 0.4, 30.0)], frames=2)
    rows = [{"image": image, "section": k, "status": "ok", "distance_m": "1,5"}
            for image in images for k in range(2)]
    with pytest.raises(InputError, match=r"s\.csv: distance_m: 000000\.png: '1,5' is not a number"):
        score_flight(tmp_path, _csv(tmp_path / "s.csv", rows))
    with pytest.raises(InputError, match=r"missing\.csv"):
        score_flight(tmp_path, tmp_path / "missing.csv")
    (tmp_path / "plain" / "frames").mkdir(parents=True)
    (tmp_path / "plain" / "frames" / "000000.json").write_text(json.dumps({"image": "a.png"}))
    with pytest.raises(InputError, match=r"frames: ground_truth\.sequence: no frame carries"):
        score_flight(tmp_path / "plain", tmp_path / "s.csv")


def test_the_bundled_flight_run_on_its_labels_is_scored_by_the_command(tmp_path):
    """The demo flight through run (exact labels) and evaluate flight: pixel quantisation is
    the only error, so the MAE is centimetres, the bars hold and the speed is within 0.05."""
    flight = SAMPLES / "flight"
    runner = CliRunner()
    result = runner.invoke(app, ["run", str(flight), "--masks", str(flight / "labels"),
                                 "--out", str(tmp_path / "run"), "--no-overlays", "--no-video"])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["evaluate", "flight", str(tmp_path / "run"), "--flight",
                                 str(flight), "--json", str(tmp_path / "score.json")])
    assert result.exit_code == 0, result.output
    assert "scene 0 (60 m): 48 of 48 frames" in result.output
    (scene,) = json.loads((tmp_path / "score.json").read_text())["scenes"]
    assert scene["estimates"] > 300 and scene["mae_m"] < 0.1 and scene["mae_filtered_m"] < 0.1
    assert scene["within_2_sigma_share"] > 0.95 and scene["lower_bound_share"] > 0.95
    assert scene["closing"]["median_abs_error_mps"] < 0.05 and scene["closing"]["samples"] > 30
    result = runner.invoke(app, ["evaluate", "flight", str(tmp_path / "run"), "--flight",
                                 str(tmp_path)])
    assert result.exit_code == 2 and "no frame carries a flight's ground truth" in result.output


def test_a_csv_of_another_kind_or_with_a_bad_section_is_refused(tmp_path):
    images = _flight(tmp_path, [(10.0, 0.4, 30.0)], frames=2)
    rows = [{"image": image, "section": k, "status": "ok", "distance_m": 1.0}
            for image in images for k in ("0", "x")]
    with pytest.raises(InputError, match=r"s\.csv: section: 000000\.png: section 'x' is not "
                                         r"one of the 2 of its ground truth"):
        score_flight(tmp_path, _csv(tmp_path / "s.csv", rows))
    (tmp_path / "t.csv").write_text("image,section,distance_m\n000000.png,0,1.0\n")
    with pytest.raises(InputError, match=r"t\.csv: status: no such column"):
        score_flight(tmp_path, tmp_path / "t.csv")


def test_the_speed_shown_while_the_vessel_lies_still_is_scored(tmp_path):
    """A vessel lying still: its closest section shows 0.1, 0.3 and -0.2 m/s on frames 2-4
    (from_frame 2), a farther section 0.9: the median magnitude is 0.2 m/s over 3 frames."""
    images = _flight(tmp_path, [(5.0, 0.0, 30.0)])
    shown = {2: 0.1, 3: 0.3, 4: -0.2}
    rows = []
    for frame, image in enumerate(images):
        rows.append({"image": image, "section": 0, "status": "ok", "distance_m": 5.0,
                     "closing_speed_mps": shown.get(frame, "")})
        rows.append({"image": image, "section": 1, "status": "ok", "distance_m": 9.0,
                     "closing_speed_mps": 0.9})
    (score,) = score_flight(tmp_path, _csv(tmp_path / "s.csv", rows), from_frame=2)
    assert score.still_speed_mps == pytest.approx(0.2) and score.still_frames == 3
    assert score.closing is None
