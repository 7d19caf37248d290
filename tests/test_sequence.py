"""Simulated flights: the vessel berths toward its nearest obstacle at a known speed."""

from __future__ import annotations

import csv
import json
import math
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
import shapely

from harborsight.errors import InputError
from harborsight.evaluation.flight import compare_closing_speeds
from harborsight.geometry.geodesy import GeoOrigin, geodetic_to_enu
from harborsight.sim.dataset import SimulationConfig, plan_frame, simulate, split_of
from harborsight.sim.samples import flight_config, write_example_vessel
from harborsight.vessel.spec import load_vessel_spec

SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"


@pytest.fixture(scope="module")
def tug(tmp_path_factory) -> dict:
    path = write_example_vessel(tmp_path_factory.mktemp("v") / "vessels")
    return {"harbour-tug": load_vessel_spec(path)}


def test_a_flight_moves_the_vessel_toward_the_quay_at_the_set_speed(tug):
    config = flight_config()
    first, later = plan_frame(config, 0, tug), plan_frame(config, 6, tug)
    dt = 6 * config.frame_interval_s
    # same harbour, moved by -v·t·u in the vessel-centred world frame
    u = np.array(later.sequence["direction_enu"])
    quay_0 = shapely.union_all(first.obstacle_footprints())
    quay_t = shapely.union_all(later.obstacle_footprints())
    moved = shapely.affinity.translate(quay_0, *(-u * config.approach_speed_mps * dt))
    assert quay_t.symmetric_difference(moved).area < 1e-6 * quay_0.area
    # the vessel's GPS moves by +v·t·u, checked with pymap3d through our geodesy helper
    enu = geodetic_to_enu(later.origin.lat_deg, later.origin.lon_deg, 0.0,
                          GeoOrigin(first.origin.lat_deg, first.origin.lon_deg, 0.0))
    np.testing.assert_allclose(enu[:2], u * config.approach_speed_mps * dt, atol=1e-3)
    # ground truth: the section nearest the quay closes at v·cos(angle) <= v, and the
    # clearance to the union of obstacles by exactly v·t (shapely, independent of our code)
    hull_0, hull_t = first.objects[0].footprint(), later.objects[0].footprint()
    assert hull_0.distance(quay_0) - hull_t.distance(quay_t) == pytest.approx(
        config.approach_speed_mps * dt, abs=1e-6)
    gt_0, gt_t = first.ground_truth(), later.ground_truth()
    d0 = min(s["distance_all_m"] for s in gt_0["sections"] if s["distance_all_m"] is not None)
    dt_ = min(s["distance_all_m"] for s in gt_t["sections"] if s["distance_all_m"] is not None)
    assert 0 < d0 - dt_ <= config.approach_speed_mps * dt + 1e-6
    assert gt_t["sequence"]["time_s"] == pytest.approx(dt)
    t0 = datetime.fromisoformat(first.timestamp)
    assert (datetime.fromisoformat(later.timestamp) - t0).total_seconds() == pytest.approx(dt)


def test_the_vessel_stops_short_of_the_quay(tug):
    config = flight_config()
    last = plan_frame(config, config.sequence_frames - 1, tug)
    assert last.sequence["speed_mps"] == 0.0          # 8.2 m to go at 0.4 m/s: stopped by 23.5 s
    hull = last.objects[0].footprint()
    clearance = hull.distance(shapely.union_all(last.obstacle_footprints()))
    assert clearance == pytest.approx(last.sequence["stop_gap_m"], abs=1e-3)


def test_timestamps_never_run_backwards_between_long_flights(tug):
    """Flights of 150 frames at 0.5 s last 74.5 s: the next scene's clock starts 2 minutes
    after this one's (it used to start 1 minute after, inside this flight)."""
    import dataclasses

    from harborsight.sim.sequence import scene_slot_s

    assert scene_slot_s(48, 0.5) == 60.0 and scene_slot_s(120, 0.5) == 60.0
    assert scene_slot_s(121, 0.5) == 120.0 and scene_slot_s(150, 0.5) == 120.0
    config = dataclasses.replace(flight_config(), sequence_frames=150)
    last, next_first = plan_frame(config, 149, tug), plan_frame(config, 150, tug)
    gap = datetime.fromisoformat(next_first.timestamp) - datetime.fromisoformat(last.timestamp)
    assert gap.total_seconds() == pytest.approx(120.0 - 74.5)


def test_frames_of_a_flight_share_their_split():
    config = SimulationConfig(seed=1, sequence_frames=8)
    for scene in range(20):
        assert len({split_of(config, scene * 8 + k) for k in range(8)}) == 1


def test_tiny_flight_renders_with_exact_labels(tmp_path):
    pytest.importorskip("bpy")
    out = tmp_path / "flight"
    write_example_vessel(out / "vessels")
    config = SimulationConfig(seed=3, preset="tiny", altitudes_m=(40.0,),
                              vessel_spec="vessels/harbour-tug/vessel.yaml", scenario="alongside",
                              sequence_frames=3, frame_interval_s=1.0)
    summary = simulate(out, 3, config)
    assert not summary.failed, [f.error for f in summary.failed]
    metas = [json.loads((out / "frames" / f"{i:06d}.json").read_text()) for i in range(3)]
    assert all(m["simulation"]["label_agreement"] >= 0.995 for m in metas)
    assert [m["ground_truth"]["sequence"]["frame"] for m in metas] == [0, 1, 2]


def test_bundled_flight_closing_speed_matches_the_truth(tmp_path):
    """The demo flight, measured with its exact labels: the closest section's closing speed
    agrees with the ground truth (pixel quantisation is the only error source here)."""
    from typer.testing import CliRunner

    from harborsight.cli import app

    flight = SAMPLES / "flight"
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", str(flight), "--masks", str(flight / "labels"),
                                      "--out", str(out), "--no-overlays", "--no-video"])
    assert result.exit_code == 0, result.output
    comparison = compare_closing_speeds(flight, out / "sections.csv")
    assert comparison is not None and comparison.samples >= 20
    assert comparison.true_mps == pytest.approx(0.4, abs=0.05)
    assert comparison.median_abs_error_mps < 0.05
    assert math.isfinite(comparison.measured_mps)


def _synthetic_flight(root: Path, scenes: list[tuple[float, float]], frames: int = 5,
                      interval_s: float = 0.5) -> list[str]:
    """Frame JSONs of several scenes, each with its own clock from 0: section 0 starts at
    d0 and closes at a constant speed, section 1 stays 50 m off."""
    (root / "frames").mkdir(parents=True)
    images = []
    for scene, (d0, speed) in enumerate(scenes):
        for frame in range(frames):
            t = interval_s * frame
            image = f"{len(images):06d}.png"
            truth = {"sections": [{"distance_m": d0 - speed * t}, {"distance_m": 50.0}],
                     "sequence": {"scene": scene, "frame": frame, "time_s": t,
                                  "speed_mps": speed}}
            (root / "frames" / f"{len(images):06d}.json").write_text(
                json.dumps({"image": image, "ground_truth": truth}))
            images.append(image)
    return images


def _sections_csv(path: Path, rows: list[dict]) -> Path:
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, ["image", "section", "distance_m", "closing_speed_mps"])
        writer.writeheader()
        writer.writerows(rows)
    return path


def test_closing_speed_truth_stays_within_each_scene(tmp_path):
    """Two scenes closing at 0.4 and 1.0 m/s, both measured exactly: every compared frame
    takes its truth from its own scene's neighbours (3 inner frames per scene)."""
    scenes = [(10.0, 0.4), (30.0, 1.0)]
    images = _synthetic_flight(tmp_path, scenes)
    rows = []
    for index, image in enumerate(images):
        (d0, speed), frame = scenes[index // 5], index % 5
        rows.append({"image": image, "section": 0, "distance_m": d0 - speed * 0.5 * frame,
                     "closing_speed_mps": speed})
        rows.append({"image": image, "section": 1, "distance_m": 50.0, "closing_speed_mps": ""})
    comparison = compare_closing_speeds(tmp_path, _sections_csv(tmp_path / "s.csv", rows))
    assert comparison.samples == 6 and comparison.median_abs_error_mps == pytest.approx(0.0)


def test_closing_speeds_of_a_run_with_other_sections_are_refused(tmp_path):
    """A run made with --sections 3 would be compared section by section against a truth
    of 2: refused, naming the CSV (it used to compare the wrong sections)."""
    images = _synthetic_flight(tmp_path, [(10.0, 0.4)])
    rows = [{"image": image, "section": k, "distance_m": 10.0, "closing_speed_mps": 0.4}
            for image in images for k in range(3)]
    with pytest.raises(InputError, match=r"s\.csv: section: 000000\.png: the run measured 3"):
        compare_closing_speeds(tmp_path, _sections_csv(tmp_path / "s.csv", rows))


def test_closing_speed_is_compared_for_the_closest_section_only(tmp_path):
    """Section 1 is the closest (2 m) but has no speed (e.g. truncated): the frame is not
    compared, rather than comparing the farther section 0."""
    images = _synthetic_flight(tmp_path, [(10.0, 0.4)])
    rows = []
    for frame, image in enumerate(images):
        rows.append({"image": image, "section": 0, "distance_m": 10.0 - 0.2 * frame,
                     "closing_speed_mps": 0.4})
        rows.append({"image": image, "section": 1, "distance_m": 2.0, "closing_speed_mps": ""})
    assert compare_closing_speeds(tmp_path, _sections_csv(tmp_path / "s.csv", rows)) is None


def test_flight_frame_yaw_stays_within_a_turn(tug):
    """The hover jitter added to a yaw drawn near 360 went past it (360.01), which the frame
    parser refuses (yaw within [-360, 360]): such a flight's frames could not be measured."""
    import dataclasses

    from harborsight.sim.sequence import sequence_frame

    config = flight_config()
    scene = dataclasses.replace(plan_frame(config, 0, tug), yaw_deg=359.95)
    yaws = [sequence_frame(scene, 0, k, 0.5, 0.4, np.random.default_rng(k)).yaw_deg
            for k in range(40)]
    assert all(0.0 <= y < 360.0 for y in yaws)
    assert any(y < 1.0 for y in yaws) and any(y > 359.0 for y in yaws)


def test_boats_under_way_keep_their_course_in_a_flight(tmp_path):
    """Each flight frame rebuilds the harbour's objects shifted; their course was dropped, so
    a boat under way lost its wake in every flight frame. A lake shore planned as one frame
    and as a flight's first frame has the same boats under way."""
    from harborsight.sim.dataset import SimulationConfig, plan_frame, prepare_vessels
    from harborsight.vessel.spec import load_vessel_spec

    under_way = []
    for seed in (4, 5, 6):
        still = SimulationConfig(seed=seed, scenario="lakeshore", altitudes_m=(40.0,))
        flight = SimulationConfig(seed=seed, scenario="lakeshore", altitudes_m=(40.0,),
                                  sequence_frames=4)
        vessels = {n: load_vessel_spec(p)
                   for n, p in prepare_vessels(tmp_path / f"v{seed}", still).items()}
        courses = [[o.course_deg for o in plan_frame(config, 0, vessels).objects]
                   for config in (still, flight)]
        assert courses[0] == courses[1]
        under_way.append(sum(c is not None for c in courses[0]))
    assert sum(under_way) >= 2
