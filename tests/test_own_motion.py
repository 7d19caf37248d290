"""The vessel's own motion of each clearance: frame fields, the rate per section, the
simulator's and the telemetry readers' velocities, the noise on them, and the run's use."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import shapely

from harborsight.clearance.own_motion import (
    UNMEASURED_TURN_DEG_S,
    VELOCITY_SIGMA_MPS,
    YAW_RATE_SIGMA_DEG_S,
    add_own_rates,
)
from harborsight.clearance.report import STATUS_CLEAR, STATUS_OK, SectionClearance
from harborsight.errors import InputError
from harborsight.frame import parse_frame_metadata
from harborsight.sim.dataset import plan_frame
from harborsight.sim.pose_noise import PoseNoise, add_pose_noise
from harborsight.sim.samples import flight_config, write_example_vessel
from harborsight.telemetry.metadata import own_motion_fields
from harborsight.vessel.spec import load_vessel_spec
from tests.test_telemetry import _nmea

SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"


def _section(hull, obstacle, status=STATUS_OK) -> SectionClearance:
    return SectionClearance(index=0, status=status, hull_px=[[0, 0], [1, 1]], visible_fraction=1.0,
                            distance_m=float(np.hypot(*np.subtract(obstacle, hull))),
                            hull_point_enu=list(hull), obstacle_point_enu=list(obstacle))


def _gap_after(hull, obstacle, antenna, velocity, yaw_rate_deg_s, dt):
    """The gap after ``dt`` s of the vessel's rigid motion (shapely): the hull point moved
    with the antenna and turned about it by the heading's rate (clockwise)."""
    turn = -math.radians(yaw_rate_deg_s) * dt           # anticlockwise angle in ENU
    point = shapely.affinity.rotate(shapely.Point(hull), turn, origin=tuple(antenna),
                                    use_radians=True)
    point = shapely.affinity.translate(point, velocity[0] * dt, velocity[1] * dt)
    return point.distance(shapely.Point(obstacle))


@pytest.mark.parametrize("hull, obstacle", [((0.0, 5.0), (0.0, 10.0)), ((3.0, 0.0), (8.0, 0.0)),
                                             ((0.0, 10.0), (5.0, 10.0)), ((-4.0, 7.0), (-6.5, 11.0))])
def test_the_own_rate_is_the_rate_of_the_gap_under_the_vessels_rigid_motion(hull, obstacle):
    antenna, velocity, yaw_rate = np.array([0.5, -1.0]), (0.8, -0.3), 3.0
    section = _section(hull, obstacle)
    add_own_rates([section], antenna, velocity, 0.05, yaw_rate, 0.2)
    dt = 1e-4
    expected = (_gap_after(hull, obstacle, antenna, velocity, yaw_rate, dt)
                - _gap_after(hull, obstacle, antenna, velocity, yaw_rate, -dt)) / (2 * dt)
    assert section.own_rate_mps == pytest.approx(expected, abs=1e-6)
    # the turn's part of the sigma: the rate's change for a turn one sigma faster
    lever_mps = abs(_gap_after(hull, obstacle, antenna, velocity, yaw_rate + 0.2, dt)
                    - _gap_after(hull, obstacle, antenna, velocity, yaw_rate, dt)) / dt
    assert section.own_rate_sigma_mps == pytest.approx(math.hypot(0.05, lever_mps), rel=1e-3)


def test_the_defaults_and_what_gets_no_own_rate():
    bow = _section((0.0, 10.0), (5.0, 10.0))         # 10 m ahead of the antenna, quay abeam
    touching = _section((0.0, 0.0), (0.0, 0.01))
    clear = _section((0.0, 0.0), (1.0, 0.0), STATUS_CLEAR)
    add_own_rates([bow, touching, clear], np.zeros(2), (1.0, 0.0))
    assert bow.own_rate_mps == pytest.approx(-1.0)
    # no rate of turn given: taken as 0 within the unmeasured turn's sigma, 10 m of lever
    assert bow.own_rate_sigma_mps == pytest.approx(
        math.hypot(VELOCITY_SIGMA_MPS, 10 * math.radians(UNMEASURED_TURN_DEG_S)))
    assert touching.own_rate_mps is None and clear.own_rate_mps is None
    add_own_rates([bow], np.zeros(2), (1.0, 0.0), yaw_rate_deg_s=0.0)
    assert bow.own_rate_sigma_mps == pytest.approx(
        math.hypot(VELOCITY_SIGMA_MPS, 10 * math.radians(YAW_RATE_SIGMA_DEG_S)))
    fresh = _section((0.0, 10.0), (5.0, 10.0))
    add_own_rates([fresh], np.zeros(2), None)
    assert fresh.own_rate_mps is None and fresh.to_dict()["own_closing_mps"] is None
    assert bow.to_dict()["own_closing_mps"] == 1.0


def _frame(**vessel) -> dict:
    frame = json.loads(sorted((SAMPLES / "frames").glob("*.json"))[0].read_text())
    frame["vessel"].update(vessel)
    return frame


def test_frame_fields_of_the_vessels_motion_are_read_written_and_checked():
    frame = _frame(velocity_en_mps=[0.3, -0.1], velocity_sigma_mps=0.05, yaw_rate_deg_s=-1.5,
                   yaw_rate_sigma_deg_s=0.2)
    meta = parse_frame_metadata(frame, "f.json")
    assert meta.vessel_velocity_en_mps == (0.3, -0.1)
    assert (meta.vessel_velocity_sigma_mps, meta.vessel_yaw_rate_deg_s,
            meta.vessel_yaw_rate_sigma_deg_s) == (0.05, -1.5, 0.2)
    again = parse_frame_metadata(meta.to_dict(), "g.json")
    assert again.vessel_yaw_rate_deg_s == -1.5 and again.vessel_velocity_sigma_mps == 0.05
    for key, value in (("velocity_sigma_mps", -0.1), ("yaw_rate_sigma_deg_s", float("nan")),
                       ("yaw_rate_deg_s", 400.0), ("yaw_rate_deg_s", "fast")):
        with pytest.raises(InputError, match=f"vessel.{key}") as caught:
            parse_frame_metadata(_frame(**{key: value}), "bad.json")
        assert "bad.json" in str(caught.value)


def test_a_flights_frames_carry_the_vessels_velocity_and_rate_of_turn(tmp_path):
    tug = {"harbour-tug": load_vessel_spec(write_example_vessel(tmp_path / "vessels"))}
    config = flight_config()
    moving = plan_frame(config, 2, tug)
    meta = moving.metadata("f.png")
    u = np.array(moving.sequence["direction_enu"])
    np.testing.assert_allclose(meta.vessel_velocity_en_mps, config.approach_speed_mps * u)
    assert meta.vessel_yaw_rate_deg_s == 0.0
    stopped = plan_frame(config, config.sequence_frames - 1, tug).metadata("g.png")
    assert stopped.vessel_velocity_en_mps == (0.0, 0.0)
    single = plan_frame(flight_config().__class__(seed=1), 0, tug)      # not a flight
    assert single.metadata("h.png").vessel_velocity_en_mps is None


def test_pose_noise_perturbs_the_velocity_and_rate_of_turn_and_leaves_the_rest():
    frame = _frame(velocity_en_mps=[0.4, 0.0], yaw_rate_deg_s=0.0)
    base = PoseNoise(gps_m=2.0, heading_deg=2.0, height_m=1.0)
    with_motion = PoseNoise(gps_m=2.0, heading_deg=2.0, height_m=1.0, velocity_mps=0.05,
                            yaw_rate_deg_s=0.1)
    velocities, turns = [], []
    for seed in range(300):
        plain = add_pose_noise(frame, base, np.random.default_rng(seed))
        noisy = add_pose_noise(frame, with_motion, np.random.default_rng(seed))
        for key in ("uav", "camera_attitude"):
            assert noisy[key] == plain[key]
        assert {k: noisy["vessel"][k] for k in ("lat", "lon", "heading_deg")} == {
            k: plain["vessel"][k] for k in ("lat", "lon", "heading_deg")}
        errors = noisy["ground_truth"]["pose_errors"]
        np.testing.assert_allclose(np.subtract(noisy["vessel"]["velocity_en_mps"], [0.4, 0.0]),
                                   errors["vessel_velocity_en_mps"], atol=1e-4)
        assert noisy["vessel"]["velocity_sigma_mps"] == 0.05
        assert noisy["vessel"]["yaw_rate_sigma_deg_s"] == 0.1
        assert noisy["ground_truth"]["true_pose"]["vessel"]["velocity_en_mps"] == [0.4, 0.0]
        velocities.append(errors["vessel_velocity_en_mps"])
        turns.append(noisy["vessel"]["yaw_rate_deg_s"])
    assert np.std(velocities) == pytest.approx(0.05, rel=0.15)
    assert np.std(turns) == pytest.approx(0.1, rel=0.15)
    # a frame without a velocity gets none
    assert "velocity_en_mps" not in add_pose_noise(_frame(), with_motion,
                                                   np.random.default_rng(0))["vessel"]


def test_a_logs_speed_and_course_over_ground_make_the_frames_velocity():
    ship = {"sog_mps": np.array([1.0, 0.02, np.nan, 2.0]),
            "cog_deg": np.array([90.0, np.nan, 10.0, 180.0]),
            "rot_deg_s": np.array([np.nan, np.nan, np.nan, -0.5])}
    assert own_motion_fields(ship, 0) == {"velocity_en_mps": [1.0, 0.0]}
    assert own_motion_fields(ship, 1) == {"velocity_en_mps": [0.0, 0.0]}    # at rest, no course
    assert own_motion_fields(ship, 2) == {}
    assert own_motion_fields(ship, 3) == {"velocity_en_mps": [0.0, -2.0], "yaw_rate_deg_s": -0.5}
    assert own_motion_fields({}, 0) == {}


def test_run_tracks_the_flight_with_its_own_motion_and_can_leave_it_out(tmp_path):
    """The bundled flight with the vessel's velocity added to its frames (as the simulator
    now writes them): sections.csv gives each section's own closing speed, the reports too;
    --no-own-motion leaves it out."""
    from typer.testing import CliRunner

    from harborsight.cli import app

    flight = tmp_path / "flight"
    flight.mkdir()
    for name in ("images", "labels"):
        (flight / name).symlink_to(SAMPLES / "flight" / name)
    (flight / "frames").mkdir()
    for path in sorted((SAMPLES / "flight" / "frames").glob("*.json"))[:12]:
        frame = json.loads(path.read_text())
        sequence = frame["ground_truth"]["sequence"]
        frame["vessel"]["velocity_en_mps"] = [sequence["speed_mps"] * c
                                              for c in sequence["direction_enu"]]
        frame["vessel"]["yaw_rate_deg_s"] = 0.0
        (flight / "frames" / path.name).write_text(json.dumps(frame))
    runner = CliRunner()
    for option, out in (([], tmp_path / "on"), (["--no-own-motion"], tmp_path / "off")):
        result = runner.invoke(app, ["run", str(flight), "--masks", str(flight / "labels"),
                                     "--vessel", str(SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml"),
                                     "--out", str(out), "--no-overlays", *option])
        assert result.exit_code == 0, result.output
    with open(tmp_path / "on" / "sections.csv") as handle:
        rows = [r for r in csv.DictReader(handle) if r["status"] == STATUS_OK]
    own = [float(r["own_closing_mps"]) for r in rows if r["own_closing_mps"]]
    assert len(own) == len(rows) > 20
    assert max(own) <= 0.4 + 1e-3 and max(own) > 0.3        # 0.4 m/s times the cosine
    assert json.loads((tmp_path / "on" / "run.json").read_text())["settings"]["own_motion"]
    with open(tmp_path / "off" / "sections.csv") as handle:
        assert not any(r["own_closing_mps"] for r in csv.DictReader(handle))


def test_an_nmea_logs_rate_of_turn_reaches_the_track_and_the_frames(tmp_path):
    """ROT (degrees per minute, status A) beside the fixes: the track's rate of turn in deg/s
    at each fix, and a frame's ``vessel.yaw_rate_deg_s``; ROT status V is skipped."""
    from harborsight.telemetry.vessel_track import read_vessel_track

    lines = []
    for k in range(6):
        clock = f"1200{k:02d}.00"
        lines += [_nmea(f"GPRMC,{clock},A,5609.10200,N,01013.69800,E,1.00,90.0,010526,,"),
                  _nmea("HEHDT,90.00,T"),
                  _nmea(f"HEROT,{-30.0 if k < 3 else 60.0:.1f},{'A' if k != 4 else 'V'}")]
    path = tmp_path / "ship.nmea"
    path.write_text("\n".join(lines) + "\n")
    track = read_vessel_track(path)
    np.testing.assert_allclose(track.rot_deg_s, [-0.5, -0.5, -0.5, 1.0, 1.0, 1.0])
    assert any("ROT status V" in note for note in track.notes)
    fields = own_motion_fields(track.sample(np.array([1.0]), max_gap_s=1.0), 0)
    assert fields["yaw_rate_deg_s"] == -0.5
    assert fields["velocity_en_mps"] == pytest.approx([1.0 * 1852 / 3600, 0.0], abs=1e-4)


def test_a_live_nmea_feeds_rate_of_turn_joins_its_newest_fix():
    from harborsight.live.nmea_in import NmeaVessel
    from harborsight.live.telemetry import LiveTrack

    vessel = NmeaVessel(LiveTrack("vessel", "nmea"))
    vessel.feed(_nmea("GPRMC,120000.00,A,5609.10200,N,01013.69800,E,1.00,90.0,010526,,"), 10.0)
    vessel.feed(_nmea("HEHDT,90.00,T"), 10.05)
    vessel.feed(_nmea("HEROT,12.0,A"), 10.1)
    track = vessel.track.track()
    assert track.rot_deg_s is not None and track.rot_deg_s[-1] == pytest.approx(0.2)


def test_the_sigma_widens_where_the_points_are_loose():
    """Moving along a quay 1 m off at 1 m/s: a pixel's tilt of the gap's direction
    (gsd 0.2 m over 1 m: 0.2 rad) reads up to 0.2 m/s that the vessel does not close; and a
    turn of 1 deg/s closes one end of a 6 m section and opens the other by 0.05 m/s."""
    along = _section((0.0, 0.0), (1.0, 0.0))         # quay to the east, moving north
    add_own_rates([along], np.zeros(2), (0.0, 1.0), 0.05, 1.0, 0.1,
                  half_lengths_m=np.array([3.0]), gsd_m_per_px=0.2)
    assert along.own_rate_mps == pytest.approx(0.0, abs=1e-12)
    turn, turn_sigma = math.radians(1.0), math.radians(0.1)
    assert along.own_rate_sigma_mps == pytest.approx(math.sqrt(
        0.05 ** 2 + (3.0 * turn) ** 2 + (3.0 * turn_sigma) ** 2 + (1.0 * 0.2) ** 2))
    # closing head on: the tilt does not matter (no speed across the gap)
    head_on = _section((0.0, 0.0), (1.0, 0.0))
    add_own_rates([head_on], np.zeros(2), (1.0, 0.0), 0.05, gsd_m_per_px=0.2, yaw_rate_deg_s=0.0,
                  yaw_rate_sigma_deg_s=0.0)
    assert head_on.own_rate_mps == pytest.approx(-1.0)
    assert head_on.own_rate_sigma_mps == pytest.approx(0.05)


def test_a_rate_of_turn_fitted_to_the_headings_where_the_log_gives_none():
    """A gyro's headings at 10 Hz (0.3° of noise) while the vessel turns at 2 deg/s through
    north: the fitted rate is unbiased and its stated sigma honest (about 95 % of the errors
    within two sigma over 20 flights)."""
    from harborsight.telemetry.track import Track

    ratios, errors = [], []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        t = np.arange(0, 30, 0.1)
        heading = (350.0 + 2.0 * t + rng.normal(0, 0.3, len(t))) % 360.0
        track = Track(source=Path("gyro"), kind="csv", t_s=t, lat_deg=np.zeros(len(t)),
                      lon_deg=np.zeros(len(t)), heading_deg=heading)
        rate, sigma = track.heading_rate(np.arange(2.0, 28.0, 0.5))
        errors += list(rate - 2.0)
        ratios += list(np.abs(rate - 2.0) / sigma)
    assert abs(np.mean(errors)) < 0.01
    assert 0.9 < np.mean(np.array(ratios) < 2) < 0.99 and np.mean(np.array(ratios) < 3) > 0.98
    assert np.isnan(track.heading_rate(np.array([-5.0]))[0][0])      # no headings around it
