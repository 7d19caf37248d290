"""The live aid's inputs (issue #28): NMEA and MAVLink decoded as they come, clocks aligned,
frames composed at their time; and the bundled flight streamed as UDP MPEG-TS video, MAVLink
and NMEA on 127.0.0.1 into a running `harborsight live`, checked against the flight's truth."""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

from harborsight.frame import parse_frame_metadata
from harborsight.live.feed import FeedPlan, play_flight
from harborsight.live.mavlink_in import MavlinkDrone
from harborsight.live.nmea_in import NmeaVessel, parse_nmea_address
from harborsight.live.telemetry import ClockMap, FrameComposer, LiveTrack
from harborsight.telemetry.nmea import Fix, Heading, NmeaDecoder
from harborsight.telemetry.track import Track

SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"
FLIGHT = SAMPLES / "flight"
LOGS = FLIGHT / "logs"
TUG = SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml"


def _nmea(body: str) -> str:
    checksum = 0
    for char in body:
        checksum ^= ord(char)
    return f"${body}*{checksum:02X}"


def test_the_decoder_turns_lines_into_fixes_and_headings():
    decoder = NmeaDecoder()
    events = [e for line in (
        _nmea("HEHDT,117.7,T"),                                       # before any fix: counted
        _nmea("GPRMC,120000.00,A,5609.10200,N,01013.69800,E,0.8,117.7,010526,,"),
        _nmea("GPGGA,120000.00,5609.10200,N,01013.69800,E,4,12,0.8,1.0,M,40.0,M,,"),
        _nmea("HEHDT,117.71,T"), _nmea("HCHDM,115.0,M"),
        "$GPRMC,120001.00,A,5609.10190,N,01013.69792,E,0.8,117.7,010526,,*00",   # bad checksum
        _nmea("GPRMC,120001.00,V,,,,,,,010526,,"),                    # no fix
    ) for e in decoder.feed(line, 1)]
    fixes = [e for e in events if isinstance(e, Fix)]
    assert [f.new for f in fixes] == [True, False]          # RMC and GGA of one epoch: one fix
    assert fixes[0].utc == datetime(2026, 5, 1, 12, 0, tzinfo=UTC)
    assert fixes[0].lat_deg == pytest.approx(56 + 9.102 / 60) and fixes[1].quality == 4
    assert [(h.deg, h.true) for h in events if isinstance(h, Heading)] == [(117.71, True), (115.0, False)]
    assert decoder.bad_count == 1
    assert decoder.skipped["headings before the first fix"] == 1
    assert decoder.skipped["RMC status V (no fix)"] == 1


def test_fixes_of_a_second_position_sensor_on_the_feed_are_left_out_until_the_first_stops():
    """The ship's GPS (GP) on whole seconds and an AIS transponder's own receiver (AI) half
    a second later, 12 m north, on one multiplexed feed: mixed, the vessel jumped 12 m every
    half second. Fixes come from the first sensor (a receiver's GP and GN talkers are one);
    the other's are counted and said, and take over once the first has been silent 5 s."""
    decoder = NmeaDecoder()
    north_12m = 12.0 / 1852.0            # minutes of latitude

    def rmc(talker: str, second: float, minutes: float) -> str:
        return _nmea(f"{talker}RMC,1200{second:05.2f},A,56{minutes:08.5f},N,01013.69800,E,0.8,117.7,010526,,")

    lines = []
    for k in range(4):
        lines += [rmc("GP" if k % 2 else "GN", k, 9.102), rmc("AI", k + 0.5, 9.102 + north_12m)]
    lines += [rmc("AI", second, 9.102 + north_12m) for second in (4.5, 6.5, 9.5, 10.5)]
    fixes = [e for line in lines for e in decoder.feed(line, 1) if isinstance(e, Fix)]
    assert [f.utc.second + f.utc.microsecond / 1e6 for f in fixes] == [0, 1, 2, 3, 9.5, 10.5]
    assert [round(f.lat_deg, 6) for f in fixes[:4]] == [round(56 + 9.102 / 60, 6)] * 4
    assert fixes[-1].lat_deg == pytest.approx(56 + (9.102 + north_12m) / 60)
    assert any("6 sentence(s) skipped: fixes from a second position sensor (AI) while GNSS" in n
               for n in decoder.notes())
    # a second sensor whose clock lags 18 s (a repeater on an instrument bus) never takes
    # over while the first gives fixes: its fixes are timed before the first's last
    lagging = NmeaDecoder()
    lines = []
    for k in range(10):
        lines += [rmc("GP", 20 + k, 9.102), rmc("II", 2 + k, 9.102 + north_12m)]
    fixes = [e for line in lines for e in lagging.feed(line, 1) if isinstance(e, Fix)]
    assert len(fixes) == 10 and all(f.lat_deg == pytest.approx(56 + 9.102 / 60) for f in fixes)


def test_a_live_gga_before_any_date_is_dated_by_this_machine_s_clock():
    """A GNSS compass sending GGA, HDT and VTG only gave no vessel position live (GGA has no
    date). Live, such a fix takes the UTC day that puts its time of day nearest to this
    machine's clock (23:59:59 read just past midnight is yesterday's); a file still skips it."""
    now = datetime(2026, 5, 2, 0, 0, 5, tzinfo=UTC)
    live = NmeaDecoder(now_utc=lambda: now)
    lines = [_nmea("GPGGA,235959.00,5609.10200,N,01013.69800,E,4,12,0.8,1.0,M,40.0,M,,"),
             _nmea("HEHDT,117.7,T"),
             _nmea("GPGGA,000004.00,5609.10210,N,01013.69800,E,4,12,0.8,1.0,M,40.0,M,,")]
    fixes = [e for line in lines for e in live.feed(line, 1) if isinstance(e, Fix)]
    assert [f.utc for f in fixes] == [datetime(2026, 5, 1, 23, 59, 59, tzinfo=UTC),
                                      datetime(2026, 5, 2, 0, 0, 4, tzinfo=UTC)]
    assert any("dated by this machine's UTC clock" in n for n in live.notes())
    from_file = NmeaDecoder()
    assert not [e for line in lines for e in from_file.feed(line, 1) if isinstance(e, Fix)]
    assert from_file.undated == 2
    track = LiveTrack("vessel", "nmea")
    vessel = NmeaVessel(track)
    for line in lines:
        vessel.feed(line, 100.0)
    assert len(track.track()) >= 1 and track.track().heading_deg is not None


def test_the_clock_map_takes_the_least_delayed_sample_and_restarts_after_a_jump():
    clock = ClockMap(window=16, jump_s=2.0)
    rng = np.random.default_rng(3)
    for k in range(40):          # source clock = local - 100 s; delays of 20-200 ms
        mapped = clock.observe(k * 0.1, 100.0 + k * 0.1 + 0.02 + rng.uniform(0, 0.18))
    assert mapped == pytest.approx(100.0 + 39 * 0.1, abs=0.03)   # within the least delay
    assert clock.to_source(103.9) == pytest.approx(3.9, abs=0.03)
    clock.observe(500.0, 104.0)                                  # the source rebooted/jumped
    assert clock.jumps == 1 and clock.to_local(500.0) == pytest.approx(104.0)


def _camera(width: int, height: int) -> dict:
    return {"width": width, "height": height, "fx": 500.0, "fy": 500.0, "cx": width / 2 - 0.5,
            "cy": height / 2 - 0.5, "distortion": [0, 0, 0, 0, 0]}


def test_a_frame_is_composed_from_both_feeds_at_its_time():
    drone, vessel = LiveTrack("drone", "mavlink"), LiveTrack("vessel", "nmea")
    for k in range(5):           # 2 Hz drone moving north, 1 Hz vessel moving east, heading 90
        drone.add_position(10.0 + 0.5 * k, 56.0 + 1e-5 * k, 10.0, 50.0 + k)
        drone.add_attitude(10.0 + 0.5 * k, 350.0 + 5.0 * k, -90.0, 0.0, "gimbal")
    for k in range(3):
        vessel.add_position(10.0 + k, 56.0001, 10.0 + 1e-5 * k)
        vessel.add_heading(10.0 + k, 90.0)
    composer = FrameComposer(drone, vessel, camera_for=_camera, water_level_m=-2.0, hold_s=0.6)
    frame, why = composer.compose(7, arrived_s=11.25, width=640, height=360)
    assert why is None and frame["frame_index"] == 7
    assert frame["uav"]["lat"] == pytest.approx(56.0 + 2.5e-5)          # halfway, by hand
    assert frame["uav"]["alt_m"] == pytest.approx(52.5)
    assert frame["camera_attitude"]["yaw_deg"] == pytest.approx(2.5)    # 360 + 2.5, unwrapped
    assert frame["vessel"]["lon"] == pytest.approx(10.0 + 1.25e-5)
    assert frame["water_level_m"] == -2.0
    # the newest vessel fix (t = 12) stands for 0.6 s, not longer
    assert composer.compose(8, 12.5, 640, 360)[1] is None
    frame, why = composer.compose(9, 12.7, 640, 360)
    assert frame is None and "vessel position" in why
    # a calibration of another size refuses the frame, saying so
    from harborsight.errors import InputError

    def fixed(width, height):
        raise InputError("cam.yaml", "calibration", f"calibrated for 1280x720, the video is {width}x{height}")
    frame, why = FrameComposer(drone, vessel, camera_for=fixed).compose(1, 11.0, 640, 360)
    assert frame is None and "1280x720" in why


def test_a_track_holds_its_newest_sample_only_as_long_as_asked():
    track = Track(source=Path("x"), kind="csv", t_s=[0.0, 1.0], lat_deg=[0.0, 1.0], lon_deg=[0.0, 0.0])
    assert math.isnan(track.sample([1.8])["lat_deg"][0])                  # half an interval
    assert track.sample([1.8], hold_s=1.0)["lat_deg"][0] == 1.0


def _mavlink_bytes(build, system: int = 1) -> bytes:
    from pymavlink.dialects.v20 import ardupilotmega as dialect

    class Sink:
        data = b""

        def write(self, chunk):
            Sink.data += chunk
    mav = dialect.MAVLink(Sink(), srcSystem=system, srcComponent=1)
    build(mav)
    return Sink.data


def _decoded(data: bytes) -> list:
    from pymavlink.dialects.v20 import ardupilotmega as dialect

    parser = dialect.MAVLink(None)
    parser.robust_parsing = True
    return [m for m in (parser.parse_buffer(data) or [])]


def _read_mavlink(data: bytes) -> tuple[MavlinkDrone, LiveTrack, list[str]]:
    """A drone reader fed ``data`` at 100 s: the reader, its track and the warnings said."""
    track = LiveTrack("drone", "mavlink")
    warnings: list[str] = []
    track.on_warning = lambda source, message: warnings.append(message)
    reader = MavlinkDrone(None, track, altitude="relative")
    for message in _decoded(data):
        reader.handle(message, 100.0)
    return reader, track, warnings


def test_mavlink_messages_become_the_drone_track_with_the_gimbal_yaw_on_the_airframe_yaw():
    from scipy.spatial.transform import Rotation

    # the gimbal 10 deg right of the nose and 60 deg down, the nose at 30 deg: camera at 40
    x, y, z, w = Rotation.from_euler("ZYX", [10.0, -60.0, 0.0], degrees=True).as_quat()
    data = _mavlink_bytes(lambda mav: (
        mav.system_time_send(1_777_636_800_000_000, 5000),
        mav.attitude_send(5000, 0.0, 0.0, math.radians(30.0), 0, 0, 0),
        mav.gimbal_device_attitude_status_send(0, 0, 5000, 32, [w, x, y, z], 0, 0, 0, 0),
        mav.gps_raw_int_send(0, 3, 0, 0, 0, 0, 0, 0, 0, 12, 0, 2000, 0, 0, 0),
        mav.global_position_int_send(5000, 561516256, 102282340, 75000, 60000, 0, 0, 0, 65535)))
    garbage = data[:20] + bytes([data[20] ^ 0xFF]) + data[21:]          # one frame's CRC fails
    reader, track, warnings = _read_mavlink(garbage + data)
    assert reader.bad_frames >= 1 and any("unreadable MAVLink" in w for w in warnings)
    sampled = track.track().sample([100.0], hold_s=1.0)
    assert sampled["yaw_deg"][0] == pytest.approx(40.0, abs=1e-4)     # float32 quaternion
    assert sampled["pitch_deg"][0] == pytest.approx(-60.0, abs=1e-4)
    assert sampled["alt_m"][0] == pytest.approx(60.0)                    # relative_alt
    assert sampled["lat_deg"][0] == pytest.approx(56.1516256)
    assert sampled["position_sigma_m"][0] == pytest.approx(2.0 / math.sqrt(2))
    assert track.attitude_of == "gimbal"
    # SYSTEM_TIME: the boot clock's 5 s is 2026-05-01T12:00:00Z
    assert track.utc_clock.to_local(5.0) == pytest.approx(1_777_636_800.0)


def test_a_gimbal_on_its_own_boot_clock_keeps_its_own_clock_map():
    """A gimbal that speaks MAVLink itself (component 154) stamps its attitude with its own
    boot time, here 1.2 s behind the autopilot's (booted later; under the 2 s a jump needs).
    Position and camera attitude of the same instant arrive together. One clock map for
    both put the attitude 1.2 s off the position; each component's own puts them together,
    and the autopilot's stays the track's (SYSTEM_TIME ties it to UTC)."""
    from pymavlink.dialects.v20 import ardupilotmega as dialect

    class Sink:
        data = b""

        def write(self, chunk):
            Sink.data += chunk

    autopilot = dialect.MAVLink(Sink(), srcSystem=1, srcComponent=1)
    gimbal = dialect.MAVLink(Sink(), srcSystem=1, srcComponent=154)
    track = LiveTrack("drone", "mavlink")
    reader = MavlinkDrone(None, track, altitude="relative")
    for k in range(6):
        Sink.data = b""
        boot_ms = 5000 + 200 * k
        autopilot.global_position_int_send(boot_ms, 561516256, 102282340, 75000, 60000, 0, 0, 0, 65535)
        gimbal.gimbal_device_attitude_status_send(0, 0, boot_ms - 1200, 16, [0.0, 0.0, -0.5, 0.8660254],
                                                  0, 0, 0, 0)           # earth-frame yaw (YAW_LOCK)
        for message in _decoded(Sink.data):
            reader.handle(message, 100.0 + 0.2 * k + 0.01 * (k % 2))   # arrival, with jitter
    drone = track.track()
    assert len(drone) == 6 and len(drone.attitude_t_s) == 6
    np.testing.assert_allclose(drone.attitude_t_s, drone.t_s, atol=1e-6)
    assert reader.clocks[(1, 1)] is track.clock and reader.clocks[(1, 154)] is not track.clock


def test_a_second_vehicle_on_the_mavlink_link_is_left_out():
    """The drone is the first system to send its position; another vehicle's position and
    attitude on the same link are counted and said, never mixed in."""
    drone = _mavlink_bytes(lambda mav: (
        mav.attitude_send(5000, 0.0, 0.0, math.radians(30.0), 0, 0, 0),
        mav.global_position_int_send(5000, 561516256, 102282340, 75000, 60000, 0, 0, 0, 65535)))
    other = _mavlink_bytes(lambda mav: (
        mav.attitude_send(5100, 0.0, 0.0, math.radians(200.0), 0, 0, 0),
        mav.global_position_int_send(5100, 561616256, 102382340, 95000, 80000, 0, 0, 0, 65535)),
        system=2)
    reader, track, warnings = _read_mavlink(drone + other)
    drone_track = track.track()
    assert reader.system_id == 1 and reader.other_systems == 2
    assert len(drone_track) == 1 and drone_track.lat_deg[0] == pytest.approx(56.1516256)
    assert np.allclose(drone_track.yaw_deg, 30.0)
    assert any("system 2 left out" in w for w in warnings)


def test_unusable_mavlink_values_are_left_out_and_the_reader_goes_on():
    """A zero quaternion (a gimbal not yet ready) raised in scipy and ended the reader thread
    for the session; a latitude past 90 deg was taken as the drone's; a gimbal yaw relative to
    the airframe was turned by the last ATTITUDE however old. Each is left out and said, and a
    message that raises for any other reason does not stop the reader."""
    import threading

    ready = _mavlink_bytes(lambda mav: (
        mav.attitude_send(5000, 0.0, 0.0, math.radians(30.0), 0, 0, 0),
        mav.gimbal_device_attitude_status_send(0, 0, 5000, 32, [0.0, 0.0, 0.0, 0.0], 0, 0, 0, 0),
        mav.global_position_int_send(5000, 2_147_483_647, 102282340, 75000, 60000, 0, 0, 0, 65535),
        mav.global_position_int_send(5000, 561516256, 102282340, 75000, 60000, 0, 0, 0, 65535)))
    reader, track, warnings = _read_mavlink(ready)
    assert reader.bad_values == 2 and len(track.track()) == 1
    assert track.track().lat_deg[0] == pytest.approx(56.1516256)
    assert any("unusable values left out" in w for w in warnings)
    # ATTITUDE stops; the drone turns; a vehicle-frame gimbal attitude 3 s later is left out
    later = _decoded(_mavlink_bytes(lambda mav: mav.gimbal_device_attitude_status_send(
        0, 0, 8000, 32, [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0)))[0]
    reader.handle(later, 100.5)                          # within 1 s of ATTITUDE: taken
    reader.handle(later, 103.0)                          # 3 s after it: left out
    assert track.attitude_of == "gimbal" and list(track.track().attitude_t_s) == [100.5]
    assert reader.gimbal_without_vehicle_yaw == 1 and any("no ATTITUDE for 3.0 s" in w for w in warnings)

    class Connection:
        """Hands out a message that raises when read, then a good position, then stops."""

        def __init__(self, messages, stop):
            self.messages, self.stop = list(messages), stop

        def recv_match(self, blocking, timeout):
            if not self.messages:
                self.stop.set()
                return None
            return self.messages.pop(0)

        def close(self):
            pass

    class Broken:
        def get_type(self):
            return "GLOBAL_POSITION_INT"

        def get_srcSystem(self):
            raise RuntimeError("a dialect mismatch")

    stop = threading.Event()
    good = _decoded(_mavlink_bytes(lambda mav: mav.global_position_int_send(
        5200, 561516300, 102282340, 75000, 60000, 0, 0, 0, 65535)))
    reader.connection = Connection([Broken(), *good], stop)
    reader.run(stop)
    assert reader.failed == 1 and track.track().lat_deg[-1] == pytest.approx(56.15163)
    assert any("could not be read" in w and "a dialect mismatch" in w for w in warnings)


def test_a_second_lagging_mavlink_link_does_not_wipe_the_drone_track():
    """Every position arrives twice: on the live link, and 1.5 s later on a second link with
    a queue (a redundant radio; mavlink-router forwards both). The late copies map to their
    own, older times; they were taken for a clock going back and cleared the track, so no
    frame could be measured while the drone looked current. Now they are left out and said,
    and the track holds its 5 Hz samples."""
    track = LiveTrack("drone", "mavlink")
    warnings: list[str] = []
    track.on_warning = lambda source, message: warnings.append(message)
    reader = MavlinkDrone(None, track, altitude="relative")
    arrivals = []
    for k in range(25):
        boot_ms = 5000 + 200 * k
        lat_e7 = 561516256 + 100 * k
        message = _decoded(_mavlink_bytes(lambda mav, boot_ms=boot_ms, lat_e7=lat_e7: (
            mav.global_position_int_send(boot_ms, lat_e7, 102282340, 75000, 60000, 0, 0, 0, 65535))))[0]
        arrivals += [(100.0 + 0.2 * k, message), (101.5 + 0.2 * k, message)]
    for now_s, message in sorted(arrivals, key=lambda pair: pair[0]):
        reader.handle(message, now_s)
    drone = track.track()
    assert len(drone) == 25 and np.allclose(np.diff(drone.t_s), 0.2)
    assert track.late_samples >= 18 and any("1.4 s late: a second link?" in w for w in warnings)
    assert drone.yaw_deg is None                         # positions and no attitude yet


def test_the_nmea_listener_times_headings_by_the_fix_before_them():
    track = LiveTrack("vessel", "nmea")
    listener = NmeaVessel(track)
    listener.feed(_nmea("GPRMC,120000.00,A,5609.10200,N,01013.69800,E,0.8,117.7,010526,,"), 50.3)
    listener.feed(_nmea("HEHDT,117.71,T"), 50.35)
    listener.feed("garbage $GP,,,*77", 50.4)
    t = track.track()
    assert t.t_s[0] == pytest.approx(50.3)               # the first fix: its own arrival
    assert t.attitude_t_s[0] == pytest.approx(50.35)     # the heading: arrival less no delay
    assert listener.decoder.bad_count == 1
    assert parse_nmea_address("udp:10110").host == "0.0.0.0"
    assert parse_nmea_address("tcp:10.0.0.2:2000").port == 2000
    assert parse_nmea_address("/dev/ttyUSB0@38400").port == 38400
    with pytest.raises(Exception, match="--nmea"):
        parse_nmea_address("10110")


def _free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _state(port: int) -> dict | None:
    with contextlib.suppress(OSError, ValueError), urllib.request.urlopen(
            f"http://127.0.0.1:{port}/api/state", timeout=2) as response:
        return json.loads(response.read())
    return None


@contextlib.contextmanager
def _states_polled(http_port: int):
    """The live states read from ``/api/state`` every 0.15 s while the block runs."""
    import threading

    states: list[dict] = []
    done = threading.Event()

    def poll() -> None:
        while not done.is_set():
            state = _state(http_port)
            if state is not None:
                states.append(state)
            time.sleep(0.15)
    poller = threading.Thread(target=poll, daemon=True)
    poller.start()
    try:
        yield states
    finally:
        done.set()
        poller.join(5)


RTSP_SERVER = (Path(__file__).resolve().parents[1] / ".tools" / "rtsp" / "node_modules"
               / "rtsp-streaming-server")


@pytest.fixture
def rtsp_server():
    """An RTSP server (rtsp-streaming-server from npm, installed by scripts/setup.sh into
    .tools/rtsp) on 127.0.0.1: (publish URL, receive URL). It carries RTP over UDP only."""
    import shutil
    import threading

    node = shutil.which("node")
    if node is None or not RTSP_SERVER.is_dir():
        pytest.skip("rtsp-streaming-server (npm) or node is missing: scripts/setup.sh installs them")
    publish_port, client_port = _free_port(), _free_port()
    rtp_start = 20000 + 2 * (os.getpid() % 4000)
    server = subprocess.Popen([node, str(Path(__file__).parent / "servers" / "rtsp_server.js"),
                               str(RTSP_SERVER), str(publish_port), str(client_port), str(rtp_start)],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ready = threading.Event()
    threading.Thread(target=lambda: ready.set() if "ready" in server.stdout.readline() else None,
                     daemon=True).start()
    try:
        assert ready.wait(20), "the RTSP server did not start in 20 s"
        yield (f"rtsp://127.0.0.1:{publish_port}/flight", f"rtsp://127.0.0.1:{client_port}/flight")
    finally:
        server.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            server.wait(5)
        if server.poll() is None:
            server.kill()


def test_the_flight_streamed_live_over_udp_is_measured_against_its_truth(tmp_path):
    """The bundled flight's video as H.264 MPEG-TS over UDP, its SRT as MAVLink over UDP, the
    ship's NMEA over UDP, into `harborsight live` run as a user would; garbage on both
    telemetry ports mid-flight."""
    video_port = _free_port(socket.SOCK_DGRAM)
    _stream_flight_into_live(tmp_path, f"udp://127.0.0.1:{video_port}",
                             f"udp://127.0.0.1:{video_port}", [], "tcp")


def test_the_flight_published_to_an_rtsp_server_is_measured_against_its_truth(tmp_path, rtsp_server):
    """As above, with the video published to a real RTSP server and `live` reading it from
    there (RTP over UDP: the server has no TCP transport)."""
    publish_url, receive_url = rtsp_server
    _stream_flight_into_live(tmp_path, publish_url, receive_url,
                             ["--rtsp-transport", "udp"], "udp", min_frames=6)


def _stream_flight_into_live(tmp_path, video_to: str, video_from: str, live_options: list[str],
                             rtsp_transport: str, min_frames: int = 8) -> None:
    truth = {}
    for path in sorted((FLIGHT / "frames").glob("*.json")):
        record = json.loads(path.read_text())
        stamp = datetime.fromisoformat(record["timestamp"].replace("Z", "+00:00")).timestamp()
        truth[stamp] = {s["index"]: s["distance_m"] for s in record["ground_truth"]["sections"]}
    mavlink_port, nmea_port, http_port = (
        _free_port(socket.SOCK_DGRAM), _free_port(socket.SOCK_DGRAM), _free_port())
    command = [sys.executable, "-m", "harborsight.cli", "live", *live_options,
               "--video", video_from,
               "--mavlink", f"udpin:127.0.0.1:{mavlink_port}", "--nmea", f"udp:127.0.0.1:{nmea_port}",
               "--camera", "dji-mavic3", "--water-level-m", "0", "--vessel", str(TUG),
               "--http", f"127.0.0.1:{http_port}", "--record", str(tmp_path / "record")]
    live = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        while _state(http_port) is None:
            assert live.poll() is None and time.monotonic() < deadline, live.stdout.read()
            time.sleep(0.2)
        import threading

        with _states_polled(http_port) as states, \
                socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as junk:
            timer = threading.Timer(6.0, lambda: (
                junk.sendto(b"$GPRMC,garbage*00\r\nnot nmea at all\r\n", ("127.0.0.1", nmea_port)),
                junk.sendto(bytes([0xFD, 9, 0, 0, 7, 1, 1, 33, 0, 0]) + os.urandom(20),
                            ("127.0.0.1", mavlink_port))))
            timer.start()
            try:
                summary = play_flight(FeedPlan(
                    LOGS / "flight.mp4", LOGS / "flight.SRT", LOGS / "ship.nmea",
                    video_to=video_to, mavlink_to=f"udpout:127.0.0.1:{mavlink_port}",
                    nmea_to=f"127.0.0.1:{nmea_port}", start_s=0.0, duration_s=14.0,
                    rtsp_transport=rtsp_transport))
            finally:
                timer.cancel()
                timer.join()
            time.sleep(0.5)
    finally:
        live.send_signal(signal.SIGTERM)
        output = live.communicate(timeout=30)[0]
    assert live.returncode == 0, output
    assert summary.frames == 28 and summary.nmea_lines == 56
    assert "frame(s) measured" in output
    measured = [s for s in states if s["frame_time"] is not None]
    assert len({s["frame_index"] for s in measured}) >= min_frames, output
    errors, lags = [], []
    for state in measured:
        stamp = datetime.fromisoformat(state["frame_time"].replace("Z", "+00:00")).timestamp()
        nearest = min(truth, key=lambda t: abs(t - stamp))
        lags.append(stamp - nearest)
        for section in state["sections"]:
            true = truth[nearest][section["index"]]
            if section["measured"] == "ok" and true is not None:
                errors.append(abs(section["distance_m"] - true))
        assert state["latency_ms"] < 1000
    errors.sort()
    print(f"{len(measured)} states, frame time - truth time {min(lags):+.3f}..{max(lags):+.3f} s, "
          f"median error {errors[len(errors) // 2]:.3f} m")
    assert max(abs(lag) for lag in lags) < 0.1   # UTC of the vessel's clock, by the video's timestamps
    assert errors and errors[len(errors) // 2] < 0.5
    sources = measured[-1]["sources"]
    assert sources["drone"]["rate_hz"] == pytest.approx(2.0, rel=0.2)
    assert sources["vessel"]["rate_hz"] == pytest.approx(2.0, rel=0.2)
    warned = " ".join(w["message"] for s in states for w in s["warnings"])
    assert "unreadable sentence" in warned and "unreadable MAVLink" in warned
    # the record replays as a flight
    assert len(list((tmp_path / "record" / "frames").glob("*.json"))) >= 8


def test_a_frame_s_time_is_its_timestamp_not_when_a_busy_decoder_returned_it(monkeypatch):
    """Frames every 0.5 s that leave the decoder 20-400 ms late (a loaded machine): their
    arrival times are within the least delay of when they were sent; a frame without a
    timestamp keeps the moment it was decoded."""
    import threading
    import types

    from harborsight.live import video_in
    from harborsight.live.stream import LatestFrame

    rng = np.random.default_rng(4)
    delay_s = rng.uniform(0.02, 0.4, 30)
    delay_s[[0, 3]] = [0.35, 0.02]                 # the first frame late, the fourth quick
    decoded_s = iter([*(1000.0 + 0.5 * np.arange(30) + delay_s), 1015.3])
    times = [*(7.0 + 0.5 * k for k in range(30)), None]      # the sender's clock
    arrivals: list[float] = []
    stop = threading.Event()

    class Container:
        def decode(self, video):
            for pts_s in times:
                yield types.SimpleNamespace(time=pts_s, to_ndarray=lambda format: np.zeros((4, 6, 3)))
            stop.set()

        def close(self):
            pass

    monkeypatch.setattr(video_in, "_open", lambda *args: Container())
    monkeypatch.setattr(video_in, "decoded_frames",
                        lambda container: ((frame, None) for frame in container.decode(video=0)))
    monkeypatch.setattr(video_in, "time", types.SimpleNamespace(monotonic=lambda: next(decoded_s)))
    video_in.read_stream("udp://127.0.0.1:1", LatestFrame(), stop,
                         on_arrival=lambda frame, now_s: arrivals.append(now_s))
    error_s = np.array(arrivals[:30]) - (1000.0 + 0.5 * np.arange(30))
    assert np.all(error_s <= delay_s + 1e-9)             # never later than it was decoded
    assert np.allclose(error_s[3:], 0.02)                # the least delay, once it has been seen
    assert error_s[0] == pytest.approx(0.35)             # before that, the first frame's own
    assert arrivals[30] == 1015.3


@pytest.mark.parametrize("case", ["stepped back", "slow timestamps"])
def test_video_timestamps_that_jump_or_drift_move_a_frame_half_a_second_at_most(monkeypatch, case):
    """An encoder restarted 1.5 s back; FFmpeg's own timestamps at 25 fps on a 15 fps camera:
    the frames' times stay within VIDEO_JUMP_S of their decoding, with a warning."""
    import threading
    import types

    from harborsight.live import video_in
    from harborsight.live.stream import LatestFrame

    n = 60
    decoded = 1000.0 + (0.5 * np.arange(n) if case == "stepped back" else np.arange(n) / 15)
    pts = 0.5 * np.arange(n) if case == "stepped back" else np.arange(n) / 25
    if case == "stepped back":
        pts[30:] -= 16.5                                 # 1.5 s before the last one's
    times, clock_s, arrivals, warnings = iter(pts), iter(decoded), [], []
    stop = threading.Event()

    class Container:
        def decode(self, video):
            for pts_s in times:
                yield types.SimpleNamespace(time=float(pts_s), to_ndarray=lambda format: np.zeros((4, 6, 3)))
            stop.set()

        def close(self):
            pass

    monkeypatch.setattr(video_in, "_open", lambda *args: Container())
    monkeypatch.setattr(video_in, "decoded_frames",
                        lambda container: ((frame, None) for frame in container.decode(video=0)))
    monkeypatch.setattr(video_in, "time", types.SimpleNamespace(monotonic=lambda: next(clock_s)))
    video_in.read_stream("udp://127.0.0.1:1", LatestFrame(), stop, warn=warnings.append,
                         on_arrival=lambda frame, now_s: arrivals.append(now_s))
    early_s = decoded - np.array(arrivals)
    assert np.all(early_s >= -1e-9) and early_s.max() <= video_in.VIDEO_JUMP_S + 1e-9
    assert any("timestamps jumped" in w for w in warnings)
    if case == "stepped back":
        assert np.allclose(early_s, 0.0)                 # every delay here is the same


def test_a_stream_that_cannot_be_opened_is_warned_about_and_retried():
    import threading

    from harborsight.live.stream import LatestFrame
    from harborsight.live.video_in import read_stream

    box, stop, warnings = LatestFrame(), threading.Event(), []
    port = _free_port(socket.SOCK_DGRAM)
    thread = threading.Thread(target=read_stream, args=(f"udp://127.0.0.1:{port}", box, stop),
                              kwargs={"warn": warnings.append, "retry_s": 0.2, "open_timeout_s": 0.5},
                              daemon=True)
    thread.start()
    time.sleep(1.8)
    stop.set()
    thread.join(5)
    assert not thread.is_alive() and box.closed
    assert len(warnings) >= 2 and all("cannot open" in w for w in warnings)


@pytest.mark.parametrize(("arguments", "option"), [
    (["--video", "udp://127.0.0.1:5600", "--metadata", "flight.jsonl"], "--metadata"),
    (["--video", "udp://127.0.0.1:5600", "--mavlink", "udpin:127.0.0.1:14550",
      "--nmea", "udp:10110"], "--camera"),
    (["--video", "udp://127.0.0.1:5600", "--mavlink", "udpin:127.0.0.1:14550",
      "--nmea", "10110", "--camera", "dji-mavic3", "--water-level-m", "0", "--vessel", str(TUG)],
     "--nmea"),
    (["--video", "udp://127.0.0.1:5600", "--mavlink", "udpin:127.0.0.1:14550", "--nmea", "udp:1",
      "--signalk", "ws://127.0.0.1:3000", "--camera", "dji-mavic3", "--water-level-m", "0",
      "--vessel", str(TUG)], "--signalk"),
    (["--video", "flight.mp4", "--metadata", "flight.jsonl", "--signalk-out", "http://x:3000",
      "--vessel", str(TUG)], "--signalk-out"),
])
def test_a_wrong_command_line_ends_live_with_one_line_naming_the_option(arguments, option, tmp_path,
                                                                         monkeypatch):
    from typer.testing import CliRunner

    from harborsight.cli import app

    monkeypatch.chdir(tmp_path)
    (tmp_path / "flight.jsonl").write_text("")
    (tmp_path / "flight.mp4").write_bytes(b"")
    result = CliRunner().invoke(app, ["live", *arguments])
    assert result.exit_code == 2, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and option in errors[0], result.output


def test_the_vessel_from_its_ais_transponder_live():
    from pyais.encode import encode_dict

    from harborsight.live.ais_in import AisVessel

    track = LiveTrack("vessel", "ais")
    warnings = []
    track.on_warning = lambda source, message: warnings.append(message)
    listener = AisVessel(track, mmsi=219000001)
    second = datetime.now(UTC).second
    own = {"type": 1, "mmsi": 219000001, "lat": 56.1517, "lon": 10.2283, "heading": 118, "second": second}
    other = dict(own, mmsi=219999999)
    listener.feed(encode_dict(own, sentence_type="VDM")[0], 20.0)
    listener.feed(encode_dict(other, sentence_type="VDM")[0], 20.1)
    listener.feed(encode_dict(dict(own, heading=511), sentence_type="VDM")[0], 20.2)
    listener.feed("!AIVDM,1,1,,B,13@ndh@P080flT`P8ES4VCd1P000,0*00", 20.3)
    # a transponder that lost its GPS repeats its last position with time stamp 63
    listener.feed(encode_dict(dict(own, second=63), sentence_type="VDM")[0], 20.4)
    vessel = track.track()
    assert len(vessel) == 1 and vessel.heading_deg[0] == 118.0
    assert vessel.lat_deg[0] == pytest.approx(56.1517, abs=2e-6)
    assert abs(vessel.t_s[0] - 20.0) <= 1.5             # the fix's second: at most a second back
    assert listener.others == 1 and listener.no_heading == 1 and listener.unreadable == 1
    assert listener.unmeasured == 1 and listener.reports == 1
    assert any("true heading" in w for w in warnings) and any("unreadable" in w for w in warnings)
    assert any("position system inoperative" in w for w in warnings)


def test_a_live_feed_with_two_heading_sensors_follows_one():
    """A gyro (HEHDT, 100 deg) and a magnetic compass (HCHDG 101 deg + 3 deg E variation =
    104 deg true) on one feed: the track follows the gyro, whichever sentence comes first,
    and says once that the compass is left out; a compass heard first is followed until the
    gyro speaks."""
    warnings: list[str] = []
    track = LiveTrack("vessel", "nmea")
    track.on_warning = lambda source, message: warnings.append(message)
    listener = NmeaVessel(track)
    for k in range(4):
        now = 10.0 + k
        listener.feed(_nmea(f"GPRMC,1200{k:02d}.00,A,5609.0000,N,01012.6000,E,0.5,10.0,010526,,,A"), now)
        compass, gyro = _nmea("HCHDG,101.0,0.0,E,3.0,E"), _nmea("HEHDT,100.0,T")
        for line in ((compass, gyro) if k % 2 else (gyro, compass)):
            listener.feed(line, now + 0.1)
    headings = track.track().heading_deg
    assert np.allclose(headings[1:], 100.0) and headings[0] in (100.0, 104.0)
    assert sum("headings from HC left out" in w for w in warnings) == 1


def test_a_live_heading_sensor_that_falls_silent_hands_over():
    """The gyro speaks for the first two seconds only: after HEADING_SENSOR_HOLD_S of its
    silence the compass's headings are taken."""
    from harborsight.live.nmea_in import HEADING_SENSOR_HOLD_S

    track = LiveTrack("vessel", "nmea")
    listener = NmeaVessel(track)
    for k in range(8):
        now = 10.0 + k
        listener.feed(_nmea(f"GPRMC,1200{k:02d}.00,A,5609.0000,N,01012.6000,E,0.5,10.0,010526,,,A"), now)
        if k < 2:
            listener.feed(_nmea("HEHDT,100.0,T"), now + 0.1)
        listener.feed(_nmea("HCHDG,101.0,0.0,E,3.0,E"), now + 0.2)
    t = track.track()
    times = t.attitude_t_s - 10.0
    assert np.allclose(t.heading_deg[times < 2.0], 100.0)
    assert np.allclose(t.heading_deg[times > 1.1 + HEADING_SENSOR_HOLD_S], 104.0)


def test_a_class_b_vessel_live_is_carried_by_the_images_past_its_report(tmp_path):
    """The bundled flight streamed into `harborsight live --ais`, the vessel as a class B
    transponder under 2 kn gives it: a report at the start, the next 3 min later. Frames
    more than 12 s from it are measured from the poses the frames before placed, the vessel's
    source not stale meanwhile (`placed_by_image`), against the flight's truth."""
    from tests.helpers import CLASS_B_MMSI, class_b_ais_log

    ais = class_b_ais_log(tmp_path / "ship.ais", LOGS / "ship.nmea")
    truth = {}
    for path in sorted((FLIGHT / "frames").glob("*.json")):
        record = json.loads(path.read_text())
        truth[record["frame_index"] if "frame_index" in record else int(path.stem)] = {
            s["index"]: s["distance_m"] for s in record["ground_truth"]["sections"]}
    video_port, mavlink_port, ais_port, http_port = (
        _free_port(socket.SOCK_DGRAM), _free_port(socket.SOCK_DGRAM), _free_port(socket.SOCK_DGRAM),
        _free_port())
    live = subprocess.Popen(
        [sys.executable, "-m", "harborsight.cli", "live", "--video", f"udp://127.0.0.1:{video_port}",
         "--mavlink", f"udpin:127.0.0.1:{mavlink_port}", "--ais", f"udp:127.0.0.1:{ais_port}",
         "--mmsi", str(CLASS_B_MMSI), "--camera", "dji-mavic3", "--water-level-m", "0",
         "--vessel", str(TUG), "--http", f"127.0.0.1:{http_port}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    states: list[dict] = []
    try:
        deadline = time.monotonic() + 60
        while _state(http_port) is None:
            assert live.poll() is None and time.monotonic() < deadline, live.stdout.read()
            time.sleep(0.2)
        with _states_polled(http_port) as polled:
            # live dates frames by the AIS receiver's clock, this machine's: flight time is
            # the frame's time less the replay's start
            started = datetime.now(UTC)
            summary = play_flight(FeedPlan(
                LOGS / "flight.mp4", LOGS / "flight.SRT", ais,
                video_to=f"udp://127.0.0.1:{video_port}",
                mavlink_to=f"udpout:127.0.0.1:{mavlink_port}", nmea_to=f"127.0.0.1:{ais_port}",
                start_s=0.0, duration_s=20.0))
            time.sleep(0.5)
        states.extend(polled)
    finally:
        live.send_signal(signal.SIGTERM)
        output = live.communicate(timeout=30)[0]
    assert live.returncode == 0, output
    assert summary.nmea_lines == 1
    def flight_s(state: dict) -> float:
        return (datetime.fromisoformat(state["frame_time"].replace("Z", "+00:00"))
                - started).total_seconds()

    late = [s for s in states if s["frame_time"] is not None and flight_s(s) > 13.5]
    assert late, output
    errors = []
    for state in late:
        assert state["pose_refinement"]["carried_from"] and not state["stale"], state
        assert state["sources"]["vessel"]["placed_by_image"], state["sources"]
        frame = min(47, round(flight_s(state) * 2))
        for section in state["sections"]:
            true = truth[frame][section["index"]]
            if section["measured"] == "ok" and true is not None:
                errors.append(abs(section["distance_m"] - true))
    errors.sort()
    print(f"{len(late)} states past 13.5 s, frames {sorted({round(flight_s(x) * 2) for x in late})}, "
          f"median error {errors[len(errors) // 2]:.3f} m")
    assert errors and errors[len(errors) // 2] < 0.5      # median, the model's masks


def test_a_replayed_ais_report_carries_the_second_it_goes_out_at():
    from pyais.encode import encode_dict
    from pyais.messages import NMEAMessage

    from harborsight.telemetry.ais import receiver_time, restamped
    from tests.helpers import ais_tag_block

    report = {"type": 18, "mmsi": 235000001, "lat": 56.15, "lon": 10.2, "heading": 118,
              "second": 7, "speed": 0.8, "course": 117.7}
    sentence = encode_dict(report, sentence_type="VDM", radio_channel="B")[0]
    again = restamped(sentence, 42)
    decoded = NMEAMessage.from_string(again).decode().asdict()
    assert again.startswith("!AIVDM,1,1,,B,") and decoded["second"] == 42
    assert {k: decoded[k] for k in ("mmsi", "heading", "speed", "course")} == {
        "mmsi": 235000001, "heading": 118, "speed": 0.8, "course": 117.7}
    static = encode_dict({"type": 5, "mmsi": 235000001, "shipname": "TUG"}, seq_id=1)
    assert [restamped(part, 42) for part in static] == static          # no time stamp
    no_fix = encode_dict(dict(report, second=63))[0]
    assert restamped(no_fix, 42) == no_fix                             # says no working fix
    assert restamped("!AIVDM,1,1,,B,garbage,0*00", 42) == "!AIVDM,1,1,,B,garbage,0*00"
    # the receiver's time: a tag block's c:, or an ISO time before the sentence
    assert receiver_time(ais_tag_block(1777636800) + sentence) == datetime(
        2026, 5, 1, 12, 0, 0, tzinfo=UTC)
    assert receiver_time(f"2026-05-01T12:00:01Z {sentence}") == datetime(2026, 5, 1, 12, 0, 1, tzinfo=UTC)
    assert receiver_time(sentence) is None and receiver_time("no sentence") is None


def test_a_live_frame_carries_the_vessels_speed_and_course_as_its_velocity():
    """The vessel's feed gives speed and course over ground (an RMC): the composed frame
    gives the ground velocity the tracker takes the vessel's own motion from."""
    drone, vessel = LiveTrack("drone", "mavlink"), LiveTrack("vessel", "nmea")
    for k in range(5):
        drone.add_position(10.0 + 0.5 * k, 56.0, 10.0, 50.0)
        drone.add_attitude(10.0 + 0.5 * k, 0.0, -90.0, 0.0, "gimbal")
    for k in range(3):
        vessel.add_position(10.0 + k, 56.0001, 10.0 + 1e-5 * k, sog_mps=0.6, cog_deg=90.0)
        vessel.add_heading(10.0 + k, 80.0)
    frame, why = FrameComposer(drone, vessel, camera_for=_camera).compose(3, 11.5, 640, 360)
    assert why is None
    assert frame["vessel"]["velocity_en_mps"] == pytest.approx([0.6, 0.0], abs=1e-4)
    meta = parse_frame_metadata(frame, "live")
    assert meta.vessel_velocity_en_mps == pytest.approx((0.6, 0.0), abs=1e-4)
