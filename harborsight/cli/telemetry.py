"""``harborsight telemetry``: real flight logs and vessel tracks (``show``, ``video``)."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path
from typing import Annotated

import cv2
import typer
from rich.table import Table

from harborsight.cli.app import (
    MAX_VIDEO_FPS,
    MAX_VIDEO_FRAMES,
    app,
    console,
    err_console,
)
from harborsight.errors import HarborsightError, InputError
from harborsight.files import prepare_output_file, strict_json

telemetry_app = typer.Typer(rich_markup_mode=None,
    no_args_is_help=True,
    help="Real flight logs (DJI SRT, PX4 ULog, ArduPilot BIN), DJI photos and vessel tracks "
    "(NMEA 0183, AIS, CSV): inspect them, and write per-frame metadata for `run` and "
    "`measure`.")


app.add_typer(telemetry_app, name="telemetry")


# the vessel-track options shared by `video`, `photos` and `bag`
VesselTrackOption = Annotated[Path, typer.Option(
    "--vessel-track",
    help="The vessel's track: NMEA 0183 (RMC/GGA position; HDT, HDG or HDM heading, magnetic "
    "made true with the WMM), AIS (AIVDM/AIVDO with receiver times; --mmsi) or CSV (time, "
    "lat, lon, heading_deg or heading_mag_deg).")]
VesselOffsetOption = Annotated[float, typer.Option(
    "--vessel-offset-s", min=-86400.0, max=86400.0,
    help="Seconds added to each frame's (photo's, image's) UTC time before reading the vessel "
    "track: -5 if the vessel's clock runs 5 s behind.")]
MaxGapOption = Annotated[float, typer.Option(
    "--max-gap-s", min=0.01, max=3600.0,
    help="Gaps in a track: a frame between two samples more than twice this apart gets no "
    "value (it is skipped, with the reason), and a track's end value is held for at most this "
    "(or half its last sample interval). Gaps up to twice this are interpolated across.")]
MmsiOption = Annotated[int | None, typer.Option(
    "--mmsi", min=1, max=999_999_999,
    help="An AIS vessel track: the vessel (default: the file's own AIVDO reports, or its only "
    "vessel).")]
AllowCogOption = Annotated[bool, typer.Option(
    "--allow-cog-heading/--no-allow-cog-heading",
    help="An AIS track: where the true heading is not available (511), use the course over "
    "ground (wrong wherever the vessel moves sideways, as when berthing).")]


_UTC_OFFSET_HELP = ("DJI SRT only: hours the SRT's local date lines are ahead of UTC (e.g. 2 "
                    "for CEST), to place them in UTC.")


@telemetry_app.command("show")
def telemetry_show(
    logs: Annotated[list[Path], typer.Argument(
        metavar="LOG...",
        help="Drone logs (.srt, .ulg, .bin, ROS bags .bag/.db3/.mcap or a ROS 2 bag folder: "
        "its topics are listed), DJI photos (.jpg: XMP and EXIF) or vessel tracks "
        "(.nmea/.txt/.log NMEA 0183, AIS, .csv).")],
    utc_offset_h: Annotated[float | None, typer.Option(
        min=-14.0, max=14.0, help=_UTC_OFFSET_HELP)] = None,
    mmsi: Annotated[int | None, typer.Option(
        min=1, max=999_999_999, help="AIS logs: the vessel to show.")] = None,
    json_out: Annotated[Path | None, typer.Option(
        "--json", help="Also write the summaries as JSON.")] = None,
) -> None:
    """What each log holds: samples, rate, duration, UTC start, extent, altitude datum,
    attitude, the accuracy figures it states (one sigma: their range), and what was skipped.
    Exit code 1 if any log could not be read."""
    from harborsight.telemetry import is_drone_log, read_drone_log
    from harborsight.telemetry.dji_photo import PHOTO_SUFFIXES
    from harborsight.telemetry.vessel_track import read_vessel_track

    if json_out:
        try:
            prepare_output_file(json_out, "--json")
        except HarborsightError as exc:
            err_console.print(f"error: {exc}", markup=False, highlight=False)
            raise typer.Exit(2) from None
    summaries, failed = [], 0
    for path in logs:
        if path.suffix.lower() in PHOTO_SUFFIXES:
            summary = _show_photo(path)
            failed += summary is None
            if summary is not None:
                summaries.append(summary)
            continue
        try:
            if path.suffix.lower() in (".bag", ".db3", ".mcap") or path.is_dir():
                _show_bag_topics(path)
            track = (read_drone_log(path, utc_offset_h) if is_drone_log(path)
                     else read_vessel_track(path, mmsi=mmsi))
        except HarborsightError as exc:
            err_console.print(f"error: {exc}", markup=False, highlight=False)
            failed += 1
            continue
        summary = track.summary()
        summaries.append(summary)
        table = Table(title=f"{path} ({summary['kind']})", title_justify="left", show_header=False)
        table.add_column("what")
        table.add_column("value")

        def span(values, digits, unit=""):
            return "—" if values is None else f"{values[0]:.{digits}f} to {values[1]:.{digits}f}{unit}"

        rate = summary["rate_hz"]
        table.add_row("samples", f"{summary['samples']} over {summary['duration_s']:.1f} s"
                      + (f" ({rate:.1f} Hz)" if rate else ""))
        table.add_row("clock", summary["clock"])
        table.add_row("UTC at t = 0", summary["utc_start"] or "unknown")
        table.add_row("latitude", span(summary["lat_deg"], 6, "°"))
        table.add_row("longitude", span(summary["lon_deg"], 6, "°"))
        table.add_row("altitude", span(summary["alt_m"], 1, " m")
                      + (f" ({summary['alt_reference']})" if summary["alt_reference"] else ""))
        table.add_row("attitude", {"gimbal": "gimbal (camera)", "vehicle": "airframe"}.get(
            summary["attitude"], "none"))
        if summary["heading"]:
            table.add_row("heading", "true heading")
        accuracy = [f"{what} " + (f"{summary[key][0]:.2f}{unit}"
                                  if f"{summary[key][0]:.2f}" == f"{summary[key][1]:.2f}"
                                  else span(summary[key], 2, unit))
                    for key, what, unit in (("position_sigma_m", "position (per axis)", " m"),
                                            ("alt_sigma_m", "altitude", " m"),
                                            ("heading_sigma_deg", "heading", "°"))
                    if summary[key] is not None]
        table.add_row("accuracy (1σ)", "; ".join(accuracy) if accuracy
                      else "none in the log (the sensor defaults apply)")
        for note in summary["notes"]:
            table.add_row("note", note)
        console.print(table)
    if json_out:
        json_out.write_text(strict_json(summaries, indent=2) + "\n")
    raise typer.Exit(1 if failed else 0)


@telemetry_app.command("video")
def telemetry_video(
    drone_log: Annotated[Path, typer.Argument(metavar="DRONE_LOG",
                                              help="The drone's log: DJI .srt (video clock), "
                                              "PX4 .ulg or ArduPilot .bin.")],
    vessel_track: VesselTrackOption,
    camera: Annotated[str, typer.Option(
        help="Camera: a preset (dji-mavic3, dji-p4rtk, dji-m30-wide) or a calibration file "
        "(OpenCV YAML/XML or ROS camera_info).")],
    water_level_m: Annotated[float, typer.Option(
        min=-1000.0, max=1000.0,
        help="The water surface in the drone altitude's datum (see "
        "`telemetry show`): e.g. -3.5 for a DJI take-off from a deck 3.5 m above the water.")],
    out: Annotated[Path, typer.Option(help="JSON lines to write, one object per frame.")],
    video: Annotated[Path | None, typer.Option(
        help="The video: its size, its frame count and each frame's own presentation time "
        "(a variable-frame-rate video's frames are not n / fps).")] = None,
    frames: Annotated[int | None, typer.Option(
        min=1, max=MAX_VIDEO_FRAMES,
        help="Frame count; with --video, write only its first this many frames.")] = None,
    fps: Annotated[float | None, typer.Option(
        min=0.1, max=MAX_VIDEO_FPS,
        help="Frame rate, without --video (with it, the video's own frame times are used).")] = None,
    image_size: Annotated[str | None, typer.Option(
        help="WIDTHxHEIGHT of the frames, without --video.")] = None,
    video_start: Annotated[str | None, typer.Option(
        help="UTC time of the video's first frame, ISO 8601 (needed for autopilot logs, and "
        "for SRTs without date lines).")] = None,
    utc_offset_h: Annotated[float | None, typer.Option(
        min=-14.0, max=14.0, help=_UTC_OFFSET_HELP)] = None,
    mount: Annotated[str, typer.Option(
        help="auto (the log's gimbal attitude where it has one, else stabilised), gimbal, "
        "stabilised (pointing at --camera-pitch-deg, no roll, the airframe's yaw), or rigid "
        "(fixed to the airframe).")] = "auto",
    camera_pitch_deg: Annotated[float, typer.Option(
        min=-90.0, max=0.0,
        help="Stabilised or rigid mount: the camera's pitch (-90: "
        "straight down, 0: at the horizon).")] = -90.0,
    camera_yaw_deg: Annotated[float | None, typer.Option(
        min=-360.0, max=360.0,
        help="A fixed camera yaw (degrees clockwise from true north) for logs without "
        "attitude.")] = None,
    vessel_offset_s: VesselOffsetOption = 0.0,
    max_gap_s: MaxGapOption = 1.0,
    mmsi: MmsiOption = None,
    allow_cog_heading: AllowCogOption = False,
) -> None:
    """Write per-frame harborsight.frame/1 metadata for a video from the drone's log and the
    vessel's track, for `harborsight run VIDEO --metadata OUT`. Frames outside a track, or in
    a gap, are left out and listed."""

    from harborsight.telemetry import read_drone_log
    from harborsight.telemetry.metadata import (
        MOUNTS,
        CameraMount,
        build_video_metadata,
        camera_block_for,
        parse_utc_time,
    )
    from harborsight.telemetry.vessel_track import read_vessel_track

    try:
        prepare_output_file(out, "--out")
        if mount not in MOUNTS:
            raise InputError(None, "--mount", f"{mount!r}: expected one of {', '.join(MOUNTS)}")
        width = height = frame_times_s = None
        if video is not None:
            from harborsight.flight.sources import open_video, video_frame_times_s

            capture = open_video(video)
            container_fps = float(capture.get(cv2.CAP_PROP_FPS))
            width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
            height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
            count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
            capture.release()
            if fps is not None and container_fps > 0 and abs(fps / container_fps - 1) > 1e-3:
                raise InputError(None, "--fps", f"{fps:g} with --video, whose container says "
                                 f"{container_fps:g} fps: each frame is placed at its own time "
                                 "in the video; leave --fps out")
            if image_size:
                raise InputError(None, "--image-size", f"with --video, whose frames are "
                                 f"{width}x{height}: leave it out (the camera block takes the "
                                 "video's size)")
            # each frame at its presentation time: a variable-frame-rate video (a phone, a
            # drone in low light) or one with dropped frames is not n / fps
            frame_times_s = video_frame_times_s(video)
            if frame_times_s is not None:
                count = len(frame_times_s)
            fps = fps or container_fps
            frames = min(frames or count, count) if count > 0 else frames
            if not frames or frames <= 0 or not fps or fps <= 0:
                raise InputError(video, None, "could not read the frame count and rate: give "
                                 "--frames and --fps")
            if frames > MAX_VIDEO_FRAMES or fps > MAX_VIDEO_FPS:
                raise InputError(video, None, f"implausible frame count {frames} or rate "
                                 f"{fps:g}/s in the container: give --frames and --fps")
            if frame_times_s is not None:
                frame_times_s = frame_times_s[:frames]
        if image_size:
            size = re.fullmatch(r"(\d{1,6})x(\d{1,6})", image_size.strip().lower())
            if size is None or not 1 <= min(int(size[1]), int(size[2])) <= max(
                    int(size[1]), int(size[2])) <= 100_000:
                raise InputError(None, "--image-size",
                                 f"expected WIDTHxHEIGHT in pixels, got {image_size!r}")
            width, height = int(size[1]), int(size[2])
        if not frames or not fps:
            raise InputError(None, "--frames", "give --video, or --frames and --fps")
        start = parse_utc_time(video_start, "--video-start") if video_start else None
        drone = read_drone_log(drone_log, utc_offset_h)
        vessel = read_vessel_track(vessel_track, mmsi=mmsi, allow_cog_heading=allow_cog_heading)
        camera_block = camera_block_for(camera, width, height, drone_log)
        result = build_video_metadata(
            drone, vessel, camera_block, frames, fps, frame_times_s=frame_times_s,
            water_level_m=water_level_m,
            mount=CameraMount(mount, camera_pitch_deg, camera_yaw_deg), video_start_utc=start,
            vessel_offset_s=vessel_offset_s, max_gap_s=max_gap_s)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    out.write_text("".join(strict_json(frame) + "\n" for frame in result.frames))
    for track in (drone, vessel):
        for note in track.notes:
            err_console.print(f"note: {track.source}: {note}", markup=False, highlight=False)
    if camera_yaw_deg is not None and result.frames:
        err_console.print(f"note: the camera's yaw is held at {camera_yaw_deg:g} deg from true north "
                          f"for all {len(result.frames)} frame(s) (--camera-yaw-deg): a turn of the "
                          "drone during the video is not seen; the pose refinement absorbs a yaw "
                          "error near the nadir and flags frames whose image contradicts it",
                          markup=False, highlight=False)
    console.print(f"{len(result.frames)} of {frames} frame(s) written to {out} (camera mount: "
                  f"{result.mount}, altitude: {drone.alt_reference})", highlight=False)
    _say_beyond_dead_reckoning(result.beyond_dead_reckoning)
    if result.skipped:
        reasons = Counter(reason.split(":")[0] for _, reason in result.skipped)
        err_console.print(f"[red]{len(result.skipped)} frame(s) left out[/] (frames "
                          f"{result.skipped[0][0]}..{result.skipped[-1][0]}):")
        for reason, count in reasons.most_common():
            err_console.print(f"  {count} x {reason}", markup=False, highlight=False)
    raise typer.Exit(1 if not result.frames else 0)


def _say_beyond_dead_reckoning(count: int, photos: bool = False) -> None:
    """Say how many frames written carry the vessel past the dead reckoning it is measured
    with, and what measures them."""
    # imported here: training imports this module, and must not need the geodesy stack
    from harborsight.geometry.sensor_sigmas import MAX_DEAD_RECKONED_S

    if count:
        how = ("`harborsight run` on the folder (not `measure`) measures those" if photos
               else "`run` and `live` measure those")
        err_console.print(f"[yellow]{count} of them[/] carry the vessel more than "
                          f"{MAX_DEAD_RECKONED_S:g} s from its last report: {how} only where "
                          "the frames before placed the vessel in the image", highlight=False)


def _show_photo(path: Path) -> dict | None:
    """Print what a DJI photo holds; its summary, or None (error printed) if unreadable."""
    from harborsight.telemetry.dji_photo import read_dji_photo

    try:
        photo = read_dji_photo(path)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        return None
    summary = photo.summary()
    table = Table(title=f"{path} (DJI photo)", title_justify="left", show_header=False)
    table.add_column("what")
    table.add_column("value")

    def number(value, digits, unit=""):
        return "—" if value is None else f"{value:.{digits}f}{unit}"

    table.add_row("camera", " ".join(v for v in (summary["make"], summary["model"],
                                                 summary["drone_model"]) if v) or "unknown")
    table.add_row("image", f"{photo.width}x{photo.height}"
                  + ("" if photo.image_whole else " (image data cut short)"))
    table.add_row("position", "—" if summary["lat_deg"] is None else
                  f"{summary['lat_deg']:.8f}°, {summary['lon_deg']:.8f}°")
    table.add_row("altitude", f"relative {number(summary['relative_altitude_m'], 2, ' m')} "
                  "(above the take-off point), absolute "
                  f"{number(summary['absolute_altitude_m'], 2, ' m')}")
    for key, what in (("gimbal_ypr_deg", "gimbal yaw/pitch/roll"),
                      ("flight_ypr_deg", "airframe yaw/pitch/roll")):
        angles = summary[key]
        table.add_row(what, "—" if angles is None else " / ".join(f"{a:.2f}°" for a in angles))
    camera = summary["camera"]
    table.add_row("intrinsics", summary["camera_from"] if camera is None else
                  f"fx {camera['fx']:.1f}, fy {camera['fy']:.1f}, cx {camera['cx']:.1f}, "
                  f"cy {camera['cy']:.1f} px; " + summary["camera_from"])
    table.add_row("capture time", (f"{summary['utc']} UTC; " if summary["utc"] else "")
                  + summary["clock"])
    table.add_row("accuracy (1σ)", summary["accuracy"] if summary["position_sigma_m"] is None
                  else f"position {summary['position_sigma_m']:.3f} m per axis ({summary['accuracy']})")
    for note in summary["notes"]:
        table.add_row("note", note)
    console.print(table)
    return summary


@telemetry_app.command("photos")
def telemetry_photos(
    photos: Annotated[list[Path], typer.Argument(
        metavar="PHOTO_OR_DIR...", help="DJI photos (.jpg) or folders of them.")],
    vessel_track: VesselTrackOption,
    water_level_m: Annotated[float, typer.Option(
        min=-10000.0, max=10000.0,
        help="The water surface in the altitude's datum: with the default relative altitude, "
        "metres above the take-off point (-3.5 for a take-off from a deck 3.5 m above the "
        "water).")],
    out: Annotated[Path, typer.Option(
        help="Folder for the frame files (<photo stem>.json, `image` pointing at the photo).")],
    utc_offset_h: Annotated[float | None, typer.Option(
        min=-14.0, max=14.0,
        help="Hours the drone's clock (EXIF DateTimeOriginal: local time, set from the "
        "remote's phone or tablet) is ahead of UTC, e.g. 2 for CEST. Needed when the photo "
        "states no zone (OffsetTimeOriginal) and no UTC time (UTCAtExposure, GPS time stamp); "
        "wins over OffsetTimeOriginal.")] = None,
    altitude: Annotated[str, typer.Option(
        help="relative (RelativeAltitude: barometric, above the take-off point) or absolute "
        "(AbsoluteAltitude: mean sea level on most DJI models, the ellipsoid on RTK ones).")
    ] = "relative",
    gimbal_yaw_reference: Annotated[str, typer.Option(
        help="true: GimbalYawDegree is from true north (DJI corrects its compass for the "
        "declination); magnetic: add the World Magnetic Model's declination.")] = "true",
    camera: Annotated[Path | None, typer.Option(
        help="A calibration file (OpenCV YAML/XML or ROS camera_info) of the photos' size, "
        "instead of the intrinsics the photos give (DewarpData, calibrated focal length, the "
        "model's sensor or the 35 mm equivalent).")] = None,
    vessel_offset_s: VesselOffsetOption = 0.0,
    max_gap_s: MaxGapOption = 1.0,
    mmsi: MmsiOption = None,
    allow_cog_heading: AllowCogOption = False,
) -> None:
    """Write one harborsight.frame/1 file per DJI photo (pose, gimbal attitude, intrinsics and
    accuracy from its XMP and EXIF; the vessel sampled at its capture time) for
    `harborsight measure OUT --vessel ...`, or `harborsight run OUT --vessel ...` (which carries
    a vessel known from sparse AIS reports from photo to photo). A photo that cannot be a frame
    is listed with its reason and skipped. Exit code 1 when no frame was written, 2 for a bad
    option or track."""
    from harborsight.cli.progress import progress_report
    from harborsight.files import prepare_output_folder
    from harborsight.telemetry.dji_photo import ALTITUDES, YAW_REFERENCES
    from harborsight.telemetry.metadata import camera_block_for
    from harborsight.telemetry.photo_batch import find_photos, write_photo_frames
    from harborsight.telemetry.vessel_track import read_vessel_track

    try:
        if altitude not in ALTITUDES:
            raise InputError(None, "--altitude", f"{altitude!r}: expected {' or '.join(ALTITUDES)}")
        if gimbal_yaw_reference not in YAW_REFERENCES:
            raise InputError(None, "--gimbal-yaw-reference", f"{gimbal_yaw_reference!r}: "
                             f"expected {' or '.join(YAW_REFERENCES)}")
        paths = find_photos(photos)
        prepare_output_folder(out, "--out")
        camera_block = None if camera is None else camera_block_for(str(camera), None, None, None)
        vessel = read_vessel_track(vessel_track, mmsi=mmsi, allow_cog_heading=allow_cog_heading)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    with progress_report("photos", len(paths), console, unit="photos") as progress:
        batch = write_photo_frames(
            paths, vessel, out, water_level_m=water_level_m, utc_offset_h=utc_offset_h,
            altitude=altitude, yaw_reference=gimbal_yaw_reference,
            vessel_offset_s=vessel_offset_s, max_gap_s=max_gap_s, camera=camera_block,
            on_photo=lambda _: progress.advance())
    for note in vessel.notes:
        err_console.print(f"note: {vessel.source}: {note}", markup=False, highlight=False)
    for note, names in list(batch.notes.items())[:12]:
        where = names[0] if len(names) == 1 else f"{len(names)} photos"
        err_console.print(f"note: {note} ({where})", markup=False, highlight=False)
    if len(batch.notes) > 12:
        err_console.print(f"note: ... and {len(batch.notes) - 12} other notes", highlight=False)
    console.print(f"{len(batch.written)} of {len(paths)} photo(s) written as frames to {out}",
                  highlight=False)
    _say_beyond_dead_reckoning(batch.beyond_dead_reckoning, photos=True)
    if batch.skipped:
        err_console.print(f"[red]{len(batch.skipped)} photo(s) left out:[/]")
        for path, reason in batch.skipped:
            err_console.print(f"  {path.name}: {reason}", markup=False, highlight=False)
    raise typer.Exit(0 if batch.written else 1)


def _show_bag_topics(path: Path) -> None:
    """Print a bag's topics, and which each role would use."""
    from harborsight.telemetry.rosbag import choose_topics
    from harborsight.telemetry.rosbag_io import open_bag

    reader = open_bag(path)
    topics = choose_topics(reader)
    roles = {topics.image: "image", topics.fix: "position", topics.rel_alt: "height",
             topics.camera_info: "intrinsics",
             topics.attitude: f"attitude ({topics.attitude_of})" if topics.attitude else None}
    table = Table(title=f"{path} ({reader.kind} bag{', damaged' if reader.damaged else ''})",
                  title_justify="left")
    for column in ("topic", "type", "messages", "used as"):
        table.add_column(column)
    for name in sorted(reader.topics):
        info = reader.topics[name]
        table.add_row(name, info.msgtype, str(info.count), roles.get(name) or "")
    console.print(table)


@telemetry_app.command("bag")
def telemetry_bag(
    bag: Annotated[Path, typer.Argument(
        metavar="BAG", help="A ROS 1 .bag, a ROS 2 bag folder, or its .db3 / .mcap file.")],
    vessel_track: VesselTrackOption,
    water_level_m: Annotated[float, typer.Option(
        min=-10000.0, max=10000.0,
        help="The water surface in the altitude's datum: the WGS-84 ellipsoid for a "
        "NavSatFix altitude, the take-off point for a rel_alt topic (`telemetry show BAG` "
        "says which).")],
    out: Annotated[Path, typer.Option(
        help="Flight folder to write: images/ and frames/ (then `harborsight run OUT`).")],
    image_topic: Annotated[str | None, typer.Option(
        help="sensor_msgs/Image or CompressedImage topic (default: the one with most "
        "messages).")] = None,
    fix_topic: Annotated[str | None, typer.Option(
        help="sensor_msgs/NavSatFix topic.")] = None,
    attitude_topic: Annotated[str | None, typer.Option(
        help="Imu, QuaternionStamped or PoseStamped topic (default: one named like "
        "gimbal/camera, else the one with most messages).")] = None,
    attitude_of: Annotated[str, typer.Option(
        help="What the attitude topic describes: auto (gimbal when its name says gimbal, "
        "camera or mount), gimbal (the camera: x its optical axis) or vehicle (the "
        "airframe).")] = "auto",
    attitude_frame: Annotated[str, typer.Option(
        help="enu: ROS's REP 103 (world east-north-up, body forward-left-up; MAVROS); ned: "
        "north-east-down and forward-right-down (PX4, DJI).")] = "enu",
    camera_info_topic: Annotated[str | None, typer.Option(
        help="sensor_msgs/CameraInfo topic.")] = None,
    rel_alt_topic: Annotated[str | None, typer.Option(
        help="std_msgs/Float64 or Float32 height above the take-off point (default: a topic "
        "named like rel_alt; without one, the NavSatFix altitude).")] = None,
    camera: Annotated[Path | None, typer.Option(
        help="A calibration file (OpenCV YAML/XML or ROS camera_info) instead of the bag's "
        "CameraInfo.")] = None,
    mount: Annotated[str, typer.Option(
        help="auto (the gimbal's attitude where the topic is the camera's, else stabilised), "
        "gimbal, stabilised or rigid, as for `telemetry video`.")] = "auto",
    camera_pitch_deg: Annotated[float, typer.Option(
        min=-90.0, max=0.0, help="Stabilised or rigid mount: the camera's pitch.")] = -90.0,
    vessel_offset_s: VesselOffsetOption = 0.0,
    max_gap_s: MaxGapOption = 1.0,
    every: Annotated[int, typer.Option(
        min=1, max=100_000, help="Write every N-th image of the topic.")] = 1,
    mmsi: MmsiOption = None,
    allow_cog_heading: AllowCogOption = False,
) -> None:
    """Turn a ROS bag into a flight folder for `harborsight run`: each image of the image
    topic with the drone's pose (NavSatFix, rel_alt, attitude) and the vessel's sampled at
    its header stamp, intrinsics from CameraInfo. An image that cannot be a frame is listed
    and skipped. Exit code 1 when no frame was written."""
    from harborsight.cli.progress import progress_report
    from harborsight.files import prepare_output_folder
    from harborsight.telemetry.metadata import MOUNTS, CameraMount, camera_block_for
    from harborsight.telemetry.rosbag import choose_topics, read_bag_track, write_bag_frames
    from harborsight.telemetry.rosbag_io import open_bag
    from harborsight.telemetry.vessel_track import read_vessel_track

    try:
        if mount not in MOUNTS:
            raise InputError(None, "--mount", f"{mount!r}: expected one of {', '.join(MOUNTS)}")
        prepare_output_folder(out, "--out")
        camera_block = None if camera is None else camera_block_for(str(camera), None, None, None)
        vessel = read_vessel_track(vessel_track, mmsi=mmsi, allow_cog_heading=allow_cog_heading)
        reader = open_bag(bag)
        topics = choose_topics(reader, image=image_topic, fix=fix_topic, attitude=attitude_topic,
                               camera_info=camera_info_topic, rel_alt=rel_alt_topic,
                               attitude_of=attitude_of)
        drone = read_bag_track(bag, reader=reader, topics=topics, attitude_frame=attitude_frame)
        total = reader.topics[topics.image].count if topics.image else None
        with progress_report("bag", total, console, unit="images") as progress:
            result = write_bag_frames(
                reader, topics, drone, vessel, out, water_level_m=water_level_m,
                mount=CameraMount(mount, camera_pitch_deg), camera=camera_block,
                vessel_offset_s=vessel_offset_s, max_gap_s=max_gap_s, every=every,
                on_image=lambda _: progress.advance())
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    for track in (drone, vessel):
        for note in track.notes:
            err_console.print(f"note: {track.source}: {note}", markup=False, highlight=False)
    for role, others in topics.others.items():
        if others:
            err_console.print(f"note: other {role} topics not used: {', '.join(others)}",
                              markup=False, highlight=False)
    console.print(f"{result.written} of {result.images} image(s) of {topics.image} written as "
                  f"frames to {out} (position {topics.fix}, attitude {topics.attitude or 'none'}"
                  f", intrinsics {result.camera_from}, altitude {drone.alt_reference})",
                  highlight=False)
    if result.skipped:
        reasons = Counter(reason.split(":")[0] for _, reason in result.skipped)
        err_console.print(f"[red]{len(result.skipped)} image(s) left out[/] (images "
                          f"{result.skipped[0][0]}..{result.skipped[-1][0]}):")
        for reason, count in reasons.most_common():
            err_console.print(f"  {count} x {reason}", markup=False, highlight=False)
    raise typer.Exit(0 if result.written else 1)
