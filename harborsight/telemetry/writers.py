"""Write a flight's frame metadata out as the logs real equipment records: a DJI video
subtitle (.SRT, the P4 RTK family) for the drone and an NMEA 0183 feed (RMC + HDT) for the
vessel, plus the video itself. Used to ship the bundled flight as real-format inputs to
``telemetry video`` and to test the readers on a known truth.

Precision is the formats' own: the SRT carries 1e-6 degrees of latitude and longitude,
0.01 m of height and 0.1 degree of attitude; RMC carries 1e-5 arc minutes (1.7e-7 degrees)
and HDT 0.01 degree. The NMEA sentences are built by pynmea2 (checksums included).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import cv2
import pynmea2

from harborsight.errors import InputError
from harborsight.frame import FrameMetadata, load_frame_metadata
from harborsight.telemetry.metadata import parse_utc_time
from harborsight.telemetry.track import KNOT_MPS


@dataclass(frozen=True)
class FlightLogs:
    srt: Path
    nmea: Path
    video: Path | None
    frames: int
    fps: float
    video_start_utc: datetime


def _utc(meta: FrameMetadata, source: Path) -> datetime:
    if not meta.timestamp:
        raise InputError(source, "timestamp", "every frame needs a time to be written as a log")
    try:
        return parse_utc_time(meta.timestamp, "timestamp")
    except InputError as exc:
        raise InputError(source, "timestamp", exc.message) from None


def _srt_clock(seconds: float) -> str:
    """``HH:MM:SS,mmm`` of a subtitle cue."""
    millis = round(seconds * 1000)
    return (f"{millis // 3_600_000:02d}:{millis // 60_000 % 60:02d}:{millis // 1000 % 60:02d},"
            f"{millis % 1000:03d}")


def srt_text(metas: Sequence[FrameMetadata], video_s: Sequence[float], frame_s: float) -> str:
    """A P4 RTK style SRT: one cue per frame with ``GPS (lon, lat, satellites)``, ``H``
    (height above the take-off point, here the frame's ``uav_alt_m``) and the gimbal's
    ``G.PRY (pitch, roll, yaw)``. No date lines, as the P4 RTK writes none: the reader
    places it with ``--video-start``."""
    cues = []
    for i, (meta, start_s) in enumerate(zip(metas, video_s, strict=True)):
        cues.append("\n".join([
            str(i + 1), f"{_srt_clock(start_s)} --> {_srt_clock(start_s + frame_s)}",
            f"F/5.6, SS 400, ISO 100, EV 0, GPS ({meta.uav_lon_deg:.6f}, {meta.uav_lat_deg:.6f}, "
            f"15), D 10.00m, H {meta.uav_alt_m:.2f}m, H.S 0.00m/s, V.S 0.00m/s, "
            f"G.PRY ({meta.pitch_deg:.1f}°, {meta.roll_deg:.1f}°, {meta.yaw_deg:.1f}°)", ""]))
    return "\n".join(cues)


def _nmea_angle(value_deg: float, degree_digits: int) -> str:
    """NMEA ``DDMM.MMMMM`` (latitude, 2 degree digits) or ``DDDMM.MMMMM`` (longitude, 3)."""
    value = abs(value_deg)
    degrees = int(value)
    minutes = round((value - degrees) * 60, 5)
    if minutes >= 60:
        degrees, minutes = degrees + 1, 0.0
    return f"{degrees:0{degree_digits}d}{minutes:08.5f}"


def _speed_and_course(meta: FrameMetadata) -> tuple[str, str]:
    """RMC's speed (knots) and course (degrees true) over ground from the frame's vessel
    velocity; empty fields without one, and no course at rest."""
    if meta.vessel_velocity_en_mps is None:
        return "", ""
    east, north = meta.vessel_velocity_en_mps
    speed_mps = math.hypot(east, north)
    if speed_mps < 1e-6:
        return "0.00", ""
    return f"{speed_mps / KNOT_MPS:.2f}", f"{math.degrees(math.atan2(east, north)) % 360:.1f}"


def nmea_lines(metas: Sequence[FrameMetadata], times_utc: Sequence[datetime]) -> list[str]:
    """An RMC fix (with the speed and course over ground of the frame's vessel velocity,
    where it gives one) and an HDT true heading per frame, in time order."""
    lines = []
    for meta, when in zip(metas, times_utc, strict=True):
        lat, lon = meta.vessel_lat_deg, meta.vessel_lon_deg
        rmc = pynmea2.RMC("GP", "RMC", (
            f"{when:%H%M%S}.{when.microsecond // 10_000:02d}", "A",
            _nmea_angle(lat, 2), "N" if lat >= 0 else "S", _nmea_angle(lon, 3),
            "E" if lon >= 0 else "W", *_speed_and_course(meta),
            f"{when:%d%m%y}", "", ""))
        hdt = pynmea2.HDT("HE", "HDT", (f"{meta.vessel_heading_deg % 360:.2f}", "T"))
        lines += [rmc.render(), hdt.render()]
    return lines


def write_flight_logs(flight: Path, out: Path, video: bool = True) -> FlightLogs:
    """``flight.SRT``, ``ship.nmea`` and (``video``) ``flight.mp4`` in ``out`` from a folder
    of frames (``flight/frames/*.json`` with timestamps, ``flight/images``). The video runs
    at the frames' rate (the first two frames' interval); cue ``n`` of the SRT is frame
    ``n``."""
    paths = sorted((flight / "frames").glob("*.json"))
    if len(paths) < 2:
        raise InputError(flight / "frames", None, "needs at least two frames")
    metas = [load_frame_metadata(path) for path in paths]
    times = [_utc(meta, path) for meta, path in zip(metas, paths, strict=True)]
    frame_s = (times[1] - times[0]).total_seconds()
    if frame_s <= 0:
        raise InputError(paths[1], "timestamp", "frames must be in time order")
    video_s = [(when - times[0]).total_seconds() for when in times]
    out.mkdir(parents=True, exist_ok=True)
    srt, nmea = out / "flight.SRT", out / "ship.nmea"
    srt.write_text(srt_text(metas, video_s, frame_s), encoding="utf-8")
    nmea.write_text("\r\n".join(nmea_lines(metas, times)) + "\r\n", encoding="ascii")
    mp4 = None
    if video:
        mp4 = out / "flight.mp4"
        first = cv2.imread(str(flight / "images" / metas[0].image))
        if first is None:
            raise InputError(flight / "images" / metas[0].image, None, "cannot read the image")
        height, width = first.shape[:2]
        writer = cv2.VideoWriter(str(mp4), cv2.VideoWriter_fourcc(*"mp4v"), 1.0 / frame_s,
                                 (width, height))
        if not writer.isOpened():
            raise InputError(mp4, None, "OpenCV cannot write an mp4 here")
        for meta in metas:
            image = cv2.imread(str(flight / "images" / meta.image))
            if image is None or image.shape[:2] != (height, width):
                writer.release()
                raise InputError(flight / "images" / meta.image, None,
                                 "unreadable, or not the first frame's size")
            writer.write(image)
        writer.release()
    return FlightLogs(srt, nmea, mp4, len(metas), 1.0 / frame_s, times[0])
