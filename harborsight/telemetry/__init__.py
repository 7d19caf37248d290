"""Readers that turn real logs into tracks, and tracks into ``harborsight.frame/1`` metadata.

Drone: DJI video ``.SRT`` (:mod:`.dji_srt`), PX4 ``.ulg`` and ArduPilot DataFlash ``.bin``
(:mod:`.autopilot`), ROS 1 and ROS 2 bags (:mod:`.rosbag`), DJI still photos
(:mod:`.dji_photo`). Vessel: NMEA 0183 or CSV (:mod:`.vessel_track`). A video's per-frame
metadata: :mod:`.metadata`.
"""

from __future__ import annotations

from pathlib import Path

from harborsight.errors import InputError
from harborsight.telemetry.track import Track

DRONE_LOG_SUFFIXES = {".srt": "DJI video telemetry", ".ulg": "PX4 ULog",
                      ".bin": "ArduPilot DataFlash", ".bag": "ROS 1 bag",
                      ".db3": "ROS 2 bag (SQLite)", ".mcap": "ROS 2 bag (MCAP)"}


def is_drone_log(path: str | Path) -> bool:
    """Whether ``path`` is read as a drone log: by its suffix, or a ROS 2 bag folder."""
    path = Path(path)
    return path.suffix.lower() in DRONE_LOG_SUFFIXES or (
        path.is_dir() and (path / "metadata.yaml").is_file())


def read_drone_log(path: str | Path, utc_offset_h: float | None = None) -> Track:
    """A drone log by its extension: ``.srt`` (DJI), ``.ulg`` (PX4), ``.bin`` (ArduPilot),
    ``.bag``/``.db3``/``.mcap`` or a ROS 2 bag folder (topics found by type:
    :mod:`.rosbag`). ``utc_offset_h`` places a DJI SRT's local date lines in UTC."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".bag", ".db3", ".mcap") or (path.is_dir() and is_drone_log(path)):
        from harborsight.telemetry.rosbag import read_bag_track

        return read_bag_track(path)
    if not path.is_file():
        raise InputError(path, None, "file not found")
    if suffix == ".srt":
        from harborsight.telemetry.dji_srt import read_dji_srt

        return read_dji_srt(path, utc_offset_h)
    if suffix == ".ulg":
        from harborsight.telemetry.autopilot import read_px4_ulog

        return read_px4_ulog(path)
    if suffix == ".bin":
        from harborsight.telemetry.autopilot import read_ardupilot_bin

        return read_ardupilot_bin(path)
    known = ", ".join(f"{s} ({what})" for s, what in DRONE_LOG_SUFFIXES.items())
    raise InputError(path, None, f"unknown drone log type {suffix!r}: expected {known}")


__all__ = ["DRONE_LOG_SUFFIXES", "Track", "is_drone_log", "read_drone_log"]
