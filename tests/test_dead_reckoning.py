"""A vessel known only from its AIS reports (every 10 s under way) between reports: carried by
its speed and course, its heading turned between reports, its error bars widened for the
time carried. Before, every frame more than a second from a report went unmeasured."""

import math
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from pyproj import Geod

from harborsight.frame import parse_frame_metadata
from harborsight.geometry.sensor_sigmas import SensorSigmas, dead_reckoning_drift, sigmas_for_frame
from harborsight.telemetry.ais import AIS_DEAD_RECKON_S, AIS_FRAME_REACH_S, KNOT_MPS, report_motion
from harborsight.telemetry.track import Track

GEOD = Geod(ellps="WGS84")
LAT0, LON0 = 53.54, 9.98


def _truth(t_s: np.ndarray, speed_mps: float, course_deg: float,
           accel_mps2: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Positions along a straight course (pyproj's geodesic: not the code's pymap3d)."""
    distance = speed_mps * t_s + 0.5 * accel_mps2 * t_s ** 2
    lon, lat, _ = GEOD.fwd(np.full(t_s.shape, LON0), np.full(t_s.shape, LAT0),
                           np.full(t_s.shape, course_deg), distance)
    return lat, lon


def _ais_track(report_s: np.ndarray, speed_mps: float, course_deg: float,
               accel_mps2: float = 0.0, heading_deg=None) -> Track:
    lat, lon = _truth(report_s, speed_mps, course_deg, accel_mps2)
    heading = np.full(report_s.shape, course_deg) if heading_deg is None else heading_deg
    return Track(source=Path("ais.nmea"), kind="ais", t_s=report_s, lat_deg=lat, lon_deg=lon,
                 heading_deg=heading, sog_mps=speed_mps + accel_mps2 * report_s,
                 cog_deg=np.full(report_s.shape, course_deg), dead_reckon_s=AIS_DEAD_RECKON_S)


def _error_m(lat_a, lon_a, lat_b, lon_b) -> np.ndarray:
    return GEOD.inv(lon_a, lat_a, lon_b, lat_b)[2]


def test_a_steady_vessel_between_reports_is_where_it_was_carried():
    report_s = np.arange(0.0, 41.0, 10.0)
    track = _ais_track(report_s, 1.5, 63.0)
    times = np.arange(0.0, 52.0, 0.5)
    samples = track.sample(times, max_gap_s=1.0)
    lat, lon = _truth(times, 1.5, 63.0)
    assert np.isfinite(samples["lat_deg"]).all() and np.isfinite(samples["heading_deg"]).all()
    assert _error_m(samples["lat_deg"], samples["lon_deg"], lat, lon).max() < 0.01
    age = samples["dead_reckoned_s"]
    assert age[times == 5.0] == pytest.approx(5.0)          # 5 s from both reports
    assert age[times == 12.0] == pytest.approx(math.sqrt(2 * 8))   # a steady acceleration's
    assert age[times == 46.0] == pytest.approx(6.0)          # past the last: carried forward
    assert age[times == 20.0] == 0.0                          # a report's own time
    assert age[times == 20.5] == pytest.approx(math.sqrt(0.5 * 9.5))
    without = Track(**{**track.__dict__, "dead_reckon_s": 0.0}).sample(times, max_gap_s=1.0)
    assert np.isnan(without["lat_deg"]).sum() > 70           # what the frames had before


def test_beyond_its_reach_a_report_carries_nothing():
    track = _ais_track(np.array([0.0, 30.0]), 1.0, 90.0)
    samples = track.sample(np.array([11.0, 13.0, 18.0, 29.5, 43.0]), max_gap_s=1.0)
    assert np.isfinite(samples["lat_deg"]).tolist() == [True, False, True, True, False]


def test_an_accelerating_turning_vessel_stays_within_the_widened_bars():
    """0.04 m/s² and 0.4 deg/s (a berthing vessel under thrusters, inside the drift model's
    0.05 m/s² and 0.5 deg/s): the truth between reports lies within two sigma of the
    carried position, receiver error left out."""
    report_s = np.arange(0.0, 61.0, 10.0)
    heading = (20.0 + 0.4 * report_s) % 360.0
    track = _ais_track(report_s, 0.6, 200.0, accel_mps2=0.04, heading_deg=heading)
    times = np.arange(0.0, 70.0, 0.25)
    samples = track.sample(times, max_gap_s=1.0)
    lat, lon = _truth(times, 0.6, 200.0, 0.04)
    error = _error_m(samples["lat_deg"], samples["lon_deg"], lat, lon)
    heading_error = np.abs((samples["heading_deg"] - (20.0 + 0.4 * times) + 180.0) % 360.0 - 180.0)
    drift = np.array([dead_reckoning_drift(a) for a in samples["dead_reckoned_s"]])
    carried = samples["dead_reckoned_s"] > 0
    assert carried.sum() > 200
    assert (error[carried] <= 2 * drift[carried, 0] + 1e-6).all()
    assert (heading_error[carried] <= 2 * drift[carried, 1] + 1e-6).all()
    assert error[carried].max() > 0.3                        # the test can tell


def test_ais_speed_and_course_and_what_they_are_not():
    assert report_motion({"speed": 10.0, "course": 271.5}) == pytest.approx((10 * KNOT_MPS, 271.5))
    sog, cog = report_motion({"speed": 102.3, "course": 360.0})
    assert math.isnan(sog) and math.isnan(cog)
    sog, cog = report_motion({})
    assert math.isnan(sog) and math.isnan(cog)


def test_a_dead_reckoned_frame_widens_the_vessel_bars():
    position_m, heading_deg = dead_reckoning_drift(10.0)
    assert position_m == pytest.approx(math.hypot(0.1 * 10, 0.5 * 0.05 * 100))
    assert heading_deg == pytest.approx(5.0)
    base = SensorSigmas()
    wide = sigmas_for_frame(base, {}, 10.0)
    assert wide.vessel_gps == pytest.approx(math.hypot(2.0, position_m))
    assert wide.vessel_heading_deg == pytest.approx(math.hypot(2.0, 5.0))
    assert sigmas_for_frame(base, {}, None) == base == sigmas_for_frame(base, {}, 0.0)


def _frame(**vessel) -> dict:
    return {"schema": "harborsight.frame/1", "image": "x.png",
            "camera": {"width": 64, "height": 36, "fx": 50.0, "fy": 50.0, "cx": 31.5, "cy": 17.5},
            "uav": {"lat": LAT0, "lon": LON0, "alt_m": 40.0},
            "camera_attitude": {"yaw_deg": 0.0, "pitch_deg": -90.0},
            "vessel": {"lat": LAT0, "lon": LON0, "heading_deg": 10.0, **vessel}}


def test_the_frame_field_is_read_checked_and_written_back():
    meta = parse_frame_metadata(_frame(dead_reckoned_s=4.5))
    assert meta.vessel_dead_reckoned_s == 4.5
    assert meta.to_dict()["vessel"]["dead_reckoned_s"] == 4.5
    assert parse_frame_metadata(_frame()).vessel_dead_reckoned_s is None
    from harborsight.errors import InputError

    with pytest.raises(InputError, match=r"vessel\.dead_reckoned_s"):
        parse_frame_metadata(_frame(dead_reckoned_s=-1.0))


def test_the_live_ais_feed_carries_the_vessel_to_the_frame(monkeypatch):
    """Reports 10 s apart: a frame 6 s after the last is composed, 9 m on along the course,
    with ``vessel.dead_reckoned_s`` 6; the receiver feed held the last report only 1 s."""
    from harborsight.live.ais_in import AisVessel
    from harborsight.live.telemetry import LiveTrack
    from harborsight.telemetry.ais import KNOT_MPS

    track = LiveTrack("ais", "ais")
    ais = AisVessel(track, None)
    assert (track.dead_reckon_s, track.frame_reach_s) == (AIS_DEAD_RECKON_S, AIS_FRAME_REACH_S)
    t0 = datetime(2026, 11, 29, 12, 0, 0, tzinfo=UTC).timestamp()
    fields = {"speed": 1.5 / KNOT_MPS, "course": 90.0, "heading": 88}
    for k, (lat, lon) in enumerate(zip(*_truth(np.array([0.0, 10.0]), 1.5, 90.0), strict=True)):
        track.add_position(t0 + 10 * k, float(lat), float(lon), *(math.nan, math.nan),
                           *report_motion(fields))
        track.add_heading(t0 + 10 * k, 88.0)
    assert ais.reports == 0                                  # fed directly, not parsed
    samples = track.track().sample(np.array([t0 + 16.0]), max_gap_s=1.0, hold_s=1.0)
    lat, lon = _truth(np.array([16.0]), 1.5, 90.0)
    assert _error_m(samples["lat_deg"], samples["lon_deg"], lat, lon)[0] < 0.01
    assert samples["dead_reckoned_s"][0] == pytest.approx(6.0)
    assert samples["heading_deg"][0] == 88.0


def test_a_vessel_carried_between_ais_reports_is_not_stale_until_it_can_no_longer_be():
    """With AIS the vessel's newest report is up to 10 s old while its pose is carried (bars
    widened): the live aid's vessel source goes stale after the 12 s it may be carried, not
    the 2 s of a GNSS feed (every distance was marked not current 8 s in 10)."""
    from harborsight.live.alarms import AlarmSettings
    from harborsight.live.engine import LiveEngine

    for vessel_stale_s, stale_at_8 in ((None, True), (AIS_DEAD_RECKON_S, False)):
        engine = LiveEngine(None, None, alarm_settings=AlarmSettings(vessel_stale_s=vessel_stale_s))
        engine.source_arrived("vessel", 100.0)
        assert engine.health["vessel"].stale(108.0) is stale_at_8
        assert engine.health["vessel"].stale(112.5)
    with pytest.raises(ValueError, match="vessel_stale_s"):
        AlarmSettings(vessel_stale_s=-1.0)


def test_the_live_ais_reader_keeps_each_report_s_speed_and_course():
    from pyais.encode import encode_dict

    from harborsight.live.ais_in import AisVessel
    from harborsight.live.telemetry import LiveTrack

    track = LiveTrack("vessel", "ais")
    listener = AisVessel(track, mmsi=219000001)
    report = {"type": 1, "mmsi": 219000001, "lat": 56.1517, "lon": 10.2283, "heading": 118,
              "second": datetime.now(UTC).second, "speed": 3.0, "course": 121.5}
    listener.feed(encode_dict(report, sentence_type="VDM")[0], 20.0)
    vessel = track.track()
    assert vessel.sog_mps[0] == pytest.approx(3.0 * KNOT_MPS)
    assert vessel.cog_deg[0] == pytest.approx(121.5) and (vessel.dead_reckon_s, vessel.frame_reach_s) == (
        AIS_DEAD_RECKON_S, AIS_FRAME_REACH_S)


def test_a_missed_report_leaves_no_jump_and_a_vessel_at_rest_is_carried_in_place():
    """Reports 20 s apart (one missed): the report after comes into reach at 8 s and the one
    before leaves it at 12 s; the first version jumped 0.8 m there (a closing speed of
    800 m/s between two frames). A moored vessel reports speed 0 and no course (AIS 360):
    its frames were left without a pose."""
    track = _ais_track(np.array([0.0, 20.0]), 1.0, 90.0, accel_mps2=0.05)
    times = np.array([7.999, 8.0, 8.001, 11.999, 12.0, 12.001])
    samples = track.sample(times, max_gap_s=1.0)
    lat, lon = _truth(np.array([0.0]), 1.0, 90.0)
    along = _error_m(np.full(6, lat[0]), np.full(6, lon[0]), samples["lat_deg"], samples["lon_deg"])
    assert np.abs(np.diff(along)[[0, 1, 3, 4]]).max() < 0.01
    assert np.abs(np.diff(samples["dead_reckoned_s"])).max() < 0.01
    lat, lon = _truth(np.arange(0.0, 21.0, 10.0), 0.0, 0.0)
    moored = Track(source=Path("ais.nmea"), kind="ais", t_s=np.arange(0.0, 21.0, 10.0),
                   lat_deg=lat, lon_deg=lon, heading_deg=np.full(3, 45.0), sog_mps=np.zeros(3),
                   cog_deg=np.full(3, np.nan), dead_reckon_s=AIS_DEAD_RECKON_S)
    samples = moored.sample(np.array([2.0, 5.0, 15.0]), max_gap_s=1.0)
    assert np.isfinite(samples["lat_deg"]).all()
    assert _error_m(samples["lat_deg"], samples["lon_deg"], lat[:1].repeat(3), lon[:1].repeat(3)).max() < 1e-6



def test_an_ais_log_s_track_carries_its_reports_speed_and_course(tmp_path):
    from harborsight.telemetry.vessel_track import read_vessel_track
    from tests.test_ais import _own_log

    track = read_vessel_track(_own_log(tmp_path))            # 10 reports, 0.8 kn at 117.7 deg
    assert (track.dead_reckon_s, track.frame_reach_s) == (AIS_DEAD_RECKON_S, AIS_FRAME_REACH_S)
    assert np.allclose(track.sog_mps, 0.8 * KNOT_MPS) and np.allclose(track.cog_deg, 117.7)
    assert any("10 of 10 report(s) give speed and course" in note for note in track.notes)


def test_a_heading_held_past_the_last_report_turns_at_its_rate_of_turn():
    """AIS gives a rate of turn (pyais: deg/min; -128 none, ±127 no rate): live, past the
    last report, the heading turns with it instead of being held."""
    from harborsight.telemetry.ais import report_turn

    assert report_turn({"turn": 60.0}) == pytest.approx(1.0)
    assert all(math.isnan(report_turn(fields)) for fields in
               ({"turn": -128.0}, {"turn": 127.0}, {"turn": -127.0}, {}))
    track = _ais_track(np.array([0.0, 10.0]), 1.0, 90.0, heading_deg=np.array([80.0, 90.0]))
    track.rot_deg_s = np.array([1.0, 1.0])
    samples = track.sample(np.array([5.0, 16.0]), max_gap_s=1.0, hold_s=1.0)
    assert samples["heading_deg"][0] == pytest.approx(85.0)     # between reports: turned
    assert samples["heading_deg"][1] == pytest.approx(96.0)     # past the last: at 1 deg/s
    track.rot_deg_s = np.array([np.nan, np.nan])
    assert track.sample(np.array([16.0]), max_gap_s=1.0, hold_s=1.0)["heading_deg"][0] == 90.0


def test_an_nmea_receiver_that_loses_its_fix_is_carried_by_its_last_rmc(tmp_path):
    """A receiver under a crane loses its fix for 4 s: the frames in the gap had no vessel
    pose (2 s of reach); the RMC's speed and course carry it up to 5 s, in files and live
    (where an RMC after the epoch's GGA adds its motion to that fix)."""
    from harborsight.live.nmea_in import NmeaVessel
    from harborsight.live.telemetry import LiveTrack
    from harborsight.telemetry.vessel_track import NMEA_DEAD_RECKON_S, read_vessel_track
    from tests.helpers import nmea_checksum

    def sentence(body: str) -> str:
        return f"${body}*{nmea_checksum(body)}"

    times = [0.0, 1.0, 2.0, 6.0, 7.0]                         # no fix from 2 to 6 s
    lat, lon = _truth(np.array(times), 2.0, 90.0)
    lines = []
    for t, la, lo in zip(times, lat, lon, strict=True):
        clock = f"1200{int(t):02d}.00"
        lat_text = f"{int(la):02d}{(la - int(la)) * 60:08.5f},N"
        lon_text = f"{int(lo):03d}{(lo - int(lo)) * 60:08.5f},E"
        epoch = [sentence(f"GPGGA,{clock},{lat_text},{lon_text},1,08,0.9,1.0,M,40.0,M,,"),
                 sentence(f"GPRMC,{clock},A,{lat_text},{lon_text},{2.0 / KNOT_MPS:.2f},90.0,"
                          "010526,,")]
        # the first epoch's RMC first (it brings the date), then each epoch's GGA first
        lines += [*(epoch[::-1] if t == 0.0 else epoch), sentence("HEHDT,90.0,T")]
    path = tmp_path / "ship.nmea"
    path.write_text("\n".join(lines) + "\n")
    track = read_vessel_track(path)
    assert track.dead_reckon_s == NMEA_DEAD_RECKON_S and np.isfinite(track.sog_mps).all()
    samples = track.sample(np.array([4.0]), max_gap_s=1.0)
    truth_lat, truth_lon = _truth(np.array([4.0]), 2.0, 90.0)
    assert _error_m(samples["lat_deg"], samples["lon_deg"], truth_lat, truth_lon)[0] < 0.05
    assert samples["dead_reckoned_s"][0] == pytest.approx(2.0)
    live = LiveTrack("vessel", "nmea")
    feed = NmeaVessel(live)
    for k, line in enumerate(lines):
        feed.feed(line, 100.0 + k / 3)
    held = live.track()
    assert held.dead_reckon_s == NMEA_DEAD_RECKON_S and len(held) == len(times)
    assert np.allclose(held.sog_mps, 2.0, atol=0.01) and np.allclose(held.cog_deg, 90.0)


def test_a_report_without_speed_or_course_still_anchors_the_position():
    """A report whose speed and course are "not available" is a fix all the same: carried with
    its neighbour's motion, it pulls the blend to where the vessel was seen. Before, only the
    report 9.5 s earlier counted, and its speed (the vessel sped up after it) put the vessel
    2.25 m short half a second before the fix."""
    def along_m(t_s):          # 1.0 m/s to 5 s, then 1.5 m/s
        t_s = np.asarray(t_s, float)
        return np.where(t_s <= 5.0, t_s, 5.0 + 1.5 * (t_s - 5.0))

    def at(t_s):
        n = len(t_s)
        lon, lat, _ = GEOD.fwd(np.full(n, LON0), np.full(n, LAT0), np.full(n, 63.0), along_m(t_s))
        return lat, lon

    report_s = np.array([0.0, 10.0, 20.0])
    lat, lon = at(report_s)
    track = Track(source=Path("ais.nmea"), kind="ais", t_s=report_s, lat_deg=lat, lon_deg=lon,
                  heading_deg=np.full(3, 63.0), sog_mps=np.array([1.0, np.nan, 1.5]),
                  cog_deg=np.array([63.0, np.nan, 63.0]), dead_reckon_s=AIS_DEAD_RECKON_S)
    times = np.array([2.0, 9.5, 10.5, 15.0])
    samples = track.sample(times, max_gap_s=1.0)
    error = _error_m(samples["lat_deg"], samples["lon_deg"], *at(times))
    assert error[1] < 0.5 and error[2] < 0.05       # beside the fix: near where it was seen
    assert error[0] < 1.0 and error[3] < 0.05
    # the fix's half second, counted with the lag of the motion it borrows (10 s):
    # sqrt(0.05 * 9.5² + 0.95 * 0.5 * (0.5 + 20)) = 3.77 s, against 9.5 s carried before
    assert samples["dead_reckoned_s"][1] == pytest.approx(3.775, abs=0.01)


def test_a_fix_without_speed_or_course_makes_no_jump_along_the_carry():
    """Which neighbour lends its motion does not change along a carry (a second read found
    6.5 m jumps between times 0.01 s apart where the choice followed the carry's middle)."""
    north = GEOD.fwd(LON0, LAT0, 0.0, 50.0)        # 10 s north at 5 m/s, then east
    east = GEOD.fwd(north[0], north[1], 90.0, 55.0)
    track = Track(source=Path("ais.nmea"), kind="ais", t_s=np.array([0.0, 10.0, 21.0]),
                  lat_deg=np.array([LAT0, north[1], east[1]]),
                  lon_deg=np.array([LON0, north[0], east[0]]),
                  heading_deg=np.array([0.0, np.nan, 90.0]), sog_mps=np.array([5.0, np.nan, 5.0]),
                  cog_deg=np.array([0.0, np.nan, 90.0]), dead_reckon_s=AIS_DEAD_RECKON_S)
    times = np.arange(0.0, 21.0, 0.01)
    samples = track.sample(times, max_gap_s=1.0)
    steps = _error_m(samples["lat_deg"][:-1], samples["lon_deg"][:-1], samples["lat_deg"][1:],
                     samples["lon_deg"][1:])
    assert np.isfinite(steps).all() and steps.max() < 0.1    # 5 m/s: 0.05 m a step


def test_reports_minutes_apart_are_never_blended_and_each_frame_has_its_nearest_s_age():
    """Class B under 2 kn: reports 180 s apart. A frame 1 s after the first is that report
    carried 1 s (a blend with the report 179 s away made it 13.4 s old, and refused); past
    12 s from both, the nearest report alone, its age said (measured only where the images
    carry the vessel); beyond the frame reach, nothing."""
    from harborsight.telemetry.ais import AIS_FRAME_REACH_S

    report_s = np.array([0.0, 180.0])
    track = _ais_track(report_s, 0.5, 60.0)
    track.frame_reach_s = AIS_FRAME_REACH_S
    times = np.array([1.0, 2.0, 11.0, 13.0, 100.0, 179.0, 379.0, 381.0])
    samples = track.sample(times)
    assert np.allclose(samples["dead_reckoned_s"][:6], [1.0, 2.0, 11.0, 13.0, 80.0, 1.0])
    lat, lon = _truth(times[:6], 0.5, 60.0)
    assert _error_m(samples["lat_deg"][:6], samples["lon_deg"][:6], lat, lon).max() < 0.01
    assert np.isfinite(samples["lat_deg"][6]) and not np.isfinite(samples["lat_deg"][7])
    assert np.allclose(samples["heading_deg"][:7], 60.0)      # the nearest report's heading
