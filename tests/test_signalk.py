"""Signal K in and out (issue #28) against a real signalk-server (npm, installed by
scripts/setup.sh into .tools/signalk), started on 127.0.0.1 for these tests and stopped after:
the vessel's pose read from it, the alarms and clearances published to it and read back by its
REST API as a chart plotter would."""

from __future__ import annotations

import json
import math
import os
import shutil
import socket
import subprocess
import threading
import time
import urllib.request
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

from harborsight.live.signalk import SignalKPublisher, SignalKVessel, stream_url
from harborsight.live.telemetry import LiveTrack

ROOT = Path(__file__).resolve().parents[1]
SERVER = ROOT / ".tools" / "signalk" / "node_modules" / ".bin" / "signalk-server"


@pytest.fixture(scope="module")
def signalk(tmp_path_factory):
    """A signalk-server on a socket bound to 127.0.0.1 (passed as systemd socket activation
    does, so that it never listens anywhere else), with its other interfaces off."""
    if not SERVER.exists() or shutil.which("node") is None:
        pytest.skip("signalk-server is not installed (scripts/setup.sh installs it with npm)")
    config = tmp_path_factory.mktemp("signalk")
    (config / "settings.json").write_text(json.dumps({
        "interfaces": {name: False for name in ("tcp", "nmea-tcp", "mdns", "playground",
                                                "appstore", "plugins", "logfiles", "webapps")},
        "mdns": False, "pipedProviders": []}))
    (config / "package.json").write_text(json.dumps({"name": "harborsight-test"}))
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(16)
    port = listener.getsockname()[1]
    fd = listener.fileno()
    log = (config / "server.log").open("w")
    # the child's fd 3 is the socket (dup2 runs before the child closes what it does not keep)
    server = subprocess.Popen(
        [str(SERVER)], env=dict(os.environ, LISTEN_FDS="1", SIGNALK_NODE_CONFIG_DIR=str(config)),
        preexec_fn=lambda: os.dup2(fd, 3), pass_fds=(fd, 3), stdout=log, stderr=subprocess.STDOUT)
    listener.close()
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/signalk", timeout=1):
                    break
            except OSError:
                assert server.poll() is None, (config / "server.log").read_text()
                assert time.monotonic() < deadline, "signalk-server did not start in 60 s"
                time.sleep(0.3)
        yield port
    finally:
        server.terminate()
        server.wait(timeout=20)
        log.close()


def _get(port: int, path: str):
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/signalk/v1/api/vessels/self/{path}",
                                timeout=3) as response:
        return json.loads(response.read())


def test_stream_urls_are_checked():
    assert stream_url("ws://10.0.0.5:3000", "--signalk") == \
        "ws://10.0.0.5:3000/signalk/v1/stream?subscribe=none"
    with pytest.raises(Exception, match="--signalk-out"):
        stream_url("http://10.0.0.5:3000", "--signalk-out")


START_S = 1_777_636_800                 # 2026-05-01T12:00:00Z


def test_only_the_self_vessel_and_one_source_per_path_are_read():
    """A chart plotter's GPS and the AIS transponder's publish the same paths 12 m apart, and
    a server may relay another vessel: mixed, the vessel jumped between them. The first
    source of each path is kept, and the others, and other vessels, are counted and said."""
    track = LiveTrack("vessel", "signalk")
    warnings = []
    track.on_warning = lambda source, message: warnings.append(message)
    reader = SignalKVessel("ws://127.0.0.1:1/signalk/v1/stream", track)
    me = "vessels.urn:mrn:imo:mmsi:219000001"
    reader.handle(json.dumps({"name": "signalk-server", "self": me, "version": "2.23.0"}), 10.0)

    def delta(context, source, k, lat):
        stamp = datetime.fromtimestamp(START_S + k, UTC).isoformat().replace("+00:00", "Z")
        heading_rad = math.radians(117.7 if source == "gps" else 123.7)
        return json.dumps({"context": context, "updates": [{"$source": source, "timestamp": stamp, "values": [
            {"path": "navigation.position", "value": {"latitude": lat, "longitude": 10.2283}},
            {"path": "navigation.headingTrue", "value": heading_rad}]}]})

    for k in range(4):
        reader.handle(delta(me, "gps", k, 56.1517), 10.0 + k)
        reader.handle(delta(me, "ais", k + 0.5, 56.1517 + 12 / 111_000), 10.5 + k)
        reader.handle(delta("vessels.urn:mrn:imo:mmsi:219999999", "gps", k + 0.7, 56.16), 10.7 + k)
    vessel = track.track()
    assert len(vessel) == 4 and np.allclose(vessel.lat_deg, 56.1517)
    assert np.allclose(vessel.heading_deg, 117.7)
    assert reader.other_sources == 8 and reader.other_vessels == 4
    assert any("'gps', heard first, is kept" in w for w in warnings)
    assert any("other vessels" in w for w in warnings)


def test_a_clock_jump_on_the_bus_is_said():
    """Two clocks on the bus (a position stamped by its GPS, another value by a server
    without time sync): each jump restarts the time alignment, and the reader says so."""
    track = LiveTrack("vessel", "signalk")
    warnings = []
    track.on_warning = lambda source, message: warnings.append(message)
    reader = SignalKVessel("ws://127.0.0.1:1/signalk/v1/stream", track)
    for k, skew_s in enumerate((0, 0, 30, 0)):
        stamp = datetime.fromtimestamp(START_S + k + skew_s, UTC).isoformat().replace("+00:00", "Z")
        reader.handle(json.dumps({"updates": [{"$source": "gps", "timestamp": stamp, "values": [
            {"path": "navigation.headingTrue", "value": 2.0}]}]}), 10.0 + k)
    assert reader.clocks["gps"].jumps == 2
    assert any("clock of source 'gps' jumped (1 time(s))" in w for w in warnings)


def test_the_cached_values_a_server_sends_on_subscribing_do_not_make_the_vessel_current():
    """On (re)subscribing a Signal K server sends each path's last value, stamped when it
    was last updated: a GPS that stopped a minute ago. Mapped to now, it made the vessel
    current for the stale limit; now what comes within half a second of subscribing is left
    out and said, and live updates after it are read."""
    track = LiveTrack("vessel", "signalk")
    warnings = []
    track.on_warning = lambda source, message: warnings.append(message)
    fixes = []
    reader = SignalKVessel("ws://127.0.0.1:1/signalk/v1/stream", track, on_fix=fixes.append)
    reader.subscribed_s = 100.0

    def update(stamp: str) -> str:
        position = {"path": "navigation.position", "value": {"latitude": 56.1517, "longitude": 10.2283}}
        return json.dumps({"context": "vessels.self", "updates": [{
            "$source": "gps", "timestamp": stamp, "values": [position]}]})

    reader.handle(update("2026-05-01T11:59:00Z"), 100.05)      # the cache: a minute old
    assert track.track() is None and not fixes and reader.replayed == 1
    assert any("cached values" in w for w in warnings)
    reader.handle(update("2026-05-01T12:00:00Z"), 101.0)       # live
    assert fixes == [101.0] and len(track.track()) == 1


def test_each_source_on_the_bus_keeps_its_own_clock():
    """A server stamps an NMEA 0183 position with its RMC's time and an NMEA 2000 heading
    with its own clock, here 1.5 s ahead (within the 2 s a jump needs): both arrive together.
    One clock map for both put the heading 1.5 s after the position it came with (at 3
    degrees a second of turn, 4.5 degrees); each source's own map puts them together, and
    the position's source keeps the track's clock (the frames' UTC) though heard second."""
    track = LiveTrack("vessel", "signalk")
    reader = SignalKVessel("ws://127.0.0.1:1/signalk/v1/stream", track)

    def update(source, t_s, path, value):
        stamp = datetime.fromtimestamp(START_S + t_s, UTC).isoformat().replace("+00:00", "Z")
        return json.dumps({"updates": [{"$source": source, "timestamp": stamp,
                                        "values": [{"path": path, "value": value}]}]})

    for k in range(6):
        arrival_s = 10.1 + k + 0.02 * (k % 3)                  # a little network jitter
        reader.handle(update("n2k.compass", k + 1.5, "navigation.headingTrue",
                             math.radians(100.0 + 3.0 * k)), arrival_s)
        reader.handle(update("nmea0183.GP", k, "navigation.position",
                             {"latitude": 56.1517, "longitude": 10.2283}), arrival_s)
    vessel = track.track()
    assert len(vessel) == 6 and len(vessel.attitude_t_s) == 6
    np.testing.assert_allclose(vessel.attitude_t_s, vessel.t_s, atol=1e-6)
    assert set(reader.clocks) == {"nmea0183.GP", "n2k.compass"}
    assert reader.clocks["nmea0183.GP"] is track.clock         # the position's, heard second


def test_the_vessel_pose_comes_from_the_server(signalk):
    """The ship's GPS and gyro publish to the server; harborsight reads the self vessel."""
    from websockets.sync.client import connect

    url = stream_url(f"ws://127.0.0.1:{signalk}", "--signalk")
    track = LiveTrack("vessel", "signalk")
    warnings = []
    track.on_warning = lambda source, message: warnings.append(message)
    reader = SignalKVessel(url, track)
    stop = threading.Event()
    thread = threading.Thread(target=reader.run, args=(stop,), daemon=True)
    thread.start()
    try:
        time.sleep(1.0)                    # subscribed
        with connect(url) as ship:
            for k in range(3):
                stamp = datetime.now(UTC).isoformat().replace("+00:00", "Z")
                ship.send(json.dumps({"context": "vessels.self", "updates": [{
                    "source": {"label": "ship-gps"}, "timestamp": stamp, "values": [
                        {"path": "navigation.position",
                         "value": {"latitude": 56.1517 + k * 1e-5, "longitude": 10.2283}},
                        {"path": "navigation.headingTrue", "value": math.radians(117.7)}]}]}))
                time.sleep(0.3)
        deadline = time.monotonic() + 5
        while reader.updates < 3 and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        stop.set()
        thread.join(5)
    assert reader.updates == 3, warnings
    vessel = track.track()
    assert vessel.lat_deg[-1] == pytest.approx(56.1517 + 2e-5)
    assert vessel.heading_deg[-1] == pytest.approx(117.7)
    # the updates' UTC times map onto this process's clock within the delivery delay
    assert abs(vessel.t_s[-1] - time.monotonic()) < 10


def test_alarms_and_clearances_reach_the_server(signalk):
    """States go out as notifications and values; the server's REST API gives them back."""
    url = stream_url(f"ws://127.0.0.1:{signalk}", "--signalk-out")
    publisher = SignalKPublisher(url, interval_s=0.0)
    stop = threading.Event()
    thread = threading.Thread(target=publisher.run, args=(stop,), daemon=True)
    thread.start()

    def state(distance: float, status: str, stale: bool = False) -> dict:
        return {"min_distance_m": distance, "stale": stale,
                "sections": [{"index": 0, "status": "ok", "distance_m": 9.5,
                              "closing_speed_mps": 0.0, "time_to_contact_s": None},
                             {"index": 1, "status": status, "distance_m": distance,
                              "closing_speed_mps": 0.4, "time_to_contact_s": distance / 0.4}],
                "alarms": [{"kind": "stale_vessel", "message": "vessel data is 2.5 s old"}] if stale else []}
    try:
        for distance, status in ((6.0, "ok"), (4.0, "caution"), (1.5, "danger")):
            publisher.publish(state(distance, status))
            time.sleep(0.4)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            notes = _get(signalk, "notifications").get("harborsight", {})
            if notes.get("section1", {}).get("value", {}).get("state") == "alarm":
                break
            time.sleep(0.2)
        assert notes["section1"]["value"]["state"] == "alarm"
        assert "sound" in notes["section1"]["value"]["method"]
        assert notes["section0"]["value"]["state"] == "normal"
        assert notes["stale"]["value"]["state"] == "normal"
        clearance = _get(signalk, "harborsight/clearance")
        assert clearance["minimum"]["value"] == 1.5
        assert clearance["section1"]["distance"]["value"] == 1.5
        assert clearance["section1"]["timeToContact"]["value"] == 3.8
        assert clearance["section1"]["closingSpeed"]["value"] == 0.4
        # stale data: an alert, and the distances withdrawn (null), never left as current
        publisher.publish(state(1.5, "danger", stale=True))
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            if _get(signalk, "notifications/harborsight/stale")["value"]["state"] == "alert":
                break
            time.sleep(0.2)
        assert _get(signalk, "notifications/harborsight/stale")["value"]["state"] == "alert"
        assert _get(signalk, "harborsight/clearance/minimum")["value"] is None
    finally:
        stop.set()
        thread.join(5)
    assert publisher.deltas_sent >= 4


def test_live_publishes_a_replayed_flight_to_signal_k(signalk, tmp_path):
    """`harborsight live --signalk-out`: the bundled flight's closest approach is a danger
    alarm on the server, and its clearances are the aid's last state's."""
    from typer.testing import CliRunner

    from harborsight.cli import app

    flight = ROOT / "harborsight" / "data" / "samples" / "flight"
    lines = []
    for k, path in enumerate(sorted((flight / "frames").glob("*.json"))):
        record = json.loads(path.read_text())
        record.pop("vessel_spec", None)
        lines.append(json.dumps(dict(record, frame_index=k)))
    (tmp_path / "flight.jsonl").write_text("\n".join(lines) + "\n")
    tug = ROOT / "harborsight" / "data" / "samples" / "vessels" / "harbour-tug" / "vessel.yaml"
    result = CliRunner().invoke(app, [
        "live", "--video", str(flight / "logs" / "flight.mp4"), "--metadata",
        str(tmp_path / "flight.jsonl"), "--vessel", str(tug), "--no-realtime",
        "--signalk-out", f"ws://127.0.0.1:{signalk}", "--record", str(tmp_path / "record")])
    assert result.exit_code == 0, result.output
    last = json.loads((tmp_path / "record" / "states.jsonl").read_text().splitlines()[-1])
    notes = _get(signalk, "notifications/harborsight")
    for section in last["sections"]:
        expected = {"ok": "normal", "caution": "warn", "danger": "alarm"}.get(section["status"], "normal")
        assert notes[f"section{section['index']}"]["value"]["state"] == expected
    assert any(notes[f"section{s['index']}"]["value"]["state"] == "alarm" for s in last["sections"])
    assert _get(signalk, "harborsight/clearance/minimum")["value"] == pytest.approx(
        last["min_distance_m"], abs=1e-3)


def test_the_vessel_s_speed_and_course_go_with_its_position():
    """Speed and course over ground (m/s, radians) go with the position of their time,
    whichever comes first in an update or in the next one of that time; they carry the
    vessel when the position stops (tests/test_dead_reckoning.py)."""
    track = LiveTrack("vessel", "signalk")
    reader = SignalKVessel("ws://127.0.0.1:1/signalk/v1/stream", track)
    assert track.dead_reckon_s > 0
    for k, order in enumerate(("position first", "motion first", "apart")):
        stamp = datetime.fromtimestamp(START_S + k, UTC).isoformat().replace("+00:00", "Z")
        position = {"path": "navigation.position", "value": {"latitude": 56.15, "longitude": 10.2}}
        motion = [{"path": "navigation.speedOverGround", "value": 1.5 + k},
                  {"path": "navigation.courseOverGroundTrue", "value": math.radians(90.0)}]
        values = [position, *motion] if order == "position first" else [*motion, position]
        if order == "apart":
            for part in ([position], motion):
                reader.handle(json.dumps({"updates": [{"$source": "gps", "timestamp": stamp,
                                                       "values": part}]}), 10.0 + k)
        else:
            reader.handle(json.dumps({"updates": [{"$source": "gps", "timestamp": stamp,
                                                   "values": values}]}), 10.0 + k)
    vessel = track.track()
    assert np.allclose(vessel.sog_mps, [1.5, 2.5, 3.5]) and np.allclose(vessel.cog_deg, 90.0)
