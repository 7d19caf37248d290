"""The vessel's pose carried from frame to frame by the images (flight/pose_carry.py): a
class B AIS transponder reports every 30 s, or every 3 min under 2 kn, and a pose
dead-reckoned past 12 s is not measured with; the poses the frames' images placed carry the
vessel instead."""

import json
import math
import shutil
import time
from dataclasses import replace
from datetime import datetime, timedelta
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from pyproj import Geod
from typer.testing import CliRunner

from harborsight.clearance.measure import measure_frame
from harborsight.clearance.pose_refinement import SENSORS_FIT
from harborsight.clearance.report import ClearanceReport
from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.flight.pose_carry import (
    CARRY_REACH_S,
    FLOOR_DEG,
    FLOOR_M,
    VesselPoseCarry,
    placed_pose,
)
from harborsight.frame import parse_frame_metadata
from harborsight.geometry.sensor_sigmas import SensorSigmas
from harborsight.images import read_mask
from harborsight.vessel.spec import load_vessel_spec
from tests.helpers import CLASS_B_MMSI, class_b_ais_log

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
FLIGHT = SAMPLES / "flight"
VESSEL = SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml"
GEOD = Geod(ellps="WGS84")


def _meta(index: int = 0, **changes):
    path = FLIGHT / "frames" / f"{index:06d}.json"
    meta = parse_frame_metadata(json.loads(path.read_text()), str(path))
    return replace(meta, **changes) if changes else meta


def _report(refinement: dict | None) -> ClearanceReport:
    return ClearanceReport(image="x.png", timestamp=None, altitude_m=40.0, gsd_m_per_px=0.05,
                           method="ground_plane", sections=[], pose_refinement=refinement)


def _applied(east: float, north: float, turn_deg: float) -> dict:
    return {"applied": True, "shift_m": [east, north], "rotation_deg": turn_deg,
            "reason": None, "sensors_contradicted": False}


def _moving_vessel(t_s: float, speed_mps=0.6, course_deg=40.0, turn_deg_s=0.8):
    """A vessel on a straight course at a steady speed, turning its heading steadily (pyproj's
    geodesic, not the code's pymap3d)."""
    meta0 = _meta()
    lon, lat, _ = GEOD.fwd(meta0.vessel_lon_deg, meta0.vessel_lat_deg, course_deg, speed_mps * t_s)
    return lat, lon, (100.0 + turn_deg_s * t_s) % 360.0


def _carry_with(times_s) -> VesselPoseCarry:
    """A carry that took the moving vessel's true pose at ``times_s``, each as a frame whose
    sensors put it 1.5 m east and 2 degrees off and whose image corrected that."""
    carry = VesselPoseCarry()
    for t in times_s:
        lat, lon, heading = _moving_vessel(t)
        lon_off, lat_off, _ = GEOD.fwd(lon, lat, 270.0, 1.5)        # the sensors: 1.5 m west
        meta = _meta(vessel_lat_deg=lat_off, vessel_lon_deg=lon_off,
                     vessel_heading_deg=heading - 2.0)
        carry.took(meta, _report(_applied(1.5, 0.0, 2.0)), t)
    return carry


def test_the_placed_poses_carry_a_moving_turning_vessel_to_a_later_frame():
    carry = _carry_with([0.0, 0.5, 1.0, 1.5, 2.0])
    for age in (0.0, 0.5, 2.0, 5.0):
        carried = carry.carried(2.0 + age)
        lat, lon, heading = _moving_vessel(2.0 + age)
        off_m = GEOD.inv(carried.lon_deg, carried.lat_deg, lon, lat)[2]
        assert off_m < 0.02, (age, off_m)
        assert abs((carried.heading_deg - heading + 180) % 360 - 180) < 0.01
        # sigmas, by hand: 5 poses over 2 s on an exact line (their scatter the floor,
        # 0.15 m and 0.3 deg), mean time 1 s before the newest, Σ(t - t̄)² = 2.5 s²; the lag
        # of a 2 s line under 0.05 m/s²; the floor; the turn at 0.5 deg/s
        share = 1 / 5 + (age + 1.0) ** 2 / 2.5
        lag_m = 0.025 * (age ** 2 + 2.0 * age + 4.0 / 6.0)
        assert carried.sigma_m == pytest.approx(math.sqrt(FLOOR_M ** 2 + 2 * 0.15 ** 2 * share
                                                          + lag_m ** 2))
        assert carried.heading_sigma_deg == pytest.approx(math.sqrt(
            FLOOR_DEG ** 2 + 0.3 ** 2 * share + (0.5 * age) ** 2))
        assert (carried.age_s, carried.image) == (pytest.approx(age), _meta().image)
    assert carry.carried(2.0 + CARRY_REACH_S + 0.01) is None       # beyond its reach
    assert carry.carried(2.0 + 9.5) is None                         # its sigma past 3 m
    assert carry.carried(1.0) is None                               # not back in time
    assert carry.carried(None) is None and carry.carried(math.nan) is None


def test_the_carried_sigma_holds_for_noisy_placements_and_a_steady_acceleration():
    """Placed poses scattered 0.15 m per axis and 0.3 deg about a vessel accelerating at
    0.05 m/s² (what the sigmas assume): the carried pose within two of its sigmas (DRMS:
    98 % of a circular normal) at least 95 % of the time at every reach, 2 fps and stills
    every 2 s, with at most 5 % of the carries refused (the scatter read as a harder
    acceleration, which widens the sigma past 3 m); and a carry from few poses over a short
    span is wider, or refused."""
    rng = np.random.default_rng(3)
    meta0 = _meta()
    for times in (np.arange(0.0, 3.01, 0.5), np.array([0.0, 2.0, 4.0])):
        for age in (0.5, 2.0, 4.0):
            inside = refused = 0
            for _ in range(300):
                carry = VesselPoseCarry()
                for t in times:
                    along = 0.5 * t + 0.025 * t ** 2 + rng.normal(0, 0.15)
                    across = rng.normal(0, 0.15)
                    lon, lat, _ = GEOD.fwd(meta0.vessel_lon_deg, meta0.vessel_lat_deg, 40.0, along)
                    lon, lat, _ = GEOD.fwd(lon, lat, 130.0, across)
                    meta = replace(meta0, vessel_lat_deg=lat, vessel_lon_deg=lon,
                                   vessel_heading_deg=100.0 + rng.normal(0, 0.3))
                    carry.took(meta, _report(_applied(0.0, 0.0, 0.0)), t)
                when = times[-1] + age
                carried = carry.carried(when)
                if carried is None:
                    refused += 1
                    continue
                truth = 0.5 * when + 0.025 * when ** 2
                lon, lat, _ = GEOD.fwd(meta0.vessel_lon_deg, meta0.vessel_lat_deg, 40.0, truth)
                inside += GEOD.inv(carried.lon_deg, carried.lat_deg, lon, lat)[2] <= 2 * carried.sigma_m
            assert refused <= 0.05 * 300 and inside >= 0.95 * (300 - refused), (times, age, inside, refused)
    short = _carry_with([0.0, 0.5, 1.0]).carried(5.0)
    longer = _carry_with([0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]).carried(7.0)
    assert short is None or short.sigma_m > longer.sigma_m


@pytest.mark.parametrize("accel_mps2", [0.3, -0.3])
def test_a_vessel_speeding_up_or_stopping_hard_widens_the_carried_sigma(accel_mps2):
    """A tug under full thrust (0.3 m/s², from 0.2 m/s; or stopping from 2 m/s), placed every
    half second for 6 s with 0.15 m of scatter: the straight line carried it 1.4-1.6 m off
    2 s past the newest pose with a sigma of 0.67 m (0 and 5 of 40 within two sigmas). The
    placed poses' own acceleration now widens the sigma: at least 95 % of the carries within
    two of their sigmas, the rest refused once the sigma passes 3 m."""
    rng = np.random.default_rng(5)
    meta0 = _meta()
    v0 = 0.2 if accel_mps2 > 0 else 2.0

    def along(t):
        return v0 * t + 0.5 * accel_mps2 * t ** 2

    for age in (1.0, 2.0, 3.0):
        inside = carried_n = 0
        for _ in range(40):
            carry = VesselPoseCarry()
            for t in np.arange(0.0, 6.01, 0.5):
                lon, lat, _ = GEOD.fwd(meta0.vessel_lon_deg, meta0.vessel_lat_deg, 40.0,
                                       along(t) + rng.normal(0, 0.15))
                lon, lat, _ = GEOD.fwd(lon, lat, 130.0, rng.normal(0, 0.15))
                carry.took(replace(meta0, vessel_lat_deg=lat, vessel_lon_deg=lon),
                           _report(_applied(0.0, 0.0, 0.0)), t)
            carried = carry.carried(6.0 + age)
            if carried is None:
                continue
            carried_n += 1
            lon, lat, _ = GEOD.fwd(meta0.vessel_lon_deg, meta0.vessel_lat_deg, 40.0, along(6.0 + age))
            inside += GEOD.inv(carried.lon_deg, carried.lat_deg, lon, lat)[2] <= 2 * carried.sigma_m
        assert inside >= 0.95 * carried_n, (age, inside, carried_n)
        if age <= 2.0:
            assert carried_n == 40          # short carries still made


def test_too_few_or_too_close_placed_poses_carry_nothing():
    assert _carry_with([0.0, 0.5]).carried(1.0) is None           # no speed from two
    assert _carry_with([0.0, 0.3, 0.6]).carried(1.0) is None      # a span under a second
    assert _carry_with([0.0, 0.5, 1.0]).carried(1.5) is not None
    # placed poses older than the fit's window are dropped: the newest three span 1 s
    carry = _carry_with([0.0, 0.5, 1.0, 10.0, 10.5, 11.0])
    assert carry.carried(11.5).age_s == pytest.approx(0.5) and len(carry._placed) == 3
    carry.forget()
    assert carry.carried(11.5) is None
    # stills every 2 s: the newest three, over 4 s, carry the vessel to the next
    stills = _carry_with([0.0, 2.0, 4.0, 6.0])
    carried = stills.carried(8.0)
    lat, lon, _ = _moving_vessel(8.0)
    assert len(stills._placed) == 3 and GEOD.inv(carried.lon_deg, carried.lat_deg, lon, lat)[2] < 0.02
    assert _carry_with([0.0, 7.0, 14.0]).carried(16.0) is None    # over 12 s: too old a speed
    # a stretch of frames that placed nothing, then one that did, carries on
    assert _carry_with([*np.arange(0.0, 10.0, 0.5), 12.5]).carried(13.0) is not None
    # a clock that jumped back starts the carry again: a placed frame, or a frame to carry
    carry = _carry_with([100.0, 100.5, 101.0])
    carry.took(_meta(), _report(_applied(0.0, 0.0, 0.0)), 20.0)
    assert len(carry._placed) == 1 and carry.carried(20.5) is None
    carry = _carry_with([100.0, 100.5, 101.0])
    carry.prior_for(_meta(vessel_dead_reckoned_s=40.0), 99.5, SensorSigmas(vessel_gps=150.0), "")
    assert len(carry._placed) == 0
    carry = _carry_with([100.0, 100.5, 101.0])        # a frame half a second late: kept
    carry.prior_for(_meta(vessel_dead_reckoned_s=40.0), 100.5, SensorSigmas(vessel_gps=150.0), "")
    assert len(carry._placed) == 3
    # stills every 5 s carry too (the newest three span 10 s)
    assert _carry_with([0.0, 5.0, 10.0]).carried(15.0) is not None


def test_only_a_pose_the_image_placed_is_taken():
    meta = _meta()
    assert placed_pose(meta, _report(None), 0.0) is None                       # refinement off
    kept = {"applied": False, "shift_m": [3.0, 0.0], "rotation_deg": 1.0,
            "reason": "30 % of the outline fits a ship edge", "sensors_contradicted": False}
    assert placed_pose(meta, _report(kept), 0.0) is None
    assert placed_pose(meta, _report({**_applied(3.0, 0.0, 1.0), "sensors_contradicted": True}),
                       0.0) is None
    fitted = placed_pose(meta, _report({**kept, "reason": SENSORS_FIT}), 0.0)
    assert fitted.lat_lon_deg == pytest.approx((meta.vessel_lat_deg, meta.vessel_lon_deg))
    moved = placed_pose(meta, _report(_applied(3.0, -4.0, 1.0)), 0.0)
    lat, lon = moved.lat_lon_deg
    azimuth, _, distance = GEOD.inv(meta.vessel_lon_deg, meta.vessel_lat_deg, lon, lat)
    assert distance == pytest.approx(5.0, abs=1e-3)
    assert azimuth % 360 == pytest.approx(math.degrees(math.atan2(3.0, -4.0)) % 360, abs=0.01)
    assert moved.heading_deg == pytest.approx((meta.vessel_heading_deg + 1.0) % 360)
    # a frame out of order, or without a time, is not taken
    carry = _carry_with([0.0, 0.5, 1.0])
    carry.took(meta, _report(_applied(0.0, 0.0, 0.0)), 0.7)
    carry.took(meta, _report(_applied(0.0, 0.0, 0.0)), None)
    assert carry.carried(1.5) is not None and len(carry._placed) == 3


def test_only_a_dead_reckoned_frame_takes_the_carried_pose_and_only_a_better_one():
    carry = _carry_with([0.0, 0.5, 1.0, 1.5, 2.0])
    live_fix = _meta()
    assert carry.prior_for(live_fix, 2.5, SensorSigmas(), "") == (live_fix, None, None)
    reckoned = _meta(vessel_dead_reckoned_s=40.0)
    meta, carried, disagreement = carry.prior_for(reckoned, 2.5, SensorSigmas(vessel_gps=150.0), "")
    assert carried is not None and disagreement is None and meta.vessel_dead_reckoned_s is None
    assert (meta.vessel_lat_deg, meta.vessel_lon_deg) == (carried.lat_deg, carried.lon_deg)
    # the sigmas go in as the frame's own: per axis for the position
    assert meta.sensor_sigmas["vessel_gps"] == pytest.approx(carried.sigma_m / math.sqrt(2))
    assert meta.sensor_sigmas["vessel_heading_deg"] == carried.heading_sigma_deg
    # an RTK fix a second old is better than what the image carries
    assert carry.prior_for(_meta(vessel_dead_reckoned_s=1.0), 2.5,
                           SensorSigmas(vessel_gps=0.1), "")[1] is None
    # another vessel: nothing carried to it, and the carry starts again
    assert carry.prior_for(reckoned, 2.5, SensorSigmas(vessel_gps=150.0), "barge")[1] is None
    assert len(carry._placed) == 0


def test_a_measurable_report_that_disagrees_with_the_carry_wins():
    """A report 0.3 s old lying 12 m (or 12 deg) from the carried pose: more than three
    combined sigmas (2 m receivers and the carry: 8.7 m; 2 deg compasses: 8.8 deg). The frame
    keeps its report, with a warning, and the carry starts again; a report 40 s old cannot
    be measured with, so the carry stands."""
    carry = _carry_with([0.0, 0.5, 1.0, 1.5, 2.0])
    carried = carry.carried(2.5)
    lon, lat, _ = GEOD.fwd(carried.lon_deg, carried.lat_deg, 200.0, 12.0)
    report = _meta(vessel_lat_deg=lat, vessel_lon_deg=lon, vessel_heading_deg=carried.heading_deg,
                   vessel_dead_reckoned_s=0.3)
    meta, taken, disagreement = carry.prior_for(report, 2.5, SensorSigmas(), "")
    assert meta is report and taken is None and len(carry._placed) == 0
    assert disagreement.startswith("the vessel's report lies 12.0 m and 0.0 deg from the pose")
    stale = replace(report, vessel_dead_reckoned_s=40.0)
    assert _carry_with([0.0, 0.5, 1.0, 1.5, 2.0]).prior_for(stale, 2.5, SensorSigmas(), "")[1]
    turned = replace(report, vessel_lat_deg=carried.lat_deg, vessel_lon_deg=carried.lon_deg,
                     vessel_heading_deg=carried.heading_deg + 12.0)
    assert _carry_with([0.0, 0.5, 1.0, 1.5, 2.0]).prior_for(turned, 2.5, SensorSigmas(), "")[2]
    near = replace(turned, vessel_heading_deg=carried.heading_deg + 3.0)
    assert _carry_with([0.0, 0.5, 1.0, 1.5, 2.0]).prior_for(near, 2.5, SensorSigmas(), "")[1]


def test_a_pose_dead_reckoned_past_twelve_seconds_is_not_measured_with():
    labels = read_mask(FLIGHT / "labels" / "000000.png")
    vessel = load_vessel_spec(VESSEL)
    assert measure_frame(labels, _meta(vessel_dead_reckoned_s=12.0), vessel).sections
    with pytest.raises(InputError) as caught:
        measure_frame(labels, _meta(vessel_dead_reckoned_s=95.0), vessel)
    assert caught.value.field == "vessel.dead_reckoned_s"
    assert "carried 95 s from its last position report, beyond the 12 s" in str(caught.value)


def _class_b_flight(root: Path, placed_frames: int, off_m: float = 2.0, turn_deg: float = 2.0,
                    hidden: range = range(0)) -> Path:
    """The bundled flight as a class B transponder gives it: the first ``placed_frames``
    frames with the true pose, a second from their report; the rest with a pose dead-reckoned
    from a report 20-44 s before, ``off_m`` metres east and ``turn_deg`` off. The frames
    ``hidden`` show no ship at all (their ship pixels made water: under a bridge)."""
    import cv2

    flight = root / "flight"
    shutil.copytree(FLIGHT / "images", flight / "images")
    shutil.copytree(FLIGHT / "labels", flight / "labels")
    for k in hidden:
        path = flight / "labels" / f"{k:06d}.png"
        labels = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        labels[labels == 1] = 0
        cv2.imwrite(str(path), labels)
    (flight / "frames").mkdir()
    start = None
    for path in sorted((FLIGHT / "frames").glob("*.json")):
        meta = json.loads(path.read_text())
        meta.pop("vessel_spec", None)
        when = datetime.fromisoformat(meta["timestamp"].replace("Z", "+00:00"))
        start = start or when
        if int(path.stem) < placed_frames:
            meta["vessel"]["dead_reckoned_s"] = 1.0
        else:
            lon, lat, _ = GEOD.fwd(meta["vessel"]["lon"], meta["vessel"]["lat"], 90.0, off_m)
            meta["vessel"].update(lat=lat, lon=lon, heading_deg=meta["vessel"]["heading_deg"] + turn_deg,
                                  dead_reckoned_s=20.0 + (when - start) / timedelta(seconds=1))
        (flight / "frames" / path.name).write_text(json.dumps(meta))
    return flight


def _section_errors(out: Path) -> tuple[list[float], int]:
    errors, carried = [], 0
    for path in sorted((out / "reports").glob("*.json")):
        report = json.loads(path.read_text())
        truth = json.loads((FLIGHT / "frames" / f"{path.stem}.json").read_text())
        expected = {s["index"]: s["distance_m"] for s in truth["ground_truth"]["sections"]}
        carried += bool(report["pose_refinement"].get("carried_from"))
        errors += [abs(s["distance_m"] - expected[s["index"]]) for s in report["sections"]
                   if s["status"] == "ok" and expected.get(s["index"]) is not None]
    return errors, carried


def run_with_masks(flight: Path, out: Path, *options: str, masks: Path | None = None):
    """`harborsight run` on a frames folder with its label masks (``flight/labels`` unless
    given; no video, no overlays): the CLI's result, and run.json."""
    masks = masks or flight / "labels"
    result = CliRunner().invoke(app, ["run", str(flight), "--masks", str(masks),
                                      "--vessel", str(VESSEL), "--out", str(out), "--no-video",
                                      "--no-overlays", *options])
    assert result.exit_code == 0, result.output
    return result, json.loads((out / "run.json").read_text())


def test_run_measures_a_class_b_vessel_s_frames_from_the_poses_its_images_placed(tmp_path):
    flight = _class_b_flight(tmp_path, placed_frames=4)
    out = tmp_path / "out"
    result, record = run_with_masks(flight, out)
    # frames 0-2 start the carry; from frame 3 on every frame is carried
    assert (record["measured"], record["skipped"], record["pose_refinement"]["carried"]) == (48, 0, 45)
    assert "carried from earlier frames' images on 45" in " ".join(result.output.split())
    errors, carried = _section_errors(out)
    # as good as with the true pose on every frame (exact labels: median 0.057 m)
    run_with_masks(FLIGHT, tmp_path / "exact")
    exact_errors, _ = _section_errors(tmp_path / "exact")
    assert carried == 45 and len(errors) == len(exact_errors)
    assert np.median(errors) < np.median(exact_errors) + 0.01
    assert np.mean(errors) < np.mean(exact_errors) + 0.01 and max(errors) < 0.3

    # the vessel hidden for 5 s (frames 20-29: flagged, its pose contradicted), then found
    # again by the carry (its sigma 1.4 m after 5.5 s) and carried on to the end
    hidden = _class_b_flight(tmp_path / "hidden", placed_frames=4, hidden=range(20, 30))
    _, record = run_with_masks(hidden, tmp_path / "out-hidden")
    assert record["measured"] == 48
    found_again = tmp_path / "found-again"
    (found_again / "reports").mkdir(parents=True)
    for k in range(30, 48):
        shutil.copy(tmp_path / "out-hidden" / "reports" / f"{k:06d}.json", found_again / "reports")
    errors, carried = _section_errors(found_again)
    assert carried == 18 and np.mean(errors) < 0.1

    # without the refinement nothing is placed: the frames past 12 s are refused, by name
    _, record = run_with_masks(flight, tmp_path / "off", "--no-refine-pose")
    assert (record["measured"], record["skipped"]) == (4, 44)
    assert all("vessel.dead_reckoned_s" in s["error"] for s in record["skipped_frames"])


def test_the_live_aid_measures_a_class_b_vessel_from_the_poses_its_images_placed():
    """The newest AIS report 30 s old: frames 0-3 a second dead-reckoned (measured, the
    vessel's source stale), then 40 s and 2 m off: carried by the images, measured, the
    vessel's source not stale while they are; without the refinement, refused by name."""
    import cv2

    from harborsight.clearance.measure import ClearanceSettings
    from harborsight.clearance.pose_refinement import PoseRefinementSettings
    from harborsight.live.alarms import AlarmSettings
    from harborsight.live.engine import LiveEngine
    from harborsight.pipeline import VesselCache

    def frames():
        for k in range(8):
            meta_path = FLIGHT / "frames" / f"{k:06d}.json"
            meta = _meta(k, vessel_dead_reckoned_s=1.0)
            if k >= 4:
                lon, lat, _ = GEOD.fwd(meta.vessel_lon_deg, meta.vessel_lat_deg, 90.0, 2.0)
                meta = replace(meta, vessel_lat_deg=lat, vessel_lon_deg=lon,
                               vessel_dead_reckoned_s=40.0)
            yield k, cv2.imread(str(FLIGHT / "images" / meta.image)), meta, meta_path

    for refine in (True, False):
        engine = LiveEngine(None, VesselCache(load_vessel_spec(VESSEL)),
                            ClearanceSettings(pose_refinement=PoseRefinementSettings(enabled=refine)),
                            AlarmSettings(vessel_stale_s=12.0))
        start = time.monotonic()        # the state is built at the process's own time
        engine.source_arrived("vessel", start - 30.0)
        states = []
        for k, image, meta, meta_path in frames():
            now = start + 0.5 * k
            engine.source_arrived("video", now)
            engine.source_arrived("drone", now)
            states.append(engine.process(k, image, meta, meta_path, 0.5 * k, now,
                                         mask_path=FLIGHT / "labels" / f"{k:06d}.png"))
        kinds = [{a["kind"] for a in state["alarms"]} for state in states]
        if refine:
            assert engine.frames_measured == 8
            assert all("stale_vessel" in kinds[k] for k in range(3))
            for state, kind in zip(states[3:], kinds[3:], strict=True):
                assert state["pose_refinement"]["carried_from"]["age_s"] == pytest.approx(0.5)
                assert state["sources"]["vessel"]["placed_by_image"] and not state["stale"]
                assert not kind & {"stale_vessel", "frame_error"}
                assert state["min_distance_m"] is not None
        else:
            assert engine.frames_measured == 4
            assert all("frame_error" in kinds[k] and "stale_vessel" in kinds[k] for k in range(4, 8))
            assert any("vessel.dead_reckoned_s" in a["message"] for a in states[-1]["alarms"])


def test_the_overlay_says_a_pose_was_carried():
    from harborsight.viz.overlay import _pose_note

    carried = {"image": "000003.jpg", "age_s": 0.5, "sigma_m": 0.5, "heading_sigma_deg": 1.0}
    applied = {**_applied(0.3, 0.4, 1.0), "height_change_m": 0.0}
    assert _pose_note(applied) == "  pose +0.5 m +1.0 deg"
    assert _pose_note({**applied, "carried_from": carried}) == "  pose +0.5 m +1.0 deg (carried)"
    fitted = {"applied": False, "reason": SENSORS_FIT, "sensors_contradicted": False}
    assert _pose_note({**fitted, "carried_from": carried}) == "  pose: carried"
    assert _pose_note(fitted) == "  pose: sensors"


def _with_sister_hull(labels: np.ndarray, meta, to_port_m: float) -> np.ndarray:
    """``labels`` with a copy of the vessel's own ship pixels ``to_port_m`` to its port side,
    painted on the water (the copy is moved by the pixel shift of the hull's middle)."""
    import cv2

    from harborsight.frame import FrameGeometry

    vessel = load_vessel_spec(VESSEL)
    middle = np.array([[(vessel.hull_points[:, 0].min() + vessel.hull_points[:, 0].max()) / 2, 0, 0]])
    geometry = FrameGeometry.from_metadata(meta)
    port_deg = math.radians(meta.vessel_heading_deg - 90.0)
    moved = replace(geometry, vessel_position_enu=to_port_m * np.array([math.sin(port_deg),
                                                                       math.cos(port_deg)]))
    here = geometry.camera.project(geometry.vessel_to_enu(middle))[0][0]
    there = moved.camera.project(moved.vessel_to_enu(middle))[0][0]
    _, blobs = cv2.connectedComponents((labels == 1).astype(np.uint8))
    row, column = np.rint(here[::-1]).astype(int)
    own = (blobs == blobs[row, column]).astype(np.uint8)
    shift = np.float32([[1, 0, there[0] - here[0]], [0, 1, there[1] - here[1]]])
    copy = cv2.warpAffine(own, shift, labels.shape[::-1], flags=cv2.INTER_NEAREST) > 0
    out = labels.copy()
    out[copy & (labels == 0)] = 1
    return out


def test_a_carry_that_began_on_a_sister_hull_gives_way_to_the_reports(tmp_path):
    """A sister hull 12 m to port; the first four frames' report (a second old) puts the
    vessel 11 m toward it, so those frames are laid on the sister; every later frame has a
    right report (class A, 0.5-10 s dead-reckoned). The carry began on the sister: the first
    right report lies 11 m from it, beyond three sigmas, and wins (it followed the sister to
    the end of the flight before: 3.98 m mean error against 0.063 m)."""
    import cv2

    flight = tmp_path / "flight"
    shutil.copytree(FLIGHT / "images", flight / "images")
    (flight / "labels").mkdir()
    (flight / "frames").mkdir()
    for path in sorted((FLIGHT / "frames").glob("*.json")):
        k = int(path.stem)
        record = json.loads(path.read_text())
        record.pop("vessel_spec", None)
        labels = cv2.imread(str(FLIGHT / "labels" / f"{path.stem}.png"), cv2.IMREAD_UNCHANGED)
        meta = parse_frame_metadata(json.loads(path.read_text()), str(path))
        cv2.imwrite(str(flight / "labels" / f"{path.stem}.png"), _with_sister_hull(labels, meta, 12.0))
        if k < 4:
            lon, lat, _ = GEOD.fwd(meta.vessel_lon_deg, meta.vessel_lat_deg,
                                   meta.vessel_heading_deg - 90.0, 11.0)
            record["vessel"].update(lat=lat, lon=lon, dead_reckoned_s=1.0)
        else:
            record["vessel"]["dead_reckoned_s"] = round(0.5 + (0.5 * k) % 10.0, 3)
        (flight / "frames" / path.name).write_text(json.dumps(record))
    out = tmp_path / "out"
    _, record = run_with_masks(flight, out)
    assert record["measured"] == 48
    said = [w["warning"] for w in record["warnings"] if "carry starts again" in w["warning"]]
    assert len(said) == 1 and "000004" in said[0]
    later = tmp_path / "later"
    (later / "reports").mkdir(parents=True)
    for k in range(4, 48):
        shutil.copy(out / "reports" / f"{k:06d}.json", later / "reports")
    errors, _ = _section_errors(later)
    assert np.mean(errors) < 0.1 and max(errors) < 0.5


def test_a_class_b_ais_log_through_telemetry_video_and_run(tmp_path):
    """A user's path: the bundled flight's vessel as a class B transponder under 2 kn gives it
    (a type 18 report at the start with speed and course, the next 3 min later), through
    `telemetry video` (every frame written, those past 12 s said) and `run` with the default
    model: every frame measured, the frames past 12 s carried by the images. (With the next
    report in the log, a blend of the two once put a frame a second from the first at 13 s
    of age: 46 of 48 frames refused.)"""
    logs = FLIGHT / "logs"
    ais = class_b_ais_log(tmp_path / "ship.ais", logs / "ship.nmea", sentence_type="VDO")
    metadata = tmp_path / "flight.jsonl"
    result = CliRunner().invoke(app, [
        "telemetry", "video", str(logs / "flight.SRT"), "--vessel-track", str(ais), "--camera",
        "dji-mavic3", "--water-level-m", "0", "--video", str(logs / "flight.mp4"),
        "--video-start", "2026-05-01T12:00:00Z", "--out", str(metadata)])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "48 of 48 frame(s) written" in text
    assert "23 of them carry the vessel more than 12 s from its last report" in text
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["run", str(logs / "flight.mp4"), "--metadata", str(metadata),
                                      "--vessel", str(VESSEL), "--out", str(out), "--no-video",
                                      "--no-overlays"])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "run.json").read_text())
    assert (record["measured"], record["skipped"]) == (48, 0)
    assert record["pose_refinement"]["carried"] >= 40


def test_stills_every_two_seconds_with_a_class_b_vessel_are_carried_by_run(tmp_path):
    """DJI photos of the bundled flight every 2 s (tests/test_dji_photo.py), the vessel from one
    class B report at the start: `telemetry photos` writes every frame and says which carry the
    vessel past 12 s, and `run` on the folder (stills: the newest three placed poses) measures
    every one of them, against the flight's truth (the next report 3 min later in the log)."""
    from tests.test_dji_photo import _flight_photo

    indices = range(0, 48, 4)                       # every 2 s, on whole seconds
    masks = tmp_path / "masks"
    masks.mkdir()
    for index in indices:
        _flight_photo(tmp_path, index)
        shutil.copy(FLIGHT / "labels" / f"{index:06d}.png", masks / f"DJI_{index:04d}.png")
    ais = class_b_ais_log(tmp_path / "ship.ais", FLIGHT / "logs" / "ship.nmea")
    result = CliRunner().invoke(app, ["telemetry", "photos", str(tmp_path / "photos"),
                                      "--vessel-track", str(ais), "--mmsi", str(CLASS_B_MMSI),
                                      "--water-level-m", "0", "--out", str(tmp_path / "frames")])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "12 of 12 photo(s) written" in text
    assert "5 of them carry the vessel more than 12 s" in text and "not `measure`" in text
    out = tmp_path / "out"
    _, record = run_with_masks(tmp_path / "frames", out, masks=masks)
    assert (record["measured"], record["skipped"]) == (12, 0) and record["pose_refinement"]["carried"] >= 5
    errors = []
    for index in indices:
        report = json.loads((out / "reports" / f"DJI_{index:04d}.json").read_text())
        truth = json.loads((FLIGHT / "frames" / f"{index:06d}.json").read_text())
        expected = {s["index"]: s["distance_m"] for s in truth["ground_truth"]["sections"]}
        errors += [abs(s["distance_m"] - expected[s["index"]]) for s in report["sections"]
                   if s["status"] == "ok" and expected.get(s["index"]) is not None]
    assert np.median(errors) < 0.1
