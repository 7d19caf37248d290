"""Telemetry readers on real logs (../shared/data/telemetry, byte for byte as published) and the
per-frame metadata they produce for `run`."""

from __future__ import annotations

import json
import math
import re
import struct
import threading
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.frame import parse_frame_metadata
from harborsight.geometry.rotations import ned_from_gimbal_rotation
from harborsight.telemetry import read_drone_log
from harborsight.telemetry.declination import magnetic_declination_deg, wmm_model_name
from harborsight.telemetry.dji_srt import read_dji_srt
from harborsight.telemetry.metadata import CameraMount, build_video_metadata, camera_attitude_deg
from harborsight.telemetry.track import Track
from harborsight.telemetry.vessel_track import read_vessel_track
from tests.helpers import pixel_of_camera_block

TELEMETRY = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "telemetry"
DJI = TELEMETRY / "dji"
FLIGHT = Path(__file__).resolve().parent.parent / "harborsight" / "data" / "samples" / "flight"
runner = CliRunner()


@pytest.fixture(scope="module", autouse=True)
def _real_logs_present():
    assert DJI.is_dir(), f"the real telemetry samples are missing: {TELEMETRY} (../shared beside the repo)"


# (file, samples, first lat, first lon, first altitude, altitude datum word, rate Hz): values
# read by eye from the files' first block
SRT_CASES = [
    ("air2s.srt", 17, 41.424724, 2.234156, 117.0, "altitude", 30.0),
    ("mavic_air2.srt", 25, 41.420684, 2.162162, 27.3, "altitude", 60.0),
    ("mavic_pro.SRT", 468, -20.2533, 149.0251, 1.9, "take-off", 1.0),
    ("old_format.SRT", 468, -20.2533, 149.0251, 1.9, "take-off", 1.0),
    ("mavic_mini.SRT", 117, 48.0771, -121.7458, 200.70, "take-off", 1.0),
    ("p4p_sample.SRT", 5, 47.4692, 8.2090, 45.60, "take-off", 1.0),
    ("p4_rtk.SRT", 55, -34.237922, -58.851745, 85.80, "take-off", 1.0),
    ("matrice_300.srt", 381, 36.6146, -6.1120, 0.3, "take-off", 1.0),     # GPS(lat, lon, altM)
]


@pytest.mark.parametrize("name, samples, lat, lon, alt, datum, rate", SRT_CASES)
def test_dji_srt_families(name, samples, lat, lon, alt, datum, rate):
    track = read_dji_srt(DJI / name)
    assert len(track) == samples
    assert track.lat_deg[0] == pytest.approx(lat) and track.lon_deg[0] == pytest.approx(lon)
    assert track.alt_m[0] == pytest.approx(alt) and datum in track.alt_reference
    assert track.summary()["rate_hz"] == pytest.approx(rate, rel=0.02)


def test_gps_brackets_are_longitude_first():
    """The Mavic Pro file writes GPS(a, b, sats); the Mavic 2 style file of the same flight labels
    its fields: `[latitude : -20.2533] [longtitude : 149.0251]`. Both must agree."""
    pro, labelled = read_dji_srt(DJI / "mavic_pro.SRT"), read_dji_srt(DJI / "mavic_2_style.SRT")
    assert labelled.lat_deg[0] == pytest.approx(-20.2533)
    assert labelled.lon_deg[0] == pytest.approx(149.0251)
    assert (pro.lat_deg[0], pro.lon_deg[0]) == (labelled.lat_deg[0], labelled.lon_deg[0])
    assert "no timecodes" in labelled.clock and labelled.alt_m is None


def test_dji_gimbal_attitude_and_dates():
    track = read_dji_srt(DJI / "p4_rtk.SRT")
    assert track.attitude_of == "gimbal"
    # G.PRY (-24.4°, 0.0°, 110.4°) = pitch, roll, yaw of the first block
    assert (track.pitch_deg[0], track.roll_deg[0], track.yaw_deg[0]) == (-24.4, 0.0, 110.4)
    air = read_dji_srt(DJI / "air2s.srt", utc_offset_h=2.0)
    # first block: timecode 00:00:00,000 and local date 2022-08-07 13:40:40,774,808; the
    # start is the median over the 17 blocks of date minus timecode, within 1 ms of it
    assert abs((air.utc_start - datetime(2022, 8, 7, 11, 40, 40, 774808, tzinfo=UTC))
               .total_seconds()) < 1e-3
    assert air.t_s[1] == pytest.approx(0.033)
    assert read_dji_srt(DJI / "air2s.srt").utc_start is None   # local time without an offset


def _srt_block(n: int, start_s: float, body: str) -> str:
    def code(t: float) -> str:
        return f"00:00:{int(t):02d},{round((t % 1) * 1000):03d}"
    return f"{n}\n{code(start_s)} --> {code(start_s + 1)}\n{body}\n"


def test_dji_gb_gimbal_fields_and_blocks_without_blank_lines(tmp_path):
    """Mavic 3 Enterprise style: the gimbal as [gb_yaw gb_pitch gb_roll]; the blocks were
    written without blank lines between them, so each timecode starts a block."""
    body = ("2023-03-15 11:26:44.{ms:03d}\n[latitude: 40.37182{k}] [longitude: -3.689040] "
            "[rel_alt: 48.2 abs_alt: 715.4] [gb_yaw: -137.7 gb_pitch: -45.0 gb_roll: 0.5]")
    text = "".join(_srt_block(k + 1, k * 1.0, body.format(ms=525 + 0, k=k)) for k in range(3))
    path = tmp_path / "m3e.srt"
    path.write_text(text)
    track = read_dji_srt(path)
    assert len(track) == 3 and list(track.t_s) == [0.0, 1.0, 2.0]
    assert track.lat_deg[2] == pytest.approx(40.371822)
    assert track.attitude_of == "gimbal"
    assert (track.yaw_deg[0], track.pitch_deg[0], track.roll_deg[0]) == (-137.7, -45.0, 0.5)


def test_dji_whole_second_dates_are_placed_by_all_blocks(tmp_path):
    """Dates truncated to whole seconds, blocks every 0.4 s, true start 10:00:00.7 local:
    the first block alone says 10:00:00.0 (0.7 s early); all of them together pin it within
    0.2 s. Positions printed to four decimals are noted as 11 m steps."""
    true_start_s = 0.7
    blocks = []
    for k in range(25):
        t = 0.4 * k
        stamp = f"2017-08-05 10:00:{int(true_start_s + t):02d}"
        blocks.append(_srt_block(k + 1, t, f"GPS(149.0251,-20.2533,16) BAROMETER:1.9\n{stamp}"))
    path = tmp_path / "old.srt"
    path.write_text("\n".join(blocks))
    track = read_dji_srt(path, utc_offset_h=0.0)
    start = datetime(2017, 8, 5, 10, 0, 0, 700000, tzinfo=UTC)
    assert abs((track.utc_start - start).total_seconds()) < 0.2
    assert any("steps of 11 m" in note for note in track.notes)
    assert not any("steps of 11 m" in note for note in read_dji_srt(DJI / "air2s.srt").notes)


def test_broken_srt_files():
    with pytest.raises(InputError, match=r"broken_empty\.SRT: no DJI telemetry block"):
        read_dji_srt(DJI / "broken_empty.SRT")
    track = read_dji_srt(DJI / "broken_incomplete.SRT")
    assert len(track) == 19 and "1 block(s) without a position skipped (line 115)" in track.notes[0]
    with pytest.raises(InputError, match="unknown drone log type"):
        read_drone_log(DJI / "LICENSE")


def test_a_ulog_that_keeps_pyulog_rescanning_is_refused_in_time(tmp_path):
    """A fuzzed ULog (the sample's first 36,865 bytes, one byte of its definitions changed
    and four inserted later) kept pyulog 1.3 re-scanning a stretch of bytes 6,859-6,871 for
    good: `telemetry` hung. Past 50 times the file's size in reads it is refused, naming why."""
    sample = (TELEMETRY / "px4" / "sample_log_small.ulg").read_bytes()[:36865]
    damaged = bytearray(sample)
    damaged[8125] = 0xDA
    damaged[30633:30633] = b"T\x00\x00\x80"
    path = tmp_path / "damaged.ulg"
    path.write_bytes(bytes(damaged))
    outcome: list = []

    def read() -> None:
        try:
            read_drone_log(path)
            outcome.append(None)
        except Exception as exc:
            outcome.append(exc)

    reader = threading.Thread(target=read, daemon=True)   # a hang fails the test, not the run
    reader.start()
    reader.join(120)
    assert outcome, "reading the damaged ULog did not end within 120 s"
    assert isinstance(outcome[0], InputError) and re.search(
        r"damaged.ulg: a damaged ULog: pyulog went over its bytes more than 50 times",
        str(outcome[0])), outcome[0]


def test_px4_ulog_position_time_and_attitude():
    from pyulog import ULog

    path = TELEMETRY / "px4" / "sample_log_small.ulg"
    track = read_drone_log(path)
    gps = ULog(str(path), ["vehicle_gps_position"]).get_dataset("vehicle_gps_position").data
    assert track.lat_deg[0] == pytest.approx(gps["lat"][0] * 1e-7)      # 1e-7 degree integers
    assert track.alt_m[0] == pytest.approx(gps["alt"][0] * 1e-3)        # millimetres
    assert 63.41 < track.lat_deg[0] < 63.42 and 10.40 < track.lon_deg[0] < 10.41  # Trondheim
    # one boot-to-UTC offset (the median over the fixes): every fix's own UTC within the
    # jitter of the GPS message's arrival, a few tens of milliseconds
    for boot_us, utc_us in zip(gps["timestamp"], gps["time_utc_usec"], strict=True):
        utc = datetime.fromtimestamp(utc_us / 1e6, tz=UTC)
        assert abs((track.utc_at(boot_us / 1e6) - utc).total_seconds()) < 0.05
    # attitude: PX4's own quaternion -> yaw formula, atan2(2(wz + xy), 1 - 2(y^2 + z^2))
    att = ULog(str(path), ["vehicle_attitude"]).get_dataset("vehicle_attitude").data
    w, x, y, z = (att[f"q[{i}]"][10].astype(float) for i in range(4))
    yaw = math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    assert track.attitude_t_s[10] == pytest.approx(att["timestamp"][10] / 1e6)
    assert track.yaw_deg[10] == pytest.approx(yaw, abs=1e-4)
    assert track.attitude_of == "vehicle" and len(track.yaw_deg) == len(att["timestamp"])


def _ulog_message(kind: str, payload: bytes) -> bytes:
    """One ULog message: uint16 payload size, uint8 type, payload (PX4's ULog file format)."""
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def _write_sensor_gps_ulog(path: Path, rows: list[tuple],
                           global_rows: list[tuple] | None = None) -> Path:
    """A ULog with a ``sensor_gps`` topic as PX4 >= 1.14 writes it (and, with
    ``global_rows``, a ``vehicle_global_position`` topic: timestamp, lat, lon, alt), built
    from the format spec: header, flag bits, formats, subscriptions, then one data message per
    row."""
    topics = [("sensor_gps", "uint64_t timestamp;uint64_t timestamp_sample;uint64_t "
               "time_utc_usec;double latitude_deg;double longitude_deg;double altitude_msl_m;"
               "uint8_t fix_type;", "<3Q3dB", rows)]
    if global_rows is not None:
        topics.append(("vehicle_global_position", "uint64_t timestamp;double lat;double lon;"
                       "float alt;", "<Q2df", global_rows))
    data = b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0)
    data += _ulog_message("B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    for name, fields, _, _ in topics:
        data += _ulog_message("F", f"{name}:{fields}".encode())
    for msg_id, (name, _, _, _) in enumerate(topics):
        data += _ulog_message("A", struct.pack("<BH", 0, msg_id) + name.encode())
    for msg_id, (_, _, layout, topic_rows) in enumerate(topics):
        for row in topic_rows:
            data += _ulog_message("D", struct.pack("<H", msg_id) + struct.pack(layout, *row))
    path.write_bytes(data)
    return path


def test_px4_altitude_is_the_estimators_where_the_log_has_it(tmp_path):
    """GPS altitude wanders 30 -> 33 m; the EKF's (vehicle_global_position.alt, every 0.1 s)
    says 20.0 + 0.5 t. Samples outside the estimator's span keep the GPS altitude, noted."""
    gps_rows = [(1_000_000 + 200_000 * i, 1_000_000 + 200_000 * i, 0, 51.9, 4.1, 30.0 + i, 3)
                for i in range(6)]                                  # t = 1.0 ... 2.0 s
    global_rows = [(1_000_000 + 100_000 * k, 51.9, 4.1, 20.0 + 0.5 * (1.0 + 0.1 * k))
                   for k in range(9)]                               # t = 1.0 ... 1.8 s
    track = read_drone_log(_write_sensor_gps_ulog(tmp_path / "ekf.ulg", gps_rows, global_rows))
    np.testing.assert_allclose(track.alt_m[:5], [20.5 + 0.1 * i for i in range(5)], atol=1e-5)
    assert track.alt_m[5] == 35.0                                   # 2.0 s: past the EKF's end
    assert "vehicle_global_position.alt" in track.alt_reference
    assert any("1 GPS sample(s) outside the estimator's time span" in n for n in track.notes)



def test_px4_extrapolated_fixes_are_not_positions(tmp_path):
    """sensor_gps.fix_type 8 is "extrapolated": the receiver did not measure it. Such
    samples are skipped and counted apart from the no-fix ones."""
    fix_types = [3, 8, 6, 8, 2, 3]
    rows = [(1_000_000 + 200_000 * i, 1_000_000 + 200_000 * i, 0, 51.9 + 1e-4 * i, 4.1, 30.0, fix)
            for i, fix in enumerate(fix_types)]
    track = read_drone_log(_write_sensor_gps_ulog(tmp_path / "extrapolated.ulg", rows))
    np.testing.assert_allclose(track.t_s, [1.0, 1.4, 2.0])
    np.testing.assert_allclose(track.lat_deg, [51.9, 51.9002, 51.9005])
    assert "2 GPS sample(s) with fix_type 8 (extrapolated, not a measured position) skipped" \
        in track.notes
    assert "1 GPS sample(s) without a 3-D fix skipped" in track.notes

def test_px4_gps_timed_by_measurement_and_a_cut_log_is_noted(tmp_path):
    # published 150 ms after the measurement, as a u-blox driver does; UTC of the measurement
    utc0_us = 1_780_000_000_000_000
    rows = [(1_200_000 + 200_000 * i, 1_050_000 + 200_000 * i, utc0_us + 200_000 * i,
             51.9 + 1e-5 * i, 4.1, 30.0, 3) for i in range(6)]
    path = _write_sensor_gps_ulog(tmp_path / "gps.ulg", rows)
    track = read_drone_log(path)
    np.testing.assert_allclose(track.t_s, [1.05 + 0.2 * i for i in range(6)])
    assert track.utc_at(1.05) == datetime.fromtimestamp(utc0_us / 1e6, tz=UTC)
    assert track.notes == ["no estimator altitude in the log: the GPS receiver's own "
                           "altitude is used, which can drift by metres in seconds",
                           "no vehicle_attitude topic: no attitude",
                           "position_sigma_m (per axis): the fix_type class for 6 (no HDOP in "
                           "the log); fix_type: 3-D fix 6"]
    # no eph in this sensor_gps: a 3-D fix is the standalone class, 2 m DRMS, per axis / √2
    np.testing.assert_allclose(track.position_sigma_m, 2.0 / math.sqrt(2.0))
    assert track.alt_sigma_m is None                # no epv either
    assert track.alt_reference == "GPS receiver altitude above mean sea level"
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(path.read_bytes()[:-20])     # power lost mid-message: 34 of its 54 bytes
    track = read_drone_log(cut)
    assert len(track) == 5
    assert "the log ends in a partial message (34 bytes): it was cut short" in track.notes[0]


def test_ardupilot_bin_gps_week_to_utc():
    track = read_drone_log(TELEMETRY / "ardupilot" / "test.BIN")
    # the sample is the first 64 KiB of a log: its last record (45 bytes from offset 65512,
    # found by walking the records by hand) is torn
    assert "the log ends in a partial record (24 bytes)" in track.notes[0]
    # first GPS message: TimeUS 81855471, GWk 1973, GMS 6448000 (read with pymavlink by hand);
    # GPS week 1973 starts 2017-10-29 00:00:00 GPS time; 18 leap seconds to UTC. TimeUS is
    # when the fix was logged: the log's startup message "u-blox 1 HW: 00040007" (a u-blox
    # 6) and GPS_DELAY_MS 0 make ArduPilot assume the fix 0.22 s older (AP_GPS_UBLOX's lag)
    # (the offset is the median over the log's fixes: one fix is off by its arrival jitter)
    expected = datetime(2017, 10, 29, 1, 47, 28, tzinfo=UTC) - timedelta(seconds=18)
    assert track.t_s[0] == pytest.approx(81.855471 - 0.22)
    assert abs((track.utc_at(81.855471 - 0.22) - expected).total_seconds()) < 0.05
    assert "GPS fixes are timed by GPS.TimeUS less 0.22 s" in " ".join(track.notes)
    assert track.lat_deg[0] == pytest.approx(-35.3626277) and track.lon_deg[0] == pytest.approx(149.1653034)
    # altitude: the EKF's POS.Alt, not the receiver's GPS.Alt (588.82 m at the first fix); the
    # first fix, logged after the first POS (81.796 s) but dated before it (81.635 s), holds
    # POS's first value
    from pymavlink import DFReader
    log = DFReader.DFReader_binary(str(TELEMETRY / "ardupilot" / "test.BIN"), zero_time_base=False)
    pos = []
    while (message := log.recv_match(type="POS")) is not None:
        pos.append((message.TimeUS / 1e6, message.Alt))
    pos_t, pos_alt = np.array(pos).T
    assert track.alt_m[0] == pytest.approx(pos_alt[0])
    assert track.alt_m[1] == pytest.approx(np.interp(track.t_s[1], pos_t, pos_alt))
    assert 584.0 < track.alt_m[0] < 584.5 and track.alt_reference == (
        "EKF altitude above mean sea level (POS.Alt)")
    assert track.attitude_of == "vehicle" and track.yaw_deg is not None


def test_ardupilot_log_cut_inside_a_record_header(tmp_path):
    """45,981 bytes end with a whole record; one more byte is the first byte of the next
    record's header (0xA3), which pymavlink does not index: still a cut log, noted."""
    data = (TELEMETRY / "ardupilot" / "test.BIN").read_bytes()
    whole, torn = tmp_path / "whole.bin", tmp_path / "torn.bin"
    whole.write_bytes(data[:45981])
    torn.write_bytes(data[:45982])
    assert not any("partial record" in note for note in read_drone_log(whole).notes)
    assert "the log ends in a partial record (1 bytes)" in read_drone_log(torn).notes[0]


def test_sampling_interpolates_angles_across_north_and_refuses_gaps():
    track = Track(source=Path("x"), kind="csv", t_s=np.array([0.0, 1.0, 2.0, 10.0]),
                  lat_deg=np.array([10.0, 10.0002, 10.0004, 10.0]), lon_deg=np.zeros(4),
                  heading_deg=np.array([350.0, 10.0, 30.0, 30.0]))
    sampled = track.sample(np.array([0.5, 1.5, 5.0, 10.5, 12.0]), max_gap_s=1.0)
    assert sampled["heading_deg"][0] == pytest.approx(0.0, abs=1e-9)    # 350 -> 10 passes north
    assert sampled["lat_deg"][1] == pytest.approx(10.0003)
    assert np.isnan(sampled["lat_deg"][2])                              # inside an 8 s gap
    assert sampled["lat_deg"][3] == pytest.approx(10.0)                 # 0.5 s past the end
    assert np.isnan(sampled["lat_deg"][4])                              # 2 s past the end
    across = Track(source=Path("x"), kind="csv", t_s=np.array([0.0, 1.0]),
                   lat_deg=np.zeros(2), lon_deg=np.array([179.9999, -179.9999]))
    assert abs(across.sample(np.array([0.5]))["lon_deg"][0]) == pytest.approx(180.0)  # not 0


def _nmea(body: str) -> str:
    """A sentence with its checksum: XOR of the characters between $ and *."""
    checksum = 0
    for char in body:
        checksum ^= ord(char)
    return f"${body}*{checksum:02X}"


def test_a_turning_feed_is_told_where_its_headings_may_be_a_fix_early(tmp_path):
    """NMEA headings carry no time: a 1 Hz feed that sends HDT just before its RMC has each
    heading placed at the fix before, a second early. The order cannot be read from the file,
    so a turning vessel's track says how much heading that may be; headings faster than the
    fixes, or a steady heading, get no note."""
    def feed(name: str, headings_per_fix: int, rate_deg_s: float) -> list[str]:
        lines = []
        for second in range(20):
            stamp = f"1200{second:02d}"
            lines += [_nmea(f"HEHDT,{(rate_deg_s * (second + (k + 1) / headings_per_fix)) % 360:.2f},T")
                      for k in range(headings_per_fix)]      # sent ahead of the fix they lead to
            lines.append(_nmea(f"GPRMC,{stamp},A,5609.000,N,01013.000,E,0.5,090.0,010526,,,A"))
        path = tmp_path / name
        path.write_text("\n".join(lines) + "\n")
        return read_vessel_track(path).notes

    turning = [n for n in feed("turning.nmea", 1, 3.0) if n.startswith("headings carry no time")]
    assert len(turning) == 1 and "(1 s) early" in turning[0] and "(3.0 deg/s) 3.0 deg" in turning[0]
    assert "0.79 m" in turning[0]                    # 15 m x 3 deg
    assert not any(n.startswith("headings carry no time") for n in feed("gyro.nmea", 4, 3.0))
    assert not any(n.startswith("headings carry no time") for n in feed("steady.nmea", 1, 0.0))


def test_nmea_vessel_track(tmp_path):
    # the NMEA 0183 standard's own RMC example (checksum 6A as published)
    lines = ["$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A",
             _nmea("HEHDT,358.0,T"),
             _nmea("GPGGA,123520,4807.040,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"),
             _nmea("HCHDG,0.5,0.5,E,1.0,W"),       # magnetic 0.5 + dev 0.5 E - var 1.0 W = 0.0
             _nmea("GPGGA,123521,4807.042,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"),
             "$HEHDT,2.0,T*00",                     # bad checksum: skipped, counted
             _nmea("HEHDT,2.0,T"),
             _nmea("GPVTG,084.4,T,,M,022.4,N,041.5,K")]  # course over ground: never heading
    path = tmp_path / "ship.nmea"
    path.write_text("\n".join(lines) + "\n")
    track = read_vessel_track(path)
    assert track.utc_start == datetime(1994, 3, 23, 12, 35, 19, tzinfo=UTC)
    assert list(track.t_s) == [0.0, 1.0, 2.0]
    assert track.lat_deg[0] == pytest.approx(48 + 7.038 / 60)
    assert track.lat_deg[2] == pytest.approx(48 + 7.042 / 60)
    np.testing.assert_allclose(track.heading_deg, [358.0, 0.0, 2.0], atol=1e-9)
    assert track.notes == ["headings from two sensors: the track uses HE (HDT), and HC (HDG)'s 1 "
                           "where it was silent",
                           "1 unreadable sentence(s) skipped (bad checksum or field; line 6)",
                           "position_sigma_m (per axis): the GGA quality class, widened by "
                           "HDOP above 1, for 2 (GPS 2)",
                           "headings carry no time in NMEA: each is placed at the fix before it, "
                           "so one sent ahead of its own fix is up to a fix interval (1 s) early, "
                           "at this feed's fastest turns (2.0 deg/s) 2.0 deg of heading (a hull "
                           "point 15 m from the antenna moves 0.52 m); --sigma vessel_heading_deg "
                           "can widen the bars for it",
                           "1 of 3 fix(es) give speed and course (RMC): across a gap in the "
                           "fixes the vessel is carried by them up to 5 s, its error bars "
                           "widened for the time"]
    assert track.dead_reckon_s == 5.0 and np.isfinite(track.sog_mps).tolist() == [True, False, False]
    # the RMC fix states no accuracy; the GGA fixes (quality 1, HDOP 0.9) are standalone GPS
    np.testing.assert_allclose(track.position_sigma_m, [np.nan, math.sqrt(2.0), math.sqrt(2.0)])
    no_heading = tmp_path / "no_heading.nmea"
    no_heading.write_text(lines[0] + "\n" + lines[-1] + "\n")
    with pytest.raises(InputError, match="no heading"):
        read_vessel_track(no_heading)


# NOAA's published test values (WMM2020testvalues.pdf, WMM2025testvalues.pdf): decimal year,
# height km, latitude, longitude, declination D in degrees (printed to 0.01)
WMM_TEST_VALUES = [(2020.0, 0, 80, 0, -1.28), (2020.0, 0, 0, 120, 0.16), (2020.0, 0, -80, 240, 69.36),
                   (2022.5, 0, 80, 0, 0.01), (2022.5, 0, 0, 120, -0.06), (2022.5, 0, -80, 240, 69.13),
                   (2025.0, 0, 80, 0, 1.28), (2025.0, 0, 0, 120, -0.16), (2025.0, 0, -80, 240, 68.78),
                   (2025.0, 100, 80, 0, 0.85), (2025.0, 65, 43, 93, 0.50)]


@pytest.mark.parametrize(("year", "height_km", "lat", "lon", "expected"), WMM_TEST_VALUES)
def test_declination_matches_noaa_test_values(year, height_km, lat, lon, expected):
    start = datetime(int(year), 1, 1, tzinfo=UTC)
    when = start + (datetime(int(year) + 1, 1, 1, tzinfo=UTC) - start) * (year - int(year))
    lon = lon - 360 if lon > 180 else lon
    got = magnetic_declination_deg(lat, lon, when, alt_m=height_km * 1000.0)
    assert got == pytest.approx(expected, abs=0.006)


def test_declination_outside_the_models_is_refused():
    assert wmm_model_name(2026.9) == "WMM-2025" and wmm_model_name(2019.5) == "WMM-2015v2"
    with pytest.raises(ValueError, match="no World Magnetic Model covers 2031"):
        magnetic_declination_deg(52.0, 4.0, datetime(2031, 1, 1, tzinfo=UTC))


def test_magnetic_nmea_headings_made_true_with_the_wmm(tmp_path):
    # Rotterdam, 2026: HDM and an HDG without variation get the WMM-2025 declination; HDG's
    # deviation is still applied
    declination = magnetic_declination_deg(51.9, 4.1, datetime(2026, 5, 1, 12, tzinfo=UTC))
    assert 1.0 < declination < 4.0                 # about 2.5 deg E there in 2026
    lines = [_nmea("GPRMC,120000,A,5154.000,N,00406.000,E,0.0,0.0,010526,,"),
             _nmea("HCHDM,100.0,M"),
             _nmea("GPRMC,120001,A,5154.000,N,00406.000,E,0.0,0.0,010526,,"),
             _nmea("HCHDG,100.0,1.5,W,,")]
    path = tmp_path / "magnetic.nmea"
    path.write_text("\n".join(lines) + "\n")
    track = read_vessel_track(path)
    np.testing.assert_allclose(track.heading_deg, [100.0 + declination, 98.5 + declination],
                               atol=0.01)
    assert "2 magnetic heading(s)" in track.notes[0] and "WMM-2025" in track.notes[0]
    # a true heading wins: the magnetic ones are left out, and said so
    path.write_text("\n".join([*lines, _nmea("HEHDT,101.0,T")]) + "\n")
    track = read_vessel_track(path)
    assert track.notes[0] == "2 magnetic heading(s) (HDM, or HDG without variation) left out: " \
        "the feed has true headings"
    # a date no model covers: a clear error, not a silent magnetic heading
    old = [line.replace("010526", "010599") for line in lines[:2]]
    path.write_text("\n".join(_nmea(line[1:-3]) for line in old) + "\n")
    with pytest.raises(InputError, match="cannot be made true: no World Magnetic Model covers 1999"):
        read_vessel_track(path)


def test_csv_magnetic_heading_column(tmp_path):
    path = tmp_path / "ship.csv"
    path.write_text("time,lat,lon,heading_mag_deg\n2026-05-01T12:00:00Z,51.9,4.1,100\n"
                    "2031-05-01T12:00:01Z,51.9,4.1,100\n")
    track = read_vessel_track(path)
    declination = magnetic_declination_deg(51.9, 4.1, datetime(2026, 5, 1, 12, tzinfo=UTC))
    assert list(track.heading_deg) == pytest.approx([100.0 + declination])
    assert "line 3: no World Magnetic Model covers 2031" in track.notes[0]
    assert "heading_mag_deg made true with the WMM-2025 declination" in track.notes[1]


def test_csv_vessel_track_skips_a_bad_row(tmp_path):
    path = tmp_path / "ship.csv"
    path.write_text("time,lat,lon,heading_deg\n2026-05-01T12:00:00Z,56.15,10.21,75\n"
                    "2026-05-01T12:00:01Z,56.15,ten,75\n2026-05-01T12:00:02+00:00,56.1501,10.21,77\n")
    track = read_vessel_track(path)
    assert list(track.t_s) == [0.0, 2.0] and list(track.heading_deg) == [75.0, 77.0]
    assert "line 3: lon: expected a number, got 'ten'" in track.notes[0]


def test_csv_with_a_byte_order_mark(tmp_path):
    """Excel's "CSV UTF-8" starts the file with a BOM, which must not become part of the
    first column's name."""
    path = tmp_path / "ship.csv"
    path.write_bytes(b"\xef\xbb\xbftime,lat,lon,heading_deg\n"
                     b"2026-05-01T12:00:00Z,56.15,10.21,75\n2026-05-01T12:00:01Z,56.15,10.21,76\n")
    assert list(read_vessel_track(path).heading_deg) == [75.0, 76.0]


def test_nmea_fixes_without_a_position_are_counted(tmp_path):
    """RMC status V, GGA quality 0 and 6 (dead reckoning) give no fix; headings before the
    first fix have no time: all are counted in the notes, not dropped silently."""
    lines = [_nmea("HEHDT,10.0,T"),
             _nmea("GPRMC,120000,V,5154.000,N,00406.000,E,0.0,0.0,010526,,"),
             _nmea("GPRMC,120001,A,5154.000,N,00406.000,E,0.0,0.0,010526,,"),
             _nmea("HEHDT,11.0,T"),
             _nmea("GPGGA,120002,5154.001,N,00406.000,E,0,08,0.9,5.0,M,46.9,M,,"),
             _nmea("GPGGA,120003,5154.002,N,00406.000,E,6,08,0.9,5.0,M,46.9,M,,"),
             _nmea("GPGGA,120004,5154.003,N,00406.000,E,1,08,0.9,5.0,M,46.9,M,,"),
             _nmea("HEHDT,12.0,T")]
    path = tmp_path / "ship.nmea"
    path.write_text("\n".join(lines) + "\n")
    track = read_vessel_track(path)
    assert list(track.t_s) == [0.0, 3.0]
    assert track.lat_deg[1] == pytest.approx(51 + 54.003 / 60)
    for what in ("1 sentence(s) skipped: RMC status V", "1 sentence(s) skipped: GGA quality 0",
                 "1 sentence(s) skipped: GGA quality 6", "1 sentence(s) skipped: headings before"):
        assert any(note.startswith(what) for note in track.notes), what



def test_nmea_fixes_and_headings_that_were_not_measured_are_skipped(tmp_path):
    """GGA quality 7 (manual input) and 8 (simulator), an RMC whose mode indicator is E
    (dead reckoning) and a THS heading whose mode is not A are not measurements: each is
    skipped and counted. THS with mode A is a true heading like HDT."""
    lines = [_nmea("GPRMC,120000,A,5154.000,N,00406.000,E,0.0,0.0,010526,,,A"),
             _nmea("GPTHS,10.0,A"),
             _nmea("GPGGA,120001,5154.001,N,00406.000,E,7,08,0.9,5.0,M,46.9,M,,"),
             _nmea("GPGGA,120002,5154.002,N,00406.000,E,8,08,0.9,5.0,M,46.9,M,,"),
             _nmea("GPRMC,120003,A,5154.003,N,00406.000,E,0.0,0.0,010526,,,E"),
             _nmea("GPGGA,120004,5154.004,N,00406.000,E,2,08,0.9,5.0,M,46.9,M,,"),
             _nmea("GPTHS,90.0,E"),                 # estimated: not used
             _nmea("GPTHS,12.0,A"),
             _nmea("GPGGA,120005,5154.005,N,00406.000,E,9,08,0.9,5.0,M,46.9,M,,"),
             _nmea("GPTHS,13.0,A")]
    path = tmp_path / "ship.nmea"
    path.write_text("\n".join(lines) + "\n")
    track = read_vessel_track(path)
    assert list(track.t_s) == [0.0, 4.0, 5.0]                   # 1, 2 and 3 are not measured
    assert track.lat_deg[1] == pytest.approx(51 + 54.004 / 60)
    np.testing.assert_allclose(track.heading_deg, [10.0, 12.0, 13.0], atol=1e-9)
    for what in ("1 sentence(s) skipped: GGA quality 7", "1 sentence(s) skipped: GGA quality 8",
                 "1 sentence(s) skipped: RMC mode E", "1 sentence(s) skipped: THS mode E"):
        assert any(note.startswith(what) for note in track.notes), (what, track.notes)
    assert not any("unreadable" in note for note in track.notes)   # THS is understood
    assert any("SBAS 1" in note for note in track.notes)           # quality 9: the DGPS class

def test_rigid_mount_composes_body_and_mount_rotations():
    """Camera = body · Ry(mount pitch); checked with harborsight's own rotation matrices."""
    body = np.array([[30.0, 5.0, -3.0], [200.0, 0.0, 0.0], [-45.0, -8.0, 12.0]])
    track = Track(source=Path("log.ulg"), kind="px4-ulog", t_s=np.arange(3.0),
                  lat_deg=np.zeros(3), lon_deg=np.zeros(3), alt_m=np.full(3, 50.0),
                  yaw_deg=body[:, 0], pitch_deg=body[:, 1], roll_deg=body[:, 2],
                  attitude_of="vehicle")
    samples = track.sample(np.arange(3.0))
    for mount_pitch in (-90.0, -60.0):
        yaw, pitch, roll = camera_attitude_deg(track, samples, CameraMount("rigid", mount_pitch))
        for i in range(3):
            expected = ned_from_gimbal_rotation(*np.deg2rad(body[i])) @ ned_from_gimbal_rotation(
                0.0, math.radians(mount_pitch), 0.0)
            got = ned_from_gimbal_rotation(*np.deg2rad([yaw[i], pitch[i], roll[i]]))
            np.testing.assert_allclose(got, expected, atol=1e-9)
    yaw, pitch, roll = camera_attitude_deg(track, samples, CameraMount("stabilised"))
    assert list(yaw) == list(body[:, 0] - 360 * (body[:, 0] > 180)) and set(pitch) == {-90.0}


def _vessel_csv(path: Path, start: datetime, seconds: int) -> Path:
    rows = ["time,lat,lon,heading_deg"]
    for s in range(seconds + 1):
        rows.append(f"{(start + timedelta(seconds=s)).isoformat()},{-34.2379 + s * 1e-5},"
                    f"{-58.8510},{90 + s}")
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_fixed_camera_yaw_is_said_to_hold_for_the_whole_video(tmp_path):
    """A DJI SRT without gimbal angles (a Mavic Mini's) takes one --camera-yaw-deg for every
    frame: the user is told that a turn of the drone goes unseen."""
    vessel = tmp_path / "ship.csv"
    vessel.write_text("time,lat,lon,heading_deg\n" + "".join(
        f"2026-05-01T12:00:{s:02d}Z,48.0772,-121.7457,90\n" for s in range(30)))
    out = tmp_path / "flight.jsonl"
    result = runner.invoke(app, [
        "telemetry", "video", str(DJI / "mavic_mini.SRT"), "--vessel-track", str(vessel),
        "--camera", "dji-mavic3", "--image-size", "1280x720", "--frames", "20", "--fps", "2",
        "--video-start", "2026-05-01T12:00:00Z", "--water-level-m", "0", "--camera-yaw-deg", "45",
        "--out", str(out)], terminal_width=400)
    assert result.exit_code == 0, result.output
    frames = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(frames) == 20 and {f["camera_attitude"]["yaw_deg"] for f in frames} == {45.0}
    assert ("the camera's yaw is held at 45 deg from true north for all 20 frame(s) "
            "(--camera-yaw-deg): a turn of the drone during the video is not seen") in result.output


def test_video_metadata_from_a_dji_srt_and_a_vessel_csv(tmp_path):
    start = datetime(2026, 5, 1, 12, 0, 0, tzinfo=UTC)
    vessel_csv = _vessel_csv(tmp_path / "ship.csv", start, 30)
    out = tmp_path / "flight.jsonl"
    result = runner.invoke(app, [
        "telemetry", "video", str(DJI / "p4_rtk.SRT"), "--vessel-track", str(vessel_csv),
        "--camera", "dji-p4rtk", "--image-size", "1280x720", "--frames", "100", "--fps", "2",
        "--video-start", "2026-05-01T12:00:00Z", "--water-level-m", "-2", "--out", str(out)],
        terminal_width=200)
    assert result.exit_code == 0, result.output
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    # 100 frames span 49.5 s of video; the 1 Hz vessel track covers 30 s, and half a sample
    # interval beyond its end
    assert [f["frame_index"] for f in lines] == list(range(62))
    assert "38 frame(s) left out" in result.output and "vessel position" in result.output
    frame = lines[2]                                       # t = 1.0 s: the SRT's second block
    assert frame["camera_attitude"] == {"yaw_deg": 110.5, "pitch_deg": -24.4, "roll_deg": 0.0}
    assert frame["uav"] == {"lat": -34.237911, "lon": -58.85174, "alt_m": 85.83}
    assert frame["vessel"]["lat"] == pytest.approx(-34.2379 + 1e-5)
    assert frame["vessel"]["heading_deg"] == pytest.approx(91.0)
    assert frame["timestamp"] == "2026-05-01T12:00:01Z"
    meta = parse_frame_metadata({**frame, "image": "video"}, "flight.jsonl")
    assert meta.height_above_water_m == pytest.approx(87.83)
    assert meta.camera.fx == pytest.approx(8.8 / 13.2 * 1280)   # the preset's f / sensor width


def test_frames_a_dji_srt_says_were_zoomed_are_left_out_with_the_reason(tmp_path):
    """The Air 2S's SRT states the focal length (``focal_len : 240``: 24 mm, 35 mm
    equivalent). A frame zoomed to 2x (480) has pixels half as large on the water as the
    preset's 24 mm intrinsics say, and every distance would read double: it is left out
    with the reason; the frames at 24 mm are written. With a calibration file, the log's
    first focal length is the one it is taken to hold for."""
    from harborsight.telemetry.metadata import CameraMount, build_video_metadata, camera_block_for
    from harborsight.telemetry.vessel_track import read_vessel_csv

    lines = (DJI / "air2s.srt").read_text(encoding="utf-8").splitlines(keepends=True)
    blocks = "".join(lines).split("\n\n")
    zoomed = "\n\n".join(b.replace("focal_len : 240", "focal_len : 480") if k >= 8 else b
                          for k, b in enumerate(blocks))
    srt = tmp_path / "zoomed.srt"
    srt.write_text(zoomed, encoding="utf-8")
    drone = read_dji_srt(srt, utc_offset_h=2.0)
    assert drone.focal_35mm_mm[0] == 24.0 and drone.focal_35mm_mm[-1] == 48.0
    start = drone.utc_start
    vessel = read_vessel_csv(_vessel_csv(tmp_path / "ship.csv", start, 2))
    camera = camera_block_for("dji-mavic3", 1280, 720, None)
    result = build_video_metadata(drone, vessel, camera, 16, 30.0, water_level_m=0.0,
                                  mount=CameraMount("stabilised", yaw_deg=0.0))
    kept = [f["frame_index"] for f in result.frames]
    assert kept == list(range(8))                        # blocks 0-7 at 24 mm, 1/30 s apart
    reasons = dict(result.skipped)
    assert "zoomed: focal_len 48 mm" in reasons[10] and "hold for 24 mm" in reasons[10]
    assert all("focal_35mm_mm" not in f["camera"] for f in result.frames)
    # a file that writes millimetres with decimals: "240.00" is a 10x zoom, not 24 mm
    (tmp_path / "mm.srt").write_text(zoomed.replace("focal_len : 240", "focal_len : 24.00")
                                     .replace("focal_len : 480", "focal_len : 240.00"), encoding="utf-8")
    in_mm = read_dji_srt(tmp_path / "mm.srt", utc_offset_h=2.0)
    assert in_mm.focal_35mm_mm[0] == 24.0 and in_mm.focal_35mm_mm[-1] == 240.0
    # the unchanged file: nothing is left out for its zoom
    whole = build_video_metadata(read_dji_srt(DJI / "air2s.srt", utc_offset_h=2.0), vessel, camera,
                                 16, 30.0, water_level_m=0.0, mount=CameraMount("stabilised", yaw_deg=0.0))
    assert not any("zoomed" in why for _, why in whole.skipped)


def test_video_metadata_needs_a_clock_and_an_attitude(tmp_path):
    start = datetime(2026, 5, 1, 12, 0, 0, tzinfo=UTC)
    vessel = read_vessel_track(_vessel_csv(tmp_path / "ship.csv", start, 30))
    camera = {"width": 64, "height": 36, "fx": 50.0, "fy": 50.0, "cx": 31.5, "cy": 17.5}
    no_attitude = read_dji_srt(DJI / "p4p_sample.SRT")
    with pytest.raises(InputError, match="UTC time is unknown"):
        build_video_metadata(no_attitude, vessel, camera, 4, 1.0, water_level_m=0.0)
    with pytest.raises(InputError, match="no attitude: give the camera's yaw"):
        build_video_metadata(no_attitude, vessel, camera, 4, 1.0, water_level_m=0.0,
                             video_start_utc=start)
    result = build_video_metadata(no_attitude, vessel, camera, 4, 1.0, water_level_m=0.0,
                                  video_start_utc=start, mount=CameraMount(yaw_deg=15.0))
    assert [f["camera_attitude"]["yaw_deg"] for f in result.frames] == [15.0] * 4
    ulog = read_drone_log(TELEMETRY / "px4" / "sample_log_small.ulg")
    with pytest.raises(InputError, match="give the video's start time in UTC"):
        build_video_metadata(ulog, vessel, camera, 4, 1.0, water_level_m=0.0)
    # placed on the log's clock by the video's UTC start: the log's GPS runs 06:30:58.6-06:31:04.8
    log_vessel = read_vessel_track(_vessel_csv(tmp_path / "ship2.csv",
                                               datetime(2021, 4, 21, 6, 30, 55, tzinfo=UTC), 15))
    result = build_video_metadata(ulog, log_vessel, camera, 9, 1.0, water_level_m=40.0,
                                  video_start_utc=datetime(2021, 4, 21, 6, 30, 58, 700000, tzinfo=UTC))
    # frames 0-6 (06:30:58.7 to 06:31:04.7) lie among the 5 Hz fixes (06:30:58.61 to 06:31:04.80);
    # frame 7 is 0.9 s after the last, beyond half a fix interval (0.1 s)
    assert [f["frame_index"] for f in result.frames] == list(range(7))
    assert [i for i, _ in result.skipped] == [7, 8]
    assert all(-91 < f["camera_attitude"]["pitch_deg"] < -89 for f in result.frames)


def test_cli_show_lists_every_log_and_fails_on_a_bad_one(tmp_path):
    result = runner.invoke(app, ["telemetry", "show", str(DJI / "p4_rtk.SRT"),
                                 str(DJI / "broken_empty.SRT"), "--json", str(tmp_path / "s.json")],
                           terminal_width=200)
    assert result.exit_code == 1
    assert "gimbal (camera)" in result.output and "broken_empty.SRT" in result.output
    [summary] = json.loads((tmp_path / "s.json").read_text())
    assert summary["kind"] == "dji-srt" and summary["samples"] == 55


def test_bundled_flight_round_trips_through_an_srt_and_nmea(tmp_path):
    """The bundled 48-frame flight written out as a P4 RTK style SRT (its precision: 1e-6 deg,
    0.01 m, 0.1 deg) and an NMEA feed (RMC + HDT), then read back into frame metadata: every
    frame within the formats' rounding of the original."""
    from harborsight.frame import load_frame_metadata
    from harborsight.telemetry.writers import write_flight_logs

    metas = [load_frame_metadata(p) for p in sorted((FLIGHT / "frames").glob("*.json"))]
    logs = write_flight_logs(FLIGHT, tmp_path, video=False)
    assert logs.frames == 48 and logs.fps == 2.0
    result = build_video_metadata(
        read_drone_log(logs.srt), read_vessel_track(logs.nmea),
        {"width": 640, "height": 360, "fx": metas[0].camera.fx, "fy": metas[0].camera.fy},
        logs.frames, logs.fps, water_level_m=0.0, video_start_utc=logs.video_start_utc)
    assert result.mount == "gimbal" and not result.skipped
    for frame, m in zip(result.frames, metas, strict=True):
        parsed = parse_frame_metadata({**frame, "image": "video"}, "round trip")
        assert datetime.fromisoformat(parsed.timestamp) == datetime.fromisoformat(m.timestamp)
        assert abs(parsed.uav_lat_deg - m.uav_lat_deg) <= 0.5e-6 + 1e-12
        assert abs(parsed.uav_lon_deg - m.uav_lon_deg) <= 0.5e-6 + 1e-12
        assert abs(parsed.uav_alt_m - m.uav_alt_m) <= 0.005 + 1e-9
        for got, want in ((parsed.yaw_deg, m.yaw_deg), (parsed.pitch_deg, m.pitch_deg),
                          (parsed.roll_deg, m.roll_deg), (parsed.vessel_heading_deg, m.vessel_heading_deg)):
            assert abs((got - want + 180) % 360 - 180) <= 0.05 + 1e-9
        # NMEA positions carry 1e-5 arc minutes: 1.7e-7 degrees
        assert abs(parsed.vessel_lat_deg - m.vessel_lat_deg) <= 1e-7
        assert abs(parsed.vessel_lon_deg - m.vessel_lon_deg) <= 1e-7
    # the logs bundled with the flight are exactly these (make-samples writes them)
    for name in ("flight.SRT", "ship.nmea"):
        assert (FLIGHT / "logs" / name).read_bytes() == (tmp_path / name).read_bytes(), name


def test_the_readmes_telemetry_example_runs_on_the_bundled_logs(tmp_path):
    """README: `telemetry video` on the bundled SRT, NMEA and mp4 writes metadata for every
    frame of the video, which `run` then measures."""
    logs = FLIGHT / "logs"
    out = tmp_path / "flight.jsonl"
    result = runner.invoke(app, ["telemetry", "video", str(logs / "flight.SRT"), "--vessel-track",
                                 str(logs / "ship.nmea"), "--video", str(logs / "flight.mp4"),
                                 "--camera", "dji-mavic3", "--video-start",
                                 "2026-05-01T12:00:00Z", "--water-level-m", "0", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "48 of 48 frame(s) written" in result.output
    assert len(out.read_text().splitlines()) == 48


def test_telemetry_video_places_each_frame_at_its_own_time_in_the_video(tmp_path):
    """The bundled flight recorded with dropped frames (frames 4 and 5 missing: the video's
    mean rate is below 2 fps): each frame's pose is the logs' at its presentation time, not
    at n / fps. `--fps` against the video's own rate, or `--image-size` against its frames,
    is refused: they would silently replace what the video says."""
    from fractions import Fraction

    import av
    import cv2

    logs = FLIGHT / "logs"
    times = [0.0, 0.5, 1.0, 1.5, 3.0, 3.5, 4.0, 4.5]
    base = Fraction(1, 1000)
    video = tmp_path / "dropped.mp4"
    capture = cv2.VideoCapture(str(logs / "flight.mp4"))
    pictures = [capture.read()[1] for _ in range(10)]
    capture.release()
    with av.open(str(video), "w") as out:
        stream = out.add_stream("libx264", rate=2)
        stream.width, stream.height, stream.pix_fmt = 640, 360, "yuv420p"
        stream.time_base = stream.codec_context.time_base = base
        stream.options = {"bf": "0"}
        for t in times:
            frame = av.VideoFrame.from_ndarray(pictures[round(2 * t)], format="bgr24")
            frame.pts, frame.time_base = round(t / base), base
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    common = ["telemetry", "video", str(logs / "flight.SRT"), "--vessel-track",
              str(logs / "ship.nmea"), "--video", str(video), "--camera", "dji-mavic3",
              "--video-start", "2026-05-01T12:00:00Z", "--water-level-m", "0"]
    out = tmp_path / "dropped.jsonl"
    result = runner.invoke(app, [*common, "--out", str(out)])
    assert result.exit_code == 0, result.output
    written = [json.loads(line) for line in out.read_text().splitlines()]
    stamps = [datetime.fromisoformat(f["timestamp"].replace("Z", "+00:00")) for f in written]
    seconds = [(t - stamps[0]).total_seconds() for t in stamps]
    np.testing.assert_allclose(seconds, times, atol=2e-3)
    truth = [json.loads((FLIGHT / "frames" / f"{round(2 * t):06d}.json").read_text()) for t in times]
    for frame, true in zip(written, truth, strict=True):
        assert abs(frame["uav"]["lat"] - true["uav"]["lat"]) < 2e-6          # 0.2 m
        assert abs(frame["vessel"]["lat"] - true["vessel"]["lat"]) < 2e-6
    for extra, option in ((["--fps", "25"], "--fps"), (["--image-size", "1280x720"], "--image-size")):
        result = runner.invoke(app, [*common, *extra, "--out", str(tmp_path / "x.jsonl")])
        assert result.exit_code == 2 and option in result.output, result.output


def test_srt_damage_is_noted_not_fatal(tmp_path):
    text = (DJI / "p4_rtk.SRT").read_text(encoding="utf-8")
    cut = tmp_path / "cut.SRT"                    # recording stopped inside the last block
    cut.write_text(text[:text.rindex("F.PRY")], encoding="utf-8")
    track = read_dji_srt(cut)                     # the torn block is left out with a note
    whole = read_dji_srt(DJI / "p4_rtk.SRT")
    assert len(track) == len(whole) - 1 and track.attitude_of == "gimbal"
    assert not np.isnan(track.yaw_deg).any() and track.yaw_deg[0] == 110.4
    assert any("cut short at the end of the file left out" in note for note in track.notes)
    legacy = tmp_path / "cp1252.SRT"              # the degree sign as one cp1252 byte
    legacy.write_bytes(text.encode("cp1252"))
    assert list(read_dji_srt(legacy).pitch_deg[:2]) == [-24.4, -24.4]
    bad = tmp_path / "bad.SRT"
    bad.write_text("1\n00:00:00,000 --> 00:00:01,000\n2017.13.45 10:00:00\nGPS(149.0,-20.2,16) "
                   "BAROMETER:1.9\n\n2\n00:00:01,000 --> 00:00:02,000\nGPS(300.0,-20.2,16)\n\n"
                   "3\n00:00:02,000 --> 00:00:03,000\n2017.08.05 10:00:02\nGPS(149.0,-20.2,16) "
                   "BAROMETER:2.0\n")
    track = read_dji_srt(bad)
    assert len(track) == 2 and track.lat_deg[0] == -20.2
    assert "1 block(s) with a position outside ±90°/±180° skipped (line 6)" in track.notes
    assert "1 block(s) with an impossible date line (date ignored) (line 1)" in track.notes


@pytest.mark.parametrize("digits", [0, 2, 5])
def test_an_srt_cut_inside_its_last_value_drops_that_block(tmp_path, digits):
    """[altitude: 117.100000] cut to [altitude: 11 was read as 11 m (issue #30)."""
    text = (DJI / "air2s.srt").read_text(encoding="utf-8")
    value = text.rindex("[altitude: ") + len("[altitude: ")
    cut = tmp_path / "cut.srt"
    cut.write_text(text[:value + digits], encoding="utf-8")      # "", "11", "117.1"
    track, whole = read_dji_srt(cut), read_dji_srt(DJI / "air2s.srt")
    assert len(track) == len(whole) - 1
    assert np.array_equal(track.alt_m, whole.alt_m[:-1])
    assert any("cut short" in note for note in track.notes)
    # a whole file saved without its final newline keeps every block
    plain = tmp_path / "plain.srt"
    plain.write_text(text.rstrip("\n"), encoding="utf-8")
    assert len(read_dji_srt(plain)) == len(whole)


def test_nmea_headings_between_fixes_and_midnight(tmp_path):
    # 1 Hz fixes, 4 Hz headings turning 4 deg/s: heading k after fix i was sent at i + k/4 s
    lines = [_nmea("GPZDA,235958.00,30,04,2026,00,00")]
    for second in range(4):
        clock = f"{(23 * 3600 + 59 * 60 + 58 + second) % 86400 // 3600:02d}" \
                f"{(59 * 60 + 58 + second) % 3600 // 60:02d}{(58 + second) % 60:02d}"
        lines.append(_nmea(f"GPGGA,{clock},5609.000,N,01013.000,E,1,08,0.9,5.0,M,40.0,M,,"))
        lines += [_nmea(f"HEHDT,{4 * (second + k / 4):.2f},T") for k in range(4)]
    path = tmp_path / "turn.nmea"
    path.write_text("\n".join(lines) + "\n")
    track = read_vessel_track(path)
    # the day rolls over at 00:00:00 although no new date arrived
    assert track.utc_start == datetime(2026, 4, 30, 23, 59, 58, tzinfo=UTC)
    assert list(track.t_s) == [0.0, 1.0, 2.0, 3.0]
    np.testing.assert_allclose(track.heading_deg, [0.0, 4.0, 8.0, 12.0], atol=1e-9)


def test_gps_time_to_utc_uses_the_leap_seconds_of_the_day():
    from harborsight.telemetry.autopilot import GPS_EPOCH, utc_from_gps_time

    for utc, leap in ((datetime(2016, 6, 1, tzinfo=UTC), 17), (datetime(2013, 1, 1, tzinfo=UTC), 16),
                      (datetime(2026, 5, 1, 12, tzinfo=UTC), 18)):
        gps_seconds = (utc - GPS_EPOCH).total_seconds() + leap
        assert utc_from_gps_time(gps_seconds) == utc


def test_mount_attitudes_in_physical_cases():
    def track_with(yaw, pitch, roll):
        return Track(source=Path("log.ulg"), kind="px4-ulog", t_s=np.zeros(1), lat_deg=np.zeros(1),
                     lon_deg=np.zeros(1), alt_m=np.full(1, 50.0), yaw_deg=np.array([yaw]),
                     pitch_deg=np.array([pitch]), roll_deg=np.array([roll]), attitude_of="vehicle")

    # a level drone heading 30 deg with a camera fixed straight down: the optical axis (x_G)
    # points down and the image top (-z_G) points along 30 deg (north-east)
    level = track_with(30.0, 0.0, 0.0)
    yaw, pitch, roll = camera_attitude_deg(level, level.sample(np.zeros(1)), CameraMount("rigid"))
    rotation = ned_from_gimbal_rotation(*np.deg2rad([yaw[0], pitch[0], roll[0]]))
    np.testing.assert_allclose(rotation[:, 0], [0.0, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(rotation @ [0.0, 0.0, -1.0],
                               [math.cos(math.radians(30)), math.sin(math.radians(30)), 0.0], atol=1e-9)
    # nose down 10 deg with a camera pitched -60 on the body: -70 deg, yaw and roll unchanged
    nose_down = track_with(30.0, -10.0, 0.0)
    got = camera_attitude_deg(nose_down, nose_down.sample(np.zeros(1)), CameraMount("rigid", -60.0))
    np.testing.assert_allclose([a[0] for a in got], [30.0, -70.0, 0.0], atol=1e-9)
    gimbal = read_dji_srt(DJI / "p4_rtk.SRT")
    with pytest.raises(InputError, match="gimbal's yaw"):
        camera_attitude_deg(gimbal, gimbal.sample(np.zeros(1)), CameraMount(yaw_deg=10.0))


def test_cli_video_refuses_bad_sizes_and_unknown_cameras(tmp_path):
    vessel_csv = _vessel_csv(tmp_path / "ship.csv", datetime(2026, 5, 1, 12, tzinfo=UTC), 5)
    base = ["telemetry", "video", str(DJI / "p4_rtk.SRT"), "--vessel-track", str(vessel_csv),
            "--frames", "4", "--fps", "2", "--video-start", "2026-05-01T12:00:00Z",
            "--water-level-m", "0", "--out", str(tmp_path / "f.jsonl")]
    bad_size = runner.invoke(app, [*base, "--camera", "dji-p4rtk", "--image-size", "-1280x720"],
                             terminal_width=200)
    assert bad_size.exit_code == 2 and "--image-size" in bad_size.output
    typo = runner.invoke(app, [*base, "--camera", "dji-p4-rtk", "--image-size", "1280x720"],
                         terminal_width=200)
    assert typo.exit_code == 2 and "neither a camera preset (dji-mavic3" in typo.output
    assert not (tmp_path / "f.jsonl").exists()


def test_random_bytes_as_a_dataflash_log_are_one_line(tmp_path, capfd):
    """20 kB of random bytes named .BIN: pymavlink's Cython indexer prints a line per bad
    header straight to the C stderr (thousands of them); we say it in one line."""
    junk = tmp_path / "junk.BIN"
    junk.write_bytes(np.random.default_rng(0).integers(0, 256, 20_000, dtype=np.uint8).tobytes())
    with pytest.raises(InputError, match="not an ArduPilot DataFlash log") as caught:
        read_drone_log(junk)
    assert "junk.BIN" in str(caught.value)
    captured = capfd.readouterr()
    assert "bad header" not in captured.out + captured.err
    result = CliRunner().invoke(app, ["telemetry", "show", str(junk)])
    assert result.exit_code == 1
    captured = capfd.readouterr()
    assert "bad header" not in result.output + captured.out + captured.err


# -- accuracy figures: what each log states, and the frames that carry them -----------------

def test_px4_accuracy_is_eph_and_epv_of_the_receiver():
    """eph is the receiver's radial horizontal accuracy (u-blox hAcc): per axis / √2; the
    altitude here is the receiver's (z_global never set), so its sigma is the receiver's epv.
    Checked against pyulog's own reading of the topic."""
    from pyulog import ULog

    path = TELEMETRY / "px4" / "sample_log_small.ulg"
    track = read_drone_log(path)
    gps = ULog(str(path), ["vehicle_gps_position"]).get_dataset("vehicle_gps_position").data
    assert set(gps["fix_type"]) == {3} and len(track) == len(gps["eph"]) == 32
    np.testing.assert_allclose(track.position_sigma_m, gps["eph"] / math.sqrt(2.0), rtol=1e-6)
    np.testing.assert_allclose(track.alt_sigma_m, gps["epv"], rtol=1e-6)
    assert gps["eph"][0] == pytest.approx(3.26) and gps["epv"][0] == pytest.approx(6.984)
    assert track.position_sigma_m[0] == pytest.approx(3.26 / math.sqrt(2.0), rel=1e-6)
    summary = track.summary()
    assert summary["position_sigma_m"] == pytest.approx([2.507 / math.sqrt(2.0), 3.26 / math.sqrt(2.0)],
                                                        rel=1e-5)
    assert summary["alt_sigma_m"] == pytest.approx([5.222, 6.984], rel=1e-5)
    assert summary["heading_sigma_deg"] is None
    assert any(n.startswith("position_sigma_m (per axis): vehicle_gps_position.eph / √2") and
               n.endswith("for 32 of 32 samples; fix_type: 3-D fix 32") for n in track.notes)
    assert "alt_sigma_m: the receiver's vehicle_gps_position.epv (vertical accuracy)" in track.notes


def test_px4_altitude_sigma_follows_the_altitudes_source(tmp_path):
    """The estimator's altitude goes with the estimator's epv; a sample outside its span keeps
    the receiver's altitude and the receiver's epv."""
    topics = "uint64_t timestamp;uint64_t timestamp_sample;uint64_t time_utc_usec;double " \
             "latitude_deg;double longitude_deg;double altitude_msl_m;uint8_t fix_type;float eph;" \
             "float epv;float hdop;"
    gps_rows = [(1_000_000 + 200_000 * i, 1_000_000 + 200_000 * i, 0, 51.9, 4.1, 30.0, fix,
                 eph, 3.0, 0.8) for i, (fix, eph) in enumerate(
                     [(6, 0.014), (6, 0.014), (5, 0.3), (3, 0.0), (3, 0.0), (6, 0.014)])]
    data = b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0)
    data += _ulog_message("B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    data += _ulog_message("F", f"sensor_gps:{topics}".encode())
    data += _ulog_message("F", b"vehicle_global_position:uint64_t timestamp;double lat;double lon;"
                          b"float alt;float eph;float epv;")
    data += _ulog_message("A", struct.pack("<BH", 0, 0) + b"sensor_gps")
    data += _ulog_message("A", struct.pack("<BH", 0, 1) + b"vehicle_global_position")
    for row in gps_rows:
        data += _ulog_message("D", struct.pack("<H", 0) + struct.pack("<3Q3dB3f", *row))
    for k in range(9):                                              # t = 1.0 ... 1.8 s
        data += _ulog_message("D", struct.pack("<H", 1) + struct.pack(
            "<Q2d3f", 1_000_000 + 100_000 * k, 51.9, 4.1, 20.0, 0.5, 0.4 + 0.01 * k))
    path = tmp_path / "rtk.ulg"
    path.write_bytes(data)
    track = read_drone_log(path)
    # eph where the receiver states it; eph 0 (none) falls back on the class: 3-D fix,
    # standalone 2 m DRMS (HDOP 0.8 does not narrow it)
    np.testing.assert_allclose(track.position_sigma_m, np.array(
        [0.014, 0.014, 0.3, 2.0, 2.0, 0.014]) / math.sqrt(2.0), rtol=1e-6)
    np.testing.assert_allclose(track.alt_sigma_m, [0.40, 0.42, 0.44, 0.46, 0.48, 3.0], rtol=1e-6)
    assert ("position_sigma_m (per axis): sensor_gps.eph / √2 (the receiver's horizontal accuracy, "
            "radial) for 4 of 6 samples; the fix_type class for 2, widened by HDOP above 1; "
            "fix_type: RTK fixed 3, 3-D fix 2, RTK float 1") in track.notes
    assert ("alt_sigma_m: the estimator's vehicle_global_position.epv; the receiver's "
            "sensor_gps.epv (vertical accuracy) outside its span") in track.notes


def _dataflash_records(log, name: str) -> tuple[list[int], int]:
    """Offsets and length of every record of one message type, from pymavlink's index."""
    kind = next(i for i, f in log.formats.items() if f.name == name)
    return list(log.offsets[kind]), log.formats[kind].len


def test_ardupilot_accuracy_is_gpa_hacc_else_the_fix_class(tmp_path):
    from pymavlink import DFReader

    path = TELEMETRY / "ardupilot" / "test.BIN"
    track = read_drone_log(path)
    log = DFReader.DFReader_binary(str(path), zero_time_base=False)
    hacc, gps_time_us = {}, []
    while (message := log.recv_match(type=["GPS", "GPA"])) is not None:
        if message.get_type() == "GPA":
            hacc[message.TimeUS] = message.HAcc
        else:
            gps_time_us.append(message.TimeUS)
    assert set(hacc) == set(gps_time_us) and set(hacc.values()) == {1.61}    # SITL's receiver
    np.testing.assert_allclose(track.position_sigma_m,
                               [hacc[t] / math.sqrt(2.0) for t in gps_time_us])
    # the altitude is the EKF's POS.Alt, whose accuracy the log does not state: GPA.VAcc
    # (2.41 m) belongs to the receiver's altitude, so the track gives none
    assert track.alt_sigma_m is None and "POS.Alt" in track.alt_reference
    assert any(n.startswith("alt_sigma_m: none for the EKF altitude (POS.Alt)") for n in track.notes)

    # without GPA: GPS.Status's class, widened by HDop. The first three GPS records are set to
    # RTK fixed with HDop 2.5, RTK float, DGPS (HDop 0.77 as logged); the GPA records dropped
    data = bytearray(path.read_bytes())
    gps_offsets, _ = _dataflash_records(log, "GPS")
    for offset, status in zip(gps_offsets[:3], (6, 5, 4), strict=True):
        data[offset + 11] = status                              # header 3 + TimeUS 8: Status
    data[gps_offsets[0] + 19:gps_offsets[0] + 21] = struct.pack("<h", 250)   # HDop x 100
    gpa_offsets, gpa_len = _dataflash_records(log, "GPA")
    for offset in reversed(gpa_offsets):
        del data[offset:offset + gpa_len]
    no_gpa = tmp_path / "no_gpa.BIN"
    no_gpa.write_bytes(bytes(data))
    track = read_drone_log(no_gpa)
    np.testing.assert_allclose(track.position_sigma_m, np.array(
        [0.02 * 2.5, 0.5, 0.5, 2.0, 2.0]) / math.sqrt(2.0))
    assert ("position_sigma_m (per axis): the GPS Status class for 5, widened by HDOP above 1; "
            "GPS Status: 3-D fix 2, DGPS/SBAS 1, RTK float 1, RTK fixed 1") in track.notes
    assert track.alt_sigma_m is None


@pytest.mark.parametrize("name", [name for name, *_ in SRT_CASES])
def test_dji_srts_state_no_accuracy(name):
    """None of the real SRT families prints an RTK flag or a standard deviation, the P4 RTK's
    and the Matrice 300's included: no accuracy figures, and the show table says so."""
    text = (DJI / name).read_text(errors="replace").lower()
    assert not any(word in text for word in ("rtk", "std", "acc", "dop", "sigma"))
    track = read_dji_srt(DJI / name)
    assert (track.position_sigma_m, track.alt_sigma_m, track.heading_sigma_deg) == (None,) * 3
    assert not any("sigma" in note for note in track.notes)


def _nmea_feed(path: Path, epochs: list[tuple[str, ...]], gst: dict[int, tuple[str, ...]],
               gst_first: bool = False) -> Path:
    """An NMEA feed written with pynmea2: per epoch a GGA (fields as given), a steady true heading,
    and where ``gst`` has the epoch a GST (before the GGA if ``gst_first``), after a ZDA that
    dates the fixes 2021-04-21."""
    import pynmea2

    lines = [str(pynmea2.ZDA("GP", "ZDA", (epochs[0][0], "21", "04", "2021", "00", "00")))]
    for k, gga_fields in enumerate(epochs):
        gga = str(pynmea2.GGA("GP", "GGA", gga_fields))
        hdt = str(pynmea2.HDT("HE", "HDT", ("90.0", "T")))      # a steady heading
        errors = [str(pynmea2.GST("GP", "GST", gst[k]))] if k in gst else []
        lines += [*errors, gga, hdt] if gst_first else [gga, *errors, hdt]
    path.write_text("\n".join(lines) + "\n")
    return path


def _gga(clock: str, quality: int, hdop: str) -> tuple[str, ...]:
    return (clock, "5154.000", "N", "00406.000", "E", str(quality), "12", hdop, "5.0", "M",
            "47.0", "M", "", "")


@pytest.mark.parametrize("gst_first", [False, True])
def test_nmea_position_sigma_from_gst(tmp_path, gst_first):
    """GST gives the latitude and longitude error sigmas (m) of its epoch's fix: one per axis
    already, their RMS is the track's figure. A GST belongs to the fix with its time, before
    or after the GGA; an epoch without one falls back on the GGA quality class."""
    clocks = [f"0630{55 + k:02d}.00" for k in range(4)]
    gst = {0: (clocks[0], "0.006", "0.023", "0.020", "273.6", "0.023", "0.020", "0.031"),
           1: (clocks[1], "0.9", "1.2", "0.8", "10.0", "1.1", "0.9", "2.0"),
           2: ("063059.00", "0.9", "1.2", "0.8", "10.0", "1.1", "0.9", "2.0"),   # no such fix
           3: (clocks[3], "0.9", "", "", "", "", "", "")}                          # no errors
    path = _nmea_feed(tmp_path / "ship.nmea", [_gga(c, 4, "0.7") for c in clocks], gst, gst_first)
    track = read_vessel_track(path)
    assert track.utc_start == datetime(2021, 4, 21, 6, 30, 55, tzinfo=UTC)
    rtk = 0.02 / math.sqrt(2.0)
    np.testing.assert_allclose(track.position_sigma_m, [
        math.sqrt((0.023 ** 2 + 0.020 ** 2) / 2), math.sqrt((1.1 ** 2 + 0.9 ** 2) / 2), rtk, rtk])
    assert track.heading_sigma_deg is None               # HDT states no accuracy
    assert track.notes == [
        "position_sigma_m (per axis): GST latitude/longitude error RMS for 2 of 4 fixes; the GGA "
        "quality class, widened by HDOP above 1, for 2 (RTK fixed 2)",
        "1 GST sentence(s) left out: no fix at their time",
        "1 GST sentence(s) without a time or a usable latitude/longitude error skipped"]


def test_nmea_position_sigma_from_the_gga_quality_class(tmp_path):
    """GGA only: 4 RTK fixed, 5 RTK float, 2 DGPS, 1 GPS give the rtk, dgps, dgps and
    standalone horizontal RMS (0.02, 0.5, 0.5, 2.0 m), widened by an HDOP above 1 (not by one
    below, nor by NMEA's 99.99 "no value"); per axis / √2. Quality 6 (dead reckoning) is no fix."""
    epochs = [_gga("120000.00", 4, "0.6"), _gga("120001.00", 5, "2.0"), _gga("120002.00", 2, "1.5"),
              _gga("120003.00", 1, "3.0"), _gga("120004.00", 1, "99.99"), _gga("120005.00", 6, "1.0"),
              _gga("120006.00", 1, "")]
    track = read_vessel_track(_nmea_feed(tmp_path / "ship.nmea", epochs, {}))
    assert len(track) == 6
    np.testing.assert_allclose(track.position_sigma_m, np.array(
        [0.02, 0.5 * 2.0, 0.5 * 1.5, 2.0 * 3.0, 2.0, 2.0]) / math.sqrt(2.0))
    assert ("position_sigma_m (per axis): the GGA quality class, widened by HDOP above 1, for 6 "
            "(GPS 3, DGPS 1, RTK fixed 1, RTK float 1)") in track.notes


def test_csv_accuracy_columns(tmp_path):
    path = tmp_path / "ship.csv"
    path.write_text("time,lat,lon,heading_deg,position_sigma_m,heading_sigma_deg\n"
                    "2026-05-01T12:00:00Z,56.15,10.21,75,0.05,0.3\n"
                    "2026-05-01T12:00:01Z,56.15,10.21,76,,0.3\n"
                    "2026-05-01T12:00:02Z,56.15,10.21,77,-1,0.3\n"
                    "2026-05-01T12:00:03Z,56.15,10.21,78,0.07,\n")
    track = read_vessel_track(path)
    assert list(track.t_s) == [0.0, 1.0, 3.0]
    np.testing.assert_allclose(track.position_sigma_m, [0.05, np.nan, 0.07])
    np.testing.assert_allclose(track.heading_sigma_deg, [0.3, 0.3, np.nan])
    assert "line 4: position_sigma_m: -1.0 is outside [0.0, 1000.0]" in track.notes[0]
    # interpolated over the rows that have it, within reach like every quantity: the 3 s
    # between them is a gap at max_gap_s 1, bridged at 2
    assert np.isnan(track.sample(np.array([0.5, 2.0]))["position_sigma_m"]).all()
    sampled = track.sample(np.array([0.5, 2.0]), max_gap_s=2.0)
    np.testing.assert_allclose(sampled["position_sigma_m"], [0.05 + 0.02 / 6, 0.05 + 0.02 * 2 / 3])
    plain = tmp_path / "plain.csv"
    plain.write_text("time,lat,lon,heading_deg\n2026-05-01T12:00:00Z,56.15,10.21,75\n")
    assert read_vessel_track(plain).position_sigma_m is None


def test_sampled_sigmas_have_gaps_like_every_quantity():
    track = Track(source=Path("x"), kind="csv", t_s=np.array([0.0, 1.0, 10.0]),
                  lat_deg=np.zeros(3), lon_deg=np.zeros(3), heading_deg=np.zeros(3),
                  position_sigma_m=np.array([1.0, 2.0, 2.0]), alt_sigma_m=np.full(3, np.nan))
    sampled = track.sample(np.array([0.5, 5.0, 12.0]))
    np.testing.assert_allclose(sampled["position_sigma_m"], [1.5, np.nan, np.nan])
    assert np.isnan(sampled["alt_sigma_m"]).all() and "heading_sigma_deg" not in sampled
    assert track.summary()["position_sigma_m"] == [1.0, 2.0] and track.summary()["alt_sigma_m"] is None
    with pytest.raises(ValueError, match="position_sigma_m"):
        Track(source=Path("x"), kind="csv", t_s=np.zeros(2), lat_deg=np.zeros(2),
              lon_deg=np.zeros(2), position_sigma_m=np.ones(3))


def test_frames_carry_the_logs_accuracy(tmp_path):
    """PX4 log + NMEA feed with GST: each frame carries the drone's per-axis position sigma
    and altitude sigma and the vessel's position sigma, sampled at its time, and they reach
    FrameMetadata.sensor_sigmas. A track without them writes no field (never null)."""
    clocks = [f"{datetime(2021, 4, 21, 6, 30, 55) + timedelta(seconds=k):%H%M%S}.00"
              for k in range(12)]
    gst = {k: (c, "0.5", "0.03", "0.02", "0.0", "0.03", "0.04", "0.05") for k, c in enumerate(clocks)}
    vessel = read_vessel_track(_nmea_feed(tmp_path / "ship.nmea",
                                          [_gga(c, 4, "0.7") for c in clocks], gst))
    drone = read_drone_log(TELEMETRY / "px4" / "sample_log_small.ulg")
    camera = {"width": 64, "height": 36, "fx": 50.0, "fy": 50.0, "cx": 31.5, "cy": 17.5}
    start = datetime(2021, 4, 21, 6, 30, 58, 700000, tzinfo=UTC)
    result = build_video_metadata(drone, vessel, camera, 7, 1.0, water_level_m=40.0,
                                  video_start_utc=start)
    assert len(result.frames) == 7
    uav = drone.sample(np.array([f["telemetry"]["drone_t_s"] for f in result.frames]))
    for frame, position, alt in zip(result.frames, uav["position_sigma_m"], uav["alt_sigma_m"],
                                    strict=True):
        assert frame["uav"]["position_sigma_m"] == pytest.approx(position, abs=1e-4)
        assert frame["uav"]["alt_sigma_m"] == pytest.approx(alt, abs=1e-4)
        assert frame["vessel"]["position_sigma_m"] == pytest.approx(0.025 * math.sqrt(2.0), abs=1e-4)
        assert "heading_sigma_deg" not in frame["vessel"]
        meta = parse_frame_metadata({**frame, "image": "video"}, "flight.jsonl")
        assert meta.sensor_sigmas == {"uav_gps": frame["uav"]["position_sigma_m"],
                                      "height_m": frame["uav"]["alt_sigma_m"],
                                      "vessel_gps": frame["vessel"]["position_sigma_m"]}
    assert 1.77 < result.frames[0]["uav"]["position_sigma_m"] < 2.31
    assert 5.2 < result.frames[0]["uav"]["alt_sigma_m"] < 7.0
    # a log that states none: the frame has no sigma field at all
    srt = read_dji_srt(DJI / "matrice_300.srt", utc_offset_h=2.0)
    csv_vessel = read_vessel_track(_vessel_csv(tmp_path / "ship.csv", srt.utc_start, 10))
    plain = build_video_metadata(srt, csv_vessel, camera, 5, 1.0, water_level_m=-5.0,
                                 mount=CameraMount(yaw_deg=30.0))
    assert len(plain.frames) == 5
    for k, frame in enumerate(plain.frames):
        # the rate of turn fitted to the CSV's headings (1 deg/s, 3 s of them around the
        # frame: none at the log's first second) brings its own sigma; the log states no
        # sensor's accuracy
        assert frame["vessel"].pop("yaw_rate_deg_s", None) == (
            None if k == 0 else pytest.approx(1.0, abs=1e-3))
        assert frame["vessel"].pop("yaw_rate_sigma_deg_s", None) == (
            None if k == 0 else pytest.approx(0.05))
        assert not any("sigma" in key for section in ("uav", "camera_attitude", "vessel")
                       for key in frame[section])
        assert parse_frame_metadata({**frame, "image": "video"}).sensor_sigmas == {}


def test_frame_sigma_fields_only_where_finite(tmp_path):
    """A sampled sigma that is NaN (a gap in the figures) or beyond the frame's 1000 limit is
    left out of that frame; the frames stay strict JSON."""
    from harborsight.files import strict_json

    start = datetime(2026, 5, 1, 12, tzinfo=UTC)
    vessel = Track(source=tmp_path / "ship.csv", kind="csv", t_s=np.arange(4.0),
                   lat_deg=np.full(4, 56.15), lon_deg=np.full(4, 10.21), heading_deg=np.full(4, 75.0),
                   position_sigma_m=np.array([0.1, np.nan, np.nan, 0.1]),
                   heading_sigma_deg=np.array([0.3, 0.3, 0.3, 5000.0]), utc_start=start)
    drone = Track(source=tmp_path / "log.ulg", kind="px4-ulog", t_s=np.arange(4.0),
                  lat_deg=np.full(4, 56.1501), lon_deg=np.full(4, 10.21), alt_m=np.full(4, 60.0),
                  yaw_deg=np.zeros(4), pitch_deg=np.zeros(4), roll_deg=np.zeros(4),
                  attitude_of="vehicle", utc_start=start, alt_sigma_m=np.full(4, 0.5))
    camera = {"width": 64, "height": 36, "fx": 50.0, "fy": 50.0, "cx": 31.5, "cy": 17.5}
    result = build_video_metadata(drone, vessel, camera, 4, 1.0, water_level_m=0.0,
                                  video_start_utc=start, max_gap_s=0.5)
    assert [f["vessel"].get("position_sigma_m") for f in result.frames] == [0.1, None, None, 0.1]
    assert [f["vessel"].get("heading_sigma_deg") for f in result.frames] == [0.3, 0.3, 0.3, None]
    assert all(f["uav"]["alt_sigma_m"] == 0.5 and "position_sigma_m" not in f["uav"]
               for f in result.frames)
    for frame in result.frames:
        strict_json(frame)
        parse_frame_metadata({**frame, "image": "video"})


def test_cli_show_lists_the_accuracy_figures(tmp_path):
    result = runner.invoke(app, ["telemetry", "show", str(TELEMETRY / "px4" / "sample_log_small.ulg"),
                                 str(TELEMETRY / "ardupilot" / "test.BIN"), str(DJI / "p4_rtk.SRT"),
                                 "--json", str(tmp_path / "s.json")], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "position (per axis) 1.77 to 2.31 m; altitude 5.22 to 6.98 m" in result.output
    assert "position (per axis) 1.14 m" in result.output
    assert "none in the log (the sensor defaults apply)" in result.output
    px4, ardupilot, dji = json.loads((tmp_path / "s.json").read_text())
    assert px4["position_sigma_m"] == pytest.approx([1.7727, 2.3052], abs=1e-4)
    assert ardupilot["alt_sigma_m"] is None and dji["position_sigma_m"] is None


def test_a_log_that_times_its_fixes_by_arrival_says_the_attitude_runs_late():
    """The sample PX4 log's vehicle_gps_position has no timestamp_sample: it carries the
    receiver's delay into the clock the attitude is matched on, and says so once. ArduPilot
    stamps GPS by when it was logged too, but its log says the delay it assumes: the fixes
    are moved back by it, and that is said instead."""
    from harborsight.telemetry.autopilot import read_ardupilot_bin, read_px4_ulog

    track = read_px4_ulog(TELEMETRY / "px4" / "sample_log_small.ulg")
    said = [note for note in track.notes if "after the receiver's delay" in note]
    assert len(said) == 1 and said[0].startswith("GPS fixes are timed by vehicle_gps_position.timestamp")
    track = read_ardupilot_bin(TELEMETRY / "ardupilot" / "test.BIN")
    assert not [note for note in track.notes if "after the receiver's delay" in note]
    assert [note for note in track.notes if "less 0.22 s" in note] == [
        "GPS fixes are timed by GPS.TimeUS less 0.22 s, the receiver's delay ArduPilot assumes "
        "(the u-blox driver's lag for hardware 00040007)"]


def test_ardupilot_receiver_lag_is_the_one_the_autopilot_assumes():
    """GPS_DELAY_MS (GPS1_DELAY_MS from ArduPilot 4.6) where set above 0, else AP_GPS_UBLOX's
    lag for the hardware of the startup message (0.22 s for u-blox 5, 6 and unknown ones,
    0.12 s later), else the EKF's EK3/EK2_GPS_DELAY; nothing where the log does not say."""
    from harborsight.telemetry.autopilot import ardupilot_gps_lag_s

    m8 = ["GPS 1: detected as u-blox at 230400 baud", "u-blox 1 HW: 00080000 SW: ROM CORE 3.01"]
    assert ardupilot_gps_lag_s({"GPS_DELAY_MS": 150.0}, m8) == (0.15, "GPS_DELAY_MS 150")
    assert ardupilot_gps_lag_s({"GPS1_DELAY_MS": 80.0}, []) == (0.08, "GPS1_DELAY_MS 80")
    assert ardupilot_gps_lag_s({"GPS_DELAY_MS": 0.0}, m8)[0] == 0.12
    assert ardupilot_gps_lag_s({}, ["u-blox 1 HW: 00040007 SW: 7.03 (45970)"])[0] == 0.22
    assert ardupilot_gps_lag_s({}, ["u-blox 1 HW: 00190000 SW: EXT CORE 1.00 (61b2dd)"])[0] == 0.12
    # an F9's hardware with other software is a generation the driver does not know: 0.22 s
    assert ardupilot_gps_lag_s({}, ["u-blox 1 HW: 00190000 SW: ROM BASE 0x118B2060"])[0] == 0.22
    assert ardupilot_gps_lag_s({}, ["u-blox 1 HW: 12345678 SW: ?"])[0] == 0.22
    # a moving-baseline rover (GPS_TYPE 18) 0.04 s more
    assert ardupilot_gps_lag_s({"GPS_TYPE": 18.0}, m8) == (
        0.16, "the u-blox driver's lag for hardware 00080000, moving baseline")
    # older firmware numbered the receivers from 0: "u-blox 0" is the first, "u-blox 1" the second
    assert ardupilot_gps_lag_s({}, ["u-blox 0 HW: 00040007 SW: 7.03", "u-blox 1 HW: 00080000 SW: 3.01"]
                               )[0] == 0.22
    assert ardupilot_gps_lag_s({}, ["u-blox 2 HW: 00080000 SW: 3.01"]) is None   # a third receiver
    # no u-blox and no GPS_DELAY_MS: the EKF's own delay where the firmware had one
    assert ardupilot_gps_lag_s({"GPS_DELAY_MS": 0.0, "EK2_GPS_DELAY": 220.0}, []) == (
        0.22, "EK2_GPS_DELAY 220")
    assert ardupilot_gps_lag_s({"GPS_DELAY_MS": 0.0}, ["GPS 1: detected as NMEA at 9600 baud"]) is None


def test_a_second_source_is_not_drawn_straight_across_its_own_gaps():
    """An altitude source interpolated onto the fixes' times has none inside its gaps, and
    the track's own gap rule then decides, with the user's max_gap_s."""
    from harborsight.telemetry.track import interpolate_source

    source_t = np.concatenate([np.arange(0, 25), np.arange(75, 101)]) * 0.2     # 0-4.8, 15-20 s
    source_alt = np.where(source_t < 10, 10.0, 50.0)
    fixes_t = np.arange(0, 201) * 0.1
    alt, widest_s = interpolate_source(fixes_t, source_t, source_alt)
    assert widest_s == pytest.approx(10.2)
    inside = (fixes_t > 4.8 + 1e-9) & (fixes_t < 15.0 - 1e-9)
    assert np.isnan(alt[inside]).all() and np.isfinite(alt[~inside]).all()
    assert set(np.round(alt[~inside], 6)) == {10.0, 50.0}
    # one sample missing is no gap
    dropped = np.delete(np.arange(0, 101) * 0.2, 10)
    alt, widest_s = interpolate_source(fixes_t, dropped, np.full(len(dropped), 10.0))
    assert widest_s is None and np.isnan(alt).sum() == 0
    track = Track(source=Path("t"), kind="test", t_s=fixes_t, lat_deg=np.full(len(fixes_t), 56.0),
                  lon_deg=np.full(len(fixes_t), 10.0),
                  alt_m=interpolate_source(fixes_t, source_t, source_alt)[0])
    assert np.isnan(track.sample(np.array([7.0, 10.0, 13.0]), max_gap_s=1.0)["alt_m"]).all()
    bridged = track.sample(np.array([10.0]), max_gap_s=6.0)["alt_m"]
    assert 10.0 < bridged[0] < 50.0      # the user asked for gaps of 12 s to be bridged


def test_an_autopilots_estimated_altitude_leaves_its_dropouts_empty():
    """The estimator's altitude merged into the GPS samples: none inside a 10 s dropout of
    its topic (not a straight line, nor the receiver's altitude metres away), with a note."""
    from harborsight.telemetry.autopilot import _estimator_altitude

    gps_t = np.arange(0.0, 20.01, 0.2)
    receiver = np.where(gps_t < 10, 114.0, 156.0)
    est_t = np.concatenate([np.arange(0.0, 5.0, 0.1), np.arange(15.0, 20.0, 0.1)])
    est_alt = np.where(est_t < 10, 110.0, 150.0)
    notes: list[str] = []
    alt, _, sigma = _estimator_altitude(gps_t, receiver, est_t, est_alt, "EKF", notes,
                                        est_sigma_m=np.full(len(est_t), 0.5))
    gap = (gps_t > 4.9 + 1e-9) & (gps_t < 15.0 - 1e-9)
    assert np.isnan(alt[gap]).all() and np.isnan(sigma[gap]).all()
    assert np.allclose(alt[gps_t <= 4.8], 110.0) and np.allclose(alt[(gps_t >= 15) & (gps_t <= 19.9)], 150.0)
    assert any("gaps of the estimator's altitude (up to 10.1 s)" in n for n in notes)


@pytest.mark.parametrize("form", ["[dzoom_ratio: {ten_thousandths}, delta:0]", "[dzoom_ratio: {ratio:.2f}]",
                                  "DZOOM {ratio:.3f},"])
def test_a_digital_zoom_in_the_srt_scales_the_frames_intrinsics(tmp_path, form):
    """A digital zoom is a centre crop of the sensor, enlarged: the focal length stays
    (``focal_len : 240``) while every pixel covers 1/ratio of the water. The frames of the
    zoomed blocks get the camera's intrinsics scaled about the image centre, checked against
    OpenCV: a point projects where the unzoomed frame's pixel lands once enlarged about the
    centre, distortion included."""
    from harborsight.telemetry.metadata import CameraMount, build_video_metadata
    from harborsight.telemetry.vessel_track import read_vessel_csv

    blocks = (DJI / "air2s.srt").read_text(encoding="utf-8").split("\n\n")
    text = "\n\n".join(b.replace("[latitude:", form.format(ten_thousandths=20000, ratio=2.0) + " [latitude:")
                       if k >= 8 else b for k, b in enumerate(blocks))
    srt = tmp_path / "zoomed.srt"
    srt.write_text(text, encoding="utf-8")
    drone = read_dji_srt(srt, utc_offset_h=2.0)
    assert np.isnan(drone.digital_zoom[0]) and drone.digital_zoom[9] == 2.0
    assert any("digital zoom in" in note and "up to 2x" in note for note in drone.notes)
    camera = {"width": 1280, "height": 720, "fx": 1010.0, "fy": 1012.0, "cx": 652.0, "cy": 351.0,
              "distortion": [-0.12, 0.05, 0.001, -0.002, 0.0]}
    vessel = read_vessel_csv(_vessel_csv(tmp_path / "ship.csv", drone.utc_start, 2))
    result = build_video_metadata(drone, vessel, camera, 16, 30.0, water_level_m=0.0,
                                  mount=CameraMount("stabilised", yaw_deg=0.0))
    assert [f["frame_index"] for f in result.frames] == list(range(16))
    plain, zoomed = result.frames[2], result.frames[12]
    assert plain["camera"] == camera and "digital_zoom" not in plain["telemetry"]
    assert zoomed["telemetry"]["digital_zoom"] == 2.0

    def pixel(block: dict) -> np.ndarray:
        return pixel_of_camera_block(block, (1.5, -0.8, 20.0))

    centre = np.array([(1280 - 1) / 2, (720 - 1) / 2])
    assert pixel(zoomed["camera"]) == pytest.approx(centre + 2.0 * (pixel(camera) - centre), abs=1e-9)


def test_px4_utc_belongs_to_timestamp_plus_timestamp_time_relative(monkeypatch):
    """sensor_gps.msg: "timestamp + timestamp_time_relative = Time of the UTC timestamp since
    system start". A driver that takes the time from another message than the position's
    sets it (+0.2 s here, in every record of the sample log): the boot's UTC moves 0.2 s
    earlier, as the definition computed with pyulog says."""
    import pyulog

    path = TELEMETRY / "px4" / "sample_log_small.ulg"
    before = read_drone_log(path).utc_start

    class Relative(pyulog.ULog):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            for d in self.data_list:
                if d.name == "vehicle_gps_position":
                    d.data["timestamp_time_relative"] = d.data["timestamp_time_relative"] + 200_000

    monkeypatch.setattr(pyulog, "ULog", Relative)
    after = read_drone_log(path).utc_start
    gps = next(d.data for d in Relative(str(path), ["vehicle_gps_position"]).data_list)
    synced = gps["time_utc_usec"] > 0
    boot_utc_s = np.median((gps["time_utc_usec"][synced].astype(float)
                            - gps["timestamp"][synced] - gps["timestamp_time_relative"][synced]) / 1e6)
    assert (before - after).total_seconds() == pytest.approx(0.2, abs=1e-6)
    assert after.timestamp() == pytest.approx(boot_utc_s, abs=1e-6)


def test_the_matrice_300s_zero_gps_altitude_is_a_placeholder_not_a_height(tmp_path):
    """The Matrice 300's GPS(lat, lon, 0.0M) is 0.0 in all its blocks while BAROMETER climbs
    to 88 m: with the barometer, nothing changes; without it the file has no altitude (not a
    drone 0 m up, 3.5 m above water at a water level of -3.5 m)."""
    real = read_dji_srt(DJI / "matrice_300.srt", utc_offset_h=2.0)
    assert real.alt_reference.startswith("barometric") and np.nanmax(real.alt_m) > 80
    text = (DJI / "matrice_300.srt").read_text(encoding="utf-8", errors="replace")
    stripped = tmp_path / "no_baro.srt"
    stripped.write_text(re.sub(r"BAROMETER:\s*[-\d.]+M?", "", text), encoding="utf-8")
    track = read_dji_srt(stripped, utc_offset_h=2.0)
    assert track.alt_m is None
    assert any("0.0 in every block, a placeholder" in note for note in track.notes)


@pytest.mark.parametrize("compass_first", [False, True])
def test_an_nmea_file_with_two_heading_sensors_keeps_one(tmp_path, compass_first):
    """A gyro (HEHDT, 100 deg) and a magnetic compass (HCHDG 101 deg + 3 deg E variation =
    104 deg true) interleaved: the track took whichever spoke last before each fix; now the
    gyro's (a true heading sentence before a compass made true), with a note of how far the
    compass differs."""
    from functools import reduce

    def sentence(body: str) -> str:
        return f"${body}*{reduce(lambda a, c: a ^ ord(c), body, 0):02X}"

    lines = []
    for k in range(6):
        pair = [sentence("HEHDT,100.0,T"), sentence("HCHDG,101.0,0.0,E,3.0,E")]
        lines += [sentence(f"GPRMC,1200{k:02d}.00,A,5609.0000,N,01012.6000,E,0.5,10.0,010526,,,A"),
                  *(pair[::-1] if compass_first else pair)]
    path = tmp_path / "two.nmea"
    path.write_text("\n".join(lines) + "\n")
    track = read_vessel_track(path)
    assert np.allclose(track.heading_deg, 100.0)
    assert any("6 heading(s) from HC (HDG) left out: the track uses HE (HDT) (HC differs from "
               "it by +4.0 deg" in note for note in track.notes)


def test_a_heading_sensor_that_falls_silent_hands_over_to_the_next(tmp_path):
    """The gyro (HEHDT, 100 deg) speaks in the first two fix intervals only, the compass
    (HCHDG, 104 deg true) in all six: the gyro where it spoke, the compass after."""
    from functools import reduce

    def sentence(body: str) -> str:
        return f"${body}*{reduce(lambda a, c: a ^ ord(c), body, 0):02X}"

    lines = []
    for k in range(6):
        lines.append(sentence(f"GPRMC,1200{k:02d}.00,A,5609.0000,N,01012.6000,E,0.5,10.0,010526,,,A"))
        lines += ([sentence("HEHDT,100.0,T")] if k < 2 else []) + [sentence("HCHDG,101.0,0.0,E,3.0,E")]
    path = tmp_path / "handover.nmea"
    path.write_text("\n".join(lines) + "\n")
    track = read_vessel_track(path)
    assert np.allclose(track.heading_deg, [100.0, 100.0, 104.0, 104.0, 104.0, 104.0])
    assert any("2 heading(s) from HC (HDG) left out" in note and "4 where it was silent" in note
               for note in track.notes)


def test_a_source_in_bursts_with_repeated_times_is_not_all_gaps():
    """A height topic stamped on arrival comes in bursts (three samples at one time, then a
    pause): its median interval is 0, and no fix may lose its height for that."""
    from harborsight.telemetry.track import interpolate_source

    bursts = np.repeat(np.arange(0.0, 10.0, 0.2), 3)
    alt, widest_s = interpolate_source(np.arange(0.0, 9.8, 0.1), bursts, np.full(len(bursts), 30.0))
    assert widest_s is None and np.isfinite(alt).all()
