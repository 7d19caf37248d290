"""`evaluate distance` on the bundled simulator frames: estimates, misses and false obstacles
are counted against the frames' ground truth, and the outputs are written."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from harborsight.clearance.measure import ClearanceSettings
from harborsight.clearance.pose_refinement import PoseRefinementSettings
from harborsight.cli import app
from harborsight.evaluation.distance import (
    evaluate_frames,
    load_frames,
    oracle_masks,
    scene_planner,
    summarise,
    summarise_by_obstacle,
    truth_obstacle_kinds,
)

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))


def _obstacle_gap_to_band_m(frame: dict, section: int) -> float:
    """Water-plane distance from the scene's obstacles to a section's band (the scene is
    rebuilt from the dataset's seed, as the flat-world masks do)."""
    import shapely

    from harborsight.frame import FrameGeometry, parse_frame_metadata
    from harborsight.sim.ground_truth import section_band_polygon

    scene, vessel = scene_planner(SAMPLES)(frame)
    geometry = FrameGeometry.from_metadata(parse_frame_metadata(frame))
    others = [shapely.transform(obj.footprint(), geometry.enu_to_vessel_xy)
              for obj in scene.objects[1:]]   # objects[0] is the vessel of interest
    band = section_band_polygon(vessel.sections(), section)
    return float(shapely.distance(band, shapely.union_all(others)))


def test_oracle_ground_plane_is_close_and_counts_nothing_missed():
    frames = load_frames(SAMPLES)
    results = evaluate_frames(SAMPLES, frames, "oracle", oracle_masks, "ground_plane")
    estimates = [r for r in results if r.kind == "estimate"]
    assert len(estimates) >= 30
    assert np.median([r.abs_error_m / r.gsd_m_per_px for r in estimates]) <= 1.0
    assert not [r for r in results if r.kind == "missed"]
    # a false obstacle is only allowed where one lies within 2 px of the band: a corner that
    # close may reach into it (pixel squares, leaning heights), and missing it would be worse
    by_stem = {Path(f["image"]).stem: f for f in frames}
    for r in (r for r in results if r.kind == "false"):
        gap_px = _obstacle_gap_to_band_m(by_stem[r.frame], r.section) / r.gsd_m_per_px
        assert gap_px <= 2.0, (r, gap_px)


def test_erased_obstacles_are_missed_and_painted_ones_are_false():
    frames = load_frames(SAMPLES)

    def no_obstacles(dataset, frame):
        labels = oracle_masks(dataset, frame).copy()
        instances_path = dataset / "instances" / frame["image"]
        import cv2

        instances = cv2.imread(str(instances_path), cv2.IMREAD_UNCHANGED)
        labels[(instances != 1) & (labels != 255)] = 0  # all but the vessel becomes water
        return labels

    results = evaluate_frames(SAMPLES, frames, "erased", no_obstacles, "ground_plane")
    truth_in_view = sum(s["distance_m"] is not None for f in frames
                        for s in f["ground_truth"]["sections"])
    missed = [r for r in results if r.kind == "missed"]
    assert missed and len(missed) <= truth_in_view
    assert not [r for r in results if r.kind == "estimate"]

    def border_wall(dataset, frame):
        labels = no_obstacles(dataset, frame)
        labels[:, :3] = 2  # a solid strip on the left edge: obstacles where the truth has none
        return labels

    results = evaluate_frames(SAMPLES, frames, "wall", border_wall, "ground_plane")
    rows = summarise(results)
    assert sum(r.false for r in rows) > 0


def test_cli_writes_csv_tables_and_plots(tmp_path):
    result = CliRunner().invoke(app, ["evaluate", "distance", "--data", str(SAMPLES),
                                      "--out", str(tmp_path), "--worst", "1"])
    assert result.exit_code == 0, result.output
    import cv2

    pictures = sorted((tmp_path / "worst").glob("*.png"))
    assert [p.name.split("-01-")[0] for p in pictures] == ["oracle-ground_plane", "oracle-gsd"]
    frame_image = cv2.imread(str(next((SAMPLES / "images").glob("*.png"))))
    panel = cv2.imread(str(pictures[0]))
    assert panel.shape == (frame_image.shape[0], 3 * frame_image.shape[1], 3)
    for name in ("sections.csv", "summary.md", "summary.json", "distance_error_box.png",
                 "distance_mae_bar.png"):
        assert (tmp_path / name).is_file(), name
    with (tmp_path / "sections.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["method"] for r in rows} == {"gsd", "ground_plane"}
    summary = json.loads((tmp_path / "summary.json").read_text())
    gp = [r["mae_m"] for r in summary if r["method"] == "ground_plane" and r["mae_m"] is not None]
    gsd = [r["mae_m"] for r in summary if r["method"] == "gsd" and r["mae_m"] is not None]
    assert np.mean(gp) < np.mean(gsd)  # the tilt-exact conversion beats the nadir GSD
    bad = CliRunner().invoke(app, ["evaluate", "distance", "--data", str(SAMPLES), "--no-oracle"])
    assert bad.exit_code == 2 and "nothing to evaluate" in bad.output


def test_sections_csv_reads_back(tmp_path):
    from harborsight.evaluation.distance import SectionResult, read_csv, summarise, write_csv

    results = [SectionResult("000001", 40.0, "oracle", "gsd", 3, "ok", 2.5, 2.4, 0.05, False, True),
               SectionResult("000001", 40.0, "oracle", "gsd", 4, "clear", None, 7.0, 0.05, False,
                             False)]
    write_csv(results, tmp_path / "s.csv")
    again = read_csv(tmp_path / "s.csv")
    assert [r.kind for r in again] == ["estimate", "missed"]
    assert again[0].abs_error_m == pytest.approx(0.1, abs=1e-4) and again[0].truncated
    assert summarise(again)[0].missed == 1


def test_flagged_frames_stay_out_of_the_calibration_shares_and_blind_bands_are_unseen(tmp_path):
    """A frame whose pose the image contradicts has its bound at 0 by construction: its
    sections count in the error figures and apart, not in the calibration shares; a clear
    section that saw none of its band (clear_to_m 0) claims nothing and is not missed."""
    from harborsight.evaluation.distance import SectionResult, read_csv, summarise, write_csv

    def row(frame, status, estimate, truth, sigma=None, lower=None, clear_to=None,
            flagged=False):
        return SectionResult(frame, 40.0, "oracle", "ground_plane", 0, status, estimate, truth,
                             0.05, False, False, sigma_m=sigma, lower_m=lower,
                             clear_to_m=clear_to, flagged=flagged)

    results = [row("a", "ok", 2.0, 2.1, 0.2, 1.7),        # holds, within 2 sigma
               row("a", "ok", 3.0, 2.0, 0.2, 2.7),        # neither
               row("b", "ok", 9.0, 2.0, 9.0, 0.0, flagged=True),
               row("b", "clear", None, 5.0, clear_to=0.0, flagged=True),
               row("a", "clear", None, 6.0, clear_to=0.0),   # hidden in full: unseen
               row("a", "clear", None, 7.0, clear_to=12.0)]  # saw the water: missed
    (summary,) = summarise(results)
    assert (summary.n, summary.missed, summary.unseen, summary.flagged) == (3, 1, 2, 2)
    assert summary.mae_m == pytest.approx((0.1 + 1.0 + 7.0) / 3)  # every estimate is scored
    assert summary.lower_bound_share == 0.5 and summary.within_2_sigma_share == 0.5
    write_csv(results, tmp_path / "s.csv")
    again = read_csv(tmp_path / "s.csv")
    assert [r.kind for r in again] == ["estimate", "estimate", "estimate", "unseen", "unseen",
                                       "missed"]
    assert [r.flagged for r in again] == [False, False, True, True, False, False]
    assert summarise(again) == [summary]


def test_a_frame_whose_pose_the_image_contradicts_is_counted_apart(tmp_path):
    """The bundled frames with the vessel's fix 20 m east: the image cannot bear the pose
    out, every section of those frames is counted as flagged, none is called missed, and the
    calibration shares have nothing left to score."""
    import math
    import shutil

    data = tmp_path / "data"
    shutil.copytree(SAMPLES, data, ignore=shutil.ignore_patterns("flight"))
    for path in sorted((data / "frames").glob("*.json")):
        frame = json.loads(path.read_text())
        frame["vessel"]["lon"] += 20.0 / (111_320 * math.cos(math.radians(frame["vessel"]["lat"])))
        path.write_text(json.dumps(frame))
    results = evaluate_frames(data, load_frames(data), "oracle", oracle_masks, "ground_plane")
    assert results and all(r.flagged for r in results)
    assert not [r for r in results if r.kind == "missed"]
    rows = summarise(results)
    assert sum(r.flagged for r in rows) == len(results)
    assert sum(r.unseen for r in rows) >= 1
    assert all(r.lower_bound_share is None and r.within_2_sigma_share is None for r in rows)


def test_altitude_summary_statistics_match_the_statistics_module():
    import statistics

    from harborsight.evaluation.distance import SectionResult, summarise

    pairs = [(2.5, 2.4), (3.0, 4.0), (10.0, 7.5), (1.0, 1.0), (6.2, 5.0)]
    results = [SectionResult("f", 60.0, "oracle", "ground_plane", i, "ok", est, truth, 0.05,
                             False, False) for i, (est, truth) in enumerate(pairs)]
    results.append(SectionResult("g", 70.0, "oracle", "ground_plane", 0, "ok", 3.0, 2.0, 0.05,
                                 False, False))
    errors = [abs(est - truth) for est, truth in pairs]
    at_60, at_70 = summarise(results)
    assert at_60.mae_m == pytest.approx(statistics.fmean(errors))
    assert at_60.std_m == pytest.approx(statistics.stdev(errors))  # the sample std (n - 1)
    assert at_60.median_m == pytest.approx(statistics.median(errors))
    assert at_60.over_1m_share == pytest.approx(2 / 5)
    assert at_70.n == 1 and at_70.mae_m == pytest.approx(1.0) and at_70.std_m is None


def test_true_nearest_obstacle_kinds_follow_the_scenarios():
    kinds_of = truth_obstacle_kinds(SAMPLES)
    kinds = {}
    for frame in load_frames(SAMPLES):
        truth = frame["ground_truth"]["sections"]
        kinds[frame["ground_truth"]["scenario"]] = found = kinds_of(frame)
        assert [k is None for k in found] == [t["distance_m"] is None for t in truth]
        assert set(found) <= {None, "quay", "pier", "ship", "boat", "fender", "buoy", "breakwater"}
    assert kinds["alongside"].count("quay") >= 2
    assert "pier" in kinds["pass"]
    # the tug touching a moored ship: the five sections at 0.68 m are along that ship
    touching = next(f for f in load_frames(SAMPLES) if f["ground_truth"]["scenario"] == "touching")
    near = [i for i, t in enumerate(touching["ground_truth"]["sections"])
            if t["distance_m"] is not None and t["distance_m"] < 0.7]
    assert len(near) == 5 and {kinds["touching"][i] for i in near} == {"ship"}


def test_signed_errors_are_summarised_per_obstacle_kind():
    from harborsight.evaluation.distance import SectionResult, markdown_obstacle_table

    def result(altitude_m, estimate_m, truth_m, obstacle, status="ok"):
        return SectionResult("f", altitude_m, "oracle", "ground_plane", 0, status, estimate_m,
                             truth_m, 0.1, False, False, obstacle)

    results = [result(30.0, 5.3, 5.0, "pier"), result(30.0, 5.1, 5.0, "pier"),
               result(60.0, 4.9, 5.0, "pier"), result(30.0, 2.0, 2.1, "quay"),
               result(30.0, None, 3.0, "quay", status="clear"),   # a miss: not an estimate
               result(30.0, 2.0, 2.1, None)]                       # not attributed
    pier, quay = summarise_by_obstacle(results)
    # pier signed px: +3, +1, -1 (0.1 m pixels)
    assert (pier.obstacle, pier.n) == ("pier", 3)
    assert pier.median_signed_px == pytest.approx(1.0) and pier.median_abs_px == pytest.approx(1.0)
    assert pier.mae_m == pytest.approx(0.5 / 3)
    assert pier.over_1px_share == pytest.approx(1 / 3) and pier.under_1px_share == 0.0
    assert pier.median_signed_px_by_altitude == pytest.approx({30.0: 2.0, 60.0: -1.0})
    assert (quay.n, quay.median_signed_px) == (1, pytest.approx(-1.0))
    table = markdown_obstacle_table([pier, quay])
    assert "| oracle | ground_plane | pier | 3 | +1.00 | 1.00 | 0.17 | 33 % | 0 % |" in table
    assert "| oracle | ground_plane | quay | -1.00 | — |" in table


def test_the_error_budget_splits_the_summed_error_by_kind_and_point_truth():
    from harborsight.evaluation.distance import (
        SectionResult,
        markdown_error_budget_table,
        summarise_error_budget,
    )

    def result(estimate_m, truth_m, obstacle, point, status="ok", masks="model:x"):
        return SectionResult("f", 30.0, masks, "ground_plane", 0, status, estimate_m, truth_m,
                             0.1, False, False, obstacle, point)

    results = [result(7.0, 5.0, "fender", "obstacle"),          # +2 m: wider, the dangerous side
               result(5.5, 5.0, "fender", "obstacle"),          # +0.5
               result(1.0, 4.0, "ship", "vessel-spill"),        # -3 m: narrower
               result(2.0, 2.5, "ship", "obstacle"),            # -0.5
               result(None, 3.0, "buoy", None, status="clear"),  # missed
               result(None, 3.0, "buoy", None, status="clear"),
               result(4.0, None, None, "false-solid"),          # false obstacle: no truth
               result(5.0, 5.1, None, "obstacle"),              # not attributed: left out
               result(5.0, 5.2, "quay", "obstacle", masks="oracle")]
    rows = summarise_error_budget(results)
    model = [r for r in rows if r.masks == "model:x"]
    # summed |error| of the attributed estimates: 2 + 0.5 + 3 + 0.5 = 6 m
    assert [(r.obstacle, r.point) for r in model] == [
        ("ship", "vessel-spill"), ("fender", "obstacle"), ("ship", "obstacle"), ("buoy", "missed")]
    spill, fender, ship, missed = model
    assert spill.error_share == pytest.approx(0.5) and (spill.wider_1m, spill.narrower_1m) == (0, 1)
    assert fender.n == 2 and fender.mae_m == pytest.approx(1.25)
    assert fender.error_share == pytest.approx(2.5 / 6) and (fender.wider_1m, fender.narrower_1m) == (1, 0)
    assert ship.error_share == pytest.approx(0.5 / 6)
    assert (missed.n, missed.mae_m, missed.error_share) == (2, None, 0.0)
    assert sum(r.error_share for r in model) == pytest.approx(1.0)
    (oracle,) = [r for r in rows if r.masks == "oracle"]
    assert (oracle.obstacle, oracle.point, oracle.error_share) == ("quay", "obstacle", 1.0)
    table = markdown_error_budget_table(rows)
    assert "| model:x | ground_plane | fender | obstacle | 2 | 1.25 | 41.7 % | 1 | 0 |" in table
    assert "| model:x | ground_plane | buoy | (missed) | 2 | — | — | — | — |" in table


def test_cli_by_obstacle_writes_the_kind_tables(tmp_path):
    result = CliRunner().invoke(app, ["evaluate", "distance", "--data", str(SAMPLES), "--out",
                                      str(tmp_path), "--methods", "ground_plane", "--by-obstacle"])
    assert result.exit_code == 0, result.output
    rows = json.loads((tmp_path / "by_obstacle.json").read_text())
    assert {r["obstacle"] for r in rows} >= {"quay", "ship", "pier"}
    assert "Median signed error (px)" in (tmp_path / "by_obstacle.md").read_text()
    assert "reported point lies on" in (tmp_path / "error_budget.md").read_text()
    with (tmp_path / "sections.csv").open() as f:
        estimates = [r for r in csv.DictReader(f) if r["kind"] == "estimate"]
    assert estimates and all(r["obstacle"] for r in estimates)
    assert sum(r["n"] for r in rows) == len(estimates)


def test_obstacle_points_are_traced_to_what_they_really_lie_on():
    from harborsight.evaluation.distance import obstacle_point_truth

    near = np.zeros((20, 30), np.uint8)
    near[5:10, 20:25] = 1
    assert obstacle_point_truth(near, (21.4, 6.0), contact=False) == "obstacle"
    assert obstacle_point_truth(near, (3.0, 3.0), contact=True) == "vessel-spill"
    assert obstacle_point_truth(near, (3.0, 3.0), contact=False) == "false-solid"
    assert obstacle_point_truth(near, (99.0, -4.0), contact=False) == "false-solid"  # clipped


def test_a_vessel_blob_spilt_onto_the_water_is_named_as_the_error_source(tmp_path):
    """Grow the vessel's own labels 6 px over the water, as a model does onto the vessel's
    shadow: the sections facing open water then read a tiny gap, and the error summary
    must put that error on the spill, not on the obstacles."""
    import cv2

    from harborsight.evaluation.distance import summarise_error_sources, write_outputs

    frames = load_frames(SAMPLES)
    oracle = evaluate_frames(SAMPLES, frames, "oracle", oracle_masks, "ground_plane")
    traced = [r for r in oracle if r.kind == "estimate"]
    assert traced and all(r.point_truth is not None for r in traced)
    assert np.mean([r.point_truth == "obstacle" for r in traced]) >= 0.95

    def spill(dataset, frame):
        labels = oracle_masks(dataset, frame).copy()
        instances = cv2.imread(str(dataset / "instances" / frame["image"]), cv2.IMREAD_UNCHANGED)
        vessel = cv2.dilate((instances == 1).astype(np.uint8), np.ones((13, 13), np.uint8))
        labels[(vessel > 0) & (labels == 0)] = 1
        return labels

    # with the sensors' (exact) pose: the pose refinement would move the vessel toward the
    # spill, which is not what this test is about
    fixed_pose = ClearanceSettings(pose_refinement=PoseRefinementSettings(enabled=False))
    results = oracle + evaluate_frames(SAMPLES, frames, "model:spill", spill, "ground_plane",
                                       clearance=fixed_pose)
    rows = {(r.masks, r.altitude_m): r for r in summarise_error_sources(results)}
    spilt = [r for (masks, _), r in rows.items() if masks == "model:spill"]
    assert spilt
    errors = {"oracle": 0.0, "model:spill": 0.0}
    spill_error = 0.0
    for r in results:
        if r.kind == "estimate":
            errors[r.masks] += r.abs_error_m
            spill_error += r.abs_error_m if r.point_truth == "vessel-spill" else 0.0
    assert errors["model:spill"] > 2 * errors["oracle"]
    total_share = sum(r.error_share["vessel-spill"] * r.mae_m * r.n for r in spilt)
    assert total_share == pytest.approx(spill_error, rel=1e-6)
    assert spill_error > 0.5 * errors["model:spill"]
    # a vessel region grown past the 6 px spill hides it (at the cost of reading a touching
    # obstacle that much farther away)
    wide = evaluate_frames(SAMPLES, frames, "model:spill", spill, "ground_plane",
                           clearance=replace(fixed_pose, pose_margin_px=8.0))
    wide_spill = sum(r.abs_error_m for r in wide
                     if r.kind == "estimate" and r.point_truth == "vessel-spill")
    assert wide_spill < 0.1 * spill_error
    # the own-vessel rim removes the spill without widening the region (8 px: the square
    # kernel's spill reaches 6·√2 px at the hull's corners), and leaves the exact labels'
    # distances as they were
    rim = replace(fixed_pose, own_rim_px=8)
    trimmed = evaluate_frames(SAMPLES, frames, "model:spill", spill, "ground_plane",
                              clearance=rim)
    trimmed_spill = sum(r.abs_error_m for r in trimmed
                        if r.kind == "estimate" and r.point_truth == "vessel-spill")
    assert trimmed_spill < 0.1 * spill_error
    oracle_rim = evaluate_frames(SAMPLES, frames, "oracle", oracle_masks, "ground_plane",
                                 clearance=rim)
    assert sum(r.abs_error_m for r in oracle_rim if r.kind == "estimate") == pytest.approx(
        errors["oracle"], rel=0.05)
    written = write_outputs(results, tmp_path)
    assert (tmp_path / "error_sources.md").is_file() and written["error_sources"]
    from harborsight.evaluation.distance import read_csv

    again = read_csv(tmp_path / "sections.csv")
    assert [r.point_truth for r in again] == [r.point_truth for r in results]


def test_bad_frames_are_skipped_and_the_rest_evaluated(tmp_path):
    """A corrupt file, a frame without truth, one without a vessel and one whose truth has
    no distance are each reported with file and field; the others are measured and written."""
    import shutil

    data = tmp_path / "data"
    shutil.copytree(SAMPLES, data)
    (data / "frames" / "000000.json").write_text("{broken")

    def edit(stem, change):
        path = data / "frames" / f"{stem}.json"
        frame = json.loads(path.read_text())
        change(frame)
        path.write_text(json.dumps(frame))

    edit("000001", lambda f: f.update(ground_truth=None))
    edit("000002", lambda f: f.pop("vessel_spec"))
    edit("000003", lambda f: f["ground_truth"]["sections"][0].update(distance_m="far"))
    problems = []
    frames = load_frames(data, problems=problems)
    assert [Path(f["image"]).stem for f in frames] == ["000002", "000004"]
    assert [Path(p).stem for p, _ in problems] == ["000000", "000001", "000003"]
    assert "ground_truth.sections" in problems[1][1]
    assert "ground_truth.sections[0].distance_m" in problems[2][1]
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["evaluate", "distance", "--data", str(data), "--out",
                                      str(out), "--methods", "ground_plane"], terminal_width=300)
    assert result.exit_code == 0, result.output
    assert "000002.json: vessel_spec:" in result.output
    assert "not readable JSON" in result.output
    rows = list(csv.DictReader((out / "sections.csv").open()))
    assert {r["frame"] for r in rows} == {"000004"}
    assert (out / "summary.md").is_file() and (out / "distance_error_box.png").is_file()


def test_a_truth_that_is_not_a_distance_or_out_of_order_costs_its_frame(tmp_path):
    """A NaN truth (JSON's NaN) was taken: its altitude's MAE, median and p95 printed NaN
    while its shares were still counted; sections listed out of order were paired with the
    report's by place (14 of 16 wrong, no word). Each now costs its frame, naming the field."""
    import shutil

    data = tmp_path / "data"
    shutil.copytree(SAMPLES, data)

    def edit(stem, change):
        path = data / "frames" / f"{stem}.json"
        frame = json.loads(path.read_text())
        change(frame)
        path.write_text(json.dumps(frame))

    edit("000000", lambda f: f["ground_truth"]["sections"][0].update(distance_m=float("nan")))
    edit("000001", lambda f: f["ground_truth"].update(sections=f["ground_truth"]["sections"][::-1]))
    problems = []
    frames = load_frames(data, problems=problems)
    assert "000000" not in [Path(f["image"]).stem for f in frames]
    assert "000001" not in [Path(f["image"]).stem for f in frames]
    reasons = dict((Path(p).stem, r) for p, r in problems)
    assert "ground_truth.sections[0].distance_m" in reasons["000000"]
    assert "ground_truth.sections[0].index" in reasons["000001"]
