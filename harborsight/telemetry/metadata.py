"""Per-frame ``harborsight.frame/1`` metadata for a video, from the drone's log and the vessel's
track: what ``harborsight run VIDEO --metadata FILE.jsonl`` reads.

Time. Frame *n* of a video at ``fps`` is ``n / fps`` seconds into it. A DJI SRT runs on the
video's clock, so the drone is sampled at that time directly; an autopilot log runs on its boot
clock, so the video's UTC start is needed to place the frame on it. The vessel track is in UTC:
the frame's UTC time is the video's start (given, or the SRT's date lines with their UTC
offset) plus ``n / fps``, plus ``vessel_offset_s`` for a vessel clock known to be off.

Camera attitude (``CameraMount``):

* ``gimbal``: the log's gimbal attitude (DJI ``G.PRY``), as is;
* ``stabilised``: a gimbal holding ``pitch_deg`` (−90: straight down) with no roll, its yaw the
  airframe's yaw, or ``yaw_deg`` where the log has no attitude (DJI SRTs mostly have none);
* ``rigid``: a camera fixed to the airframe, pitched ``pitch_deg`` about the body's right axis:
  ``R_NED<-G = R_NED<-B · Ry(pitch)``, whose ZYX Euler angles are written (scipy; at exactly
  −90° pitch the split between yaw and roll is arbitrary and the rotation still exact).

Accuracy: where a track states its own (:class:`Track`'s ``position_sigma_m``, ``alt_sigma_m``,
``heading_sigma_deg``), the frame carries the figure sampled at its time as the optional
``uav.position_sigma_m``, ``uav.alt_sigma_m``, ``vessel.position_sigma_m`` and
``vessel.heading_sigma_deg`` (:data:`~harborsight.geometry.sensor_sigmas.FRAME_SIGMA_FIELDS`),
which override the sensor-class defaults for that frame. A figure that is missing at that
time (NaN, or outside the frame's 0-1000 limit) is left out of the frame, never null.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from harborsight.errors import InputError, brief
from harborsight.geometry.sensor_sigmas import MAX_DEAD_RECKONED_S
from harborsight.telemetry.accuracy import MAX_SIGMA_M
from harborsight.telemetry.track import AT_REST_MPS, Track

MOUNTS = ("auto", "gimbal", "stabilised", "rigid")
#: the frame fields written from each track's accuracy figures: (section, key, track quantity)
UAV_SIGMA_FIELDS = (("uav", "position_sigma_m", "position_sigma_m"),
                    ("uav", "alt_sigma_m", "alt_sigma_m"))
VESSEL_SIGMA_FIELDS = (("vessel", "position_sigma_m", "position_sigma_m"),
                       ("vessel", "heading_sigma_deg", "heading_sigma_deg"))


@dataclass(frozen=True)
class CameraMount:
    mode: str = "auto"              # auto: gimbal where the log has one, else stabilised
    pitch_deg: float = -90.0
    yaw_deg: float | None = None    # a fixed camera yaw, for logs without attitude

    def resolve(self, drone: Track) -> str:
        if self.mode not in MOUNTS:
            raise ValueError(f"camera mount {self.mode!r}: expected one of {', '.join(MOUNTS)}")
        if self.mode == "auto":
            return "gimbal" if drone.attitude_of == "gimbal" else "stabilised"
        return self.mode


def camera_attitude_deg(drone: Track, samples: dict[str, np.ndarray], mount: CameraMount
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera yaw, pitch, roll (NED ZYX Euler, degrees) per sample; NaN where unknown."""
    n = len(samples["lat_deg"])
    mode = mount.resolve(drone)
    has_attitude = drone.has_attitude and "yaw_deg" in samples
    if mode == "gimbal":
        if mount.yaw_deg is not None:
            raise InputError(drone.source, "attitude", "the log gives the gimbal's yaw; a fixed "
                             "camera yaw is for logs without attitude (or a stabilised mount)")
        if drone.attitude_of != "gimbal":
            raise InputError(drone.source, "attitude", "the log has no gimbal attitude; use the "
                             "stabilised or rigid camera mount")
        return samples["yaw_deg"], samples["pitch_deg"], samples.get("roll_deg", np.zeros(n))
    if mount.yaw_deg is not None:
        yaw = np.full(n, float(mount.yaw_deg))
    elif has_attitude:
        yaw = samples["yaw_deg"]
    else:
        raise InputError(drone.source, "attitude", "the log has no attitude: give the camera's "
                         "yaw (degrees clockwise from true north)")
    if mode == "stabilised":
        return yaw, np.full(n, float(mount.pitch_deg)), np.zeros(n)
    if not has_attitude or drone.attitude_of != "vehicle":
        raise InputError(drone.source, "attitude", "a rigid mount needs the airframe's attitude "
                         "(PX4 vehicle_attitude or ArduPilot ATT)")
    body = np.column_stack([samples["yaw_deg"], samples["pitch_deg"], samples["roll_deg"]])
    out = np.full((n, 3), np.nan)
    finite = np.isfinite(body).all(axis=1)
    if finite.any():
        ned_from_body = Rotation.from_euler("ZYX", body[finite], degrees=True)
        mount_rotation = Rotation.from_euler("Y", float(mount.pitch_deg), degrees=True)
        with warnings.catch_warnings():     # gimbal lock at -90 deg: yaw absorbs the roll
            warnings.simplefilter("ignore", UserWarning)
            out[finite] = (ned_from_body * mount_rotation).as_euler("ZYX", degrees=True)
    return out[:, 0], out[:, 1], out[:, 2]


def parse_utc_time(text: str, field: str) -> datetime:
    """An ISO 8601 time (``Z`` for UTC; a time without a zone is taken as UTC) in UTC, for an
    option such as ``--video-start``. :class:`InputError` naming ``field`` if it is not ISO
    8601, or if in UTC it falls outside the years 1 to 9999 that a time can take
    (``9999-12-31T23:59:59-01:00`` is in the year 10000 in UTC)."""
    try:
        when = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except (AttributeError, ValueError):
        raise InputError(None, field, f"not an ISO 8601 time: {brief(text)}") from None
    if when.tzinfo is None:
        return when.replace(tzinfo=UTC)
    try:
        return when.astimezone(UTC)
    except OverflowError:
        raise InputError(None, field, f"{text.strip()} is before the year 1 or after 9999 in UTC"
                         ) from None


def camera_block_for(camera: str, width: int | None, height: int | None,
                     source: str | Path | None) -> dict:
    """A frame/1 ``camera`` block from a preset name (at the video's size) or a calibration
    file (which must be of the video's size, where that is known). :class:`InputError`
    naming ``--camera`` or the calibration otherwise."""
    from harborsight.geometry.calibration_files import load_camera_calibration
    from harborsight.sim.cameras import CAMERA_PRESETS

    if camera in CAMERA_PRESETS:
        if not width or not height:
            raise InputError(source, "size", f"camera preset {camera!r} needs the image size: "
                             "give --video or --image-size")
        intrinsics = CAMERA_PRESETS[camera].intrinsics(width, height)
        focal_35mm = CAMERA_PRESETS[camera].focal_35mm_mm
    else:
        focal_35mm = None
        if not Path(camera).is_file():
            raise InputError(camera, "--camera", "neither a camera preset ("
                             + ", ".join(CAMERA_PRESETS) + ") nor a calibration file")
        intrinsics = load_camera_calibration(Path(camera))
        if width and height and (intrinsics.width, intrinsics.height) != (width, height):
            raise InputError(camera, "calibration", f"calibrated for {intrinsics.width}x"
                             f"{intrinsics.height}, the video is {width}x{height}")
    block = {"width": intrinsics.width, "height": intrinsics.height, "fx": intrinsics.fx,
             "fy": intrinsics.fy, "cx": intrinsics.cx, "cy": intrinsics.cy,
             "distortion": list(intrinsics.distortion)}
    if focal_35mm is not None:      # not written to frames: what zoom_reason compares with
        block["focal_35mm_mm"] = focal_35mm
    return block


@dataclass
class FrameMetadataResult:
    frames: list[dict]                      # one harborsight.frame/1 object per usable frame
    skipped: list[tuple[int, str]]          # (frame index, "what: detail")
    mount: str

    @property
    def beyond_dead_reckoning(self) -> int:
        """Frames whose vessel pose is dead-reckoned past what is measured with
        (:data:`~harborsight.geometry.sensor_sigmas.MAX_DEAD_RECKONED_S`): `run` and `live`
        measure them where the frames before placed the vessel in the image."""
        return sum((frame["vessel"].get("dead_reckoned_s") or 0.0) > MAX_DEAD_RECKONED_S
                   for frame in self.frames)


def build_video_metadata(
    drone: Track, vessel: Track, camera: dict, n_frames: int, fps: float, *,
    water_level_m: float, mount: CameraMount = CameraMount(),
    video_start_utc: datetime | None = None, vessel_offset_s: float = 0.0,
    max_gap_s: float = 1.0, frame_times_s: np.ndarray | None = None,
) -> FrameMetadataResult:
    """One ``harborsight.frame/1`` dict per frame of the video (``frame_index`` keyed), with
    the drone and vessel sampled at the frame's time: ``frame_times_s[n]`` (its presentation
    time in the video, from the first frame's) when given, else ``n / fps``. A frame whose
    time falls outside a track or in a gap (:meth:`Track.sample`) is skipped with the
    reason. A naive ``video_start_utc`` is taken as UTC."""
    if n_frames < 1 or not (fps > 0):
        raise ValueError("need at least one frame and a positive frame rate")
    if frame_times_s is not None and len(frame_times_s) < n_frames:
        raise ValueError(f"{len(frame_times_s)} frame times for {n_frames} frames")
    if video_start_utc is not None and video_start_utc.tzinfo is None:
        video_start_utc = video_start_utc.replace(tzinfo=UTC)     # naive: taken as UTC
    if drone.alt_m is None:
        raise InputError(drone.source, "altitude", "the log has no altitude")
    video_s = (np.asarray(frame_times_s[:n_frames], float) if frame_times_s is not None
               else np.arange(n_frames) / fps)
    if drone.kind == "dji-srt":
        drone_t = video_s
        start_utc = video_start_utc or drone.utc_at(0.0)
    else:
        if video_start_utc is None:
            raise InputError(drone.source, None, "an autopilot log runs on its own clock: give "
                             "the video's start time in UTC to place the frames on it")
        if drone.utc_start is None:
            raise InputError(drone.source, "GPS time", "the log has no UTC time from its GPS")
        drone_t = drone.seconds_of(video_start_utc) + video_s
        start_utc = video_start_utc
    if start_utc is None:
        raise InputError(drone.source, "date", "the frames' UTC time is unknown (the SRT has no "
                         "date lines, or no UTC offset for them): give the video's start time in "
                         "UTC, or the offset of the SRT's local time")
    try:
        start_utc + timedelta(seconds=float(video_s[-1]))
    except OverflowError:
        source, field = ((None, "--video-start") if video_start_utc is not None
                         else (drone.source, "date"))
        raise InputError(source, field, f"the video starts at {start_utc.isoformat()} UTC and "
                         f"runs {video_s[-1]:g} s: its last frame falls after the year 9999"
                         ) from None
    utc = [start_utc + timedelta(seconds=float(s)) for s in video_s]
    vessel_t = np.array([vessel.seconds_of(u) for u in utc]) + vessel_offset_s
    return frames_at_times(drone, vessel, camera, drone_t, vessel_t, utc, water_level_m=water_level_m,
                           mount=mount, max_gap_s=max_gap_s)


def frames_at_times(
    drone: Track, vessel: Track, camera: dict, drone_t: np.ndarray, vessel_t: np.ndarray,
    utc: list[datetime], *, water_level_m: float, mount: CameraMount = CameraMount(),
    max_gap_s: float = 1.0, hold_s: float | None = None, indices: list[int] | None = None,
) -> FrameMetadataResult:
    """One ``harborsight.frame/1`` dict per time: the drone sampled at ``drone_t`` (its
    track's clock), the vessel at ``vessel_t`` (its clock), stamped ``utc``; ``frame_index``
    from ``indices`` (default 0, 1, ...). ``hold_s``: see :meth:`Track.sample`. A time
    without a usable sample is skipped with the reason."""
    n_frames = len(utc)
    indices = list(range(n_frames)) if indices is None else indices
    uav = drone.sample(drone_t, max_gap_s, hold_s)
    focal = uav.get("focal_35mm_mm")
    digital = uav.get("digital_zoom")
    reference_focal = camera.get("focal_35mm_mm") or _first_focal(drone)
    ship = vessel.sample(vessel_t, max_gap_s, hold_s)
    turn, turn_sigma = vessel.heading_rate(vessel_t)        # where the log gives no ROT
    yaw, pitch, roll = camera_attitude_deg(drone, uav, mount)
    frames, skipped = [], []
    for i in range(n_frames):
        missing = [name for name, value in (
            ("drone position", uav["lat_deg"][i]), ("drone altitude", uav["alt_m"][i]),
            ("camera attitude", yaw[i] + pitch[i] + roll[i]),
            ("vessel position", ship["lat_deg"][i]), ("vessel heading", ship["heading_deg"][i]),
        ) if not np.isfinite(value)]
        if missing:
            skipped.append((indices[i], f"no {', '.join(missing)}: none within reach of "
                                        f"{utc[i].isoformat()}"))
            continue
        zoomed = zoom_reason(None if focal is None else focal[i], reference_focal, camera)
        if zoomed:
            skipped.append((indices[i], zoomed))
            continue
        ratio = None if digital is None or not np.isfinite(digital[i]) else float(digital[i])
        if ratio is not None and ratio < 1.0 - ZOOM_TOLERANCE:
            skipped.append((indices[i], f"digital zoom {ratio:g}x in the log: below 1x, not a "
                                        "zoom this reader knows"))
            continue
        frame_camera = digitally_zoomed(camera, ratio or 1.0)
        height_m = uav["alt_m"][i] - water_level_m
        if height_m <= 0:
            skipped.append((indices[i], f"drone not above the water level: altitude "
                                        f"{uav['alt_m'][i]:.2f} m, water level {water_level_m:g} m"))
            continue
        frames.append({
            "schema": "harborsight.frame/1", "frame_index": indices[i],
            "timestamp": utc[i].isoformat().replace("+00:00", "Z"),
            "camera": frame_camera,
            "uav": {"lat": round(float(uav["lat_deg"][i]), 8), "lon": round(float(uav["lon_deg"][i]), 8),
                    "alt_m": round(float(uav["alt_m"][i]), 3)},
            "camera_attitude": {"yaw_deg": round(float(yaw[i]), 3), "pitch_deg": round(float(pitch[i]), 3),
                                "roll_deg": round(float(roll[i]), 3)},
            "vessel": {"lat": round(float(ship["lat_deg"][i]), 8),
                       "lon": round(float(ship["lon_deg"][i]), 8),
                       "heading_deg": round(float(ship["heading_deg"][i]) % 360.0, 3)},
            "water_level_m": water_level_m,
            "telemetry": {"drone": str(drone.source), "drone_t_s": round(float(drone_t[i]), 4),
                          "vessel": str(vessel.source), "vessel_t_s": round(float(vessel_t[i]), 4),
                          "alt_reference": drone.alt_reference},
        })
        if frame_camera["fx"] != camera["fx"]:
            frames[-1]["telemetry"]["digital_zoom"] = ratio
        frames[-1]["vessel"].update(own_motion_fields(ship, i, turn[i], turn_sigma[i]))
        reckoned_s = ship.get("dead_reckoned_s")
        if reckoned_s is not None and reckoned_s[i] > 0:   # between reports: the bars widen
            frames[-1]["vessel"]["dead_reckoned_s"] = round(float(reckoned_s[i]), 3)
        for samples, fields in ((uav, UAV_SIGMA_FIELDS), (ship, VESSEL_SIGMA_FIELDS)):
            for section, key, name in fields:
                value = _frame_sigma(samples.get(name), i)
                if value is not None:
                    frames[-1][section][key] = value
    return FrameMetadataResult(frames, skipped, mount.resolve(drone))


def own_motion_fields(ship: dict, i: int, heading_rate_deg_s: float = math.nan,
                      heading_rate_sigma_deg_s: float = math.nan) -> dict:
    """The vessel's ground velocity (east, north; m/s) from the speed and course over ground
    its log gives at sample ``i`` (NMEA RMC, AIS), and its rate of turn (NMEA ROT, AIS; else
    ``heading_rate_deg_s``, fitted to the headings, with its sigma), as frame fields
    (``velocity_en_mps``, ``yaw_rate_deg_s``, ``yaw_rate_sigma_deg_s``;
    :mod:`harborsight.clearance.own_motion` gives the rest their default sigmas). A speed at
    rest without a course is a velocity of 0."""
    fields: dict = {}
    sog, cog = ship.get("sog_mps"), ship.get("cog_deg")
    if sog is not None and np.isfinite(sog[i]) and sog[i] >= 0:
        if cog is not None and np.isfinite(cog[i]):
            course = math.radians(float(cog[i]))
            fields["velocity_en_mps"] = [round(float(sog[i]) * math.sin(course), 4),
                                         round(float(sog[i]) * math.cos(course), 4)]
        elif sog[i] < AT_REST_MPS:
            fields["velocity_en_mps"] = [0.0, 0.0]
    rot = ship.get("rot_deg_s")
    if rot is not None and np.isfinite(rot[i]):
        fields["yaw_rate_deg_s"] = round(float(rot[i]), 4)
    elif math.isfinite(heading_rate_deg_s) and math.isfinite(heading_rate_sigma_deg_s):
        fields["yaw_rate_deg_s"] = round(float(heading_rate_deg_s), 4)
        fields["yaw_rate_sigma_deg_s"] = round(float(heading_rate_sigma_deg_s), 4)
    return fields


#: how far a frame's focal length may differ from the camera's (a share)
ZOOM_TOLERANCE = 0.01


def _first_focal(drone: Track) -> float | None:
    """The log's first stated focal length (35 mm equivalent): what a calibration file is
    taken to hold for, when the camera block does not say."""
    if drone.focal_35mm_mm is None:
        return None
    values = drone.focal_35mm_mm
    stated = values[np.isfinite(values) & (values > 0)]
    return float(stated[0]) if len(stated) else None


def zoom_reason(focal_mm: float | None, reference_mm: float | None, camera: dict) -> str | None:
    """Why a frame cannot be measured with ``camera``: the log says the camera was zoomed to
    ``focal_mm`` (35 mm equivalent), and the intrinsics hold for ``reference_mm`` (a preset's
    24 mm, or the log's first value for a calibration file). A zoom of 2x halves every
    distance, and nothing in the picture says so; None when the two agree or either is
    unknown."""
    if (focal_mm is None or reference_mm is None or not np.isfinite(focal_mm)
            or focal_mm <= 0 or not reference_mm > 0):
        return None                 # unknown (a log's 0 is no focal length)
    if abs(focal_mm / reference_mm - 1.0) <= ZOOM_TOLERANCE:
        return None
    return (f"zoomed: focal_len {focal_mm:g} mm (35 mm equivalent) in the log, the camera's "
            f"intrinsics ({camera.get('fx', 0):.1f} px) hold for {reference_mm:g} mm; a zoomed "
            "frame needs intrinsics of its own")


def digitally_zoomed(camera: dict, ratio: float) -> dict:
    """The frame/1 camera block of a frame taken with a digital zoom of ``ratio``: a centre
    crop of ``1/ratio`` of the sensor, enlarged to the full frame, so a pixel ``u`` of the
    unzoomed image is at ``c + ratio (u - c)``, ``c = (width - 1) / 2`` (pixel centres at
    whole numbers): ``fx, fy`` times ``ratio``, ``cx`` and ``cy`` moved away from the centre
    by it. The distortion coefficients act on normalized coordinates, which the crop does not
    change, and stay. Within :data:`ZOOM_TOLERANCE` of 1x the block is the camera's."""
    block = {k: v for k, v in camera.items() if k != "focal_35mm_mm"}
    if abs(ratio - 1.0) <= ZOOM_TOLERANCE:
        return block
    centre_u, centre_v = (camera["width"] - 1) / 2.0, (camera["height"] - 1) / 2.0
    block.update(fx=camera["fx"] * ratio, fy=camera["fy"] * ratio,
                 cx=centre_u + ratio * (camera["cx"] - centre_u),
                 cy=centre_v + ratio * (camera["cy"] - centre_v))
    return block


def _frame_sigma(values: np.ndarray | None, i: int) -> float | None:
    """Sample ``i`` of a sampled accuracy figure, rounded for the frame; None where the track
    has none or it is missing there (NaN, or not within the frame's limits: above 0 and at most
    1000)."""
    if values is None or not (0.0 < values[i] <= MAX_SIGMA_M):
        return None
    return max(round(float(values[i]), 4), 0.0001)
