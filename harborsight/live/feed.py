"""A recorded flight played as the live feeds a drone and a ship send, in real time: the
video as H.264 in MPEG-TS over UDP (PyAV, x264 with zero-latency tuning), the drone's log as
MAVLink 2 over UDP (pymavlink) and the vessel's NMEA 0183 over UDP, each item at its recorded
time. For rehearsing ``harborsight live`` before a flight, and for its tests.

Times. Flight time ``t`` counts from the video's first frame. The drone's log is sampled on
its own clock: a DJI SRT runs on the video's, an autopilot log is placed by the video's UTC
start (as ``telemetry video`` does). The vessel's sentences go out with the fix they follow,
at that fix's UTC time less the video's UTC start: ``--video-start``, else the SRT's date
lines, else the vessel's first fix (the two recordings are then taken to start together; an
AIS log's first line with a receiver time, whichever vessel's).

The vessel's log may be AIS (AIVDM/AIVDO with receiver times, as `telemetry video` reads it;
for `live --ais`): each sentence goes out at its receiver time less the video's UTC start,
without its tag block, and a position report re-encoded with the second of the minute it is
sent at (a receiver dates a report by its own clock's minute and the report's second, so a
recording replayed later must carry the seconds of now). Lines go out in the file's order:
a line older than the one before is sent at once and dated now by the receiver, and a
fragment of a multi-part message without a receiver time of its own is left out (`live`
reads position reports, all single-part); the transponder's own delay is not replayed.

MAVLink: ``GLOBAL_POSITION_INT`` (``relative_alt`` and ``alt`` both the log's altitude: the
receiver's ``--water-level-m`` is in the log's datum), ``GIMBAL_DEVICE_ATTITUDE_STATUS`` with
yaw in the earth frame for a gimbal attitude, ``ATTITUDE`` for an airframe's, ``SYSTEM_TIME``
once a second; ``time_boot_ms`` is the log time plus a boot offset. Only what the log holds
is sent: an SRT's flight has no ``ATTITUDE``.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

import cv2
import numpy as np

from harborsight.errors import InputError
from harborsight.telemetry import read_drone_log
from harborsight.telemetry.ais import receiver_time, restamped, sentence_start
from harborsight.telemetry.nmea import Fix, NmeaDecoder
from harborsight.telemetry.track import Track
from harborsight.telemetry.vessel_track import is_ais_log

#: the autopilot "booted" this long before the video's first frame
BOOT_OFFSET_S = 120.0


@dataclass
class FeedPlan:
    video: Path
    drone_log: Path
    vessel_nmea: Path
    video_to: str = "udp://127.0.0.1:5600"          # MPEG-TS over UDP, or rtsp:// (published)
    mavlink_to: str = "udpout:127.0.0.1:14550"      # pymavlink address
    nmea_to: str = "127.0.0.1:10110"                # UDP HOST:PORT
    start_s: float = 0.0                            # flight time to start at
    duration_s: float | None = None                 # None: to the end of the video
    video_start_utc: datetime | None = None
    utc_offset_h: float | None = None               # of a DJI SRT's local date lines
    keyframe_s: float = 1.0                         # a receiver joining waits at most this
    rtsp_transport: str = "tcp"                     # an rtsp:// video_to: RTP over tcp or udp


@dataclass
class FeedSummary:
    frames: int = 0
    mavlink_messages: int = 0
    nmea_lines: int = 0
    late_ms: list[float] = field(default_factory=list)    # how late each item went out

    def lateness_p95_ms(self) -> float:
        return float(np.percentile(self.late_ms, 95)) if self.late_ms else 0.0


class _Clock:
    """Sends each item at its flight time (module docstring) from a shared start: the moment
    every sender is ready (:meth:`ready`), so that opening the encoder delays nothing."""

    def __init__(self, plan: FeedPlan, stop: threading.Event, summary: FeedSummary,
                 senders: int) -> None:
        self.start_s, self.stop, self.summary = plan.start_s, stop, summary
        self.end_s = math.inf if plan.duration_s is None else plan.start_s + plan.duration_s
        self.t0 = math.inf
        self._barrier = threading.Barrier(senders, action=self._start)

    def _start(self) -> None:
        self.t0 = time.monotonic() + 0.05

    def ready(self) -> None:
        """Wait for the other senders (a sender that failed to open breaks the wait)."""
        try:
            self._barrier.wait(timeout=30.0)
        except threading.BrokenBarrierError:
            self.stop.set()

    def abort(self) -> None:
        self._barrier.abort()

    def wait_for(self, t_s: float) -> bool:
        """Wait until flight time ``t_s`` (in the window); False if stopped."""
        due = self.t0 + (t_s - self.start_s)
        delay = due - time.monotonic()
        if delay > 0 and self.stop.wait(delay):
            return False
        self.summary.late_ms.append(max(0.0, -delay) * 1000.0)
        return not self.stop.is_set()


def _video_start(plan: FeedPlan, drone: Track) -> datetime:
    if plan.video_start_utc is not None:
        return plan.video_start_utc
    if drone.kind == "dji-srt" and drone.utc_at(0.0) is not None:
        return drone.utc_at(0.0)
    lines = plan.vessel_nmea.read_text(errors="replace").splitlines()
    if is_ais_log(plan.vessel_nmea):
        for line in lines:
            received = receiver_time(line)
            if received is not None:
                return received
        raise InputError(plan.vessel_nmea, None, "no AIS sentence with a receiver time: give "
                         "--video-start")
    decoder = NmeaDecoder()
    for line in lines:
        for event in decoder.feed(line):
            if isinstance(event, Fix):
                return event.utc
    raise InputError(plan.vessel_nmea, None, "no NMEA fix with a date: give --video-start")


def _send_video(plan: FeedPlan, clock: _Clock) -> None:
    import av

    capture = cv2.VideoCapture(str(plan.video))
    fps = capture.get(cv2.CAP_PROP_FPS) or 10.0
    width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
    height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
    if plan.video_to.lower().startswith("rtsp://"):
        # published to an RTSP server (ANNOUNCE, RECORD), which serves it to the receivers
        container = av.open(plan.video_to, mode="w", format="rtsp",
                            options={"rtsp_transport": plan.rtsp_transport})
    else:
        url = plan.video_to + ("&" if "?" in plan.video_to else "?") + "pkt_size=1316"
        # each packet flushed at once; the PES length written, so that a receiver's demuxer
        # hands a frame on when it is complete instead of when the next one starts (one frame
        # later)
        container = av.open(url, mode="w", format="mpegts",
                            container_options={"flush_packets": "1", "omit_video_pes_length": "0"})
    stream = container.add_stream("libx264", rate=round(fps))
    stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
    stream.options = {"preset": "ultrafast", "tune": "zerolatency",
                      "g": str(max(1, round(plan.keyframe_s * fps)))}
    clock.ready()
    try:
        index = 0
        while True:
            ok, image = capture.read()
            if not ok:
                break
            t_s = index / fps
            index += 1
            if t_s < clock.start_s:
                continue
            if t_s >= clock.end_s or not clock.wait_for(t_s):
                break
            frame = av.VideoFrame.from_ndarray(image, format="bgr24")
            frame.pts = clock.summary.frames
            container.mux(stream.encode(frame))
            clock.summary.frames += 1
        container.mux(stream.encode(None))
    finally:
        container.close()
        capture.release()


def _quaternion_wxyz(yaw_deg: float, pitch_deg: float, roll_deg: float) -> list[float]:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_euler("ZYX", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_quat()
    return [float(w), float(x), float(y), float(z)]


def _send_mavlink(plan: FeedPlan, drone: Track, video_start: datetime, clock: _Clock) -> None:
    from harborsight.live.mavlink_in import mavlink2

    connection = mavlink2().mavlink_connection(plan.mavlink_to, source_system=1, source_component=1,
                                               dialect="ardupilotmega")
    mav = connection.mav
    # flight time of each log time
    shift = 0.0 if drone.kind == "dji-srt" else -drone.seconds_of(video_start)
    events = [(t + shift, "position", i) for i, t in enumerate(drone.t_s)]
    if drone.has_attitude:
        attitude_t = drone.attitude_t_s if drone.attitude_t_s is not None else drone.t_s
        events += [(t + shift, "attitude", i) for i, t in enumerate(attitude_t)]
    events.sort(key=lambda e: e[0])
    last_time_s = -math.inf
    clock.ready()
    try:
        for t_s, kind, i in events:
            if t_s < clock.start_s:
                continue
            if t_s >= clock.end_s or not clock.wait_for(t_s):
                break
            boot_ms = round((float(t_s) + BOOT_OFFSET_S) * 1000)
            if t_s - last_time_s >= 1.0:
                unix_us = int((video_start + timedelta(seconds=t_s)).timestamp() * 1e6)
                mav.system_time_send(unix_us, boot_ms)
                last_time_s = t_s
                clock.summary.mavlink_messages += 1
            if kind == "position":
                if not (np.isfinite(drone.lat_deg[i]) and np.isfinite(drone.lon_deg[i])):
                    continue
                alt_mm = round(float(drone.alt_m[i]) * 1000) if drone.alt_m is not None else 0
                mav.global_position_int_send(boot_ms, round(float(drone.lat_deg[i]) * 1e7),
                                             round(float(drone.lon_deg[i]) * 1e7), alt_mm, alt_mm,
                                             0, 0, 0, 65535)
            else:
                yaw, pitch, roll = (float(drone.yaw_deg[i]), float(drone.pitch_deg[i]),
                                    float(drone.roll_deg[i]) if drone.roll_deg is not None else 0.0)
                if not all(map(math.isfinite, (yaw, pitch, roll))):
                    continue
                if drone.attitude_of == "gimbal":
                    mav.gimbal_device_attitude_status_send(
                        0, 0, boot_ms, 64, _quaternion_wxyz(yaw, pitch, roll),   # yaw in earth frame
                        math.nan, math.nan, math.nan, 0)
                else:
                    mav.attitude_send(boot_ms, math.radians(roll), math.radians(pitch),
                                      math.radians(yaw), 0.0, 0.0, 0.0)
            clock.summary.mavlink_messages += 1
    finally:
        connection.close()


def _send_ais(plan: FeedPlan, video_start: datetime, clock: _Clock) -> None:
    """The AIS log's sentences at their receiver times (module docstring); a line without
    one cannot be placed and is left out."""
    host, _, port = plan.nmea_to.rpartition(":")
    lines = plan.vessel_nmea.read_text(errors="replace").splitlines()
    clock.ready()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for line in lines:
            received = receiver_time(line)
            if received is None:
                continue
            t_s = (received - video_start).total_seconds()
            if t_s < clock.start_s:
                continue
            if t_s >= clock.end_s or not clock.wait_for(t_s):
                break
            sentence = restamped(line[sentence_start(line):], datetime.now(UTC).second)
            sock.sendto((sentence.strip() + "\r\n").encode("ascii", errors="replace"),
                        (host, int(port)))
            clock.summary.nmea_lines += 1


def _send_nmea(plan: FeedPlan, video_start: datetime, clock: _Clock) -> None:
    if is_ais_log(plan.vessel_nmea):
        _send_ais(plan, video_start, clock)
        return
    host, _, port = plan.nmea_to.rpartition(":")
    decoder = NmeaDecoder()
    epoch_s: float | None = None
    lines = plan.vessel_nmea.read_text(errors="replace").splitlines()
    clock.ready()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for line in lines:
            for event in decoder.feed(line):
                if isinstance(event, Fix):
                    epoch_s = (event.utc - video_start).total_seconds()
            t_s = clock.start_s if epoch_s is None else epoch_s    # before any fix: at once
            if t_s < clock.start_s:
                continue
            if t_s >= clock.end_s or not clock.wait_for(t_s):
                break
            sock.sendto((line.strip() + "\r\n").encode("ascii", errors="replace"), (host, int(port)))
            clock.summary.nmea_lines += 1


def play_flight(plan: FeedPlan, stop: threading.Event | None = None) -> FeedSummary:
    """Send the three feeds until the window ends or ``stop`` is set."""
    stop = stop or threading.Event()
    drone = read_drone_log(plan.drone_log, plan.utc_offset_h)
    video_start = _video_start(plan, drone)
    summary = FeedSummary()
    clock = _Clock(plan, stop, summary, senders=3)
    errors: list[BaseException] = []

    def guarded(target, *args) -> None:
        try:
            target(*args)
        except BaseException as exc:     # reported to the caller once all have stopped
            errors.append(exc)
            stop.set()
            clock.abort()

    threads = [threading.Thread(target=guarded, args=args, daemon=True) for args in (
        (_send_video, plan, clock), (_send_mavlink, plan, drone, video_start, clock),
        (_send_nmea, plan, video_start, clock))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    if errors:
        raise errors[0]
    return summary
